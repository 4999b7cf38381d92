"""ARX regressors in the observer form, shared by the batch fit and the recursive window.

The ARX model of paper Eq. (23) with q1 = q2 = q,

    y_k = B_0 u_k + sum_{i=1..q} (A_i y_{k-i} + B_i u_{k-i}) + eps_k,

is written with one regressor vector per sample

    phi_k = [u_k; v_{k-1}; v_{k-2}; ...; v_{k-q}],   v_j = [y_j; u_j],

of length ``d = m + q (p + m)``, so that ``y_k^T = phi_k^T Theta + eps_k^T`` with ``Theta`` of
shape ``(d, p)``. Rows ``Theta[:m]`` hold ``B_0^T = D^T`` and the rows of lag ``i`` hold
``[A_i, B_i]^T``. This ordering makes the regressor of sample ``k + 1`` a shift of that of
sample ``k``, which the recursive window relies on.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "regressor_length",
    "samples_for_order",
    "longest_given_order",
    "arx_regressors",
    "regressor_at",
    "valid_regressor_rows",
    "check_io_arrays",
    "real_array",
]

#: numpy dtype kinds a record array may have: bool, signed/unsigned integer, real float.
REAL_KINDS = "biuf"
_KIND_NAMES = {"c": "complex", "O": "object", "U": "string", "S": "bytes", "V": "structured", "M": "datetime",
               "m": "timedelta"}


def real_array(name: str, value: object) -> np.ndarray:
    """``value`` as a float64 array, or ValueError saying why it is not a real numeric array.

    ``np.asarray(value, dtype=float)`` alone would drop the imaginary part of a complex array
    (with a warning only) and parse numeric strings.
    """
    arr = np.asarray(value)
    if arr.dtype.kind not in REAL_KINDS:
        kind = _KIND_NAMES.get(arr.dtype.kind, str(arr.dtype))
        article = "an" if kind[0] in "aeiou" else "a"
        raise ValueError(f"{name} must hold real numbers, got {article} {kind} array (dtype {arr.dtype})")
    with np.errstate(over="ignore"):  # float128 beyond float64's range becomes inf, reported by the caller
        return arr.astype(float, copy=False)  # float64 as given, as np.asarray did: no copy per check


def regressor_length(order: int, n_outputs: int, n_inputs: int) -> int:
    """Length ``d = m + q (p + m)`` of one ARX regressor vector."""
    return n_inputs + order * (n_outputs + n_inputs)


def samples_for_order(order: int, n_outputs: int, n_inputs: int) -> int:
    """The fewest samples a given ARX ``order`` is fitted to: ``q`` lags, then ``d + 1`` rows for ``d`` coefficients."""
    return order + regressor_length(order, n_outputs, n_inputs) + 1


def longest_given_order(n_samples: int, n_outputs: int, n_inputs: int) -> int:
    """The largest ARX order :func:`samples_for_order` lets ``n_samples`` fit (below 2: none the realization takes)."""
    return max((n_samples - n_inputs - 1) // (1 + n_outputs + n_inputs), 0)


def check_io_arrays(u: np.ndarray, y: np.ndarray, *, allow_no_inputs: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Return ``u`` and ``y`` as 2-D float arrays ``(N, m)`` and ``(N, p)``, or raise ValueError.

    One-dimensional arrays are taken as a single channel. The reason names the offending array.
    ``allow_no_inputs``: ``u`` may have no columns (an output-only model, m = 0).
    """
    u, y = real_array("u", u), real_array("y", y)
    if u.ndim == 1:
        u = u[:, None]
    if y.ndim == 1:
        y = y[:, None]
    if u.ndim != 2 or y.ndim != 2:
        raise ValueError(f"u and y must be 2-D (N, channels); got u{u.shape}, y{y.shape}")
    if u.shape[0] != y.shape[0]:
        raise ValueError(
            f"u and y have different lengths: {u.shape[0]} and {y.shape[0]} samples"
        )
    if (u.shape[1] == 0 and not allow_no_inputs) or y.shape[1] == 0:
        raise ValueError(f"u and y need at least one channel each; got u{u.shape}, y{y.shape}")
    for name, arr in (("u", u), ("y", y)):
        if not np.all(np.isfinite(arr)):
            bad = np.argwhere(~np.isfinite(arr))[0]
            raise ValueError(f"{name} holds NaN or Inf (first at sample {bad[0]}, channel {bad[1]})")
    return u, y


def arx_regressors(
    u: np.ndarray, y: np.ndarray, order: int, valid: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stack the ARX regressors of a record.

    Parameters
    ----------
    u : (N, m) inputs.
    y : (N, p) outputs.
    order : ARX order q >= 1.
    valid : (N,) bool, optional
        Samples to trust. A row ``k`` is used only if samples ``k - q .. k`` are all valid, so
        that no regressor mixes data across a gap.

    Returns
    -------
    phi : (M, d) regressor rows ``phi_k^T``.
    targets : (M, p) the outputs ``y_k^T`` of the same rows.
    rows : (M,) the sample indices ``k`` of the rows.
    """
    if order < 1:
        raise ValueError(f"ARX order must be >= 1, got {order}")
    n_samples, m = u.shape
    p = y.shape[1]
    rows = valid_regressor_rows(n_samples, order, valid)
    v = np.hstack([y, u])  # (N, p + m)
    d = regressor_length(order, p, m)
    phi = np.empty((rows.size, d))
    phi[:, :m] = u[rows]
    w = p + m
    for lag in range(1, order + 1):
        phi[:, m + (lag - 1) * w : m + lag * w] = v[rows - lag]
    return phi, y[rows], rows


def valid_regressor_rows(n_samples: int, order: int, valid: np.ndarray | None = None) -> np.ndarray:
    """Indices ``k`` whose samples ``k - order .. k`` are all present (and valid)."""
    if valid is None:
        return np.arange(order, n_samples)
    valid = np.asarray(valid, dtype=bool)
    # Length of the run of consecutive valid samples that ends at each index: the distance to
    # the last invalid sample at or before it.
    index = np.arange(n_samples)
    last_invalid = np.maximum.accumulate(np.where(valid, -1, index))
    return np.flatnonzero(index - last_invalid >= order + 1)


def regressor_at(u: np.ndarray, y: np.ndarray, k: int, order: int) -> np.ndarray:
    """The single regressor ``phi_k`` (d,) of sample ``k`` (needs ``k >= order``)."""
    if k < order:
        raise ValueError(f"sample {k} has fewer than {order} past samples")
    v = np.hstack([y[k - order : k], u[k - order : k]])[::-1]  # rows: lag 1 .. q
    return np.concatenate([u[k], v.ravel()])
