"""Least-squares completion of a realization ``(Abar, C)`` into a full innovation model.

With the predictor poles ``Abar`` (n, n) and output matrix ``C`` (p, n) taken from the
realization, the one-step predictor

    xhat_{k+1} = Abar xhat_k + Bbar u_k + L y_k,       yhat_k = C xhat_k + D u_k,

is *linear* in ``Gam = [L, Bbar]`` (n, p + m), ``D`` (p, m) and the initial state ``x0`` (n):

    yhat_k = C Abar^k x0 + sum_{t<k} C Abar^{k-1-t} Gam v_t + D u_k,    v_t = [y_t; u_t].

So they are refitted by linear least squares on the data, which is far less fragile than taking
``L`` from the realization (an error in ``L`` moves the physical poles of ``A = Abar + L C``).
Then ``A = Abar + L C``, ``B = Bbar + L D`` and the paper's gain is ``K = A^{-1} L``.
The regressors are the data filtered by each pole of ``Abar`` (one first-order filter per pole
and data channel, the same for every output), so the normal equations come from one Gram of
those signals, about ``N (n (p + m))^2`` flops (:func:`_modal_normal_equations`); where
``Abar`` has no well-conditioned eigenvector basis, each output's regressors are convolved by
FFT, about ``N p (n (p + m))^2`` flops (:func:`_convolution_normal_equations`).

The other completion, from a state sequence (fast with many outputs), is
:mod:`okid_ros.core.state_completion`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import fft, linalg, signal

from okid_ros.core.statespace import InnovationModel, free_parameters, spectral_radius, split_poles

__all__ = ["PredictorFit", "refit_predictor", "gain_from_predictor", "innovation_covariance"]


@dataclass
class PredictorFit:
    """A completed innovation model and its fit statistics on the record it was fitted to.

    Attributes
    ----------
    model : the innovation form ``x+ = A x + B u + A K e``, ``y = C x + D u + e``.
    x0 : (n,) initial predictor state of the fitted record.
    innovations : (N, p) the one-step prediction errors on the fitted record, or None for a
        fit screened from the window's Gram (:mod:`.state_gram`), which has only their count.
    n_parameters : free parameters of the predictor (for information criteria).
    n_samples : number of innovations when ``innovations`` is None.
    """

    model: InnovationModel
    x0: np.ndarray
    innovations: np.ndarray | None
    n_parameters: int
    n_samples: int = 0

    def bic(self) -> float:
        """Bayesian information criterion ``N log det(Re) + n_par log N`` (lower is better)."""
        n_samples = self.innovations.shape[0] if self.innovations is not None else self.n_samples
        sign, logdet = np.linalg.slogdet(self.model.innovation_covariance)
        if sign <= 0 or not np.isfinite(logdet):
            return float("inf")
        return float(n_samples * logdet + self.n_parameters * np.log(n_samples))


def innovation_covariance(innovations: np.ndarray) -> np.ndarray:
    """(p, p) symmetric sample covariance ``e^T e / N`` of innovations (N, p)."""
    cov = innovations.T @ innovations / max(innovations.shape[0], 1)
    return 0.5 * (cov + cov.T)


def gain_from_predictor(A: np.ndarray, L: np.ndarray) -> np.ndarray:
    """The paper's gain ``K`` from the predictor gain ``L = A K``.

    ``A`` singular or ill-conditioned (a state with a pole at 0, e.g. of a noise-free record):
    the least-squares (minimum-norm) ``K``, not a solve that scipy warns about.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", linalg.LinAlgWarning)
            return linalg.solve(A, L)
    except (linalg.LinAlgError, linalg.LinAlgWarning):
        return linalg.lstsq(A, L)[0]


# Rows of C Abar^k computed per block (one product per block instead of one per lag).
IMPULSE_BLOCK = 64


