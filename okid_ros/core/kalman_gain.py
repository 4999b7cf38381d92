"""State-estimator gain from noise covariances by the discrete Riccati equation.

For ``x_{k+1} = A x_k + B u_k + w_k``, ``y_k = C x_k + D u_k + v_k`` with
``cov([w; v]) = [[Q, S], [S^T, R]]``, the steady-state a-priori error covariance ``P`` is the
stabilizing solution of the filtering Riccati equation

    P = A P A^T + Q - (A P C^T + S) (C P C^T + R)^{-1} (A P C^T + S)^T

and the optimal one-step predictor has the gain ``L = (A P C^T + S) Re^{-1}``,
``Re = C P C^T + R``. Being the stabilizing solution, ``A - L C`` has all its eigenvalues
inside the unit circle whenever ``(A, C)`` is detectable and the noise reaches every unstable
mode: the predictor is stable by construction. This is how subspace methods obtain their gain
(Van Overschee & De Moor 1996): ``Q``, ``R``, ``S`` are the covariances of the residuals of the
state and output equations of an identified state sequence.

In the paper's convention (Eqs. 30-31) the gain is ``K = A^{-1} L``.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import linalg

__all__ = [
    "riccati_covariance", "riccati_residual", "riccati_predictor_gain", "noise_covariances",
    "kalman_gain_from_residuals", "kalman_gain_from_covariances",
]


def riccati_covariance(
    A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, S: np.ndarray | None = None
) -> np.ndarray:
    """Stabilizing solution ``P`` (n, n) of the filtering Riccati equation (module docstring).

    Parameters
    ----------
    A : (n, n); C : (p, n); Q : (n, n) PSD; R : (p, p) PD; S : (n, p) or None (uncorrelated).

    Raises
    ------
    numpy.linalg.LinAlgError / ValueError
        When no stabilizing solution exists (scipy's messages).
    """
    n, p = A.shape[0], C.shape[0]
    S = np.zeros((n, p)) if S is None else np.asarray(S, dtype=float)
    P = _doubling(A, C, Q, R, S)
    if P is None:
        P = linalg.solve_discrete_are(A.T, C.T, Q, R, s=S)
    return 0.5 * (P + P.T)


# Relative residual of the Riccati equation below which the doubling solution is taken.
DOUBLING_TOLERANCE = 1e-9
DOUBLING_MAX_STEPS = 60


def riccati_residual(A, C, Q, R, S, P) -> float:
    """Relative residual ``||P - rhs(P)|| / max(||P||, ||Q||)`` of the filtering Riccati equation."""
    gain_term = A @ P @ C.T + S
    rhs = A @ P @ A.T + Q - gain_term @ linalg.solve(C @ P @ C.T + R, gain_term.T, assume_a="pos")
    return float(np.linalg.norm(P - rhs) / max(np.linalg.norm(P), np.linalg.norm(Q), np.finfo(float).tiny))


def _doubling(A, C, Q, R, S) -> np.ndarray | None:
    """Stabilizing ``P`` by the structured doubling algorithm, or None (then scipy's QZ solver).

    Written by hand because scipy has no doubling solver and its ``solve_discrete_are`` (an
    ordered QZ of a 2n pencil) took 0.2 s at n = 116 where the doubling takes about a tenth:
    it needs only n x n products and solves, converges quadratically (Chu, Fan & Lin 2005,
    SDA-1 with the cross covariance folded into ``A`` and ``Q``). The answer is kept only
    when its residual is at the rounding level and the predictor is stable.
    """
    n = A.shape[0]
    try:
        r_inv_c = linalg.solve(R, C, assume_a="pos")  # R^-1 C
        r_inv_st = linalg.solve(R, S.T, assume_a="pos")  # R^-1 S^T
    except (linalg.LinAlgError, ValueError):
        return None
    a_k = (A - S @ r_inv_c).T  # control form of the filter equation
    g_k = C.T @ r_inv_c
    h_k = Q - S @ r_inv_st
    h_k = 0.5 * (h_k + h_k.T)
    eye = np.eye(n)
    with np.errstate(all="ignore"):
        for _ in range(DOUBLING_MAX_STEPS):
            try:
                lu = linalg.lu_factor(eye + g_k @ h_k, check_finite=False)
            except (linalg.LinAlgError, ValueError):
                return None
            w_a = linalg.lu_solve(lu, a_k, check_finite=False)  # (I + G H)^-1 A
            w_g = linalg.lu_solve(lu, g_k, check_finite=False)  # (I + G H)^-1 G
            h_next = h_k + a_k.T @ h_k @ w_a
            g_k = g_k + a_k @ w_g @ a_k.T
            a_k = a_k @ w_a
            g_k, h_next = 0.5 * (g_k + g_k.T), 0.5 * (h_next + h_next.T)
            if not np.all(np.isfinite(h_next)):
                return None
            change = np.linalg.norm(h_next - h_k) / max(np.linalg.norm(h_next), np.finfo(float).tiny)
            h_k = h_next
            if change < 1e-14:
                break
    try:
        if riccati_residual(A, C, Q, R, S, h_k) > DOUBLING_TOLERANCE:
            return None
        gain = linalg.solve(C @ h_k @ C.T + R, (A @ h_k @ C.T + S).T, assume_a="pos").T
    except (linalg.LinAlgError, ValueError):
        return None
    if not np.max(np.abs(linalg.eigvals(A - gain @ C))) < 1.0:
        return None
    return h_k


def riccati_predictor_gain(
    A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, S: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steady-state Kalman predictor gain.

    Returns
    -------
    L : (n, p) predictor gain ``(A P C^T + S) Re^{-1}``.
    Re : (p, p) innovation covariance ``C P C^T + R``.
    P : (n, n) a-priori state error covariance.
    """
    n, p = A.shape[0], C.shape[0]
    S = np.zeros((n, p)) if S is None else np.asarray(S, dtype=float)
    P = riccati_covariance(A, C, Q, R, S)
    Re = C @ P @ C.T + R
    Re = 0.5 * (Re + Re.T)
    L = linalg.solve(Re, (A @ P @ C.T + S).T, assume_a="pos").T
    return L, Re, P


def noise_covariances(
    process_residuals: np.ndarray, output_residuals: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``Q``, ``R``, ``S`` as the sample covariances of state- and output-equation residuals.

    Parameters
    ----------
    process_residuals : (N, n) ``w_k = x_{k+1} - A x_k - B u_k``.
    output_residuals : (N, p) ``v_k = y_k - C x_k - D u_k`` of the same samples.

    Returns
    -------
    Q : (n, n); R : (p, p), made positive definite; S : (n, p).
    """
    w, v = np.asarray(process_residuals, float), np.asarray(output_residuals, float)
    if w.shape[0] != v.shape[0]:
        raise ValueError(f"residuals have different lengths: {w.shape[0]} and {v.shape[0]}")
    joint = np.hstack([w, v])
    cov = joint.T @ joint / max(joint.shape[0], 1)
    cov = 0.5 * (cov + cov.T)
    n = w.shape[1]
    # The joint covariance of a finite sample is PSD; a whisper on the diagonal keeps R PD and
    # the Riccati equation solvable when an output channel is (numerically) noise-free.
    scale = max(np.trace(cov) / cov.shape[0], np.finfo(float).tiny)
    cov += 1e-10 * scale * np.eye(cov.shape[0])
    return cov[:n, :n], cov[n:, n:], cov[:n, n:]


def kalman_gain_from_residuals(
    A: np.ndarray, C: np.ndarray, process_residuals: np.ndarray, output_residuals: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Predictor gain ``L`` (n, p) and innovation covariance (p, p) from residual covariances.

    Raises
    ------
    ValueError
        When the Riccati equation has no stabilizing solution for these covariances.
    """
    Q, R, S = noise_covariances(process_residuals, output_residuals)
    return kalman_gain_from_covariances(A, C, Q, R, S)


def kalman_gain_from_covariances(
    A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, S: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """As :func:`kalman_gain_from_residuals`, from ``Q`` (n, n), ``R`` (p, p), ``S`` (n, p)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", linalg.LinAlgWarning)
            L, Re, _ = riccati_predictor_gain(A, C, Q, R, S)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ValueError(f"no stabilizing Riccati solution: {exc}") from None
    if not np.all(np.isfinite(L)):
        raise ValueError("no stabilizing Riccati solution: non-finite gain")
    return L, Re
