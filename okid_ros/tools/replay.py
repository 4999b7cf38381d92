"""Publish a bag on live topics with its original timing, like ``ros2 bag play``.

Messages are read in log-time order and published when ``(t - t_first) / rate`` has elapsed
on the monotonic wall clock since the start of the pass, by an rclpy publisher of the Python
class of its type (``pkg/msg/Name`` -> ``pkg.msg.Name``, imported on demand). The stored bytes
are published as they are when they are plain little-endian CDR
(:data:`~okid_ros.nodes.raw_inputs.PLAIN_CDR_LE`, what rclpy itself sends); others are turned
into that class by
``rclpy.serialization.deserialize_message`` first. Header stamps are not touched, so with
``loop`` every pass starts again at the first stamp of the bag: subscribers see a backward
time jump, as with ``ros2 bag play --loop`` (the nodes' sample grid re-anchors on it, see
:mod:`okid_ros.service.sample_grid`).

Publishers are reliable, keep-last with ``queue_depth``, volatile: compatible with the
sensor-data (best effort) subscriptions of the nodes and with reliable ones. With ``clock``
the player also publishes the bag time on ``/clock`` (rosgraph_msgs/Clock) at ``clock_hz``
for nodes run with ``use_sim_time``.
"""

from __future__ import annotations

import sys
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from okid_ros.errors import DataError, OkidWarning, shown_path
from okid_ros.tools.bagio import open_bag
from okid_ros.tools.errors import BagReadError, ReplayError, ToolParameterError
from okid_ros.tools.ros_domain import ros_context

__all__ = ["ReplayStats", "BagPlayer", "parse_remaps", "message_class", "MIN_RATE", "MAX_DELAY_S",
           "CLOCK_HZ_RANGE", "MAX_QUEUE_DEPTH", "MAX_SUBSCRIBERS"]

#: Slowest playback factor: slower, a short bag would play for days (a hang to the user).
MIN_RATE = 1e-3
#: Longest --delay [s]: it waits for discovery (about a second); a longer wait is the shell's job.
MAX_DELAY_S = 3600.0
#: /clock rates [Hz]: below, the clock step in ns overflows; above, one tick per message anyway.
CLOCK_HZ_RANGE = (1e-3, 1e6)
#: Deepest publisher history: as the nodes' inputs.queue_depth. The rmw takes a size_t, but Fast
#: DDS keeps the depth in an int32 and preallocates for it; rclpy refuses beyond 64 bits (a TypeError).
MAX_QUEUE_DEPTH = 100_000
#: Most subscriptions --wait-for-subscribers waits for (more than any graph here has).
MAX_SUBSCRIBERS = 1000
#: Seconds between the reminders while --wait-for-subscribers waits (it waits without end).
WAIT_REMINDER_S = 10.0


@dataclass
class ReplayStats:
    """What a replay did.

    Attributes
    ----------
        published: messages published per output topic.
        passes: passes over the bag started (> 1 with loop).
        max_lag_s: largest delay of a publication behind its schedule [s].
        wall_time_s: time from the first publication to the end [s].
    """

    published: dict[str, int] = field(default_factory=dict)
    passes: int = 0
    max_lag_s: float = 0.0
    wall_time_s: float = 0.0

    @property
    def total(self) -> int:
        return sum(self.published.values())


def parse_remaps(items: Sequence[str]) -> dict[str, str]:
    """``["/a:=/b", ...]`` -> ``{"/a": "/b"}``; ToolParameterError for a malformed item."""
    remaps: dict[str, str] = {}
    for item in items:
        source, sep, target = item.partition(":=")
        if not sep or not source or not target:
            raise ToolParameterError(f"--remap {item!r} must be FROM:=TO, e.g. /okid/io_sample:=/rig/io")
        if remaps.get(source, target) != target:  # the later one was taken in silence
            raise ToolParameterError(f"--remap {shown_path(source)} is given twice, to {shown_path(remaps[source])} "
                                     f"and to {shown_path(target)}: a topic is published on one")
        remaps[source] = target
    return remaps


def message_class(msgtype: str) -> type:
    """The rclpy message class of ``pkg/msg/Name``; ReplayError if it cannot be imported."""
    parts = msgtype.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise ReplayError(f"cannot replay message type {msgtype!r}: expected pkg/msg/Name")
    from okid_ros.nodes.raw_inputs import message_class as rclpy_message_class

    try:
        return rclpy_message_class(msgtype)
    except (ImportError, AttributeError) as exc:
        raise ReplayError(f"no Python message class for {msgtype} ({exc}); build or source the package "
                          f"{parts[0]}, or leave its topics out with --topics") from None


