"""Validation of an identified model against its record: fits, FRFs, MAC and output spectra.

The numbers behind the standard views (``tools/validation_plots.py``); no plotting here.

- :func:`fit_percent`: ``100 (1 - ||y - yhat|| / ||y - mean(y)||)`` per output (the NRMSE fit
  of MATLAB's ``compare``; 100 is perfect, 0 is no better than the mean).
- :func:`prediction_fits`: that fit for the one-step prediction (the innovation form's
  predictor, what the model is fitted for) and for the free-run simulation ``y = C x + D u``
  from the inputs alone (noise not predicted).
- :func:`h1_frf`: the measured FRF ``H1 = S_yu S_uu^-1`` from Welch cross spectra (Hann
  windows, half overlap).
- :func:`model_frf`: ``C (z I - A)^-1 B + D`` at ``z = exp(i 2 pi f dt)``.
- :func:`mac_matrix`: modal assurance criteria between two sets of shapes.
- :func:`output_singular_values`: singular values of the output cross-spectral matrix per
  frequency (complex mode indicator function, CMIF).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import linalg, signal

from okid_ros.core.channels import channel_scales
from okid_ros.core.statespace import one_step_prediction, simulate

__all__ = [
    "fit_percent",
    "prediction_fits",
    "default_segment_samples",
    "h1_frf",
    "model_frf",
    "mac_matrix",
    "output_singular_values",
]


def fit_percent(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray | float:
    """Fit in percent per output column (a float for 1-D input); NaN samples are left out.

    Parameters
    ----------
    y, y_hat : (N,) or (N, p) measured and estimated outputs.
    """
    y, y_hat = np.asarray(y, float), np.asarray(y_hat, float)
    one = y.ndim == 1
    y2, h2 = (y[:, None], y_hat[:, None]) if one else (y, y_hat)
    out = np.full(y2.shape[1], math.nan)
    for k in range(y2.shape[1]):
        ok = np.isfinite(y2[:, k]) & np.isfinite(h2[:, k])
        if ok.sum() < 2:
            continue
        spread = np.linalg.norm(y2[ok, k] - y2[ok, k].mean())
        if spread > 0:
            out[k] = 100.0 * (1.0 - np.linalg.norm(y2[ok, k] - h2[ok, k]) / spread)
    return float(out[0]) if one else out


def _offset(model, name: str, size: int) -> np.ndarray:
    """The model's offset of that name, zeros when it has none."""
    value = getattr(model, name, None)
    return np.zeros(size) if value is None else np.asarray(value, float).reshape(size)


