"""Whether node 2's sample stream has gone quiet (the end of a replayed bag, a sensor pause).

A delivered model is applied at the next sample
(:meth:`~okid_ros.service.estimation.ModalEstimationService.step`); when no sample comes,
:meth:`~okid_ros.service.estimation.ModalEstimationService.apply_ready_if_idle` applies it once
:class:`IdleWatch` says the stream is idle. While samples flow an outcome waits at most one
sample period, so the criterion only has to tell a pause from the spacing of the samples.
When the caller knows that the stream has ended (the end of a record processed offline),
:meth:`IdleWatch.end` makes it idle at once.
"""

from __future__ import annotations

import math

__all__ = ["IDLE_AFTER_S", "IDLE_AFTER_SAMPLES", "IdleWatch", "idle_after_s"]

#: The stream is idle after no sample for this long [s] (or :data:`IDLE_AFTER_SAMPLES` periods).
IDLE_AFTER_S = 0.5
#: Sample periods without a sample after which the stream is idle, when longer than :data:`IDLE_AFTER_S`.
IDLE_AFTER_SAMPLES = 5


def idle_after_s(sample_time_s: float) -> float:
    """How long without a sample makes the stream idle [s]: ``max(0.5 s, 5 sample periods)``."""
    return max(IDLE_AFTER_S, IDLE_AFTER_SAMPLES * float(sample_time_s))


class IdleWatch:
    """Whether no sample arrived for :func:`idle_after_s`, from the sample count seen at each look.

    Looked at now and then (a timer), never on the sample path: the quiet time runs from the
    first look that saw the current count, on the caller's monotonic clock. The stream is thus
    idle between :func:`idle_after_s` and that plus one period of the looks after its last sample.
    """

    def __init__(self) -> None:
        self._count = -1
        self._since_s = math.nan
        self._idle = False  # what the last look found

    def idle(self, count: int, now_s: float, sample_time_s: float) -> bool:
        """Whether the stream is idle at ``now_s`` [s], ``count`` samples having arrived in all."""
        if count != self._count:
            self._count, self._since_s = count, float(now_s)
            self._idle = False
        else:
            self._idle = now_s - self._since_s >= idle_after_s(sample_time_s)
        return self._idle

    def end(self, count: int) -> None:
        """The stream has ended after ``count`` samples: idle from now on, with no quiet time to wait.

        As if the quiet time had run out at the last look: a later look at the same count finds it
        idle too; a sample after all makes it busy again.
        """
        self._count, self._since_s, self._idle = int(count), -math.inf, True

    def still_idle(self, count: int) -> bool:
        """Whether the last look found the stream idle and no sample came since (``count`` samples in all)."""
        return self._idle and count == self._count
