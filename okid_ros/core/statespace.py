"""Small state-space utilities shared by the core: simulation and the one-step predictor.

The model is the paper's innovation form (Eqs. 30-31)::

    x_{k+1} = A x_k + B u_k + A K e_k,      y_k = C x_k + D u_k + e_k,

whose one-step predictor is ``x_{k+1} = (A - A K C) x_k + (B - A K D) u_k + A K y_k``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["simulate", "one_step_prediction", "spectral_radius"]


def spectral_radius(A: np.ndarray) -> float:
    """Largest eigenvalue modulus of a square matrix (0 for an empty one)."""
    return float(np.max(np.abs(np.linalg.eigvals(A)))) if A.size else 0.0


def _run(F: np.ndarray, G: np.ndarray, H: np.ndarray, J: np.ndarray, w: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """Outputs of ``x+ = F x + G w, z = H x + J w`` for inputs ``w`` (N, r): (N, p)."""
    n_samples = w.shape[0]
    states = np.empty((n_samples, F.shape[0]))
    x = x0.astype(float).copy()
    Gw = w @ G.T  # precompute the input drive: one matmul instead of N small ones
    for k in range(n_samples):
        states[k] = x
        x = F @ x + Gw[k]
    return states @ H.T + w @ J.T


def simulate(
    A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, u: np.ndarray, x0: np.ndarray | None = None
) -> np.ndarray:
    """Deterministic response ``y_k = C x_k + D u_k`` to inputs ``u`` (N, m): (N, p)."""
    x0 = np.zeros(A.shape[0]) if x0 is None else np.asarray(x0, dtype=float)
    return _run(A, B, C, D, np.asarray(u, dtype=float), x0)


def one_step_prediction(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    D: np.ndarray,
    K: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    x0: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One-step predictions ``yhat_k = C xhat_k + D u_k`` and innovations ``y_k - yhat_k``.

    Parameters
    ----------
    K : (n, p) the gain in the paper's convention (predictor gain ``A K``).
    u : (N, m); y : (N, p).

    Returns
    -------
    y_hat : (N, p); innovations : (N, p)
    """
    L = A @ K
    F = A - L @ C
    G = np.hstack([B - L @ D, L])
    m = B.shape[1]
    J = np.hstack([D, np.zeros((C.shape[0], C.shape[0]))])
    w = np.hstack([np.asarray(u, dtype=float), np.asarray(y, dtype=float)])
    x0 = np.zeros(A.shape[0]) if x0 is None else np.asarray(x0, dtype=float)
    y_hat = _run(F, G, C, J[:, : m + C.shape[0]], w, x0)
    return y_hat, y - y_hat
