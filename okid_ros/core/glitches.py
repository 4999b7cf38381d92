"""The glitch rule: one sample of some outputs far off, judged by the innovations of a model's predictor.

A glitch is a single output sample far off (interference, a telemetry bit error; for records
see :mod:`.output_spikes`). A sample whose innovation lies beyond :data:`GLITCH_STD` of the
model's innovation standard deviations in some outputs, while not every output is beyond
:data:`QUIET_STD`, is a glitch *candidate* (:func:`glitch_candidates`); it is a glitch when the
next sample's innovation, once the predictor has taken the candidate's prediction in its place,
is :func:`settled` (within :data:`QUIET_STD` in every output). Gaussian innovations never reach
:data:`GLITCH_STD`; a change raises their power over many samples, an unmeasured impact shows
in every output at once, and a jump of the state goes on in the next samples' innovations. With
one output a glitch and an impact look alike: never a candidate.

Used by the change test (:mod:`.change_monitor`), the modal-state estimator (:mod:`.estimator`)
and node 1's window, there with the ARX fit's prediction errors (:mod:`.arx_glitches`). No rclpy;
numpy only.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.output_spikes import most_spikes

__all__ = ["GLITCH_STD", "QUIET_STD", "glitch_candidates", "held_last", "settled", "without_glitches"]

#: Innovation standard deviations of the model that some output of a glitch's sample is beyond.
#: Without the rule, ten glitches of 30 output spreads in a 20000-sample record made `track`
#: declare 3 changes.
GLITCH_STD = 12.0
#: ... the level no output passes in a glitch's sample's company (every output at once: an
#: impact) or in the sample after it (the model's own expectation again).
QUIET_STD = GLITCH_STD / 3


def glitch_candidates(e: np.ndarray, innovation_std: np.ndarray) -> np.ndarray:
    """Rows of innovations ``e`` (N, p) that may be glitches, given the model's innovation std (p,).

    Returns a bool array (N,); all False with one output.
    """
    if e.shape[1] < 2:  # one output: a glitch and an unmeasured impact look alike
        return np.zeros(e.shape[0], bool)
    # A std of 0 (node 1's window fitted exactly: as many rows as coefficients) puts any error beyond it.
    with np.errstate(divide="ignore", invalid="ignore"):
        size = np.abs(e) / innovation_std
    return np.any(size > GLITCH_STD, axis=1) & ~np.all(size > QUIET_STD, axis=1)


def settled(e: np.ndarray, innovation_std: np.ndarray) -> bool:
    """The innovation ``e`` (p,) of the sample after a candidate, its prediction taken: as the model expects."""
    return bool(np.all(np.abs(e) <= QUIET_STD * innovation_std))



def without_glitches(predictor, innovation_std: np.ndarray, u: np.ndarray, y: np.ndarray, e: np.ndarray,
                     x0: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """The innovations ``e`` of a block (u (N, m), y (N, p)) run by ``predictor`` from state ``x0``, its glitches out.

    A glitch's outputs are replaced by their prediction (its innovation 0) and the block run
    again from ``x0``, the first one first (the later innovations depend on it); it stays
    taken out when the next sample's innovation is then :func:`settled`. A block's last sample
    is not judged here (no next sample: the change monitor holds it). ``predictor`` (an
    :class:`~okid_ros.core.statespace.InnovationPredictor`) ends in the block's last state.

    Returns
    -------
    e : (N, p) the innovations; y : (N, p) the outputs with the glitches' predictions in their place;
    the glitches taken out.
    """
    end_state, rejected, taken = predictor.x.copy(), set(), 0
    for _ in range(most_spikes(e.shape[0])):  # more: heavy-tailed innovations, tested as they are
        found = np.flatnonzero(glitch_candidates(e[:-1], innovation_std))
        candidates = [k for k in found if k not in rejected]
        if not candidates:
            break
        k = candidates[0]
        trial = y.copy()
        predictor.x = x0.copy()
        predictor.advance(u[:k], y[:k])
        trial[k] = predictor.predicted_output(u[k])  # its prediction in its place
        predictor.x = x0.copy()
        e_trial = predictor.run(u, trial)
        if settled(e_trial[k + 1], innovation_std):
            y, e, end_state = trial, e_trial, predictor.x.copy()
            taken += 1
        else:
            rejected.add(k)
    predictor.x = end_state
    return e, y, taken


def held_last(predictor, u: np.ndarray, y: np.ndarray, e: np.ndarray, x0: np.ndarray, first_index: int) -> tuple:
    """A block's last sample, a glitch candidate, held for the next sample's verdict, as the change monitor's step does.

    ``u`` (N, m), ``y`` (N, p) the block run by ``predictor`` from ``x0``, its glitches' predictions
    in place; ``e`` (N, p) its innovations. The predictor goes on from the last sample's prediction;
    the next block's first sample (or the monitor's ``finish``) judges it. Tested as it came, an
    absurd sample (1e200) overflowed the model-error check's squares or was declared a change.

    Returns
    -------
    (its innovation, its inputs, its index, the predictor's state after it as it came).
    """
    as_came = predictor.x
    predictor.x = x0.copy()
    predictor.advance(u[:-1], y[:-1])
    predictor.step(u[-1], predictor.predicted_output(u[-1]))  # its prediction in its place
    return e[-1], u[-1], first_index + e.shape[0] - 1, as_came
