"""Regularized least squares from normal equations: the solver behind the ARX fits (paper Eq. 23).

The window's sufficient statistics (:class:`NormalEquations`), the prior precision of the
coefficients (ridge or tuned/correlated kernel), the GCV choice of the penalty and the fixed-penalty
solve used by the recursive window. See :mod:`okid_ros.core.arx` for the model and its conventions;
split from it so each module keeps to one concern.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import linalg, optimize

from okid_ros.core.regressors import regressor_length
from okid_ros.core.symmetric_eigen import SymmetricEigen

__all__ = [
    "NEGLIGIBLE_RELATIVE_SPREAD",
    "NormalEquations",
    "center_normal_equations",
    "constant_columns",
    "channel_mean_square",
    "normal_equations",
    "prior_precision",
    "residual_covariance",
    "scaled_condition_number",
    "solve_fixed_penalty",
    "solve_normal_equations",
]


@dataclass
class NormalEquations:
    """Sufficient statistics of a least-squares window.

    Attributes
    ----------
    R : (d, d) ``Phi^T Phi``.
    r : (d, p) ``Phi^T Y``.
    yy : (p, p) ``Y^T Y``.
    n_rows : number of regressor rows summed.
    phi_sum : (d,) ``Phi^T 1``, the column sums of the regressor rows (None if not kept).
    y_sum : (p,) ``Y^T 1``, the column sums of the targets (None if not kept).
        With both, :func:`center_normal_equations` gives the fit with an intercept (offsets).
    """

    R: np.ndarray
    r: np.ndarray
    yy: np.ndarray
    n_rows: int
    phi_sum: np.ndarray | None = None
    y_sum: np.ndarray | None = None


def normal_equations(phi: np.ndarray, targets: np.ndarray) -> NormalEquations:
    """Form ``Phi^T Phi``, ``Phi^T Y`` and ``Y^T Y`` of a block of regressor rows."""
    return NormalEquations(
        phi.T @ phi, phi.T @ targets, targets.T @ targets, phi.shape[0], phi.sum(axis=0), targets.sum(axis=0)
    )


def prior_precision(
    order: int,
    n_outputs: int,
    n_inputs: int,
    channel_mean_square: np.ndarray,
    kind: str = "ridge",
    decay: float = 0.95,
) -> np.ndarray:
    """Inverse prior covariance ``P^{-1}`` (d, d) of the ARX coefficients.

    Parameters
    ----------
    channel_mean_square : (p + m,) mean square of each channel of ``v = [y; u]``; used to make the
        penalty independent of the channels' units.
    kind : "ridge" (diagonal) or "tc" (tuned/correlated kernel with ``decay`` alpha in (0, 1)).
    """
    p, m, q = n_outputs, n_inputs, order
    ms = np.maximum(np.asarray(channel_mean_square, dtype=float), np.finfo(float).tiny)
    d = regressor_length(q, p, m)
    w = p + m
    if kind == "ridge":
        diag = np.concatenate([ms[p:], np.tile(ms, q)])
        return np.diag(diag)
    if kind != "tc":
        raise ValueError(f"unknown prior kind {kind!r}; expected 'ridge' or 'tc'")
    if not 0.0 < decay < 1.0:
        raise ValueError(f"TC decay must be in (0, 1), got {decay}")
    precision = np.zeros((d, d))
    # The feedthrough D has no lag: an independent prior of unit (scaled) variance.
    precision[:m, :m] = np.diag(ms[p:])
    lags = np.arange(1, q + 1)
    tc = decay ** np.maximum.outer(lags, lags)
    tc_inv = linalg.inv(tc)
    tc_inv = 0.5 * (tc_inv + tc_inv.T)
    for c in range(w):
        idx = m + (lags - 1) * w + c
        precision[np.ix_(idx, idx)] = tc_inv * ms[c]
    return precision


def _gcv_curve(s: np.ndarray, g2: np.ndarray, yy_trace: float, n_rows: int, p: int):
    """GCV score and its parts as functions of the penalty, in the whitened coordinates."""

    def parts(penalty: float) -> tuple[float, float, float]:
        # Null directions (s = 0) with no penalty contribute nothing to the fit.
        denom = s + penalty
        with np.errstate(over="ignore", invalid="ignore"):
            # s inv <= 1; a vanishing penalty on an unexcited window can still overflow inv and g2 inv.
            inv = np.divide(1.0, denom, out=np.zeros_like(denom), where=denom > 0)
            rss = yy_trace - float(np.sum(g2 * inv * (2.0 - s * inv)))
        if not np.isfinite(rss):
            return math.inf, math.inf, math.nan  # this penalty is unusable: GCV looks elsewhere
        dof = float(np.sum(s * inv))
        rss = max(rss, 0.0)
        return n_rows * rss / max(n_rows - dof, 1.0) ** 2, rss, dof

    return parts


def solve_normal_equations(
    normal: NormalEquations,
    precision: np.ndarray | None,
    penalty: float | str = "gcv",
) -> tuple[np.ndarray, float, float, float]:
    """Solve ``(R + penalty P^{-1}) Theta = r``, with the penalty chosen by GCV if asked.

    Returns
    -------
    theta : (d, p)
    penalty : the penalty used
    dof : effective number of parameters per output (trace of the hat matrix)
    gcv : the GCV score at that penalty (residual sum of squares scaled by (n - dof)^-2)
    """
    R, r, n_rows = normal.R, normal.r, normal.n_rows
    d, p = r.shape
    if precision is None:
        precision = np.diag(np.maximum(np.diag(R), np.finfo(float).tiny) / max(n_rows, 1))
    whiten, unwhiten = _whitening(precision)
    r_t = whiten(r)
    R_t = whiten(whiten(R).T)
    R_t = 0.5 * (R_t + R_t.T)
    eigen = SymmetricEigen(R_t)  # V kept factored: only V^T r_t and V theta are needed
    s = np.maximum(eigen.values, 0.0)
    g = eigen.project(r_t)  # (d, p)
    # GCV on outputs of equal weight (each divided by its root mean square): with the per-channel
    # prior the penalty, hence the fit, does not depend on the units of any channel.
    yy = np.diag(normal.yy)
    root_weight = 1.0 / np.sqrt(np.maximum(yy, np.finfo(float).tiny))
    with np.errstate(over="ignore"):  # an unexcited window: inf, which the GCV search avoids
        g2 = np.sum((g * root_weight) ** 2, axis=1)
    parts = _gcv_curve(s, g2, float(np.sum(yy * root_weight**2)), n_rows, p)
    if isinstance(penalty, str):
        if penalty != "gcv":
            raise ValueError(f"penalty must be a number or 'gcv', got {penalty!r}")
        scale = max(float(np.mean(s)), np.finfo(float).tiny)
        grid = scale * np.logspace(-12, 2, 29)
        scores = [parts(lam)[0] for lam in grid]
        best = int(np.argmin(scores))
        lo = np.log(grid[max(best - 1, 0)])
        hi = np.log(grid[min(best + 1, grid.size - 1)])
        with np.errstate(over="ignore", invalid="ignore"):  # an unusable (infinite) score is a valid answer
            res = optimize.minimize_scalar(lambda t: parts(np.exp(t))[0], bounds=(lo, hi), method="bounded")
        lam = float(np.exp(res.x)) if res.fun <= scores[best] else float(grid[best])
    else:
        lam = float(penalty)
        if lam < 0:
            raise ValueError(f"penalty must be >= 0, got {lam}")
    gcv, _, dof = parts(lam)
    denom = s + lam
    if lam == 0.0:
        # Unregularized: a pseudo-inverse that drops numerically null directions.
        keep = s > s.max() * d * np.finfo(float).eps
        denom = np.where(keep, s, np.inf)
    theta = unwhiten(eigen.expand(g / denom[:, None]))
    return theta, lam, dof, gcv


def _whitening(precision: np.ndarray) -> tuple[Callable, Callable]:
    """``x -> L^-1 x`` and ``x -> L^-T x`` for the Cholesky factor ``L`` of the precision, ``P^-1 = L L^T``.

    The ridge prior is diagonal: then ``L`` is the square root of its diagonal and both are a
    scaling of the rows, ``d^2`` operations per column instead of the triangular solves' ``d^3``
    for ``R`` (0.2 s of the steel subframe's ARX order search, where ``d`` is 602-1202). As
    OpenBLAS's triangular solve, one column is divided by the diagonal and several are multiplied
    by its reciprocals: the fits are the same to the last bit as by the solves.
    """
    diagonal = np.diag(precision)
    if np.count_nonzero(precision) == np.count_nonzero(diagonal):  # nothing off the diagonal
        if not np.all(np.isfinite(diagonal)):
            raise ValueError("the prior precision must not contain infs or NaNs")
        if not np.all(diagonal > 0):
            raise linalg.LinAlgError("the prior precision is not positive definite")
        root = np.sqrt(diagonal)[:, None]
        inverse = 1.0 / root

        def scale(x: np.ndarray) -> np.ndarray:
            return x / root if x.shape[1] == 1 else x * inverse

        return scale, scale
    chol = linalg.cholesky(precision, lower=True)

    def solve(x: np.ndarray) -> np.ndarray:
        return linalg.solve_triangular(chol, x, lower=True)

    def solve_transposed(x: np.ndarray) -> np.ndarray:
        return linalg.solve_triangular(chol.T, x, lower=False)

    return solve, solve_transposed


def scaled_condition_number(R: np.ndarray) -> float:
    """Condition number of ``R`` after scaling its columns to unit diagonal."""
    diag = np.sqrt(np.maximum(np.diag(R), np.finfo(float).tiny))
    eig = linalg.eigvalsh(R / np.outer(diag, diag))
    if eig[0] <= 0:
        return float("inf")
    return float(eig[-1] / eig[0])


def residual_covariance(normal: NormalEquations, theta: np.ndarray, dof: float) -> np.ndarray:
    """(p, p) residual covariance ``(Y - Phi Theta)^T (Y - Phi Theta) / (n - dof)``."""
    rt = theta.T @ normal.r
    cov = normal.yy - rt - rt.T + theta.T @ normal.R @ theta
    cov = 0.5 * (cov + cov.T)
    return cov / max(normal.n_rows - dof, 1.0)


def channel_mean_square(normal: NormalEquations, n_outputs: int, n_inputs: int, order: int) -> np.ndarray:
    """Mean square of each channel of ``v = [y; u]`` read from the diagonal of ``R``.

    Read from the lagged columns; an input zero in all of them, but not in its feedthrough column (a
    single blow at the window's newest sample over a silent force), from that one: its square, scaled
    by the floor of the prior (the tiny float), overflowed float64 in the prior's whitening.
    """
    m, p, w = n_inputs, n_outputs, n_outputs + n_inputs
    diag = np.diag(normal.R)
    square = diag[m:].reshape(order, w).mean(axis=0)
    square[p:] = np.where(square[p:] > 0, square[p:], diag[:m])
    return np.maximum(square / max(normal.n_rows, 1), np.finfo(float).tiny)


#: A standard deviation at most this fraction of a channel's level is no variation (below the
#: resolution of a 24-bit converter around that level): the channel is a constant.
NEGLIGIBLE_RELATIVE_SPREAD = 1e-7


def constant_columns(mean_square: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """Mask of the columns that do not vary, from their mean squares and variances (each (d,)).

    All zeros, or a spread of at most :data:`NEGLIGIBLE_RELATIVE_SPREAD` of their level (rounding
    leaves ``eps * mean^2`` of variance in a constant column, a sliding window's downdates about as
    much).
    """
    return (mean_square == 0) | (variance <= (NEGLIGIBLE_RELATIVE_SPREAD**2 + 64 * np.finfo(float).eps) * mean_square)


def center_normal_equations(normal: NormalEquations) -> NormalEquations:
    """The normal equations of the column-centered rows: the fit with an intercept.

    Least squares with a constant term equals least squares on regressors and targets with
    their column means removed: ``R - s s^T / n``, ``r - s t^T / n``, ``Y^T Y - t t^T / n``
    with the column sums ``s`` of ``Phi`` and ``t`` of ``Y``. Used to identify records and
    live inputs with offsets (non-zero means). A regressor column that is constant
    (:func:`constant_columns`) centres to exactly zero.

    Raises
    ------
    ValueError
        If the normal equations do not carry the column sums.
    """
    if normal.phi_sum is None or normal.y_sum is None:
        raise ValueError("these normal equations keep no column sums: cannot remove offsets")
    n = max(normal.n_rows, 1)
    s, t = normal.phi_sum, normal.y_sum
    R, r = normal.R - np.outer(s, s) / n, normal.r - np.outer(s, t) / n
    # A constant regressor (a stuck input) centres to rounding residue, which the column scaling
    # would blow up to unit spread (ARX penalties of 1e263): it is exactly zero, as a zero column.
    constant = constant_columns(np.maximum(np.diag(normal.R), 0.0) / n, np.maximum(np.diag(R), 0.0) / n)
    if constant.any():
        R[constant, :], R[:, constant], r[constant, :] = 0.0, 0.0, 0.0
    return NormalEquations(R, r, normal.yy - np.outer(t, t) / n, normal.n_rows, np.zeros_like(s), np.zeros_like(t))


def solve_fixed_penalty(
    normal: NormalEquations, precision: np.ndarray, penalty: float
) -> np.ndarray:
    """Solve ``(R + penalty P^{-1}) Theta = r`` for a fixed penalty by a Cholesky factorization.

    The same solution as :func:`solve_normal_equations` with a numeric penalty > 0, at a fraction
    of its cost (one Cholesky instead of a symmetric eigendecomposition), for callers such as the
    recursive window that solve often with a fixed prior. ``precision`` is ``P^{-1}`` (d, d).

    Returns
    -------
    theta : (d, p)

    Raises
    ------
    numpy.linalg.LinAlgError
        If ``R + penalty P^{-1}`` is not numerically positive definite (e.g. penalty 0 on a
        rank-deficient window).
    """
    lam = float(penalty)
    if lam < 0:
        raise ValueError(f"penalty must be >= 0, got {lam}")
    system = normal.R + lam * precision if lam > 0.0 else normal.R
    factor = linalg.cho_factor(system, lower=False, check_finite=False)
    return linalg.cho_solve(factor, normal.r, check_finite=False)
