"""Least-squares completion of a realization: ``(Abar, C)`` or a state sequence -> full model.

Two ways, both linear least squares on the data:

:func:`refit_predictor` (accurate, cost grows with p^2)

With the predictor poles ``Abar`` (n, n) and output matrix ``C`` (p, n) taken from the
realization, the one-step predictor

    xhat_{k+1} = Abar xhat_k + Bbar u_k + L y_k,       yhat_k = C xhat_k + D u_k,

is *linear* in ``Gam = [L, Bbar]`` (n, p + m), ``D`` (p, m) and the initial state ``x0`` (n):

    yhat_k = C Abar^k x0 + sum_{t<k} C Abar^{k-1-t} Gam v_t + D u_k,    v_t = [y_t; u_t].

So they are refitted by linear least squares on the data, which is far less fragile than taking
``L`` from the realization (an error in ``L`` moves the physical poles of ``A = Abar + L C``).
Then ``A = Abar + L C``, ``B = Bbar + L D`` and the paper's gain is ``K = A^{-1} L``.
The convolutions are done by FFT, one output channel at a time to bound memory. The normal
equations cost about ``N p (n (p + m))^2`` flops: fine for a few outputs, slow for tens.

:func:`fit_from_states` (fast, for many outputs)
    The weighted ERA gives ``Gamma`` and, through the ARX predictor, a state estimate for each
    sample, ``xhat_k = pinv(Gamma) H(0) z_k`` with ``z_k = [v_{k-1}; ...; v_{k-c}]`` (the
    predictor-based subspace idea). Then ``y_k = C xhat_k + D u_k + e_k`` gives ``C``, ``D`` and
    the innovations, and ``xhat_{k+1} = A xhat_k + B u_k + L e_k`` gives ``A``, ``B``, ``L``.
    Cost ``O(N (n + m + p)^2)`` once the states are formed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import fft, linalg

from okid_ros.core.statespace import spectral_radius

__all__ = ["PredictorFit", "refit_predictor", "fit_from_states", "gain_from_predictor"]


@dataclass
class PredictorFit:
    """A refitted innovation-form model (paper convention) and its fit statistics.

    Attributes
    ----------
    A, B, C, D, K : the innovation form ``x+ = A x + B u + A K e``, ``y = C x + D u + e``.
    x0 : (n,) initial predictor state of the fitted record.
    innovation_covariance : (p, p) covariance of the one-step prediction errors.
    innovations : (N, p) the prediction errors on the fitted record.
    n_parameters : free parameters of the predictor (for information criteria).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray
    x0: np.ndarray
    innovation_covariance: np.ndarray
    innovations: np.ndarray
    n_parameters: int

    def bic(self) -> float:
        """Bayesian information criterion ``N log det(Re) + n_par log N`` (lower is better)."""
        n_samples = self.innovations.shape[0]
        sign, logdet = np.linalg.slogdet(self.innovation_covariance)
        if sign <= 0:
            return float("inf")
        return float(n_samples * logdet + self.n_parameters * np.log(n_samples))


def gain_from_predictor(A: np.ndarray, L: np.ndarray) -> np.ndarray:
    """The paper's gain ``K`` from the predictor gain ``L = A K``."""
    try:
        return linalg.solve(A, L)
    except linalg.LinAlgError:
        return linalg.lstsq(A, L)[0]


def _impulse_rows(Abar: np.ndarray, C: np.ndarray, length: int) -> np.ndarray:
    """``C Abar^k`` for k = 0..length-1: (length, p, n), zero once it has decayed to 1e-13."""
    p, n = C.shape
    out = np.zeros((length, p, n))
    row = C.copy()
    scale = max(np.abs(C).max(), np.finfo(float).tiny)
    for k in range(length):
        out[k] = row
        row = row @ Abar
        if np.abs(row).max() < 1e-13 * scale:
            break
    return out


