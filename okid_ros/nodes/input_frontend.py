"""A node's input topics: subscriptions, the messages' values on the sample grid, their health.

Both nodes read their input sources (``inputs.sources``, :mod:`okid_ros.service.inputs`) through
one :class:`InputFrontend`; the node's input thread (:mod:`.input_thread`) takes what is queued.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions

from okid_ros.nodes.common import SIM_CLOCK_SILENCE_S, SIM_TIME_WITHOUT_CLOCK, make_status, sensor_qos
from okid_ros.nodes.conversions import source_values
from okid_ros.nodes.raw_inputs import message_class, raw_reader
from okid_ros.service.grid_samples import NO_DATA, GridSample
from okid_ros.service.inputs import no_data_reason, sources_and_grid, time_jump_note

__all__ = ["DRAIN_MAX", "InputFrontend"]

#: Rounds (one message per input topic each) an input callback takes from the queues after
#: the message it was called with, or the input thread after a wait.
DRAIN_MAX = 50


class InputFrontend:
    """Subscriptions of the input sources, assembly on the sample grid, rates and staleness.

    ``on_sample`` is called (on the executor thread) with every complete
    :class:`~okid_ros.service.grid_samples.GridSample`.
    """

    def __init__(self, node: Node, values: dict[str, Any], on_sample: Callable[[GridSample], None]) -> None:
        self.node = node
        self.m, self.p = int(values["n_inputs"]), int(values["n_outputs"])
        self.specs, self.grid = sources_and_grid(values, node.get_namespace())
        self._time_jump_note = ""
        self._tell_time_jump(values)
        self.stale_timeout_ns = int(float(values["inputs.stale_timeout_s"]) * 1e9)
        self.on_sample = on_sample
        self._clock = node.get_clock()
        # use_sim_time given at the start with nothing on /clock: the node clock stands at 0 and
        # the node's timers with it, so the node fell silent with nothing said (note_clock_at_zero).
        self.sim_clock_told = False
        self._clock_at_zero_since: float | None = None
        n = len(self.specs)
        self.last_arrival_ns: list[int | None] = [None] * n
        self.stale = [False] * n
        # Messages that arrive but make no sample (a source stamped later than the grid's latency,
        # or all of one source's messages refused) left every input "receiving", status OK, while
        # nothing was identified or published: told as starved. Mark: (since [ns], samples
        # emitted, missing, refusals per source then).
        self.starved = False
        self._emission_mark = (self._clock.now().nanoseconds, 0, 0, self._refusals())
        self._counts = [0] * n
        self._no_data_told: set[str] = set()  # topics whose messages declared no data (REP 145): told once each
        self._rate_mark = (self._clock.now().nanoseconds, [0] * n)
        self.rates_hz = [0.0] * n
        # Publishers of another message type on an input topic: DDS never matches them (their
        # messages never arrive) and Fast DDS reports no event for it, so the graph is asked.
        self.wrong_type_publishers: list[tuple[str, ...]] = [()] * n
        self._busy_s = 0.0  # time spent in the input callbacks since the last diagnostics
        self._busy_max_s = 0.0
        self.callback_stats = (0.0, 0.0)  # (mean us per message, max ms) of the last period
        qos = sensor_qos(int(values["inputs.queue_depth"]))
        self.subscriptions = []
        # Per source, the reader of its serialized messages (nodes/raw_inputs.py), or None when
        # its messages are taken as objects; the input thread takes them as bytes.
        self.raw_readers = []
        for i, spec in enumerate(self.specs):
            msg_type = message_class(spec.msg_type)
            self.raw_readers.append(raw_reader(spec, self.m, self.p, msg_type))
            self.subscriptions.append(node.create_subscription(
                msg_type, spec.topic, partial(self._on_message, i), qos,
                qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            ))

    def _on_message(self, index: int, msg: Any) -> None:
        """Subscription callback (when an executor serves the inputs): this message, then the queue."""
        start = time.perf_counter()
        self._handle(index, msg, self._clock.now().nanoseconds)
        self._drain()
        self._account(start)

    def take_all(self) -> None:
        """Take and handle the queued input messages (the node's input thread, after a wait)."""
        start = time.perf_counter()
        self._drain()
        self._account(start)

    def _drain(self) -> None:
        # One message per topic and round so that the topics stay in step (the grid's latency
        # budget counts slots): the overhead of a wake is paid once per backlog, and the node
        # catches up quickly after any stall. The messages of a round arrive (are taken) at the
        # same instant on the node clock, read once.
        for _ in range(DRAIN_MAX):
            now_ns = None
            for i, (sub, reader) in enumerate(zip(self.subscriptions, self.raw_readers)):
                try:
                    with sub.handle:
                        taken = sub.handle.take_message(sub.msg_type, reader is not None)
                except Exception:  # destroyed while shutting down, or an rclpy without this API
                    return
                if taken is None:
                    continue
                if now_ns is None:
                    now_ns = self._clock.now().nanoseconds
                if reader is None:
                    self._handle(i, taken[0], now_ns)
                else:
                    self._accept(i, *reader.read(taken[0]), now_ns)
            if now_ns is None:
                break

    def _account(self, start: float) -> None:
        took = time.perf_counter() - start
        self._busy_s += took
        self._busy_max_s = max(self._busy_max_s, took)

    def _handle(self, index: int, msg: Any, now_ns: int) -> None:
        self._accept(index, *source_values(msg, self.specs[index], self.m, self.p), now_ns)

    def _accept(self, index: int, stamp: float | None, values: Any, now_ns: int) -> None:
        """One message's stamp (None: none, stamped ``now_ns``, its arrival) and values onto the grid."""
        if not now_ns:
            self.note_clock_at_zero()
        self.last_arrival_ns[index] = now_ns
        self._counts[index] += 1
        if stamp is None:
            stamp = now_ns * 1e-9
        if values is NO_DATA:
            self._tell_no_data(self.specs[index])
        for sample in self.grid.add(index, stamp, values):
            self.on_sample(sample)

    def _tell_no_data(self, spec: Any) -> None:
        """Warn once per topic that its messages declare no data (counted as ``no_data`` by the grid)."""
        if spec.topic in self._no_data_told:
            return
        self._no_data_told.add(spec.topic)
        self.node.get_logger().warning(f"input {spec.topic}: a message rejected, never used as data: its "
                                       f"{no_data_reason(spec)}; said once per topic, each counted in the "
                                       "diagnostics ('grid no_data', the topic's 'rejected')")

    def note_clock_at_zero(self) -> None:
        """A message arrived with the node clock at 0 (``use_sim_time``, nothing on /clock yet): told once.

        Said when messages have kept arriving so for :data:`~okid_ros.nodes.common.SIM_CLOCK_SILENCE_S`
        (the monotonic clock; the node clock stands still), unless it was said already.
        """
        if self.sim_clock_told:
            return
        now_s = time.monotonic()
        if self._clock_at_zero_since is None:
            self._clock_at_zero_since = now_s
        elif now_s - self._clock_at_zero_since >= SIM_CLOCK_SILENCE_S:
            self.sim_clock_told = True
            self.node.get_logger().warning(SIM_TIME_WITHOUT_CLOCK)

    def reset(self) -> None:
        self.grid.reset()

    def apply_parameters(self, values: dict[str, Any]) -> None:
        """Take the run-time tunable ``inputs.*`` parameters (already validated)."""
        self.stale_timeout_ns = int(float(values["inputs.stale_timeout_s"]) * 1e9)
        self.grid.tolerance = float(values["inputs.stamp_tolerance"])
        self.grid.latency_samples = int(values["inputs.latency_samples"])
        self.grid.time_jump_s = float(values["inputs.time_jump_s"])
        self._tell_time_jump(values)

    def _tell_time_jump(self, values: dict[str, Any]) -> None:
        """Warn once when the grid raises a time-jump threshold set too low (the rule of ``okid-ros process``)."""
        note = time_jump_note(values)
        if note and note != self._time_jump_note:
            self.node.get_logger().warning(note)
        self._time_jump_note = note

    def update_health(self) -> list[tuple[str, bool]]:
        """Recompute input rates and staleness.

        Return (message, is_warning) for inputs that
        changed state. An input that never sent anything is waiting, not stale.
        """
        now = self._clock.now().nanoseconds
        t0, counts0 = self._rate_mark
        span = (now - t0) * 1e-9
        if span > 0:
            self.rates_hz = [(c - c0) / span for c, c0 in zip(self._counts, counts0)]
        messages = sum(self._counts) - sum(counts0)
        self.callback_stats = (1e6 * self._busy_s / max(messages, 1), 1e3 * self._busy_max_s)
        self._busy_s = self._busy_max_s = 0.0
        self._rate_mark = (now, list(self._counts))
        changes = []
        for i, spec in enumerate(self.specs):
            last = self.last_arrival_ns[i]
            stale = last is not None and now - last > self.stale_timeout_ns
            if stale != self.stale[i]:
                if stale:
                    changes.append((f"input {spec.topic} is stale: no message for more than "
                                    f"{self.stale_timeout_ns * 1e-9:g} s{self._publishers_note(spec.topic)}", True))
                else:
                    changes.append((f"input {spec.topic} is receiving again", False))
            self.stale[i] = stale
            changes += self._check_types(i, spec)
        return changes + self._check_starved(now)

    def _refusals(self) -> list[dict[str, int]]:
        return [self.grid.source_counters(i).rejections() for i in range(len(self.specs))]

    def _check_starved(self, now_ns: int) -> list[tuple[str, bool]]:
        """(message, is_warning) when messages arrive but no sample is assembled for ``stale_timeout_s``, or again."""
        counters = self.grid.counters
        since_ns, emitted, missing, refused = self._emission_mark
        arriving = any(last is not None and now_ns - last <= self.stale_timeout_ns for last in self.last_arrival_ns)
        # A source that never sent, or went stale: the status says so already.
        told = None in self.last_arrival_ns or any(self.stale)
        if counters.samples_emitted != emitted or not arriving or told:
            self._emission_mark = (now_ns, counters.samples_emitted, counters.missing, self._refusals())
            starved = False
        else:
            starved = now_ns - since_ns > self.stale_timeout_ns
        if starved == self.starved:
            return []
        self.starved = starved
        if not starved:
            return [("inputs: samples assembled again", False)]
        why = [f"{spec.topic} {reason} {count - refused[i].get(reason, 0)}"
               for i, (spec, counts) in enumerate(zip(self.specs, self._refusals()))
               for reason, count in counts.items() if count > refused[i].get(reason, 0)]
        timeout_s = self.stale_timeout_ns * 1e-9
        return [(f"inputs: messages arrive but no sample was assembled for more than {timeout_s:g} s: "
                 f"{counters.missing - missing} sample times missing; messages refused meanwhile: "
                 f"{', '.join(why) or 'none'} (a source stamped more than inputs.latency_samples sample times "
                 "behind the others, or all of its messages refused)", True)]

    def _publishers_note(self, topic: str) -> str:
        """For a stale input: the publishers still in the graph (a stall can lose them for good)."""
        try:
            count = self.node.count_publishers(topic)
        except Exception:  # graph not available (shutting down)
            return ""
        if not count:
            return ""
        return (f", though {count} publisher(s) of it are in the graph: if they still publish, this node "
                "lost them (Fast DDS shared memory after a stall of this process over 1 s; restart the "
                "node, see docs/robustness-live.md)")

    def _check_types(self, index: int, spec: Any) -> list[tuple[str, bool]]:
        """Warn when publishers of another type appear on (or leave) input topic ``spec.topic``."""
        try:
            infos = self.node.get_publishers_info_by_topic(spec.topic)
        except Exception:  # graph not available (shutting down)
            return []
        wrong = tuple(sorted(f"{i.node_namespace.rstrip('/')}/{i.node_name} ({i.topic_type})"
                             for i in infos if i.topic_type != spec.msg_type))
        if wrong == self.wrong_type_publishers[index]:
            return []
        self.wrong_type_publishers[index] = wrong
        if not wrong:
            return [(f"input {spec.topic}: no publisher of another type any more", False)]
        return [(f"input {spec.topic} expects {spec.msg_type}; ignored publisher(s) of another type "
                 f"(their messages never arrive): {', '.join(wrong)}", True)]

    def status(self, node_name: str) -> DiagnosticStatus:
        """Diagnostics of the inputs: per topic rate, staleness, messages and rejections."""
        values: dict[str, Any] = {}
        for i, spec in enumerate(self.specs):
            c = self.grid.source_counters(i)
            values[f"{spec.topic} type"] = spec.msg_type
            values[f"{spec.topic} rate_hz"] = round(self.rates_hz[i], 3)
            values[f"{spec.topic} stale"] = self.stale[i]
            values[f"{spec.topic} messages"] = c.messages
            values[f"{spec.topic} rejected"] = c.rejected_messages
            values[f"{spec.topic} wrong_type_publishers"] = len(self.wrong_type_publishers[i])
        values["starved"] = self.starved
        for key, value in self.grid.counters.as_dict().items():
            values[f"grid {key}"] = value
        values["input callback mean_us"] = round(self.callback_stats[0], 1)
        values["input callback max_ms"] = round(self.callback_stats[1], 3)
        stale = [s.topic for s, flag in zip(self.specs, self.stale) if flag]
        waiting = [s.topic for s, last in zip(self.specs, self.last_arrival_ns) if last is None]
        problems = [f"stale: {', '.join(stale)}"] if stale else []
        if self.starved:
            timeout_s = self.stale_timeout_ns * 1e-9
            problems.append(f"no sample assembled for more than {timeout_s:g} s though messages arrive")
        level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
        if problems:
            message = "; ".join(problems)
        elif waiting:
            message = "waiting for the first message on " + ", ".join(waiting)
        else:
            message = f"{len(self.specs)} input(s) receiving"
        return make_status(f"{node_name}: inputs", level, message, values)
