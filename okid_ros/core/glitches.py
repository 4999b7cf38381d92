"""The glitch rule: one sample of some outputs far off (interference, a bit error), judged by a model.

A sample whose prediction error lies beyond :data:`GLITCH_STD` of the model's standard deviations
in some outputs, while not every output is beyond :data:`QUIET_STD` (every output at once is an
unmeasured impact), may be a glitch; it is one when the next sample's prediction error, the model
having taken the sample's prediction in its place, is within :data:`QUIET_STD` in every output
(:func:`settled`). Gaussian prediction errors never reach the limit; a structural change raises
their power over many samples, and a jump of the state goes on in the next samples' errors. The
change test (:mod:`.change_monitor`) and node 1's window (:mod:`.arx_glitches`) apply it; records
have their own test without a model (:mod:`.output_spikes`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["GLITCH_STD", "QUIET_STD", "glitch_rows", "settled"]

#: Standard deviations of the model's prediction error beyond which an output's sample may be a glitch.
#: Without the rule, ten glitches of 30 output spreads in a 20000-sample record made `track`
#: declare 3 structural changes.
GLITCH_STD = 12.0
#: ... the level no output passes in a glitch's company (every output at once: an impact) or in
#: the sample after it (the model's own expectation again).
QUIET_STD = GLITCH_STD / 3


def glitch_rows(errors: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Rows of prediction errors ``errors`` (N, p) that may be glitches, given the model's ``std`` (p,).

    None with one output: a glitch and an unmeasured impact look alike.
    """
    if errors.shape[1] < 2:
        return np.zeros(errors.shape[0], bool)
    size = np.abs(errors) / std
    return np.any(size > GLITCH_STD, axis=1) & ~np.all(size > QUIET_STD, axis=1)


def settled(error: np.ndarray, std: np.ndarray) -> bool:
    """The prediction error (p,) of the sample after a glitch, its prediction taken: as the model expects."""
    return bool(np.all(np.abs(error) <= QUIET_STD * std))
