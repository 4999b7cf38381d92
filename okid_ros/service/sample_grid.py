"""Assembly of synchronized input/output samples on the sample grid from partial channel updates.

The identification works on samples ``[u_k; y_k]`` taken at ``t_k = t_0 + k dt``. On live
topics the channels of one sample arrive in several messages (one ``sensor_msgs/Imu`` per
accelerometer, one ``geometry_msgs/WrenchStamped`` per thruster, ...), each with its own header
stamp. :class:`SampleGrid` collects them into whole samples.

Each *source* provides a fixed list of channels (indices into ``[u_0 .. u_{m-1}, y_0 .. y_{p-1}]``);
every channel is provided by exactly one source (:mod:`okid_ros.service.grid_sources`).
:meth:`SampleGrid.add` takes one message's values with its stamp in seconds and returns the
samples that became complete, oldest first (:class:`GridSample`, :mod:`okid_ros.service.grid_samples`).

Policy
------
grid
    Anchored at the first accepted stamp: slot ``k`` is ``t_0 + k dt``. A stamp snaps to the
    nearest slot if it is within ``tolerance`` sample times of it (default 0.25), otherwise the
    message is rejected (``off_grid``). The phase ``t_0`` follows slow drifts of the stamps (it
    moves by 1 % of each accepted stamp's offset). If only off-grid messages arrive for more than
    ``latency_samples`` times the number of sources messages in a row (at least one per source),
    the grid is re-anchored at the newest stamp (the sensors' clock phase changed).
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
    A message whose values are not finite (NaN/Inf), whose stamp is not finite or beyond any ROS 2
    time (:data:`MAX_STAMP_S`; an array source's stamp field may hold anything), both counted
    ``nonfinite``, whose value count is not the source's (``wrong_size``), or that declares it carries no
    data (:data:`NO_DATA`, REP 145: ``no_data``) is rejected as a whole.
timeline
    The *timeline* is the newest stamp of the stream (taken, or confirmed as below). A stamp
    more than the *jump threshold* before or after it is held as the *candidate* of a new
    timeline instead of being acted on: one corrupt stamp (0, or 1e6 s ahead) must not restart
    the grid and the nodes, nor strand the timeline where every later message looks like a jump.
    The threshold: ``time_jump_s`` (default 1 s), at least ``latency_samples + 2`` sample times
    (:func:`least_time_jump_s`: a source lagging within the latency, the next slot). Then:

    - a stamp off the old timeline within the threshold of the candidate, from any source
      (one still before the last jump or step too), confirms it: the candidate is taken as the
      first message of the new timeline (a time jump or a forward step, below), then the
      confirming one. The candidate's own source must step
      on from it (a repeat of its slot is a ``duplicate``, an earlier slot ``out_of_order``);
    - a stamp on the old timeline from the candidate's source, or one taking the old timeline
      more than the threshold on, rejects the candidate: counted ``off_timeline``. The other
      sources' messages on the old timeline are taken meanwhile (after a loop the sources jump
      one after another);
    - a stamp off both timelines rejects the candidate and becomes the candidate.

    A real jump or step thus takes effect one message late, with no sample lost.
    :meth:`SampleGrid.flush` rejects a candidate still held; :meth:`SampleGrid.reset` forgets it.
time jumps
    A confirmed timeline before the old one (a bag replayed in a loop, a simulation restarted)
    re-anchors the grid there: incomplete slots are dropped (``missing``), the jump is counted,
    and the next sample (also after a re-anchoring) has ``restart`` and ``time_jump`` set. A
    confirmed timeline after the old one (a clock set forward) is a gap (``missing``, ``skipped > 0``).
    After either, the messages of the other sources still on the old side are dropped
    (``late``) until each source has moved too.

Whole samples
-------------
A stream of whole samples is checked by :class:`StampSequence` with the grid's step rule
(:func:`classify_step`), both from :mod:`okid_ros.service.stamp_steps` and re-exported here, as
are :class:`GridSample`, :class:`GridCounters`, :data:`RESTART_SKIP` and :data:`REJECTION_REASONS`
from :mod:`okid_ros.service.grid_samples`.

No rclpy: the nodes and the offline tools both use this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from okid_ros.core.options import sample_time_problem
from okid_ros.service.channels import channel_name
from okid_ros.service.grid_samples import NO_DATA, REJECTION_REASONS, RESTART_SKIP, GridCounters, GridSample
from okid_ros.service.grid_sources import GridSource, grid_sources
from okid_ros.service.stamp_steps import MAX_STAMP_S, StampSequence, StampStep, classify_step, least_time_jump_s

__all__ = ["GridSample", "GridCounters", "SampleGrid", "MAX_STAMP_S", "RESTART_SKIP", "REJECTION_REASONS",
           "StampStep", "StampSequence", "classify_step", "least_time_jump_s"]

#: Fraction of each accepted stamp's offset from its slot by which the grid phase follows it.
PHASE_GAIN = 0.01


@dataclass
class _Slot:
    values: np.ndarray
    filled: int  # bit c set: channel c has arrived (a Python int: cheaper per message than an array)
    stamp_s: float


@dataclass
class _Candidate:
    """A message stamped off the timeline, held until the messages after it confirm or refute it."""

    source: int
    stamp_s: float
    values: np.ndarray
    old_newest_s: float  # the newest stamp of the old timeline when the candidate came


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
    time_jump_s : a stamp more than this before or after the newest one starts a new timeline [s],
        once the next message confirms it (a time jump back, a gap forward; module docstring);
        the grid uses at least :func:`least_time_jump_s` (:attr:`jump_threshold_s`).

    Raises
    ------
    ValueError naming the bad argument.
    """

    def __init__(self, sample_time_s: float, n_inputs: int, n_outputs: int, sources: Sequence[Sequence[int]], *,
                 tolerance: float = 0.25, latency_samples: int = 5, time_jump_s: float = 1.0) -> None:
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
        self._sources = grid_sources(sources, m, n)
        self._all_bits = (1 << n) - 1
        self.reset()

    def channel_name(self, channel: int) -> str:
        """'u0', 'u1', ..., 'y0', ... for a channel index."""
        return channel_name(channel, self.n_inputs)

    @property
    def jump_threshold_s(self) -> float:
        """The step from the newest stamp beyond which a stamp is off the timeline [s] (module docstring)."""
        return max(self.time_jump_s, least_time_jump_s(self.sample_time_s, self.latency_samples))

    @property
    def n_sources(self) -> int:
        return len(self._sources)

    def reset(self) -> None:
        """Forget the grid, pending slots, a held candidate timeline and the counters."""
        self.counters = GridCounters()
        for src in self._sources:
            src.counters = GridCounters()
            src.last_slot = None
            src.before_jump = False
        self._candidate: _Candidate | None = None
        self._jumped = False  # a time jump the next sample is to carry (kept by _clear_grid)
        self._old_side = 1  # where before_jump stamps lie (_side): +1 after a jump back, -1 a step on
        self._clear_grid()

    def _clear_grid(self) -> None:
        self._anchor: float | None = None
        self._pending: dict[int, _Slot] = {}
        self._newest_slot: int | None = None
        self._newest_stamp = -math.inf
        self._horizon: int | None = None  # newest slot emitted or dropped
        self._last_emitted: int | None = None
        self._restart = True
        self._off_grid_run = 0

    def source_counters(self, source: int) -> GridCounters:
        """Counters of one source (messages and the rejections attributed to it)."""
        return self._sources[source].counters

    @property
    def pending_slots(self) -> int:
        return len(self._pending)

    # ------------------------------------------------------------------ input
    def _count(self, src: GridSource, name: str, amount: int = 1) -> None:
        setattr(self.counters, name, getattr(self.counters, name) + amount)
        setattr(src.counters, name, getattr(src.counters, name) + amount)

    def add(self, source: int, stamp_s: float, values) -> list[GridSample]:
        """Offer one message's channel values; return the samples that became complete.

        Parameters
        ----------
        source : index of the source (order of ``sources`` at construction).
        stamp_s : the message's stamp [s].
        values : the source's channel values, in the order of its channel list, or :data:`NO_DATA`.
        """
        src = self._sources[source]
        self._count(src, "messages")
        if values is NO_DATA:
            self._count(src, "no_data")
            return []
        vals = np.asarray(values, dtype=float).reshape(-1)
        if vals.size != src.channels.size:
            self._count(src, "wrong_size")
            return []
        stamp_s = float(stamp_s)
        if not abs(stamp_s) <= MAX_STAMP_S or not np.isfinite(vals).all():  # NaN fails the comparison too
            self._count(src, "nonfinite")
            return []
        if self._anchor is None:
            self._anchor = stamp_s
        return self._follow_timeline(source, stamp_s, vals)

    def _follow_timeline(self, source: int, stamp_s: float, vals: np.ndarray) -> list[GridSample]:
        """Place a message on the timeline; hold, confirm or reject one off it (module docstring)."""
        src = self._sources[source]
        jump = self.jump_threshold_s
        side = self._side(stamp_s, jump)
        cand = self._candidate
        agrees = cand is not None and abs(stamp_s - cand.stamp_s) <= jump
        if src.before_jump and side == self._old_side and not agrees:
            # Stamped before the jump or step the other sources made. One that agrees with a held
            # candidate confirms it instead (a source that stepped on alone and now comes back).
            self._count(src, "late")
            return []
        if side == 0:
            src.before_jump = False
            if cand is not None and (cand.source == source or stamp_s > cand.old_newest_s + jump):
                self._reject_candidate()  # the old timeline goes on: the candidate was a lone stamp
            # The timeline follows the stream also where the grid refuses it (off its phase).
            self._newest_stamp = max(self._newest_stamp, stamp_s)
            return self._place(src, stamp_s, vals)
        if agrees:
            if cand.source == source:
                # A source confirms its own candidate only by stepping on from it: a repeat of
                # one corrupt stamp is no timeline.
                step = classify_step((stamp_s - cand.stamp_s) / self.sample_time_s)
                if step in (StampStep.DUPLICATE, StampStep.OUT_OF_ORDER):
                    self._count(src, step.value)
                    return []
            self._candidate = None
            return self._take_candidate(cand) + self._follow_timeline(source, stamp_s, vals)
        self._reject_candidate()  # another stamp off both timelines: the candidate was alone
        self._candidate = _Candidate(source, stamp_s, vals.copy(), self._newest_stamp)
        return []

    def _side(self, stamp_s: float, jump: float) -> int:
        """-1 / +1 for a stamp more than ``jump`` before / after the timeline, else (or none yet) 0."""
        step = stamp_s - self._newest_stamp
        if not math.isfinite(self._newest_stamp) or abs(step) <= jump:
            return 0
        return 1 if step > 0 else -1

    def _reject_candidate(self) -> None:
        cand, self._candidate = self._candidate, None
        if cand is not None:
            self._count(self._sources[cand.source], "off_timeline")

    def _take_candidate(self, cand: _Candidate) -> list[GridSample]:
        """Act on a confirmed candidate: the time jump or forward step, then its own message."""
        src = self._sources[cand.source]
        back = cand.stamp_s < self._newest_stamp
        out = self._time_jump(src, cand.stamp_s) if back else []
        out += self._place(src, cand.stamp_s, cand.values)
        # The timeline moves there even if the grid refused the message (a forward step off the
        # grid's phase: the off-grid run then re-anchors the grid as it would without the hold).
        self._newest_stamp = max(self._newest_stamp, cand.stamp_s)
        self._old_side = 1 if back else -1
        for s in self._sources:
            s.before_jump = s is not src
        return out

    def _place(self, src: GridSource, stamp_s: float, vals: np.ndarray) -> list[GridSample]:
        """Put a message of the timeline into its slot; return the samples that became complete."""
        dt = self.sample_time_s
        out: list[GridSample] = []
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
            self._clear_grid()  # keeps a time jump no sample has carried yet (_jumped) to be marked
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
            slot = _Slot(np.zeros(self.n_channels), 0, stamp_s)
            self._pending[k] = slot
        slot.values[src.index] = vals
        slot.filled |= src.bits
        if self._newest_slot is None or k > self._newest_slot:
            self._newest_slot = k
        self._newest_stamp = max(self._newest_stamp, stamp_s)
        out += self._emit_ready()
        return out

    def _slot_of(self, stamp_s: float) -> tuple[int, float]:
        rel = (stamp_s - self._anchor) / self.sample_time_s
        k = int(math.floor(rel + 0.5))
        return k, (rel - k) * self.sample_time_s

    def _time_jump(self, src: GridSource, stamp_s: float) -> list[GridSample]:
        out = self._drop_all_pending()
        self.counters.time_jumps += 1
        src.counters.time_jumps += 1
        self._clear_grid()
        self._jumped = True
        self._anchor = stamp_s
        for s in self._sources:
            s.last_slot = None
        return out

    def _drop_all_pending(self) -> list[GridSample]:
        """Emit what is complete, drop the rest as missing (time jump, re-anchoring, flush)."""
        out: list[GridSample] = []
        for k in sorted(self._pending):
            slot = self._pending.pop(k)
            if slot.filled == self._all_bits:
                out.append(self._emit(k, slot))
            else:
                self._finish(k, dropped=True)
        return out

    def flush(self) -> list[GridSample]:
        """Emit every complete pending slot and drop the incomplete ones (end of a record).

        A candidate timeline still held is rejected (``off_timeline``): nothing confirmed it.
        """
        self._reject_candidate()
        return self._drop_all_pending()

    # ------------------------------------------------------------------ output
    def _emit_ready(self) -> list[GridSample]:
        out: list[GridSample] = []
        while self._pending:
            k = min(self._pending)
            slot = self._pending[k]
            if slot.filled == self._all_bits:
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
