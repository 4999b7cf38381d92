"""A step of an output's level (a sensor re-zeroed, a cable replugged) in a live predictor's innovations.

A record's level shifts are found from the samples (:mod:`okid_ros.core.level_shifts`); on the
sample path node 2 sees one in its estimator's innovations first. An offset ``d`` (p,) added to
the outputs from sample ``theta`` on adds to the innovations of a predictor ``xhat+ = F xhat +
G_u u + G_y y``, for ``k >= theta``::

    d - C sum_{j < k - theta} F^j G_y d  =  G_inf d + C F^(k - theta) S d,
    S = (I - F)^{-1} G_y,   G_inf = I - C S

a constant and a free response from the state error ``S d``: the regressors of the state-jump
fit (:mod:`okid_ros.core.state_jump`). An explained excursion whose fitted constant is beyond
noise is therefore an output step ``d = G_inf^{-1} c`` (``c`` the constant in the record's
units), and the predictor's state holds ``sum_{j < k - theta} F^j G_y d`` of it. ``G_inf`` is the
inverse of the innovation model's transfer function at frequency 0; it is invertible when
``A`` has no eigenvalue at 1 (a stable model).

The constant is fitted over tens of samples, and ``G_inf^{-1}`` carries its noise into every
channel: on the steel subframe (28 outputs) a re-zero of 3 spreads in one channel came back with
up to 0.2 spreads in others, which, taken off, made a new excursion. So a channel's step is taken
only where it lies beyond :data:`STEP_CHANNEL_STD` of its noise (the constant's noise, ``P1 b /
L`` per whitened component over the ``L`` fitted samples, through ``G_inf^{-1} W^{-1}``); the
rest of the constant is left to the change test's tracked mean.

No rclpy; numpy and scipy only.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from okid_ros.core.state_jump import StateJump

__all__ = ["STEP_CHANNEL_STD", "STEP_PROBABILITY", "output_step", "step_response"]

# A fitted constant whose energy white innovations reach this rarely is an output step.
STEP_PROBABILITY = 1e-6
# A channel's step is taken when it lies beyond this many of its noise's standard deviations.
STEP_CHANNEL_STD = 6.0


def output_step(jump: StateJump, F: np.ndarray, G_y: np.ndarray, C: np.ndarray, whiten: np.ndarray, *,
                baseline_power: float = 1.0) -> np.ndarray | None:
    """The outputs' step (p,), in the record's units, that an explained jump's constant stands for.

    Parameters
    ----------
    jump : the state-jump fit of whitened innovations ``whiten @ e``.
    F : (n, n), G_y : (n, p) the predictor's state matrix and output gain; C : (p, n).
    whiten : (p, p) the whitening of the innovations the fit was made of.
    baseline_power : the mean ``|z|^2 / p`` of white innovations (1 for an exact model).

    Returns
    -------
    ``d`` (p,), 0 in the channels whose step is within noise; None when the whole constant is
    (``samples |c|^2 / b`` below the chi-square level of :data:`STEP_PROBABILITY`), no channel's
    step is beyond it, or ``G_inf`` is singular.
    """
    samples = jump.last_index - jump.onset_index + 1
    c = np.asarray(jump.offset, dtype=float)
    p = c.size
    if not samples * float(c @ c) / baseline_power > stats.chi2.isf(STEP_PROBABILITY, p):
        return None
    try:
        S = np.linalg.solve(np.eye(F.shape[0]) - F, G_y)
        to_step = np.linalg.solve(np.eye(p) - C @ S, np.linalg.inv(whiten))  # G_inf^-1 W^-1 (p, p)
    except np.linalg.LinAlgError:
        return None
    d = to_step @ c
    noise = np.sqrt(max(jump.power_after, 1.0) * baseline_power / samples * np.einsum("ij,ij->i", to_step, to_step))
    d = np.where(np.abs(d) > STEP_CHANNEL_STD * noise, d, 0.0)
    return d if np.all(np.isfinite(d)) and np.any(d) else None


def step_response(F: np.ndarray, G_y: np.ndarray, d: np.ndarray, samples: int | None = None) -> np.ndarray:
    """(n,) ``sum_{j < samples} F^j G_y d``: what a predictor's state took of an output step over ``samples``.

    None: the steady value ``(I - F)^{-1} G_y d``.
    """
    steady = np.linalg.solve(np.eye(F.shape[0]) - F, G_y @ np.asarray(d, dtype=float))
    if samples is None:
        return steady
    return steady - np.linalg.matrix_power(F, int(samples)) @ steady