def _check_options(rate: float, delay_s: float, duration_s: float | None, queue_depth: int,
                   clock_hz: float, wait_for_subscribers: int) -> None:
    """ToolParameterError naming the first option of :class:`BagPlayer` out of its range.

    The comparisons are written so that NaN fails them (``nan < 0`` is False: a NaN delay
    once passed and the player waited forever).
    """
    if not rate >= MIN_RATE:  # inf is allowed: as fast as possible
        raise ToolParameterError(f"--rate must be a factor >= {MIN_RATE:g}, got {rate}")
    if not 0.0 <= delay_s <= MAX_DELAY_S:
        raise ToolParameterError(f"--delay must be from 0 to {MAX_DELAY_S:g} s, got {delay_s}")
    if duration_s is not None and not duration_s > 0:
        raise ToolParameterError(f"--duration must be a positive number of seconds, got {duration_s}")
    if not 1 <= queue_depth <= MAX_QUEUE_DEPTH:
        raise ToolParameterError(f"--queue-depth must be from 1 to {MAX_QUEUE_DEPTH}, got {queue_depth}")
    if not CLOCK_HZ_RANGE[0] <= clock_hz <= CLOCK_HZ_RANGE[1]:
        raise ToolParameterError(f"--clock rate must be from {CLOCK_HZ_RANGE[0]:g} to {CLOCK_HZ_RANGE[1]:g} Hz, "
                                 f"got {clock_hz}")
    if not 0 <= wait_for_subscribers <= MAX_SUBSCRIBERS:
        raise ToolParameterError(f"--subscribers must be from 0 to {MAX_SUBSCRIBERS} subscriptions, "
                                 f"got {wait_for_subscribers}")


def _check_one_type_per_topic(node, outputs: Sequence[tuple[str, str, str]]) -> None:
    """DataError when two outputs ``(what, topic, type)`` resolve to one topic with different types.

    rcl refuses a second publisher of another type on a topic of the same node (an RCLError);
    a remap onto another replayed topic (or onto /clock with ``--clock``) does that. Of one type,
    an OkidWarning: their messages interleave on the topic (two accelerometers read as one;
    was said by nothing).
    """
    seen: dict[str, tuple[str, str]] = {}
    for what, name, msgtype in outputs:
        try:
            resolved = node.resolve_topic_name(name)
        except RuntimeError:  # an invalid name: create_publisher reports it in its own words
            continue
        first, first_type = seen.setdefault(resolved, (what, msgtype))
        if first_type != msgtype:
            raise DataError(f"cannot publish {what} ({msgtype}) on {resolved}: {first} ({first_type}) is "
                            f"published there too, and a topic has one message type; remap one of them elsewhere")
        if first != what:
            warnings.warn(f"{first} and {what} are both published on {resolved}: their messages interleave there, "
                          "and no subscriber can tell them apart", OkidWarning, stacklevel=2)


