"""The CUSUM's threshold: its average run length under no change, and the calibration's allowance.

The change test of :mod:`okid_ros.core.change_detection` sums the log-likelihood ratio
``l_k = a |w_k|^2 - b`` of a covariance increase by ``gamma`` (``a = (1 - 1/gamma) / 2``,
``b = (p / 2) ln gamma``). Under no change ``|w_k|^2`` is chi-square with ``p`` degrees of
freedom; :func:`cusum_average_run_length` computes the expected samples to a false alarm (ARL0)
by the Markov-chain method of Brook & Evans (1972), :func:`cusum_threshold` the threshold of a
requested ARL0, and :func:`calibration_scale` how much a calibration of finitely many samples
may inflate ``|w_k|^2``.

No rclpy; numpy and scipy only.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import stats

from okid_ros.core.options import DEFAULT_VARIANCE_RATIO

__all__ = [
    "CALIBRATION_CONFIDENCE",
    "DEFAULT_VARIANCE_RATIO",
    "calibration_scale",
    "cusum_average_run_length",
    "cusum_threshold",
]

#: Fraction of calibrations for which the false-alarm rate holds (:func:`calibration_scale`).
CALIBRATION_CONFIDENCE = 0.9


@lru_cache(maxsize=64)
def cusum_average_run_length(threshold: float, n_outputs: int, variance_ratio: float, bins: int = 400, *,
                             scale: float = 1.0) -> float:
    """ARL0 of the CUSUM of this module under no change (chi-square increments), in samples.

    Brook & Evans' Markov chain: ``g`` (scaled to ``s = |w|^2`` units, increments ``s - c``)
    discretized into ``bins`` states on ``[0, h)``; state 0 is ``g = 0``. ``scale``: the
    monitored ``|w|^2`` is ``scale`` times chi-square (a calibration that under-estimated the
    covariance by that factor, :func:`calibration_scale`).
    """
    gamma, p = float(variance_ratio), int(n_outputs)
    a = 0.5 * (1.0 - 1.0 / gamma) * float(scale)
    c = 0.5 * p * math.log(gamma) / a
    h = float(threshold) / a
    width = h / (bins - 0.5)
    centers = np.arange(bins) * width  # state i: g in [(i - 0.5) w, (i + 0.5) w), state 0 at g = 0
    upper = (np.arange(bins) + 0.5) * width
    cdf = stats.chi2(p).cdf
    # P(next state <= j | state i) = P(s <= upper_j - centers_i + c)
    below = cdf(np.maximum(upper[None, :] - centers[:, None] + c, 0.0))
    R = np.diff(np.concatenate([np.zeros((bins, 1)), below], axis=1), axis=1)
    arl = np.linalg.solve(np.eye(bins) - R, np.ones(bins))
    return float(arl[0])


@lru_cache(maxsize=64)
def cusum_threshold(
    false_alarm_samples: float, n_outputs: int, variance_ratio: float = DEFAULT_VARIANCE_RATIO, *,
    scale: float = 1.0,
) -> float:
    """The CUSUM threshold h [nats] whose ARL0 is ``false_alarm_samples`` (bisection).

    ``scale``: as in :func:`cusum_average_run_length` (1: an exact calibration).
    """
    target = float(false_alarm_samples)
    if not target > 1.0:
        raise ValueError(f"false_alarm_samples must be > 1, got {false_alarm_samples}")
    lo, hi = 0.0, 2.0
    while cusum_average_run_length(hi, n_outputs, variance_ratio, scale=scale) < target:
        lo, hi = hi, 2.0 * hi
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if cusum_average_run_length(mid, n_outputs, variance_ratio, scale=scale) < target:
            lo = mid
        else:
            hi = mid
    return hi


def calibration_scale(calibration_samples: float, n_outputs: int,
                      confidence: float = CALIBRATION_CONFIDENCE) -> float:
    """How much a calibration of ``calibration_samples`` may under-estimate the covariance.

    The calibrated covariance of ``N`` samples in ``p`` outputs scatters about the truth like
    ``chi2(p (N - 1)) / (p (N - 1))`` (pooled over the outputs), and an under-estimate inflates
    every monitored ``|w|^2`` for as long as the calibration is used. The threshold is therefore
    set for the ``1 - confidence`` quantile of that under-estimate, so that the false-alarm rate
    holds for ``confidence`` of the calibrations ("guaranteed conditional performance" of
    control charts with estimated parameters); ``calibration_samples`` may be the effective number
    (divided by the innovations' correlation factor).
    """
    dof = float(n_outputs) * max(float(calibration_samples) - 1.0, 1.0)
    return float(dof / stats.chi2.ppf(1.0 - float(confidence), dof))
