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

No rclpy; numpy and scipy only.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from okid_ros.core.state_jump import StateJump

__all__ = ["STEP_PROBABILITY", "output_step", "step_response"]

# A fitted constant whose energy white innovations reach this rarely is an output step.
STEP_PROBABILITY = 1e-6


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
    ``d`` (p,), or None when the constant is within noise (``samples |c|^2 / b`` below the
    chi-square level of :data:`STEP_PROBABILITY`) or ``G_inf`` is singular.
    """
    samples = jump.last_index - jump.onset_index + 1
    c = np.asarray(jump.offset, dtype=float)
    p = c.size
    if not samples * float(c @ c) / baseline_power > stats.chi2.isf(STEP_PROBABILITY, p):
        return None
    try:
        S = np.linalg.solve(np.eye(F.shape[0]) - F, G_y)
        d = np.linalg.solve(np.eye(p) - C @ S, np.linalg.solve(whiten, c))
    except np.linalg.LinAlgError:
        return None
    return d if np.all(np.isfinite(d)) else None


def step_response(F: np.ndarray, G_y: np.ndarray, d: np.ndarray, samples: int | None = None) -> np.ndarray:
    """(n,) ``sum_{j < samples} F^j G_y d``: what a predictor's state took of an output step over ``samples``.

    None: the steady value ``(I - F)^{-1} G_y d``.
    """
    steady = np.linalg.solve(np.eye(F.shape[0]) - F, G_y @ np.asarray(d, dtype=float))
    if samples is None:
        return steady
    return steady - np.linalg.matrix_power(F, int(samples)) @ steady