class BagPlayer:
    """Replays one bag; :meth:`run` blocks until the end (or ``stop()``, or the duration).

    Parameters
    ----------
    path : the bag.
    rate : playback speed factor (> 0; 2.0 plays twice as fast).
    loop : start again from the beginning at the end.
    topics : topics to play (default: all).
    remaps : output topic per bag topic.
    delay_s : wait after creating the publishers (and after the subscribers, with
        ``wait_for_subscribers``), before the first message (discovery).
    wait_for_subscribers : before playing, wait until every publisher has matched this many
        subscriptions (0: do not wait; True counts as 1). Waiting for one lets a fast
        subscriber (a probe) start the replay before a slower node has matched.
    duration_s : stop after this much wall time of playback (None: no limit).
    queue_depth : depth of each publisher's history.
    clock : publish the bag time on /clock.
    clock_hz : rate of /clock messages in bag time.
    node_name : name of the player's ROS node.
    log : callable for progress lines (default: print to stderr).

    Raises
    ------
        BagReadError, ToolParameterError, ReplayError (at construction or start); an OkidWarning at
        construction when the topics played hold no message.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        rate: float = 1.0,
        loop: bool = False,
        topics: Sequence[str] | None = None,
        remaps: dict[str, str] | None = None,
        delay_s: float = 0.0,
        duration_s: float | None = None,
        queue_depth: int = 1000,
        clock: bool = False,
        clock_hz: float = 100.0,
        node_name: str = "okid_replay",
        log: Callable[[str], None] | None = None,
        wait_for_subscribers: int = 0,
        namespace: str | None = None,
    ) -> None:
        _check_options(rate, delay_s, duration_s, queue_depth, clock_hz, int(wait_for_subscribers))
        self.path = Path(path)
        self.rate = float(rate)
        self.loop = bool(loop)
        self.remaps = dict(remaps or {})
        self.delay_s = float(delay_s)
        self.wait_for_subscribers = int(wait_for_subscribers)
        self.duration_s = duration_s
        self.queue_depth = int(queue_depth)
        self.clock = bool(clock)
        self.clock_hz = float(clock_hz)
        self.node_name = node_name
        self.log = log or (lambda line: print(line, file=sys.stderr, flush=True))
        self._stop = threading.Event()
        with open_bag(self.path) as bag:
            self.bag_topics = dict(bag.topics)
            self.duration_bag_s = bag.duration_s
            wanted = list(dict.fromkeys(topics)) if topics else sorted(bag.topics)  # a topic given twice is one
            unknown = [t for t in wanted if t not in bag.topics]
            if unknown:
                raise BagReadError(f"{shown_path(self.path)}: no topic {', '.join(unknown)}; the bag has: "
                                   f"{', '.join(sorted(bag.topics)) or 'none'}")
            self.topics = wanted
            self.message_count = bag.message_count(wanted)  # as stored: what is played
            self.metadata_count = bag.message_count(wanted, as_metadata=True)
        if not self.message_count:  # "replayed 0 messages", exit 0, was all it said (after waiting for subscribers)
            where = f"on {', '.join(map(shown_path, wanted))}" if wanted else "(the bag has no topic)"
            warnings.warn(f"{shown_path(self.path)}: no message to replay {where}: nothing is published",
                          OkidWarning, stacklevel=2)
        bad_remaps = [t for t in self.remaps if t not in self.topics]
        if bad_remaps:
            raise ToolParameterError(f"--remap of {', '.join(bad_remaps)}: not a replayed topic "
                                     f"({', '.join(self.topics)})")
        if namespace is not None:
            # The bag's topics of the default rig namespace (/okid/io_sample, ...) go to the
            # rig's namespace (/rig1/io_sample, ...); explicit --remap wins.
            from okid_ros.service.topics import DEFAULT_NAMESPACE, resolve_topic, validate_namespace

            try:
                namespace = validate_namespace(namespace)
            except ValueError as exc:
                raise ToolParameterError(f"--namespace: {exc}") from None
            prefix = DEFAULT_NAMESPACE + "/"
            for topic in self.topics:
                if topic.startswith(prefix) and topic not in self.remaps:
                    self.remaps[topic] = resolve_topic(topic[len(prefix):], namespace)
        self.classes = {t: message_class(self.bag_topics[t]) for t in self.topics}

    def plan(self) -> str:
        """The line said before playing: the messages stored (and played), the metadata's count where it differs."""
        differs = self.metadata_count != self.message_count
        return (f"replay {self.path}: {self.message_count} messages"
                + (f" (metadata.yaml says {self.metadata_count})" if differs else "")
                + f" on {len(self.topics)} topics, {self.duration_bag_s:.1f} s at rate {self.rate:g}"
                + (" (loop)" if self.loop else ""))

    def stop(self) -> None:
        """Ask :meth:`run` to return (thread-safe)."""
        self._stop.set()

    def _sleep_until(self, deadline: float, wall_end: float | None) -> bool:
        """Sleep until the monotonic ``deadline``; False if stopped or out of time first."""
        while True:
            now = time.monotonic()
            if self._stop.is_set() or (wall_end is not None and now >= wall_end):
                return False
            remaining = deadline - now
            if remaining <= 0:
                return True
            limit = remaining if wall_end is None else min(remaining, wall_end - now)
            self._stop.wait(min(limit, 0.05))

    def _publishers(self, node) -> tuple[dict, object]:
        """One publisher per replayed topic (remapped), and the /clock publisher if asked."""
        from rclpy.exceptions import InvalidTopicNameException
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=self.queue_depth,
                         reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        outputs = [(topic, self.remaps.get(topic, topic), self.bag_topics[topic]) for topic in self.topics]
        if self.clock:
            outputs.append(("the bag time (--clock)", "/clock", "rosgraph_msgs/msg/Clock"))
        _check_one_type_per_topic(node, outputs)
        publishers = {}
        for topic in self.topics:
            name = self.remaps.get(topic, topic)
            try:
                publishers[topic] = node.create_publisher(self.classes[topic], name, qos)
            except (InvalidTopicNameException, ValueError) as exc:
                raise ToolParameterError(f"cannot publish on {name!r}: {' '.join(str(exc).split())}") from None
        clock_pub = None
        if self.clock:
            from rosgraph_msgs.msg import Clock

            clock_pub = node.create_publisher(Clock, "/clock", QoSProfile(depth=10))
        return publishers, clock_pub

    def _play_pass(self, publishers: dict, clock_pub, stats: ReplayStats, wall_end: float | None) -> bool:
        """One pass over the bag at ``rate``; True when it reached the end of a non-empty bag."""
        from rclpy.serialization import deserialize_message

        from okid_ros.nodes.raw_inputs import PLAIN_CDR_LE

        clock_step_ns = int(1e9 / self.clock_hz)
        pass_start = time.monotonic()
        first_ns = None
        next_clock_ns = None
        if clock_pub is not None:
            from rosgraph_msgs.msg import Clock

            clock_msg = Clock()
        with open_bag(self.path) as bag:
            for topic, _msgtype, stamp_ns, raw in bag.raw_messages(self.topics):
                if first_ns is None:
                    first_ns = stamp_ns
                due = pass_start + (stamp_ns - first_ns) * 1e-9 / self.rate
                if not self._sleep_until(due, wall_end):
                    return False
                stats.max_lag_s = max(stats.max_lag_s, time.monotonic() - due)
                if clock_pub is not None and (next_clock_ns is None or stamp_ns >= next_clock_ns):
                    clock_msg.clock.sec, clock_msg.clock.nanosec = divmod(stamp_ns, 1_000_000_000)
                    clock_pub.publish(clock_msg)
                    next_clock_ns = stamp_ns + clock_step_ns
                raw = bytes(raw)
                if raw[:2] == PLAIN_CDR_LE:
                    # As stored, as ``ros2 bag play`` does: building the message object (about 20 us
                    # for an Imu, then serialized again) was most of a replay's CPU.
                    publishers[topic].publish(raw)
                else:
                    publishers[topic].publish(deserialize_message(raw, self.classes[topic]))
                stats.published[self.remaps.get(topic, topic)] += 1
        return first_ns is not None

    def _wait_for_subscriptions(self, publishers) -> None:
        """Block until every publisher has matched ``wait_for_subscribers`` subscriptions (or stop())."""
        wanted = self.wait_for_subscribers

        def short() -> list:
            return [p for p in publishers if p.get_subscription_count() < wanted]

        def matched(waiting: list) -> str:
            return ", ".join(f"{p.topic_name} ({p.get_subscription_count()} matched)" for p in waiting)

        waiting = short()
        if waiting:
            self.log(f"replay: waiting for {wanted} subscription{'s' if wanted != 1 else ''} on {matched(waiting)}")
        started = remind = time.monotonic()
        while waiting:
            if time.monotonic() - remind >= WAIT_REMINDER_S:
                # It waits without end: say so now and then, so that a replay started before the
                # nodes (or with a topic remapped wrong) is not taken for a hang.
                remind = time.monotonic()
                self.log(f"replay: still waiting after {remind - started:.0f} s: {matched(waiting)}; start the "
                         f"nodes that subscribe (or check the topic names), or stop with Ctrl-C")
            if not self._sleep_until(time.monotonic() + 0.05, None):
                break
            waiting = short()

    def run(self, context=None) -> ReplayStats:
        """Play the bag (blocks). ``context``: an initialized rclpy Context, else one is made."""
        try:
            import rclpy
        except ImportError as exc:
            raise ReplayError(f"ROS 2 (rclpy) is not available ({exc}); run `make setup` or source ROS") from None

        own_context = context is None
        if own_context:
            context = ros_context()
        stats = ReplayStats(published={self.remaps.get(t, t): 0 for t in self.topics})
        node = rclpy.create_node(self.node_name, context=context)
        try:
            publishers, clock_pub = self._publishers(node)
            self.log(self.plan())
            self._wait_for_subscriptions(publishers.values())
            if self.delay_s:
                self._sleep_until(time.monotonic() + self.delay_s, None)
            started = time.monotonic()
            wall_end = None if self.duration_s is None else started + self.duration_s
            while not self._stop.is_set():
                stats.passes += 1
                if stats.passes > 1:
                    self.log(f"replay: pass {stats.passes} (stamps jump back to the start of the bag)")
                if not (self._play_pass(publishers, clock_pub, stats, wall_end) and self.loop):
                    break
            stats.wall_time_s = time.monotonic() - started
            # Reliable subscribers may not have acknowledged the last messages yet; destroying
            # the publishers now would drop them.
            from rclpy.duration import Duration

            for publisher in publishers.values():
                publisher.wait_for_all_acked(Duration(seconds=2.0))
        finally:
            node.destroy_node()
            if own_context:
                context.try_shutdown()
        return stats
