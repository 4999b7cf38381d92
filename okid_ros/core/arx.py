"""MIMO ARX least squares with regularization (paper Eq. 23).

The fit minimizes, over the coefficient matrix ``Theta`` (d, p) of the observer-form regressor
of :mod:`okid_ros.core.regressors`,

    sum_k || y_k - Theta^T phi_k ||^2 + penalty * trace(Theta^T P^{-1} Theta),

i.e. ``(R + penalty P^{-1}) Theta = r`` with the normal equations ``R = Phi^T Phi`` (d, d) and
``r = Phi^T Y`` (d, p). The paper uses ``penalty = 0``; with inputs that leave part of the band
unexcited that solution is junk there and the rest of the chain amplifies it
(``docs/method.md``). ``P`` is a prior covariance of the coefficients:

- ``"ridge"``: diagonal, each regressor column scaled by its mean square (so outputs and inputs
  of different units are penalized alike);
- ``"tc"``: the tuned/correlated kernel ``P[(i, c), (j, c)] = alpha^max(i, j) / ms_c`` over lags
  ``i, j`` of the same channel ``c`` (Chen, Ohlsson & Ljung 2012), which encodes that the
  coefficients of a stable predictor decay with the lag.

The penalty (and ``alpha``) are chosen by generalized cross-validation, computed from the
normal equations alone so that the recursive window, which keeps only ``R``, ``r`` and
``Y^T Y``, can choose them the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, optimize

from okid_ros.core.regressors import arx_regressors, check_io_arrays, regressor_length

__all__ = [
    "ArxFit",
    "NormalEquations",
    "fit_arx",
    "normal_equations",
    "prior_precision",
    "solve_normal_equations",
    "solve_fixed_penalty",
    "minimum_samples",
    "ArxOrderChoice",
    "center_normal_equations",
    "select_arx_order",
]

REGULARIZATIONS = ("none", "ridge", "tc")
TC_DECAYS = (0.8, 0.9, 0.95, 0.97, 0.98, 0.99, 0.995)


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


@dataclass
class ArxFit:
    """An identified ARX model in the observer-form layout.

    Attributes
    ----------
    theta : (d, p) coefficients, ``y_k^T = phi_k^T theta``.
    order : ARX order q.
    n_inputs, n_outputs : m and p.
    residual_covariance : (p, p) one-step prediction-error covariance of the fit.
    condition_number : condition number of the column-scaled ``Phi^T Phi`` (before regularization).
    regularization : "none", "ridge" or "tc".
    penalty : the regularization weight used (0 for "none").
    decay : the TC kernel decay alpha (None unless "tc").
    effective_parameters : trace of the hat matrix (degrees of freedom used, per output).
    n_rows : number of regressor rows in the fit.
    """

    theta: np.ndarray
    order: int
    n_inputs: int
    n_outputs: int
    residual_covariance: np.ndarray
    condition_number: float
    regularization: str = "none"
    penalty: float = 0.0
    decay: float | None = None
    effective_parameters: float = 0.0
    n_rows: int = 0
    extras: dict = field(default_factory=dict)

    @property
    def D(self) -> np.ndarray:
        """(p, m) direct feedthrough ``B_0``."""
        return self.theta[: self.n_inputs].T.copy()

    @property
    def observer_markov(self) -> np.ndarray:
        """(q, p, p + m) the lag blocks ``[A_i, B_i]`` (ARX output and input coefficients)."""
        m, p, q = self.n_inputs, self.n_outputs, self.order
        return self.theta[m:].reshape(q, p + m, p).transpose(0, 2, 1).copy()

    @property
    def output_coefficients(self) -> np.ndarray:
        """(q, p, p) ``A_i`` of paper Eq. (23)."""
        return self.observer_markov[:, :, : self.n_outputs]

    @property
    def input_coefficients(self) -> np.ndarray:
        """(q, p, m) ``B_i`` of paper Eq. (23), i >= 1."""
        return self.observer_markov[:, :, self.n_outputs :]


def minimum_samples(order: int, n_outputs: int, n_inputs: int) -> int:
    """Fewest samples for a determined unregularized fit: ``q + d`` (d rows after q lags)."""
    return order + regressor_length(order, n_outputs, n_inputs)


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
        inv = np.divide(1.0, denom, out=np.zeros_like(denom), where=denom > 0)
        with np.errstate(over="ignore", invalid="ignore"):
            # s inv <= 1; a vanishing penalty on an unexcited window can still overflow g2 inv.
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
    # Whiten with the Cholesky factor of the precision: P^{-1} = L L^T.
    chol = linalg.cholesky(precision, lower=True)
    r_t = linalg.solve_triangular(chol, r, lower=True)
    R_t = linalg.solve_triangular(chol, linalg.solve_triangular(chol, R, lower=True).T, lower=True)
    R_t = 0.5 * (R_t + R_t.T)
    s, V = linalg.eigh(R_t)
    s = np.maximum(s, 0.0)
    g = V.T @ r_t  # (d, p)
    g2 = np.sum(g * g, axis=1)
    parts = _gcv_curve(s, g2, float(np.trace(normal.yy)), n_rows, p)
    if isinstance(penalty, str):
        if penalty != "gcv":
            raise ValueError(f"penalty must be a number or 'gcv', got {penalty!r}")
        scale = max(float(np.mean(s)), np.finfo(float).tiny)
        grid = scale * np.logspace(-12, 2, 29)
        scores = [parts(lam)[0] for lam in grid]
        best = int(np.argmin(scores))
        lo = np.log(grid[max(best - 1, 0)])
        hi = np.log(grid[min(best + 1, grid.size - 1)])
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
    theta_t = V @ (g / denom[:, None])
    theta = linalg.solve_triangular(chol.T, theta_t, lower=False)
    return theta, lam, dof, gcv


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


def fit_arx(
    u: np.ndarray,
    y: np.ndarray,
    order: int,
    regularization: str = "ridge",
    penalty: float | str = "gcv",
    decay: float | str = "gcv",
    valid: np.ndarray | None = None,
    *,
    center: bool = False,
) -> ArxFit:
    """Fit a MIMO ARX model of order q by regularized least squares (paper Eq. 23).

    Parameters
    ----------
    u : (N, m) inputs; y : (N, p) outputs.
    order : q, the number of past samples of y and u in each regressor.
    regularization : "none" (the paper), "ridge" or "tc" (see module docstring).
    penalty : a fixed penalty, or "gcv" to choose it by generalized cross-validation.
    decay : TC kernel alpha, or "gcv" to choose it from ``TC_DECAYS`` with the penalty.
    valid : (N,) bool, optional mask of trustworthy samples (gaps break the regressors).
    center : fit an intercept too (signals with offsets; :func:`center_normal_equations`).

    Returns
    -------
    ArxFit

    Raises
    ------
    ValueError
        On bad shapes, non-finite data, or fewer samples than the order needs.
    """
    u, y = check_io_arrays(u, y)
    if regularization not in REGULARIZATIONS:
        raise ValueError(f"regularization must be one of {REGULARIZATIONS}, got {regularization!r}")
    if order < 1:
        raise ValueError(f"ARX order must be >= 1, got {order}")
    m, p = u.shape[1], y.shape[1]
    phi, targets, _ = arx_regressors(u, y, order, valid)
    d = phi.shape[1]
    needed = minimum_samples(order, p, m)
    if regularization == "none" and phi.shape[0] < d:
        raise ValueError(
            f"too few samples for ARX order {order}: {u.shape[0]} given, at least {needed} needed "
            f"(d = {d} coefficients per output)"
        )
    if phi.shape[0] < max(order + 1, 2 * (p + m)):
        raise ValueError(
            f"too few samples for ARX order {order}: {u.shape[0]} given, at least {needed} recommended"
        )
    normal = normal_equations(phi, targets)
    return fit_from_normal_equations(normal, order, p, m, regularization, penalty, decay, center=center)


def channel_mean_square(normal: NormalEquations, n_outputs: int, n_inputs: int, order: int) -> np.ndarray:
    """Mean square of each channel of ``v = [y; u]`` read from the diagonal of ``R``."""
    m, w = n_inputs, n_outputs + n_inputs
    diag = np.diag(normal.R)[m:].reshape(order, w)
    return np.maximum(diag.mean(axis=0) / max(normal.n_rows, 1), np.finfo(float).tiny)


def center_normal_equations(normal: NormalEquations) -> NormalEquations:
    """The normal equations of the column-centered rows: the fit with an intercept.

    Least squares with a constant term equals least squares on regressors and targets with
    their column means removed: ``R - s s^T / n``, ``r - s t^T / n``, ``Y^T Y - t t^T / n``
    with the column sums ``s`` of ``Phi`` and ``t`` of ``Y``. Used to identify records and
    live inputs with offsets (non-zero means).

    Raises
    ------
    ValueError
        If the normal equations do not carry the column sums.
    """
    if normal.phi_sum is None or normal.y_sum is None:
        raise ValueError("these normal equations keep no column sums: cannot remove offsets")
    n = max(normal.n_rows, 1)
    s, t = normal.phi_sum, normal.y_sum
    return NormalEquations(
        normal.R - np.outer(s, s) / n,
        normal.r - np.outer(s, t) / n,
        normal.yy - np.outer(t, t) / n,
        normal.n_rows,
        np.zeros_like(s),
        np.zeros_like(t),
    )


def fit_from_normal_equations(
    normal: NormalEquations,
    order: int,
    n_outputs: int,
    n_inputs: int,
    regularization: str = "ridge",
    penalty: float | str = "gcv",
    decay: float | str = "gcv",
    *,
    center: bool = False,
) -> ArxFit:
    """The ARX solution of a window given only its normal equations (see :func:`fit_arx`).

    ``center=True`` fits an intercept (offsets of inputs and outputs) along with the
    coefficients (:func:`center_normal_equations`).
    """
    p, m = n_outputs, n_inputs
    if center:
        normal = center_normal_equations(normal)
    ms = channel_mean_square(normal, p, m, order)
    cond = scaled_condition_number(normal.R)
    chosen_decay: float | None = None
    if regularization == "none":
        theta, lam, dof, _ = solve_normal_equations(normal, prior_precision(order, p, m, ms, "ridge"), 0.0)
    elif regularization == "ridge":
        theta, lam, dof, _ = solve_normal_equations(normal, prior_precision(order, p, m, ms, "ridge"), penalty)
    else:
        decays = TC_DECAYS if decay == "gcv" else (float(decay),)
        best = None
        for alpha in decays:
            sol = solve_normal_equations(normal, prior_precision(order, p, m, ms, "tc", alpha), penalty)
            if best is None or sol[3] < best[0][3]:
                best = (sol, alpha)
        (theta, lam, dof, _), chosen_decay = best
    return ArxFit(
        theta=theta,
        order=order,
        n_inputs=m,
        n_outputs=p,
        residual_covariance=residual_covariance(normal, theta, dof),
        condition_number=cond,
        regularization=regularization,
        penalty=lam,
        decay=chosen_decay,
        effective_parameters=dof,
        n_rows=normal.n_rows,
    )


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


@dataclass
class ArxOrderChoice:
    """Result of :func:`select_arx_order`.

    Attributes
    ----------
    order : the chosen ARX order q.
    scores : GCV score per row of each order tried (q -> score; lower is better).
    limited_by : why larger orders were not tried ("" if the candidates ran out or the
        score rose), e.g. the record length or the cost limit.
    """

    order: int
    scores: dict[int, float]
    limited_by: str = ""


def select_arx_order(
    u: np.ndarray,
    y: np.ndarray,
    *,
    candidates: tuple[int, ...],
    min_order: int = 2,
    max_coefficients: int = 2500,
    min_rows_per_coefficient: float = 2.0,
    patience: int = 2,
    center: bool = False,
) -> ArxOrderChoice:
    """Choose the ARX order by generalized cross-validation of the ridge fit.

    The GCV score ``n rss / (n - dof)^2`` of the ridge fit (penalty itself chosen by GCV)
    estimates the one-step prediction error on new data, so it compares orders fairly. The
    candidates at or above ``min_order`` are tried in increasing order while the regressor
    length ``d = m + q (p + m)`` stays within ``max_coefficients`` and the record gives at
    least ``min_rows_per_coefficient`` rows per coefficient; the search stops ``patience``
    candidates after the best one.

    Parameters
    ----------
    u : (N, m); y : (N, p) one contiguous record.
    candidates : ARX orders to try.
    min_order : smallest order allowed (e.g. what the realization's Hankel matrix needs).
    center : score the fits with an intercept (signals with offsets).

    Raises
    ------
    ValueError
        If no candidate fits the record.
    """
    u, y = check_io_arrays(u, y)
    m, p = u.shape[1], y.shape[1]
    tried = {max(int(q), 1) for q in candidates if q >= min_order}
    tried = sorted(tried | ({min_order} if min_order > max(candidates) else set()))
    scores: dict[int, float] = {}
    limited_by = ""
    best_q, best_score, since_best = 0, np.inf, 0
    for q in tried:
        d = regressor_length(q, p, m)
        if d > max_coefficients:
            limited_by = f"cost: ARX order {q} has {d} coefficients per output (limit {max_coefficients})"
            break
        if u.shape[0] - q < min_rows_per_coefficient * d:
            limited_by = f"record length: ARX order {q} needs {int(min_rows_per_coefficient * d) + q} samples"
            break
        phi, targets, _ = arx_regressors(u, y, q)
        normal = normal_equations(phi, targets)
        if center:
            normal = center_normal_equations(normal)
        precision = prior_precision(q, p, m, channel_mean_square(normal, p, m, q), "ridge")
        _, _, dof, gcv = solve_normal_equations(normal, precision, "gcv")
        scores[q] = float(gcv) / normal.n_rows  # per row: orders differ in row count
        if scores[q] < best_score:
            best_q, best_score, since_best = q, scores[q], 0
        else:
            since_best += 1
            if since_best >= patience:
                break
    if not scores:
        raise ValueError(
            f"no ARX order can be fitted to {u.shape[0]} samples with {m} inputs and {p} outputs ({limited_by})"
        )
    return ArxOrderChoice(best_q, scores, limited_by if best_q == max(scores) else "")
