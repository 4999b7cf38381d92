"""The ARX normal equations and predictions of a record from lagged products of its samples.

The regressor rows ``phi_k = [u_k; v_{k-1}; ..; v_{k-q}]`` (:mod:`okid_ros.core.regressors`)
repeat every sample ``q + 1`` times, so the matrix of rows holds ``(N - q) (m + q w)`` numbers
(``w = p + m``) and its Gram costs ``2 N d^2`` flops. Every block of that Gram is a lagged
product of the samples, ``sum_k s_{k-i} s_{k-j}^T`` with ``s_t = [y_t; u_t]``, which is the
whole-record product ``sum_t s_t s_{t-(j-i)}^T`` less at most ``q`` terms at each end:
``2 N q w^2`` flops and no row matrix (100x fewer flops at the paper's size, q = 100).

:func:`arx_normal_equations` equals ``normal_equations(*arx_regressors(u, y, q, valid)[:2])``
and :func:`arx_regressor_product` equals ``arx_regressors(u, y, q)[0] @ theta``, to rounding
(``test/core/test_arx_gram.py``). No library forms these sums: statsmodels' VAR and SIPPY's ARX
build the row matrix as :func:`~okid_ros.core.regressors.arx_regressors` does.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.least_squares import NormalEquations
from okid_ros.core.regressors import valid_regressor_rows

__all__ = ["arx_normal_equations", "arx_regressor_product", "lagged_gram", "segment_lagged_gram",
           "segment_lagged_grams"]

#: Below this many rows per lag a run of samples is summed from its row matrix (the end
#: corrections would be most of the work).
MIN_ROWS_PER_LAG = 4


def lagged_gram(u: np.ndarray, y: np.ndarray, order: int, valid: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gram and column sums of the lagged sample vectors ``z_k = [s_k; s_{k-1}; ..; s_{k-q}]``.

    ``s_k = [y_k; u_k]``, summed over the rows ``k`` of
    :func:`~okid_ros.core.regressors.arx_regressors`: ``z_k`` is ``[y_k; phi_k]``, the target
    and the regressor of row k side by side.

    Parameters
    ----------
    u : (N, m) inputs (m may be 0: a vector autoregression); y : (N, p) outputs.
    order : ARX order q >= 1.
    valid : (N,) bool, optional: a row only where its samples ``k - q .. k`` are all valid.

    Returns
    -------
    gram : ((q + 1) w, (q + 1) w) ``sum_k z_k z_k^T``, ``w = p + m``.
    sums : ((q + 1) w,) ``sum_k z_k``.
    rows : (M,) the sample indices k summed.
    """
    if order < 1:
        raise ValueError(f"ARX order must be >= 1, got {order}")
    u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
    s = np.hstack([y, u])
    rows = valid_regressor_rows(u.shape[0], order, valid)
    size = (order + 1) * s.shape[1]
    gram, sums = np.zeros((size, size)), np.zeros(size)
    # Runs of consecutive rows: each a contiguous stretch of samples, summed on its own.
    for run in np.split(rows, np.flatnonzero(np.diff(rows) != 1) + 1) if rows.size else []:
        part_gram, part_sums = _run_gram(s[int(run[0]) - order : int(run[-1]) + 1], order)
        gram += part_gram
        sums += part_sums
    return gram, sums, rows


