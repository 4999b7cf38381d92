"""Standard deviations of each identified mode's frequency and damping ratio.

First-order (delta-method) propagation of the prediction-error parameter covariance:

1. The model's one-step predictor ``xhat+ = Abar xhat + [L, Bbar] v``, ``yhat = C xhat + D u``
   (``Abar = A - L C``, ``L = A K``, ``v = [y; u]``) is written in complex-diagonal coordinates,
   the parametrization of :mod:`okid_ros.core.refine` (a pole pair ``lambda`` with input row
   ``g`` and output column ``c`` adds ``2 Re(c xi)``, ``xi+ = lambda xi + g^T v``). One
   component of each ``c`` (the largest) is held fixed: it removes the free complex scale of
   each ``xi``, which the predictor does not see, so the information matrix is regular.
2. The Jacobian ``J`` of the one-step predictions is analytic (one recursive filter per pole).
   The refinement minimizes the *unweighted* sum of squared prediction errors, so the
   parameter covariance is the sandwich ``cov(theta) = H^-1 M H^-1`` with ``H = sum_k J_k^T
   J_k`` and ``M = sum_k J_k^T Re J_k``, ``Re`` the covariance of the prediction errors
   (``M = H Re`` for one output; ``(J^T Re^-1 J)^-1`` when ``Re`` is a multiple of I).
3. The modes are the eigenvalues ``mu`` of ``A = Abar + L C``; their first-order derivatives
   with respect to every parameter are ``chi dA psi`` (left/right eigenvectors), then ``s =
   ln(mu) / dt``, ``frequency_hz = |s| / 2 pi``, ``damping_ratio = -Re(s) / |s|``.

The standard deviations describe the scatter of an estimator that reaches the prediction-error
optimum on records like this one; they do not cover a bias from a wrong model order or from
data the model class cannot describe. Calibration against simulated truth:
``bench/mode_uncertainty.py`` and ``docs/benchmarks-uncertainty.md``.

Cost: ``H`` and ``M`` take about ``2 N p P^2`` flops for ``P`` parameters
(``P = n (2 p + m) + p m``); the paper case (n = 8, p = m = 2, N = 3750) needs ~4e7. When
``2 N p P^2`` exceeds ``max_flops`` the rows are subsampled evenly (an unbiased estimate of the
information; the same when the Jacobian would exceed ``MAX_JACOBIAN_ENTRIES``), and when fewer
than ``MIN_ROWS_PER_PARAMETER`` rows per parameter would remain
(tens of outputs, where ``P`` is in the thousands) the standard deviations are left NaN
(``null`` in JSON) with the reason returned; the identification chain then measures them by a
jackknife instead (:mod:`okid_ros.core.mode_jackknife`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, signal

from okid_ros.core.regressors import check_io_arrays
from okid_ros.core.statespace import split_poles

__all__ = ["UncertaintyResult", "attach_mode_uncertainty", "n_parameters", "steady_poles", "noisy_poles", "same_pole",
           "uncertainty_problem", "DEFAULT_MAX_FLOPS", "STEADY_STD_PER_WIDTH", "NOISY_STD_PER_WIDTH"]

#: Budget for forming H and M (2 N p P^2 flops); 1e9 is ~0.1-0.3 s here.
DEFAULT_MAX_FLOPS = 1e9
#: Cap on the Jacobian's entries (rows x outputs x parameters; 2e7 doubles = 160 MB).
MAX_JACOBIAN_ENTRIES = 20_000_000
#: Below this many residual rows per parameter the information estimate is too rough.
MIN_ROWS_PER_PARAMETER = 10
DEFAULT_BURN_IN = 100

#: A mode the stabilization diagram does not confirm is still physical when its standard
#: deviations put its pole this precisely (:func:`steady_poles`, used by the pipeline):
#: neighbouring orders can lose a well-resolved mode (its damping jumping between 1.4 and 5 %
#: from order to order) without it being any less sure. Measured on 180 random structures with
#: a measured input (``okid_bench.cases.random_case``; docs/benchmarks-realization.md): of the
#: modes only the diagram refused, those up to 0.1 were all true (10 of 10, within 0.4 %); the
#: first wrong one scattered 0.136 (1 % off, damping 3x), the first spurious one 0.175.
STEADY_STD_PER_WIDTH = 0.1

#: A mode whose frequency standard deviation exceeds this many half-power half-widths is not
#: listed (:func:`noisy_poles`, used by the pipeline): the data do not place its pole within its
#: own resonance, the mark of a pole fitting noise (the output-only chain drops them by the same
#: measure of its jackknife scatter). The width is ``zeta f``, but at least the record's
#: resolution ``1 / T``: a lightly damped mode barely decaying within the record has a width
#: below what the record resolves. Measured (docs/benchmarks-realization.md): the 1674 true modes
#: listed on the simulated cases and 240 random structures at most 1.06, the spurious modes of
#: the many-outputs case 2.6-5.7.
NOISY_STD_PER_WIDTH = 2.0


@dataclass
class UncertaintyResult:
    """What :func:`attach_mode_uncertainty` did.

    Attributes
    ----------
    computed : the modes' ``frequency_hz_std`` and ``damping_ratio_std`` were filled.
    reason : why not (empty when computed).
    n_parameters : predictor parameters in the covariance (gauge-fixed).
    rows_used : residual rows (samples x outputs) in the information matrix.
    method : how they were computed: "prediction-error covariance" (this module) or
        "jackknife" (:mod:`okid_ros.core.mode_jackknife`, where this module's cost is out of reach).
    """

    computed: bool
    reason: str = ""
    n_parameters: int = 0
    rows_used: int = 0
    method: str = "prediction-error covariance"


def _set_nan(modes: list) -> None:
    for mode in modes:
        mode.frequency_hz_std = float("nan")
        mode.damping_ratio_std = float("nan")


class _Layout:
    """Column positions of the gauge-fixed parameters.

    Per pair: Re lambda, Im lambda, Re g (w), Im g (w), Re c (p), Im c (p) without the fixed
    component ``ref``; per real pole: lambda, g (w), c (p) without ``ref``; then D (p m).
    """

    def __init__(self, pair_refs: list[int], real_refs: list[int], p: int, m: int) -> None:
        w = p + m
        self.p, self.m, self.w = p, m, w
        pos = 0
        self.pairs = []
        for ref in pair_refs:
            keep = np.array([k for k in range(p) if k != ref], dtype=int)
            cols = {"lam": pos, "g_re": pos + 2, "g_im": pos + 2 + w, "c_re": pos + 2 + 2 * w,
                    "c_im": pos + 2 + 2 * w + keep.size, "keep": keep}
            pos += 2 + 2 * w + 2 * keep.size
            self.pairs.append(cols)
        self.reals = []
        for ref in real_refs:
            keep = np.array([k for k in range(p) if k != ref], dtype=int)
            self.reals.append({"lam": pos, "g": pos + 1, "c": pos + 1 + w, "keep": keep})
            pos += 1 + w + keep.size
        self.d = pos
        self.size = pos + p * m


def _jacobian_and_residuals(pairs: tuple, reals: tuple, D, layout: _Layout, *,
                            u: np.ndarray, y: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``d yhat / d theta`` at the sample indices ``rows``: (R, p, P), and the residuals (R, p).

    ``pairs`` and ``reals``: (poles, input residues, output shapes) of the complex pairs (upper
    halves) and of the real poles.
    """
    lam_pairs, g_pairs, c_pairs = pairs
    lam_reals, g_reals, c_reals = reals
    p, m = layout.p, layout.m
    v = np.hstack([y, u])
    J = np.zeros((rows.size, p, layout.size))
    y_hat = u[rows] @ D.T
    for lam, g, c, cols in zip(lam_pairs, g_pairs, c_pairs, layout.pairs):
        f = signal.lfilter([0.0, 1.0], [1.0, -lam], v, axis=0)[rows]  # (R, w) d xi / d g
        dxi = signal.lfilter([0.0, 0.0, 1.0], [1.0, -2.0 * lam, lam * lam], v @ g)[rows]
        xi = f @ g
        y_hat += 2.0 * np.real(np.outer(xi, c))
        cd = np.outer(dxi, c)  # (R, p)
        J[:, :, cols["lam"]] = 2.0 * cd.real
        J[:, :, cols["lam"] + 1] = -2.0 * cd.imag
        cf = f[:, None, :] * c[None, :, None]  # (R, p, w)
        J[:, :, cols["g_re"] : cols["g_re"] + layout.w] = 2.0 * cf.real
        J[:, :, cols["g_im"] : cols["g_im"] + layout.w] = -2.0 * cf.imag
        for i, k in enumerate(cols["keep"]):
            J[:, k, cols["c_re"] + i] = 2.0 * xi.real
            J[:, k, cols["c_im"] + i] = -2.0 * xi.imag
    for lam, g, c, cols in zip(lam_reals, g_reals, c_reals, layout.reals):
        f = signal.lfilter([0.0, 1.0], [1.0, -lam], v, axis=0)[rows]
        dxi = signal.lfilter([0.0, 0.0, 1.0], [1.0, -2.0 * lam, lam * lam], v @ g)[rows]
        xi = f @ g
        y_hat += np.outer(xi, c)
        J[:, :, cols["lam"]] = np.outer(dxi, c)
        J[:, :, cols["g"] : cols["g"] + layout.w] = f[:, None, :] * c[None, :, None]
        for i, k in enumerate(cols["keep"]):
            J[:, k, cols["c"] + i] = xi
    for k in range(p):
        J[:, k, layout.d + k * m : layout.d + (k + 1) * m] = u[rows]
    return J, y[rows] - y_hat


def _eigenvalue_gradient(a: np.ndarray, b: np.ndarray, C_c: np.ndarray, L_c: np.ndarray, n_pairs: int,
                         layout: _Layout) -> np.ndarray:
    """Complex gradient (P,) of one eigenvalue of ``A_c = diag(lambda) + L_c C_c``.

    ``a`` (row) and ``b`` (column) are its left and right eigenvectors with ``a b = 1``; the
    complex states are ordered [pairs, their conjugates, real poles].
    """
    p = layout.p
    grad = np.zeros(layout.size, dtype=complex)
    Cb = C_c @ b  # (p,)
    aL = a @ L_c  # (p,)
    for i, cols in enumerate(layout.pairs):
        j = i + n_pairs  # the conjugate state
        s_ab, d_ab = a[i] * b[i] + a[j] * b[j], a[i] * b[i] - a[j] * b[j]
        grad[cols["lam"]] = s_ab
        grad[cols["lam"] + 1] = 1j * d_ab
        grad[cols["g_re"] : cols["g_re"] + p] = (a[i] + a[j]) * Cb
        grad[cols["g_im"] : cols["g_im"] + p] = 1j * (a[i] - a[j]) * Cb
        keep = cols["keep"]
        grad[cols["c_re"] : cols["c_re"] + keep.size] = aL[keep] * (b[i] + b[j])
        grad[cols["c_im"] : cols["c_im"] + keep.size] = 1j * aL[keep] * (b[i] - b[j])
    for r, cols in enumerate(layout.reals):
        j = 2 * n_pairs + r
        grad[cols["lam"]] = a[j] * b[j]
        grad[cols["g"] : cols["g"] + p] = a[j] * Cb
        keep = cols["keep"]
        grad[cols["c"] : cols["c"] + keep.size] = aL[keep] * b[j]
    return grad


def attach_mode_uncertainty(
    model,
    u: np.ndarray,
    y: np.ndarray,
    *,
    burn_in: int | None = None,
    max_flops: float = DEFAULT_MAX_FLOPS,
) -> UncertaintyResult:
    """Fill ``frequency_hz_std`` and ``damping_ratio_std`` of every mode in ``model.modes``.

    Parameters
    ----------
    model : an identified innovation model with ``A`` (n, n), ``B`` (n, m), ``C`` (p, n),
        ``D`` (p, m), ``K`` (n, p) (paper convention, predictor gain ``A K``),
        ``sample_time_s`` and ``modes`` (each with ``eigenvalue``), e.g.
        :class:`okid_ros.core.pipeline.IdentifiedModel`.
    u : (N, m); y : (N, p) the record the model was identified from (an output-only model,
        m = 0: ``u`` of shape (N, 0)).
    burn_in : first samples left out (the predictor starts from zero); default the ARX order
        ``model.arx.order`` if there is one, else 100, at most N / 4.
    max_flops : budget for the information matrices (see the module docstring).

    Returns
    -------
    :class:`UncertaintyResult`; when not computed, both standard deviations are NaN.
    """
    modes = list(model.modes)
    A, B, C, D, K = (np.asarray(getattr(model, k), dtype=float) for k in ("A", "B", "C", "D", "K"))
    u, y = check_io_arrays(u, y, allow_no_inputs=B.shape[1] == 0)
    n, p, m = A.shape[0], C.shape[0], B.shape[1]
    if not modes:
        return UncertaintyResult(True)
    if u.shape[0] != y.shape[0] or u.shape[1] != m or y.shape[1] != p:
        _set_nan(modes)
        return UncertaintyResult(False, f"record u{u.shape}, y{y.shape} does not fit the model (m={m}, p={p})")
    if burn_in is None:
        burn_in = int(getattr(getattr(model, "arx", None), "order", DEFAULT_BURN_IN))
    # Before the eigendecomposition: the parameter count is n (2 p + m) + p m whatever the poles.
    size = n_parameters(n, p, m)
    rows = _sample_rows(y.shape[0], burn_in, p=p, n_states=n, n_parameters=size, max_flops=max_flops)
    if isinstance(rows, str):
        _set_nan(modes)
        return UncertaintyResult(False, rows, size)
    predictor = _diagonal_predictor(A, B, C, D, K)
    if isinstance(predictor, str):
        _set_nan(modes)
        return UncertaintyResult(False, predictor)
    lam, upper, real, G, Cw = predictor
    layout = _Layout([int(np.argmax(np.abs(Cw[:, i]))) for i in upper],
                     [int(np.argmax(np.abs(Cw[:, i]))) for i in real], p, m)
    J, residuals = _jacobian_and_residuals(
        (lam[upper], G[upper], Cw[:, upper].T), (lam[real].real, G[real].real, Cw[:, real].real.T), D, layout,
        u=u, y=y, rows=rows,
    )
    cov = _parameter_covariance(J, residuals, stride=int(rows[1] - rows[0]) if rows.size > 1 else 1)
    _propagate_to_modes(modes, cov, predictor, layout, p=p, sample_time_s=float(model.sample_time_s))
    return UncertaintyResult(True, "", layout.size, int(rows.size * p))


def n_parameters(n_states: int, p: int, m: int) -> int:
    """Gauge-fixed predictor parameters: ``2 p + m`` per state, and ``p m`` for ``D``.

    A pole pair has 2 for lambda, 2 (p + m) for g and 2 (p - 1) for c; a real pole half that.
    """
    return n_states * (2 * p + m) + p * m


def uncertainty_problem(n_states: int, p: int, m: int, n_samples: int, *, burn_in: int,
                        max_flops: float = DEFAULT_MAX_FLOPS) -> str:
    """Why :func:`attach_mode_uncertainty` would not compute a model's standard deviations ("" if it would)."""
    rows = _sample_rows(n_samples, burn_in, p=p, n_states=n_states, n_parameters=n_parameters(n_states, p, m),
                        max_flops=max_flops)
    return rows if isinstance(rows, str) else ""


def steady_poles(modes: list) -> list[complex]:
    """Eigenvalues of the modes whose standard deviations (NaN: not computed) say the pole is steady.

    Steady: frequency std at most :data:`STEADY_STD_PER_WIDTH` times ``zeta f`` and damping std
    at most that times ``zeta``.
    """
    return [mode.eigenvalue for mode in modes
            if mode.frequency_hz_std <= STEADY_STD_PER_WIDTH * mode.damping_ratio * mode.frequency_hz
            and mode.damping_ratio_std <= STEADY_STD_PER_WIDTH * mode.damping_ratio]


def noisy_poles(modes: list, record_s: float) -> list[complex]:
    """Eigenvalues of the modes whose frequency standard deviation says the pole is noise.

    Noisy: frequency std above :data:`NOISY_STD_PER_WIDTH` times ``max(zeta f, 1 / record_s)``
    (NaN standard deviations: never).

    Parameters
    ----------
    modes : identified modes with ``eigenvalue``, ``frequency_hz``, ``damping_ratio`` and
        ``frequency_hz_std``.
    record_s : length of the record the modes were identified from [s].
    """
    floor = 1.0 / record_s
    return [mode.eigenvalue for mode in modes
            if mode.frequency_hz_std > NOISY_STD_PER_WIDTH * max(mode.damping_ratio * mode.frequency_hz, floor)]


def same_pole(eigenvalue: complex, others: list[complex]) -> bool:
    """Whether ``eigenvalue`` is one of ``others`` (eigenvalues of the same A, computed again)."""
    return any(abs(eigenvalue - other) <= 1e-9 * max(1.0, abs(other)) for other in others)


def _diagonal_predictor(A, B, C, D, K) -> tuple | str:
    """The predictor ``A - A K C`` in its eigenbasis: (poles, upper pairs, reals, G, C W), or why not."""
    L = A @ K
    lam, W = linalg.eig(A - L @ C)
    upper, real = split_poles(lam)
    if 2 * upper.size + real.size != A.shape[0] or np.max(np.abs(lam)) >= 1.0:
        return "the predictor has repeated or unstable poles"
    try:
        W_inv = linalg.inv(W)
    except linalg.LinAlgError:
        return "the predictor is not diagonalizable"
    return lam, upper, real, W_inv @ np.hstack([L, B - L @ D]), C @ W  # G: rows g (n, w); C W: columns c


def _sample_rows(n_samples: int, burn_in: int, *, p: int, n_states: int, n_parameters: int,
                 max_flops: float) -> np.ndarray | str:
    """The sample indices the information matrices use (every ``stride``-th), or why there are too few."""
    P = n_parameters
    burn_in = int(min(max(burn_in, 0), n_samples // 4))
    available = n_samples - burn_in
    max_samples = int(min(max_flops / (2.0 * p * P * P), MAX_JACOBIAN_ENTRIES / (p * P)))
    if max_samples * p < MIN_ROWS_PER_PARAMETER * P or available * p < MIN_ROWS_PER_PARAMETER * P:
        need = 2.0 * min(available, max(max_samples, 1)) * p * P * P
        return (f"not computed: {P} predictor parameters ({p} outputs, {n_states} states) need more than "
                f"{MIN_ROWS_PER_PARAMETER} residuals per parameter within the budget of {max_flops:.0e} flops "
                f"({need:.1e} for the rows available)")
    stride = max(1, int(np.ceil(available / max_samples)))
    return np.arange(burn_in, n_samples, stride)


def _parameter_covariance(J: np.ndarray, residuals: np.ndarray, *, stride: int) -> np.ndarray:
    """Sandwich covariance ``H^-1 M H^-1`` of the predictor parameters from the Jacobian (R, p, P)."""
    rows, p, P = J.shape
    innovation_cov = residuals.T @ residuals / rows
    Jf = J.reshape(rows * p, P)
    H = Jf.T @ Jf
    chol = linalg.cholesky(innovation_cov + 1e-300 * np.eye(p), lower=True)  # Re = chol chol^T
    Jw = np.einsum("ij,rip->rjp", chol, J).reshape(rows * p, P)
    M = Jw.T @ Jw
    # Subsampled rows stand for ``stride`` samples each.
    H *= stride
    M *= stride
    scale = np.sqrt(np.maximum(np.diag(H), 1e-300))
    evals, evecs = linalg.eigh(H / np.outer(scale, scale))
    keep = evals > 1e-12 * evals.max()
    H_inv = ((evecs[:, keep] / evals[keep]) @ evecs[:, keep].T) / np.outer(scale, scale)
    return H_inv @ M @ H_inv


def _propagate_to_modes(modes: list, cov: np.ndarray, predictor: tuple, layout: "_Layout", *, p: int,
                        sample_time_s: float) -> None:
    """Each mode's frequency and damping standard deviations from the parameters' covariance."""
    lam, upper, real, G, Cw = predictor
    # Eigenvalues of A in the complex coordinates [pairs, conjugates, reals].
    lam_c = np.concatenate([lam[upper], np.conj(lam[upper]), lam[real].real])
    L_c = np.vstack([G[upper, :p], np.conj(G[upper, :p]), G[real, :p].real])
    C_c = np.hstack([Cw[:, upper], np.conj(Cw[:, upper]), Cw[:, real].real])
    mu, R = linalg.eig(np.diag(lam_c) + L_c @ C_c)
    Lf = linalg.inv(R)
    dt = sample_time_s
    for mode in modes:
        j = int(np.argmin(np.abs(mu - complex(mode.eigenvalue))))
        grad_mu = _eigenvalue_gradient(Lf[j], R[:, j], C_c, L_c, upper.size, layout)
        z = mu[j]
        s = np.log(z) / dt
        w = abs(s)
        ds = grad_mu / (z * dt)
        dw = np.real(np.conj(s) * ds) / w
        d_freq = dw / (2.0 * np.pi)
        d_zeta = -np.real(ds) / w + s.real * dw / w**2
        mode.frequency_hz_std = float(np.sqrt(max(d_freq @ cov @ d_freq, 0.0)))
        mode.damping_ratio_std = float(np.sqrt(max(d_zeta @ cov @ d_zeta, 0.0)))
