"""State-estimator gain by the paper's z-domain whitening method (paper Eqs. 36-45).

With ``(A, B, C, D)`` known, subtract the deterministic response (Eq. 36) from the output; what
remains is the moving average of the innovations (Eq. 39)

    s_k = y_k - y_{k,1} = e_k + sum_{i>=1} C A^i K e_{k-i}   =   M(z^-1) e_k.

Fit an AR(r) whitening filter ``sum_{i=0..r} N_i s_{k-i} = e_k`` (``N_0 = I``, Eq. 42) by least
squares, invert the polynomial matrix by power-series long division (``M = N^{-1}``:
``M_0 = I``, ``M_j = -sum_{i=1..min(j,r)} N_i M_{j-i}``) to get ``C A^j K ~ M_j``, and solve
Eq. (44) ``K = pinv([CA; CA^2; ...; CA^{q1}]) [M_1; ...; M_{q1}]``.

The residual of the AR fit estimates the innovation covariance. The deterministic response is
started from rest, as in the paper; with lightly damped structures the initial-condition
response then leaks into ``s_k`` (pass the initial state if it is known).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from okid_ros.core.regressors import arx_regressors
from okid_ros.core.statespace import simulate

__all__ = ["WhiteningGain", "gain_by_whitening", "invert_polynomial_matrix"]


@dataclass
class WhiteningGain:
    """Result of :func:`gain_by_whitening`.

    Attributes
    ----------
    K : (n, p) estimator gain, paper convention (predictor gain ``A K``).
    innovation_covariance : (p, p) covariance of the AR whitening residual.
    stochastic_markov : (q1, p, p) the identified ``C A^i K``, i = 1..q1 (paper Fig. 3).
    ar_coefficients : (r, p, p) ``N_1 .. N_r``.
    """

    K: np.ndarray
    innovation_covariance: np.ndarray
    stochastic_markov: np.ndarray
    ar_coefficients: np.ndarray


def invert_polynomial_matrix(coefficients: np.ndarray, n_terms: int) -> np.ndarray:
    """Power series of ``(I + sum_i N_i z^-i)^{-1}``: (n_terms, p, p), term 0 = I.

    Parameters
    ----------
    coefficients : (r, p, p) ``N_1 .. N_r``.
    """
    r, p, _ = coefficients.shape
    out = np.zeros((n_terms, p, p))
    out[0] = np.eye(p)
    for j in range(1, n_terms):
        acc = np.zeros((p, p))
        for i in range(1, min(j, r) + 1):
            acc -= coefficients[i - 1] @ out[j - i]
        out[j] = acc
    return out


def gain_by_whitening(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    D: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    *,
    ar_order: int,
    n_markov: int | None = None,
    x0: np.ndarray | None = None,
) -> WhiteningGain:
    """Identify ``K`` by the paper's whitening method.

    Parameters
    ----------
    A, B, C, D : the realized deterministic model.
    u : (N, m); y : (N, p) the identification record.
    ar_order : r, the order of the AR whitening filter.
    n_markov : q1, the number of ``C A^i K`` used in Eq. (44) (default ``max(r, 2 n)``).
    x0 : optional initial state of the deterministic response.

    Returns
    -------
    WhiteningGain
    """
    n = A.shape[0]
    p = C.shape[0]
    if ar_order < 1:
        raise ValueError(f"AR order must be >= 1, got {ar_order}")
    n_markov = max(ar_order, 2 * n) if n_markov is None else int(n_markov)
    s = y - simulate(A, B, C, D, u, x0)
    # An AR model is an ARX model without inputs: the shared regressors with a zero-width input.
    phi, targets, _ = arx_regressors(np.zeros((s.shape[0], 0)), s, ar_order)
    if phi.shape[0] <= phi.shape[1]:
        raise ValueError(f"{y.shape[0]} samples are too few for an AR({ar_order}) whitening filter")
    coef, *_ = linalg.lstsq(phi, targets)
    residual = targets - phi @ coef
    # coef rows of lag i hold the predictor coefficients P_i^T with s_k = sum P_i s_{k-i}: N_i = -P_i.
    ar = -coef.reshape(ar_order, p, p).transpose(0, 2, 1)
    markov = invert_polynomial_matrix(ar, n_markov + 1)[1:]  # C A^i K, i = 1..q1
    obs = np.empty((n_markov * p, n))
    row = C @ A
    for i in range(n_markov):
        obs[i * p : (i + 1) * p] = row
        row = row @ A
    K = linalg.lstsq(obs, markov.reshape(n_markov * p, p))[0]
    cov = residual.T @ residual / residual.shape[0]
    return WhiteningGain(K=K, innovation_covariance=0.5 * (cov + cov.T), stochastic_markov=markov, ar_coefficients=ar)