def _impulse_rows(Abar: np.ndarray, C: np.ndarray, length: int) -> tuple[np.ndarray, int]:
    """``C Abar^k`` for k = 0..length-1: (length, p, n), zero once it has decayed to 1e-13.

    Also returns how many leading rows are filled (the rest are zero): the rows up to the first
    whose largest entry is below 1e-13 of ``C``'s, as a lag-by-lag recursion stops. The rows are
    made in blocks of :data:`IMPULSE_BLOCK` lags, ``block_{j+1} = block_j Abar^64``, the first
    block by doubling (``[R; R Abar^k]``), so a predictor decaying in a few hundred lags takes a
    handful of matrix products instead of hundreds of Python steps.
    """
    p, n = C.shape
    out = np.zeros((length, p, n))
    scale = max(np.abs(C).max(), np.finfo(float).tiny)
    block, power = C[None].copy(), Abar.copy()  # rows C Abar^0..k-1 and Abar^k
    while block.shape[0] < min(IMPULSE_BLOCK, length):
        block = np.concatenate([block, block @ power])
        power = power @ power
    start = 0
    while start < length:
        rows = block[: length - start]
        decayed = np.flatnonzero(np.abs(rows).reshape(rows.shape[0], -1).max(axis=1) < 1e-13 * scale)
        decayed = decayed[decayed + start > 0]  # row 0 (C itself) is always kept
        if decayed.size:
            stop = int(decayed[0])
            out[start : start + stop] = rows[:stop]
            return out, start + stop
        out[start : start + rows.shape[0]] = rows
        start += rows.shape[0]
        block = block @ power
    return out, length


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
    w = p + m
    n_gam = n * w
    n_x0 = n if fit_initial_state else 0
    n_par = n_gam + n_x0 + p * m
    if n_samples * p <= n_par:
        raise ValueError(f"{n_samples} samples are too few to refit {n_par} predictor parameters")
    impulse, filled = _impulse_rows(Abar, C, n_samples)  # C Abar^k, (N, p, n), zero after `filled` rows
    x0_rows = [impulse[:, c, :] if fit_initial_state else np.zeros((n_samples, 0)) for c in range(p)]
    system = _modal_normal_equations(Abar, C, u, y, x0_rows, filled)
    if system is None:
        system = _convolution_normal_equations(impulse, filled, u, y, x0_rows)
    normal, rhs, predict = system
    # A whisper of ridge keeps the solve defined if some direction is unexcited.
    ridge = 1e-12 * max(np.trace(normal) / n_par, np.finfo(float).tiny)
    theta = linalg.solve(normal + ridge * np.eye(n_par), rhs, assume_a="pos")
    gam = theta[:n_gam].reshape(n, w)
    x0 = theta[n_gam : n_gam + n] if fit_initial_state else np.zeros(n)
    D = theta[n_gam + n_x0 :].reshape(p, m)
    L, Bbar = gam[:, :p], gam[:, p:]
    innovations = y - predict(theta)
    A = Abar + L @ C
    B = Bbar + L @ D
    K = gain_from_predictor(A, L)
    model = InnovationModel(A, B, C.copy(), D, K, innovation_covariance(innovations))
    return PredictorFit(model, x0, innovations, free_parameters(n, p, m, initial_state=fit_initial_state))


# Above this condition number of Abar's eigenvectors the refit's regressors are formed by FFT
# convolutions instead of the modal filters (whose products they are combined from lose about
# cond(W) in accuracy).
MAX_MODAL_CONDITION = 1e6