def prediction_fits(model, u: np.ndarray, y: np.ndarray, *, burn_in: int | None = None) -> dict:
    """Fit % of the one-step prediction and of the free-run simulation on a record.

    Parameters
    ----------
    model : ``A, B, C, D, K`` (paper convention) and optionally ``x0`` (state at sample 0) and
        ``arx.order``.
    u : (N, m); y : (N, p).
    burn_in : samples left out at the start (default: the ARX order, at most N / 4), where the
        unknown initial state still shows.

    Returns
    -------
    ``{"one_step_pct": [p floats], "simulation_pct": [p floats], "burn_in_samples": int}``.
    """
    u, y = np.asarray(u, float), np.asarray(y, float)
    # The model applies to the signals less the offsets it removed (if any); fit % is invariant.
    u = u - _offset(model, "input_offset", u.shape[1])
    y = y - _offset(model, "output_offset", y.shape[1])
    if burn_in is None:
        burn_in = int(getattr(getattr(model, "arx", None), "order", 0) or 0)
    burn_in = int(min(max(burn_in, 0), y.shape[0] // 4))
    x0 = getattr(model, "x0", None)
    if x0 is not None and np.asarray(x0).shape != (model.A.shape[0],):
        x0 = None
    y_pred, _ = one_step_prediction(model, u, y, x0=x0)
    y_sim = simulate(model.A, model.B, model.C, model.D, u, x0)
    return {
        "one_step_pct": [float(v) for v in fit_percent(y[burn_in:], y_pred[burn_in:])],
        "simulation_pct": [float(v) for v in fit_percent(y[burn_in:], y_sim[burn_in:])],
        "burn_in_samples": burn_in,
    }


def default_segment_samples(n_samples: int) -> int:
    """Welch segment length: the largest power of two up to N / 4 (at least 64, at most N)."""
    if n_samples < 8:
        return max(n_samples, 1)
    return int(min(n_samples, max(64, 2 ** int(np.floor(np.log2(n_samples / 4))))))


def _cross_spectra(a: np.ndarray, b: np.ndarray, dt: float, nperseg: int) -> tuple[np.ndarray, np.ndarray]:
    """``S[f, i, j] = E[b_i conj(a_j)]`` for a (N, r), b (N, s): frequencies (F,), S (F, s, r)."""
    freq, S = None, None
    for i in range(b.shape[1]):
        for j in range(a.shape[1]):
            f, s_ij = signal.csd(a[:, j], b[:, i], fs=1.0 / dt, window="hann", nperseg=nperseg,
                                 noverlap=nperseg // 2, detrend="constant")
            if S is None:
                freq, S = f, np.zeros((f.size, b.shape[1], a.shape[1]), dtype=complex)
            S[:, i, j] = s_ij
    return freq, S


def h1_frf(u: np.ndarray, y: np.ndarray, sample_time_s: float, *, segment_samples: int | None = None
           ) -> tuple[np.ndarray, np.ndarray]:
    """Measured FRF ``H1 = S_yu S_uu^-1`` (unbiased by output noise uncorrelated with the inputs).

    Parameters
    ----------
    u : (N, m); y : (N, p); sample_time_s : seconds per sample.
    segment_samples : Welch segment length (default :func:`default_segment_samples`).

    Returns
    -------
    frequency_hz : (F,); H : (F, p, m) complex [output unit / input unit].
    """
    u, y = np.asarray(u, float), np.asarray(y, float)
    # Spectra of channels of unit spread (no overflow, S_uu not ill-conditioned by the units).
    scales = channel_scales(u, y)
    u, y = scales.scale(u, y)
    nperseg = segment_samples or default_segment_samples(u.shape[0])
    freq, S_yu = _cross_spectra(u, y, sample_time_s, nperseg)
    _, S_uu = _cross_spectra(u, u, sample_time_s, nperseg)
    H = np.full_like(S_yu, np.nan)
    with warnings.catch_warnings():
        # S_uu singular to working precision (fewer segments than inputs: a short record; inputs
        # that move together) does not determine H there: NaN, as for an exactly singular one.
        warnings.simplefilter("error", linalg.LinAlgWarning)
        for k in range(freq.size):
            try:
                H[k] = linalg.solve(S_uu[k].T, S_yu[k].T).T  # S_yu S_uu^-1
            except (linalg.LinAlgError, linalg.LinAlgWarning, ValueError):
                continue
    return freq, H * scales.output[None, :, None] / scales.input[None, None, :]


def model_frf(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, frequency_hz: np.ndarray,
              sample_time_s: float) -> np.ndarray:
    """``C (z I - A)^-1 B + D``, ``z = exp(i 2 pi f dt)``: (F, p, m) complex."""
    frequency_hz = np.atleast_1d(np.asarray(frequency_hz, float))
    lam, V = linalg.eig(A)
    CV = C @ V
    VB = linalg.solve(V, B)
    z = np.exp(1j * 2.0 * np.pi * frequency_hz * sample_time_s)
    return np.einsum("pn,fn,nm->fpm", CV, 1.0 / (z[:, None] - lam[None, :]), VB) + D[None, :, :]


def mac_matrix(shapes_a: np.ndarray, shapes_b: np.ndarray) -> np.ndarray:
    """``MAC[i, j] = |a_i^H b_j|^2 / (|a_i|^2 |b_j|^2)`` for shapes as columns: (p, k), (p, l) -> (k, l)."""
    a, b = np.asarray(shapes_a, complex), np.asarray(shapes_b, complex)
    num = np.abs(a.conj().T @ b) ** 2
    den = np.outer(np.sum(np.abs(a) ** 2, axis=0), np.sum(np.abs(b) ** 2, axis=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


def output_singular_values(y: np.ndarray, sample_time_s: float, *, segment_samples: int | None = None
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Singular values of the output cross-spectral matrix per frequency (CMIF).

    Returns
    -------
    frequency_hz : (F,); singular_values : (F, p), descending [output unit^2 / Hz].
    """
    y = np.asarray(y, float)
    nperseg = segment_samples or default_segment_samples(y.shape[0])
    freq, S_yy = _cross_spectra(y, y, sample_time_s, nperseg)
    return freq, np.linalg.svd(S_yy, compute_uv=False)