def segment_lagged_grams(u: np.ndarray, y: np.ndarray, order: int, bounds: np.ndarray,
                         valid: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """:func:`lagged_gram` of the rows ``k`` in each segment ``bounds[j] <= k < bounds[j + 1]``.

    The segments partition the rows of ``lagged_gram(u, y, order, valid)``: their Grams and sums
    add up to it (each row's lagged samples are read whatever segment they fall in).

    Returns
    -------
    One ``(gram, sums, n_rows)`` per segment (:func:`segment_lagged_gram`).
    """
    return [segment_lagged_gram(u, y, order, (lo, hi), valid) for lo, hi in zip(bounds[:-1], bounds[1:])]


def segment_lagged_gram(u: np.ndarray, y: np.ndarray, order: int, segment: tuple[int, int],
                        valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """:func:`lagged_gram` of the rows ``k`` with ``lo <= k < hi`` (``segment = (lo, hi)``).

    One segment at a time: a caller that needs each segment's Gram once holds one of them,
    not one per segment (tens of them of tens of megabytes at many outputs).

    Returns
    -------
    gram, sums : as :func:`lagged_gram`; n_rows : the rows summed.
    """
    n_samples = np.shape(y)[0]
    present = np.ones(n_samples, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    lo, hi = int(segment[0]), int(segment[1])
    # Samples lo - q .. hi - 1: exactly the rows lo .. hi - 1 have their whole past in them.
    inside = np.zeros(n_samples, dtype=bool)
    inside[max(lo - order, 0) : hi] = True
    gram, sums, rows = lagged_gram(u, y, order, present & inside)
    return gram, sums, int(rows.size)


def arx_normal_equations(u: np.ndarray, y: np.ndarray, order: int, valid: np.ndarray | None = None
                         ) -> NormalEquations:
    """``Phi^T Phi``, ``Phi^T Y``, ``Y^T Y`` and the column sums of the ARX rows of a record.

    Parameters
    ----------
    u : (N, m) inputs (m may be 0); y : (N, p) outputs; order : ARX order q >= 1.
    valid : (N,) bool, optional, as :func:`~okid_ros.core.regressors.arx_regressors`.

    Returns
    -------
    NormalEquations with ``R`` (d, d), ``r`` (d, p), ``yy`` (p, p), the row count and the
    column sums, ``d = m + q (p + m)``.
    """
    gram, sums, rows = lagged_gram(u, y, order, valid)
    p = np.shape(y)[1]
    # z_k = [y_k; phi_k]: the targets first, then the regressor [u_k; v_{k-1}; ..; v_{k-q}].
    return NormalEquations(gram[p:, p:].copy(), gram[p:, :p].copy(), gram[:p, :p].copy(), rows.size,
                           sums[p:].copy(), sums[:p].copy())


def arx_regressor_product(u: np.ndarray, y: np.ndarray, order: int, theta: np.ndarray) -> np.ndarray:
    """``Phi Theta`` (N - q, p) for the rows of a contiguous record, ``theta`` (d, p).

    The one-step ARX prediction of samples ``q .. N-1`` (no intercept), one product per lag.
    """
    m, p = u.shape[1], y.shape[1]
    w = p + m
    n_rows = u.shape[0] - order
    out = u[order:] @ theta[:m]
    v = np.hstack([y, u])
    for lag in range(1, order + 1):
        out += v[order - lag : order - lag + n_rows] @ theta[m + (lag - 1) * w : m + lag * w]
    return out


def _run_gram(s: np.ndarray, q: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`lagged_gram` of one contiguous stretch ``s`` (L, w): the rows ``q .. L-1``."""
    n_samples, w = s.shape
    if n_samples - q < MIN_ROWS_PER_LAG * q + q:
        index = np.arange(q, n_samples)[:, None] - np.arange(q + 1)[None, :]
        z = s[index].reshape(n_samples - q, (q + 1) * w)
        return z.T @ z, z.sum(axis=0)
    return _lagged_gram(s, q)


def _lagged_gram(s: np.ndarray, q: int) -> tuple[np.ndarray, np.ndarray]:
    """Gram ((q+1) w, (q+1) w) and column sums ((q+1) w,) of ``z_k = [s_k; ..; s_{k-q}]``, k = q..L-1.

    Block (i, j), i <= j, is ``sum_{t = q-i}^{L-1-i} s_t s_{t-d}^T`` with ``d = j - i``: the
    whole-record lag product ``T_d = sum_{t=d}^{L-1} s_t s_{t-d}^T`` less the ``q - j`` terms
    before ``t = q - i`` and the ``i`` terms from ``t = L - i`` on.
    """
    n_samples, w = s.shape
    lags = np.arange(q + 1)
    whole = np.stack([s[d:].T @ s[: n_samples - d] for d in lags])  # (q+1, w, w): T_d
    # head[d, t] = s_t s_{t-d}^T for t < q (zero where t < d), summed over t = d..t.
    head = np.zeros((q + 1, q, w, w))
    # tail[d, r] = s_t s_{t-d}^T at t = L-1-r, summed over r' = 0..r (t = L-1-r .. L-1).
    tail = np.empty((q + 1, q, w, w))
    for d in lags:
        head[d, d:] = s[d:q, :, None] * s[: q - d, None, :]
        t = n_samples - 1 - np.arange(q)
        tail[d] = s[t, :, None] * s[t - d, None, :]
    head = np.cumsum(head, axis=1)
    tail = np.cumsum(tail, axis=1)
    i, j = np.triu_indices(q + 1)
    d = j - i
    blocks = whole[d].copy()
    before = q - i - 1  # the last head term's t (none when negative)
    has_head = before >= 0
    blocks[has_head] -= head[d[has_head], before[has_head]]
    has_tail = i >= 1
    blocks[has_tail] -= tail[d[has_tail], i[has_tail] - 1]
    gram = np.empty((q + 1, q + 1, w, w))
    gram[i, j] = blocks
    gram[j, i] = blocks.transpose(0, 2, 1)
    gram = gram.transpose(0, 2, 1, 3).reshape((q + 1) * w, (q + 1) * w)
    # Column sums: sum_{k=q}^{L-1} s_{k-i} = sum_{t=q-i}^{L-1-i} s_t.
    cumulative = np.vstack([np.zeros((1, w)), np.cumsum(s, axis=0)])
    sums = (cumulative[n_samples - lags] - cumulative[q - lags]).reshape(-1)
    return gram, sums
