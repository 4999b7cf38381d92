"""What the sample grid hands out: whole samples, and the counts of its messages and samples.

:class:`GridSample` is one complete sample of :class:`okid_ros.service.sample_grid.SampleGrid`
(its policy: that module's docstring); :class:`GridCounters` counts the messages it took and
refused, by reason (:data:`REJECTION_REASONS`), for the grid and for each source.

No rclpy: the nodes and the offline tools both use this module.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

__all__ = ["GridCounters", "GridSample", "NO_DATA", "REJECTION_REASONS", "RESTART_SKIP"]

#: ``skipped`` value that stands for a restart (start, reset, time jump) where a count is expected.
RESTART_SKIP = -1

#: The values of a message that declares it carries no data (REP 145,
#: :func:`okid_ros.service.inputs.declares_no_data`): the grid refuses it as ``no_data``; told apart by identity.
NO_DATA = np.zeros(0)
NO_DATA.flags.writeable = False


@dataclass
class GridSample:
    """One complete sample on the grid.

    Attributes
    ----------
    slot : grid index ``k`` (restarts at 0 after a re-anchoring).
    stamp_s : stamp of the first message received for this slot [s].
    u : (m,) inputs.
    y : (p,) outputs.
    skipped : slots dropped or never seen between the previous emitted sample and this one.
    restart : True for the first sample after the start, a reset or a time jump.
    time_jump : True for the first sample after a backward time jump (then ``restart`` too).
    """

    slot: int
    stamp_s: float
    u: np.ndarray
    y: np.ndarray
    skipped: int = 0
    restart: bool = False
    time_jump: bool = False

    @property
    def gap_before(self) -> bool:
        """True when this sample is not contiguous with the previous emitted one."""
        return self.skipped > 0 or self.restart


#: The reasons a message is refused (fields of :class:`GridCounters`), the likeliest mistake first.
REJECTION_REASONS = ("wrong_size", "nonfinite", "no_data", "late", "duplicate", "out_of_order", "off_grid",
                     "off_timeline")


@dataclass
class GridCounters:
    """Message and sample counts of a :class:`SampleGrid` (since start or reset)."""

    messages: int = 0
    samples_emitted: int = 0
    missing: int = 0
    late: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    nonfinite: int = 0
    wrong_size: int = 0
    no_data: int = 0  # messages whose covariance declares no data (REP 145)
    off_grid: int = 0
    off_timeline: int = 0  # lone stamps far from the timeline that the next messages did not confirm
    time_jumps: int = 0
    reanchors: int = 0

    @property
    def rejected_messages(self) -> int:
        """Messages refused as a whole or in part (late, duplicate, out of order, bad values, stamps)."""
        return sum(getattr(self, reason) for reason in REJECTION_REASONS)

    def rejections(self) -> dict[str, int]:
        """The messages refused, by reason (:data:`REJECTION_REASONS`, only those that occurred)."""
        return {reason: int(getattr(self, reason)) for reason in REJECTION_REASONS if getattr(self, reason)}

    def as_dict(self) -> dict[str, int]:
        out = {f.name: int(getattr(self, f.name)) for f in fields(self)}
        out["rejected_messages"] = self.rejected_messages
        return out
