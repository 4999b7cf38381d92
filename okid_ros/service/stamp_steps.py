"""The step rule of a stream's stamps, in sample times: next, gap, duplicate or out of order.

One rule for both kinds of stream: :class:`okid_ros.service.sample_grid.SampleGrid` applies it
per source to the slots of the messages it assembles, and :class:`StampSequence` to a stream of
samples that arrive already whole (``okid_ros.service.identification`` fed by a caller other
than the grid). A step of at most half a sample time from the previous accepted stamp is a
duplicate, a step back by more than that is out of order, a step of more than
:data:`GAP_STEP` sample times is a gap (:func:`classify_step`). This module is the only place
that rule is written, and the one of the smallest step a grid may take for a time jump
(:func:`least_time_jump_s`).

No rclpy: the nodes and the offline tools both use this module.
"""

from __future__ import annotations

import math
from enum import Enum

from okid_ros.core.options import sample_time_problem

__all__ = ["GAP_STEP", "JUMP_MARGIN_SAMPLES", "MAX_STAMP_S", "StampStep", "StampSequence", "classify_step",
           "least_time_jump_s"]


class StampStep(Enum):
    """How a stamp relates to the previous accepted stamp of the same stream."""

    NEXT = "next"
    GAP = "gap"
    DUPLICATE = "duplicate"
    OUT_OF_ORDER = "out_of_order"


#: Largest step, in sample times, that is still the next sample; a longer step is a gap.
GAP_STEP = 1.5
#: Largest ``sec`` of a ROS 2 stamp (builtin_interfaces/Time.sec is an int32): no stamp lies further from 0.
MAX_STAMP_S = 2**31 - 1


def classify_step(step_samples: float) -> StampStep:
    """The grid's rule for the step of a stream from its previous accepted stamp.

    Parameters
    ----------
    step_samples : the step in sample times (a whole number of slots on the grid).

    Returns
    -------
    StampStep
        ``OUT_OF_ORDER`` below -1/2, ``DUPLICATE`` up to 1/2, ``GAP`` above ``GAP_STEP``,
        else ``NEXT``.

    Examples
    --------
    >>> [classify_step(s).value for s in (-3, 0.2, 1.0, 4.0)]
    ['out_of_order', 'duplicate', 'next', 'gap']
    """
    if step_samples < -0.5:
        return StampStep.OUT_OF_ORDER
    if step_samples <= 0.5:
        return StampStep.DUPLICATE
    if step_samples > GAP_STEP:
        return StampStep.GAP
    return StampStep.NEXT


#: Sample times beyond a grid's latency within which a stamp is never a time jump: the next
#: slot (one) with its stamp tolerance (under half a sample time) on either side.
JUMP_MARGIN_SAMPLES = 2


def least_time_jump_s(sample_time_s: float, latency_samples: int) -> float:
    """The smallest time-jump threshold of a sample grid [s]: ``latency_samples + 2`` sample times.

    A source may lag the newest stamp by up to ``latency_samples`` slots (the grid waits that
    long for it), and the next slot lies one sample time on, each stamp up to half a sample time
    off its slot: no step of the ongoing stream is a jump. The grid
    (:class:`okid_ros.service.sample_grid.SampleGrid`) uses ``max(time_jump_s, this)``.

    Examples
    --------
    >>> least_time_jump_s(0.008, 5), least_time_jump_s(2.0, 5)
    (0.056, 14.0)
    """
    return (int(latency_samples) + JUMP_MARGIN_SAMPLES) * float(sample_time_s)


class StampSequence:
    """The stamp check of one stream of whole samples (:func:`classify_step` in sample times).

    Parameters
    ----------
    sample_time_s : dt [s] > 0.
    """

    def __init__(self, sample_time_s: float) -> None:
        if problem := sample_time_problem(sample_time_s):
            raise ValueError(problem)
        self.sample_time_s = float(sample_time_s)
        self.reset()

    def reset(self) -> None:
        """Forget the last accepted stamp."""
        self._last: float | None = None

    @property
    def newest_stamp_s(self) -> float:
        """The last accepted stamp [s] (nan before the first)."""
        return math.nan if self._last is None else self._last

    def check(self, stamp_s: float) -> StampStep:
        """Classify a stamp against the last accepted one (``NEXT`` for the first); no state change."""
        if self._last is None:
            return StampStep.NEXT
        return classify_step((float(stamp_s) - self._last) / self.sample_time_s)

    def accept(self, stamp_s: float) -> None:
        """Make ``stamp_s`` the last accepted stamp."""
        self._last = float(stamp_s)