def _modal_signals(Abar: np.ndarray, C: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The data filtered by each pole of ``Abar`` and each output's weights of them.

    Returns ``R`` (w, n, N): for each data channel ``j`` of ``v`` (N, w), the real and imaginary
    parts of its filtering by each pole pair, then by each real pole (time last: contiguous
    rows, no strided writes); ``B`` (p, n, n):
    ``B[c, i, r]`` the weight of signal ``r`` in the regressor of ``Gam[i, j]`` for output c.
    None when ``Abar`` has no well-conditioned eigenvector basis (:data:`MAX_MODAL_CONDITION`).
    """
    n, p = Abar.shape[0], C.shape[0]
    lam, W = linalg.eig(Abar)
    with np.errstate(all="ignore"):
        condition = np.linalg.cond(W)
    if not np.isfinite(condition) or condition > MAX_MODAL_CONDITION:
        return None
    upper, real = split_poles(lam)
    if 2 * upper.size + real.size != n:
        return None
    v_rows = np.ascontiguousarray(v.T)  # (w, N)
    R = np.empty((v.shape[1], n, v.shape[0]))
    for r, pole in enumerate(lam[upper]):
        g = signal.lfilter([0.0, 1.0], [1.0, -pole], v_rows, axis=-1)
        R[:, 2 * r], R[:, 2 * r + 1] = g.real, g.imag
    for r, pole in enumerate(lam[real].real, start=2 * upper.size):
        R[:, r] = signal.lfilter([0.0, 1.0], [1.0, -pole], v_rows, axis=-1)
    a = (C @ W)[:, :, None] * linalg.inv(W)[None, :, :]  # a[c, l, i] = (C W)[c, l] W^-1[l, i]
    B = np.empty((p, n, n))
    B[:, :, 0 : 2 * upper.size : 2] = 2.0 * a[:, upper, :].real.transpose(0, 2, 1)
    B[:, :, 1 : 2 * upper.size : 2] = -2.0 * a[:, upper, :].imag.transpose(0, 2, 1)
    B[:, :, 2 * upper.size :] = a[:, real, :].real.transpose(0, 2, 1)
    return R, B


def _modal_normal_equations(Abar: np.ndarray, C: np.ndarray, u: np.ndarray, y: np.ndarray,
                            x0_rows: list[np.ndarray], filled: int):
    """The refit's normal equations from the data filtered by each pole of ``Abar`` once.

    With ``Abar = W diag(lambda) W^-1`` the regressor of ``Gam[i, j]`` for output c is
    ``sum_l (C W)[c, l] W^-1[l, i] g_lj``, ``g_lj = z^-1 / (1 - lambda_l z^-1) v_j``: the same n w
    filtered signals (real and imaginary parts of a pair's) for every output, combined by a
    small matrix per output. So their Gram, formed once (N (n w)^2 flops), gives every output's
    normal equations, where the convolutions built each output's n w regressors and their Gram
    (N p (n w)^2 and p n w FFTs: 0.8 s per refit at 6 outputs, 14 states, 15000 samples).
    Same equations to rounding. ``scipy.signal.lfilter`` runs the first-order filters.

    Returns ``(normal, rhs, predict)`` as :func:`_convolution_normal_equations`, or None when
    ``Abar`` has no well-conditioned eigenvector basis (:data:`MAX_MODAL_CONDITION`).
    """
    n_samples, m = u.shape
    p = y.shape[1]
    w = p + m
    signals = _modal_signals(Abar, C, np.hstack([y, u]))
    if signals is None:
        return None
    R, B = signals
    n = Abar.shape[0]
    flat = R.reshape(w * n, n_samples)  # row j n + r: channel j filtered by pole r
    gram = (flat @ flat.T).reshape(w, n, w, n)
    signals_u = (flat @ u).reshape(w, n, m)
    signals_y = (flat @ y).reshape(w, n, p)
    gram_u = u.T @ u
    n_x0 = x0_rows[0].shape[1]
    n_gam = n * w
    n_par = n_gam + n_x0 + p * m
    normal = np.zeros((n_par, n_par))
    rhs = np.zeros(n_par)
    gam, init = slice(0, n_gam), slice(n_gam, n_gam + n_x0)
    for c in range(p):
        Bc, X = B[c], x0_rows[c][:filled]
        d = slice(n_gam + n_x0 + c * m, n_gam + n_x0 + (c + 1) * m)
        normal[gam, gam] += np.einsum("ir,jrks,ls->ijlk", Bc, gram, Bc, optimize=True).reshape(n_gam, n_gam)
        cross_u = np.einsum("ir,jrm->ijm", Bc, signals_u).reshape(n_gam, m)
        normal[gam, d] += cross_u
        normal[d, gam] += cross_u.T
        normal[d, d] += gram_u
        rhs[gam] += np.einsum("ir,jr->ij", Bc, signals_y[:, :, c]).reshape(n_gam)
        rhs[d] += u.T @ y[:, c]
        if n_x0:
            signals_x = (flat[:, :filled] @ X).reshape(w, n, n_x0)
            cross_x = np.einsum("ir,jrl->ijl", Bc, signals_x).reshape(n_gam, n_x0)
            normal[gam, init] += cross_x
            normal[init, gam] += cross_x.T
            normal[init, init] += X.T @ X
            cross_xu = X.T @ u[:filled]
            normal[init, d] += cross_xu
            normal[d, init] += cross_xu.T
            rhs[init] += X.T @ y[:filled, c]

    def predict(theta: np.ndarray) -> np.ndarray:
        gam_theta = theta[:n_gam].reshape(n, w)
        out = np.empty((n_samples, p))
        for c in range(p):
            weights = np.einsum("ij,ir->jr", gam_theta, B[c])  # (w, n)
            out[:, c] = weights.ravel() @ flat + u @ theta[n_gam + n_x0 + c * m : n_gam + n_x0 + (c + 1) * m]
            if n_x0:
                out[:, c] += x0_rows[c] @ theta[init]
        return out

    return normal, rhs, predict


def _convolution_normal_equations(impulse: np.ndarray, filled: int, u: np.ndarray, y: np.ndarray,
                                  x0_rows: list[np.ndarray]):
    """The refit's normal equations from each output's regressors, convolved by FFT.

    The general route (any stable ``Abar``). Returns ``(normal, rhs, predict)``: ``normal``
    (P, P) and ``rhs`` (P,) for the parameters ``[Gam (n w, row-major); x0; D (p m, row-major)]``,
    and ``predict(theta)`` (N, p) the one-step predictions.
    """
    n_samples, m = u.shape
    p, n = y.shape[1], impulse.shape[2]
    v = np.hstack([y, u])
    w = p + m
    n_gam, n_x0 = n * w, x0_rows[0].shape[1]
    n_par = n_gam + n_x0 + p * m
    # Regressor of Gam[i, j] for output c at time k: sum_{tau>=1} (C Abar^{tau-1})[c, i] v_j(k - tau).
    # The impulse is nonzero at lags 1..filled only, so N + filled points keep the circular
    # convolution's first N samples free of wrap-around (a stable predictor decays within a few
    # hundred samples: the FFTs are about half as long as 2 N).
    nfft = fft.next_fast_len(n_samples + filled)
    # Time along the last axis: contiguous transforms, and each output's design built transposed
    # (parameters x samples) so that no strided copy is needed.
    h = np.zeros((p, n, nfft))
    h[:, :, 1 : filled + 1] = impulse[:filled].transpose(1, 2, 0)
    h_f = fft.rfft(h, axis=-1)
    v_f = fft.rfft(v.T, n=nfft, axis=-1)  # (w, nfft / 2 + 1)
    normal = np.zeros((n_par, n_par))
    rhs = np.zeros(n_par)
    blocks = []
    for c in range(p):
        design = np.zeros((n_par, n_samples))  # transposed: one row per parameter
        z = fft.irfft(h_f[c][:, None, :] * v_f[None, :, :], n=nfft, axis=-1)  # (n, w, nfft)
        design[:n_gam] = z[:, :, :n_samples].reshape(n_gam, n_samples)
        design[n_gam : n_gam + n_x0] = x0_rows[c].T
        design[n_gam + n_x0 + c * m : n_gam + n_x0 + (c + 1) * m] = u.T
        normal += design @ design.T
        rhs += design @ y[:, c]
        blocks.append(design)

    def predict(theta: np.ndarray) -> np.ndarray:
        return np.column_stack([theta @ blocks[c] for c in range(p)])

    return normal, rhs, predict
