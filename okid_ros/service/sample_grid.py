"""Assembly of synchronized input/output samples on the sample grid from partial channel updates.

The identification works on samples ``[u_k; y_k]`` taken at ``t_k = t_0 + k dt``. On live
topics the channels of one sample arrive in several messages (one ``sensor_msgs/Imu`` per
accelerometer, one ``geometry_msgs/WrenchStamped`` per thruster, ...), each with its own header
stamp. :class:`SampleGrid` collects them into whole samples.

Each *source* provides a fixed list of channels (indices into ``[u_0 .. u_{m-1}, y_0 .. y_{p-1}]``);
every channel is provided by exactly one source. :meth:`SampleGrid.add` takes one message's
values with its stamp in seconds and returns the samples that became complete, oldest first.

Policy
------
grid
    Anchored at the first accepted stamp: slot ``k`` is ``t_0 + k dt``. A stamp snaps to the
    nearest slot if it is within ``tolerance`` sample times of it (default 0.25), otherwise the
    message is rejected (``off_grid``). The phase ``t_0`` follows slow drifts of the stamps (it
    moves by 1 % of each accepted stamp's offset). If only off-grid messages arrive for more than
    ``latency_samples`` messages in a row, the grid is re-anchored at the newest stamp (the
    sensors' clock phase changed).
order
    A sample is emitted when all its channels have arrived, and samples are emitted in slot
    order: a complete slot waits for older incomplete slots until they complete or expire.
missing channels
    A slot still incomplete when a newer slot ``latency_samples`` (default 5) ahead has
    received data is dropped and counted as ``missing`` (one count per slot, whichever channels
    were absent). Slots for which nothing at all arrived count as missing too. Every dropped
    slot is a gap for the recursive window: the next emitted sample has ``skipped > 0``.
late channels
    A channel for a slot that was already emitted or dropped is counted ``late`` and dropped.
duplicates / out of order
    Per source, a stamp that maps to the slot of the source's previous message is a
    ``duplicate``, one that maps to an earlier slot is ``out_of_order``; both are rejected
    (the first value received for a slot is kept).
bad values
    A message whose values are not finite (NaN/Inf), whose stamp is not finite, or whose value
    count is not the source's channel count (``wrong_size``) is rejected as a whole.
time jumps
    A stamp more than ``time_jump_s`` (default 1 s) before the newest stamp seen (a bag replayed
    in a loop, a simulation restarted) re-anchors the grid there: incomplete slots are dropped
    (``missing``), the jump is counted, and the next emitted sample has ``restart=True``. Messages
    of the other sources still stamped before the jump are dropped (``late``) until each of them
    has jumped too. Forward jumps are ordinary gaps.

Whole samples
-------------
A stream of samples that arrive already whole (``okid_ros.service.identification`` fed by a
caller other than the grid) is checked by :class:`StampSequence` with the same rule in sample
times (:func:`classify_step`): a step of at most half a sample time from the previous accepted
stamp is a duplicate, a step back by more than that is out of order, a step of more than 1.5
sample times is a gap. This module is the only place that policy is written.

No rclpy: the nodes and the offline tools both use this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from enum import Enum
from typing import Sequence

import numpy as np

from okid_ros.core.options import sample_time_problem

__all__ = [
    "GridSample",
    "GridCounters",
    "SampleGrid",
    "RESTART_SKIP",
    "StampStep",
    "StampSequence",
    "classify_step",
]

#: ``skipped`` value that stands for a restart (start, reset, time jump) where a count is expected.
RESTART_SKIP = -1

#: Fraction of each accepted stamp's offset from its slot by which the grid phase follows it.
PHASE_GAIN = 0.01


class StampStep(Enum):
    """How a stamp relates to the previous accepted stamp of the same stream."""

    NEXT = "next"
    GAP = "gap"
    DUPLICATE = "duplicate"
    OUT_OF_ORDER = "out_of_order"


#: Largest step, in sample times, that is still the next sample; a longer step is a gap.
GAP_STEP = 1.5


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
REJECTION_REASONS = ("wrong_size", "nonfinite", "late", "duplicate", "out_of_order", "off_grid")


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
    off_grid: int = 0
    time_jumps: int = 0
    reanchors: int = 0

    @property
    def rejected_messages(self) -> int:
        """Messages refused as a whole or in part (late, duplicate, out of order, bad values)."""
        return sum(getattr(self, reason) for reason in REJECTION_REASONS)

    def rejections(self) -> dict[str, int]:
        """The messages refused, by reason (:data:`REJECTION_REASONS`, only those that occurred)."""
        return {reason: int(getattr(self, reason)) for reason in REJECTION_REASONS if getattr(self, reason)}

    def as_dict(self) -> dict[str, int]:
        out = {f.name: int(getattr(self, f.name)) for f in fields(self)}
        out["rejected_messages"] = self.rejected_messages
        return out


@dataclass
class _Slot:
    values: np.ndarray
    filled: np.ndarray
    stamp_s: float


@dataclass
class _Source:
    channels: np.ndarray
    last_slot: int | None = None
    before_jump: bool = False  # still sending stamps from before the last backward time jump
    counters: GridCounters = field(default_factory=GridCounters)


class SampleGrid:
    """Collects per-source channel updates into whole samples on the sample grid.

    Parameters
    ----------
    sample_time_s : dt [s] > 0.
    n_inputs, n_outputs : m and p; channel ``c < m`` is ``u_c``, channel ``m + j`` is ``y_j``.
    sources : for each source, the channel indices its values fill, in the order of its values.
        Every channel must be filled by exactly one source.
    tolerance : largest distance of a stamp from its slot, as a fraction of dt, in (0, 0.5).
    latency_samples : how many slots newer data may be ahead before an incomplete slot is
        dropped (>= 0; 0 drops a slot as soon as a newer slot receives data).
    time_jump_s : a stamp this much older than the newest one re-anchors the grid [s].

    Raises
    ------
    ValueError naming the bad argument.
    """

    def __init__(
        self,
        sample_time_s: float,
        n_inputs: int,
        n_outputs: int,
        sources: Sequence[Sequence[int]],
        *,
        tolerance: float = 0.25,
        latency_samples: int = 5,
        time_jump_s: float = 1.0,
    ) -> None:
        if problem := sample_time_problem(sample_time_s):
            raise ValueError(problem)
        if int(n_inputs) < 0 or int(n_outputs) < 1:
            raise ValueError(f"need m >= 0 inputs (0: outputs only) and at least one output, got m={n_inputs}, "
                             f"p={n_outputs}")
        if not 0.0 < tolerance < 0.5:
            raise ValueError(f"tolerance must be in (0, 0.5) sample times, got {tolerance}")
        if int(latency_samples) < 0:
            raise ValueError(f"latency_samples must be >= 0, got {latency_samples}")
        if not time_jump_s > 0:
            raise ValueError(f"time_jump_s must be > 0, got {time_jump_s}")
        self.sample_time_s = float(sample_time_s)
        self.n_inputs = m = int(n_inputs)
        self.n_outputs = int(n_outputs)
        self.n_channels = n = m + self.n_outputs
        self.tolerance = float(tolerance)
        self.latency_samples = int(latency_samples)
        self.time_jump_s = float(time_jump_s)
        owner = [-1] * n
        self._sources: list[_Source] = []
        for s, chans in enumerate(sources):
            chans = np.asarray(list(chans), dtype=np.int64)
            if chans.size == 0:
                raise ValueError(f"source {s} provides no channel")
            for c in chans:
                if not 0 <= c < n:
                    raise ValueError(f"source {s} names channel {c}; channels are 0..{n - 1}")
                if owner[c] >= 0:
                    raise ValueError(
                        f"channel {self.channel_name(c)} is provided by sources {owner[c]} and {s}; "
                        "each channel must come from exactly one source"
                    )
                owner[c] = s
            self._sources.append(_Source(chans))
        missing = [self.channel_name(c) for c in range(n) if owner[c] < 0]
        if missing:
            raise ValueError(f"no source provides channel(s) {', '.join(missing)}")
        self.reset()

    def channel_name(self, channel: int) -> str:
        """'u0', 'u1', ..., 'y0', ... for a channel index."""
        m = self.n_inputs
        return f"u{channel}" if channel < m else f"y{channel - m}"

    @property
    def n_sources(self) -> int:
        return len(self._sources)

    def reset(self) -> None:
        """Forget the grid, pending slots and counters."""
        self.counters = GridCounters()
        for src in self._sources:
            src.counters = GridCounters()
            src.last_slot = None
            src.before_jump = False
        self._clear_grid()

    def _clear_grid(self) -> None:
        self._anchor: float | None = None
        self._pending: dict[int, _Slot] = {}
        self._newest_slot: int | None = None
        self._newest_stamp = -math.inf
        self._horizon: int | None = None  # newest slot emitted or dropped
        self._last_emitted: int | None = None
        self._restart = True
        self._jumped = False
        self._off_grid_run = 0

    def source_counters(self, source: int) -> GridCounters:
        """Counters of one source (messages and the rejections attributed to it)."""
        return self._sources[source].counters

    @property
    def pending_slots(self) -> int:
        return len(self._pending)

    # ------------------------------------------------------------------ input
    def _count(self, src: _Source, name: str, amount: int = 1) -> None:
        setattr(self.counters, name, getattr(self.counters, name) + amount)
        setattr(src.counters, name, getattr(src.counters, name) + amount)

    def add(self, source: int, stamp_s: float, values) -> list[GridSample]:
        """Offer one message's channel values; return the samples that became complete.

        Parameters
        ----------
        source : index of the source (order of ``sources`` at construction).
        stamp_s : the message's stamp [s].
        values : the source's channel values, in the order of its channel list.
        """
        src = self._sources[source]
        self._count(src, "messages")
        vals = np.asarray(values, dtype=float).reshape(-1)
        if vals.size != src.channels.size:
            self._count(src, "wrong_size")
            return []
        stamp_s = float(stamp_s)
        if not math.isfinite(stamp_s) or not np.isfinite(vals).all():
            self._count(src, "nonfinite")
            return []
        dt = self.sample_time_s
        out: list[GridSample] = []
        if self._anchor is None:
            self._anchor = stamp_s
        elif src.before_jump:
            if stamp_s > self._newest_stamp + self.time_jump_s:
                self._count(src, "late")  # stamped before the time jump the other sources made
                return out
            src.before_jump = False
        elif stamp_s < self._newest_stamp - self.time_jump_s:
            out += self._time_jump(src, stamp_s)
        if not math.isfinite((stamp_s - self._anchor) / dt):
            self._count(src, "nonfinite")  # a stamp so far ahead its slot number is not a number
            return out
        k, offset = self._slot_of(stamp_s)
        if abs(offset) > self.tolerance * dt:
            self._off_grid_run += 1
            if self._off_grid_run <= max(self.latency_samples, 1) * self.n_sources:
                self._count(src, "off_grid")
                return out
            # Only off-grid stamps for a while: the sensors' clock phase moved. Re-anchor here.
            out += self._drop_all_pending()
            if self._horizon is not None:  # the slots up to this stamp are lost too: count them
                self.counters.missing += max(0, math.floor((stamp_s - self._anchor) / dt) - self._horizon)
            self._clear_grid()
            self._anchor = stamp_s
            for s in self._sources:
                s.last_slot = None
            self.counters.reanchors += 1
            k, offset = 0, 0.0
        self._off_grid_run = 0
        # Follow slow drifts of the sensors' clock phase (an exponential average of the offsets).
        self._anchor += PHASE_GAIN * offset
        if src.last_slot is not None:
            step = classify_step(k - src.last_slot)
            if step in (StampStep.DUPLICATE, StampStep.OUT_OF_ORDER):
                self._count(src, step.value)
                return out
        src.last_slot = k
        if self._horizon is not None and k <= self._horizon:
            self._count(src, "late")
            return out
        slot = self._pending.get(k)
        if slot is None:
            slot = _Slot(np.zeros(self.n_channels), np.zeros(self.n_channels, dtype=bool), stamp_s)
            self._pending[k] = slot
        slot.values[src.channels] = vals
        slot.filled[src.channels] = True
        if self._newest_slot is None or k > self._newest_slot:
            self._newest_slot = k
        self._newest_stamp = max(self._newest_stamp, stamp_s)
        out += self._emit_ready()
        return out

    def _slot_of(self, stamp_s: float) -> tuple[int, float]:
        rel = (stamp_s - self._anchor) / self.sample_time_s
        k = int(math.floor(rel + 0.5))
        return k, (rel - k) * self.sample_time_s

    def _time_jump(self, src: _Source, stamp_s: float) -> list[GridSample]:
        out = self._drop_all_pending()
        self.counters.time_jumps += 1
        src.counters.time_jumps += 1
        self._clear_grid()
        self._jumped = True
        self._anchor = stamp_s
        for s in self._sources:
            s.last_slot = None
            s.before_jump = s is not src
        return out

    def _drop_all_pending(self) -> list[GridSample]:
        """Emit what is complete, drop the rest as missing (time jump, re-anchoring, flush)."""
        out: list[GridSample] = []
        for k in sorted(self._pending):
            slot = self._pending.pop(k)
            if slot.filled.all():
                out.append(self._emit(k, slot))
            else:
                self._finish(k, dropped=True)
        return out

    def flush(self) -> list[GridSample]:
        """Emit every complete pending slot and drop the incomplete ones (end of a record)."""
        return self._drop_all_pending()

    # ------------------------------------------------------------------ output
    def _emit_ready(self) -> list[GridSample]:
        out: list[GridSample] = []
        while self._pending:
            k = min(self._pending)
            slot = self._pending[k]
            if slot.filled.all():
                del self._pending[k]
                out.append(self._emit(k, slot))
            elif self._newest_slot - k > self.latency_samples:
                del self._pending[k]
                self._finish(k, dropped=True)
            else:
                break
        return out

    def _finish(self, k: int, dropped: bool) -> None:
        """Slot k is emitted or dropped: count it and the never-seen slots before it as missing."""
        if self._horizon is not None and k > self._horizon + 1:
            self.counters.missing += k - self._horizon - 1
        if dropped:
            self.counters.missing += 1
        self._horizon = k

    def _emit(self, k: int, slot: _Slot) -> GridSample:
        last = self._last_emitted
        skipped = 0 if (last is None or self._restart) else k - last - 1
        self._finish(k, dropped=False)
        self._last_emitted = k
        m = self.n_inputs
        sample = GridSample(
            slot=k, stamp_s=slot.stamp_s, u=slot.values[:m].copy(), y=slot.values[m:].copy(),
            skipped=skipped, restart=self._restart, time_jump=self._jumped,
        )
        self._restart = False
        self._jumped = False
        self.counters.samples_emitted += 1
        return sample