def refit_predictor(
    Abar: np.ndarray,
    C: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    fit_initial_state: bool = True,
) -> PredictorFit:
    """Refit ``L``, ``Bbar``, ``D`` (and ``x0``) by least squares for fixed ``Abar``, ``C``.

    Parameters
    ----------
    Abar : (n, n) predictor state matrix (must be stable: spectral radius < 1).
    C : (p, n) output matrix.
    u : (N, m) inputs; y : (N, p) outputs of one contiguous record.
    fit_initial_state : also fit ``x0`` (recommended for lightly damped structures).

    Returns
    -------
    PredictorFit

    Raises
    ------
    ValueError if ``Abar`` is not stable or the record is too short for the parameters.
    """
    n = Abar.shape[0]
    n_samples, m = u.shape
    p = y.shape[1]
    rho = spectral_radius(Abar)
    if rho >= 1.0:
        raise ValueError(f"the predictor Abar is unstable (spectral radius {rho:.4f})")
    v = np.hstack([y, u])
    w = p + m
    n_gam = n * w
    n_x0 = n if fit_initial_state else 0
    n_par = n_gam + n_x0 + p * m
    if n_samples * p <= n_par:
        raise ValueError(f"{n_samples} samples are too few to refit {n_par} predictor parameters")
    impulse = _impulse_rows(Abar, C, n_samples)  # C Abar^k, (N, p, n)
    # Regressor of Gam[i, j] for output c at time k: sum_{tau>=1} (C Abar^{tau-1})[c, i] v_j(k - tau).
    nfft = fft.next_fast_len(2 * n_samples)
    h = np.zeros((nfft, p, n))
    h[1 : n_samples + 1] = impulse[: min(n_samples, nfft - 1)]
    h_f = fft.rfft(h, axis=0)
    v_f = fft.rfft(v, n=nfft, axis=0)
    normal = np.zeros((n_par, n_par))
    rhs = np.zeros(n_par)
    blocks = []
    for c in range(p):
        z = fft.irfft(h_f[:, c, :, None] * v_f[:, None, :], n=nfft, axis=0)[:n_samples]
        design = np.zeros((n_samples, n_par))
        design[:, :n_gam] = z.reshape(n_samples, n_gam)
        if fit_initial_state:
            design[:, n_gam : n_gam + n] = impulse[:, c, :]
        design[:, n_gam + n_x0 + c * m : n_gam + n_x0 + (c + 1) * m] = u
        normal += design.T @ design
        rhs += design.T @ y[:, c]
        blocks.append(design)
    # A whisper of ridge keeps the solve defined if some direction is unexcited.
    ridge = 1e-12 * max(np.trace(normal) / n_par, np.finfo(float).tiny)
    theta = linalg.solve(normal + ridge * np.eye(n_par), rhs, assume_a="pos")
    gam = theta[:n_gam].reshape(n, w)
    x0 = theta[n_gam : n_gam + n] if fit_initial_state else np.zeros(n)
    D = theta[n_gam + n_x0 :].reshape(p, m)
    L, Bbar = gam[:, :p], gam[:, p:]
    innovations = np.column_stack([y[:, c] - blocks[c] @ theta for c in range(p)])
    A = Abar + L @ C
    B = Bbar + L @ D
    K = gain_from_predictor(A, L)
    cov = innovations.T @ innovations / n_samples
    # Free parameters: (Abar, C, Gam, D) less the n^2 of a similarity transform, plus x0.
    n_free = n * (2 * p + m) + p * m + n_x0
    return PredictorFit(A, B, C.copy(), D, K, x0, 0.5 * (cov + cov.T), innovations, n_free)


def fit_from_states(states: np.ndarray, u: np.ndarray, y: np.ndarray) -> PredictorFit:
    """Innovation-form model from a state sequence by two least-squares regressions.

    Parameters
    ----------
    states : (N, n) state estimates ``xhat_k`` of the samples of ``u`` (N, m) and ``y`` (N, p),
        consecutive in time.

    Returns
    -------
    PredictorFit (``x0`` is the first state; ``innovations`` are the residuals of the output
    equation).
    """
    n_samples, n = states.shape
    m, p = u.shape[1], y.shape[1]
    if n_samples <= 2 * (n + m + p):
        raise ValueError(f"{n_samples} samples are too few to fit a {n}-state model")
    if not np.all(np.isfinite(states)):
        raise ValueError("the state sequence is not finite")
    regressor = np.hstack([states, u])
    cd = linalg.lstsq(regressor, y)[0].T
    C, D = cd[:, :n], cd[:, n:]
    innovations = y - regressor @ cd.T
    abl = linalg.lstsq(np.hstack([states[:-1], u[:-1], innovations[:-1]]), states[1:])[0].T
    A, B, L = abl[:, :n], abl[:, n : n + m], abl[:, n + m :]
    cov = innovations.T @ innovations / n_samples
    n_free = n * (2 * p + m) + p * m
    return PredictorFit(
        A, B, C, D, gain_from_predictor(A, L), states[0].copy(), 0.5 * (cov + cov.T), innovations, n_free
    )
