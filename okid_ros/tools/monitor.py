"""A live terminal view of the modes carried by ``okid_msgs/ModalStates``.

:class:`ModalStatesView` keeps what the table needs from the stream of ModalStates messages
(any object with the message's attributes: rclpy or rosbags messages) and renders it:

========  ==================================================================================
column    meaning
========  ==================================================================================
id        persistent mode id (kept across model updates by the estimator)
f [Hz]    undamped natural frequency; ``w [rad/s]`` the same in rad/s
zeta [%]  damping ratio in percent
+-f       standard deviations of frequency [Hz] and damping ratio [%] (``-``: not computed)
+-zeta
trend     frequency now against ``trend_window_s`` ago (stamps): up, down or steady (relative
          change below ``trend_threshold``); ``new`` for a mode younger than the window
EMAC MPC  accuracy indicators of the mode (1 = best); MSV its modal singular value;
MSV MAC   MAC against the previous model's matched mode
stable    discrete eigenvalue inside the unit circle
RMS amp   RMS over the last ``window_samples`` samples of the modal coordinates' magnitude
          ``sqrt(c1^2 + c2^2)`` (normalized modal state, see okid_ros/core/modal.py)
========  ==================================================================================

:class:`TerminalMonitor` draws the view: on a terminal it redraws in place with ANSI escapes
(cursor home, clear to end) a few times per second; otherwise (a pipe, a log file) it prints a
whole table every ``interval_s`` seconds. :func:`run_monitor` subscribes with rclpy.
"""

from __future__ import annotations

import math
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, TextIO

from okid_ros.tools.errors import ToolParameterError
from okid_ros.tools.ros_domain import ros_context

__all__ = ["ModalStatesView", "TerminalMonitor", "run_monitor", "MAX_WINDOW_SAMPLES"]

ANSI_HOME_CLEAR = "\x1b[H\x1b[J"
#: Arrivals over this many seconds give the message rate.
RATE_WINDOW_S = 2.0
#: No message for this long: the stream is shown as stopped.
STOPPED_AFTER_S = 1.0
#: Most samples in the RMS amplitude: each draw sums them per mode, and a deque's maxlen must fit
#: a C ssize_t (an OverflowError beyond). 100000 is minutes of samples at the usual rates.
MAX_WINDOW_SAMPLES = 100_000


@dataclass
class _ModeTrack:
    history: deque = field(default_factory=deque)  # (stamp_s, frequency_hz)
    amplitude_sq: deque = field(default_factory=deque)  # c1^2 + c2^2 of recent samples
    first_stamp_s: float = math.nan
    mode: Any = None


def _stamp_s(msg: Any) -> float:
    stamp = msg.header.stamp
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


class ModalStatesView:
    """State of the monitor table, fed with ModalStates messages.

    Parameters
    ----------
    window_samples : samples in the RMS amplitude (> 0).
    trend_window_s : look-back of the frequency trend [s] (> 0).
    trend_threshold : relative frequency change shown as a trend (> 0).
    arrows : characters for up, down, steady (default: Unicode arrows).
    """

    def __init__(self, window_samples: int = 250, trend_window_s: float = 10.0, trend_threshold: float = 1e-3,
                 arrows: tuple[str, str, str] = ("\u2191", "\u2193", "\u2192")) -> None:
        if not 1 <= window_samples <= MAX_WINDOW_SAMPLES:
            raise ToolParameterError(f"--window must be from 1 to {MAX_WINDOW_SAMPLES} samples, got {window_samples}")
        if not trend_window_s > 0:
            raise ToolParameterError(f"--trend-window must be positive, got {trend_window_s}")
        self.window_samples = int(window_samples)
        self.trend_window_s = float(trend_window_s)
        self.trend_threshold = float(trend_threshold)
        self.arrows = arrows
        self.tracks: dict[int, _ModeTrack] = {}
        self.current_ids: list[int] = []
        self.messages = 0
        self.model_id: int | None = None
        self.model_changes = 0
        self.stamp_s = math.nan
        self.innovation_sq: deque = deque(maxlen=self.window_samples)
        self._arrivals: deque = deque(maxlen=200)

    def update(self, msg: Any, received_s: float | None = None) -> None:
        """Take one ModalStates message."""
        stamp = _stamp_s(msg)
        self.messages += 1
        self._arrivals.append(time.monotonic() if received_s is None else received_s)
        if self.model_id is not None and int(msg.model_id) != self.model_id:
            self.model_changes += 1
        self.model_id = int(msg.model_id)
        if stamp < self.stamp_s - self.trend_window_s:
            for track in self.tracks.values():  # time jumped back (bag loop): restart the trends
                track.history.clear()
                track.first_stamp_s = stamp
        self.stamp_s = stamp
        coords = list(msg.modal_coordinates)
        self.current_ids = []
        for i, mode in enumerate(msg.modes):
            mode_id = int(mode.id)
            track = self.tracks.get(mode_id)
            if track is None:
                track = self.tracks[mode_id] = _ModeTrack(amplitude_sq=deque(maxlen=self.window_samples),
                                                          first_stamp_s=stamp)
            track.mode = mode
            if not track.history or track.history[-1][1] != mode.frequency_hz:
                track.history.append((stamp, float(mode.frequency_hz)))
            # keep one entry older than the trend window, drop the rest
            while len(track.history) > 2 and track.history[1][0] <= stamp - self.trend_window_s:
                track.history.popleft()
            if 2 * i + 1 < len(coords):  # products, not ** 2: a float's power beyond 1e308 raises OverflowError
                c1, c2 = float(coords[2 * i]), float(coords[2 * i + 1])
                track.amplitude_sq.append(c1 * c1 + c2 * c2)
            self.current_ids.append(mode_id)
        innovation = list(msg.innovation)
        if innovation:
            self.innovation_sq.append(sum(e * e for e in innovation) / len(innovation))

    def trend(self, mode_id: int) -> str:
        """The trend arrow of a mode, or 'new'."""
        track = self.tracks[mode_id]
        if self.stamp_s - track.first_stamp_s < self.trend_window_s or not track.history:
            return "new"
        now = track.history[-1][1]
        past = track.history[0][1]
        for stamp, freq in track.history:
            if stamp <= self.stamp_s - self.trend_window_s:
                past = freq
        change = (now - past) / past if past else 0.0
        if change > self.trend_threshold:
            return self.arrows[0]
        if change < -self.trend_threshold:
            return self.arrows[1]
        return self.arrows[2]

    def amplitude(self, mode_id: int) -> float:
        """RMS of the modal coordinates' magnitude over the recent samples."""
        values = self.tracks[mode_id].amplitude_sq
        return math.sqrt(sum(values) / len(values)) if values else math.nan

    def message_rate_hz(self, now: float | None = None) -> float:
        """Messages per second over the last :data:`RATE_WINDOW_S` (nan before two arrivals)."""
        if len(self._arrivals) < 2:
            return math.nan
        now = time.monotonic() if now is None else now
        recent = [t for t in self._arrivals if t >= now - RATE_WINDOW_S]
        if len(recent) < 2:
            return 0.0
        span = recent[-1] - recent[0]
        return (len(recent) - 1) / span if span > 0 else math.nan

    def silent_s(self, now: float | None = None) -> float:
        """Seconds since the last message (nan before the first)."""
        if not self._arrivals:
            return math.nan
        return (time.monotonic() if now is None else now) - self._arrivals[-1]

    def stream_state(self, now: float | None = None) -> str:
        """'12.5 /s' while messages flow, 'stopped (no message for 6.2 s)', or 'starting'."""
        silent = self.silent_s(now)
        if silent > STOPPED_AFTER_S:
            return f"stopped (no message for {silent:.1f} s)"
        rate = self.message_rate_hz(now)
        return "starting" if math.isnan(rate) else f"{rate:.1f} /s"

    def render(self, title: str = "okid-ros monitor", now: float | None = None) -> str:
        """The table as text (no escape sequences)."""
        if not self.messages:
            return f"{title}: waiting for okid_msgs/ModalStates ...\n"
        stamp = time.strftime("%H:%M:%S", time.gmtime(self.stamp_s)) + f".{int(1e3 * (self.stamp_s % 1)):03d}"
        innovation_rms = (math.sqrt(sum(self.innovation_sq) / len(self.innovation_sq))
                          if self.innovation_sq else math.nan)
        lines = [
            f"{title}   stamp {stamp} UTC   model {self.model_id} ({self.model_changes} updates)   "
            f"{self.messages} samples   {self.stream_state(now)}   innovation RMS {_fmt(innovation_rms, 3, 'e')}",
            f"{'id':>3} {'f [Hz]':>9} {'w [rad/s]':>10} {'zeta [%]':>9} {'+-f [Hz]':>9} {'+-zeta [%]':>10} "
            f"{'trend':>5} {'EMAC':>6} {'MPC':>6} "
            f"{'MSV':>8} {'MAC':>6} {'stable':>6} {'RMS amp':>9}",
        ]
        for mode_id in sorted(self.current_ids, key=lambda i: self.tracks[i].mode.frequency_hz):
            mode = self.tracks[mode_id].mode
            lines.append(
                f"{mode_id:>3} {mode.frequency_hz:>9.4f} {mode.frequency_rad_s:>10.4f} "
                f"{100 * mode.damping_ratio:>9.3f} {_fmt(getattr(mode, 'frequency_hz_std', math.nan), 2, 'e'):>9} "
                f"{_fmt(100 * getattr(mode, 'damping_ratio_std', math.nan), 2, 'e'):>10} "
                f"{self.trend(mode_id):>5} {_fmt(mode.emac, 3):>6} "
                f"{_fmt(mode.mpc, 3):>6} {_fmt(mode.msv, 2, 'e'):>8} {_fmt(mode.mac_previous, 3):>6} "
                f"{'yes' if mode.stable else 'NO':>6} {_fmt(self.amplitude(mode_id), 3, 'e'):>9}"
            )
        if not self.current_ids:
            lines.append("  (the current model has no physical modes)")
        return "\n".join(lines) + "\n"


def _fmt(value: float, digits: int, kind: str = "f") -> str:
    value = float(value)
    if math.isnan(value):
        return "-"
    return f"{value:.{digits}{kind}}"


class TerminalMonitor:
    """Draws a :class:`ModalStatesView` on a stream.

    Parameters
    ----------
    view : the view.
    stream : where to draw (default stdout).
    interval_s : time between draws (default 0.25 s on a terminal, 2 s otherwise).
    ansi : redraw in place (default: when ``stream`` is a terminal).
    """

    def __init__(self, view: ModalStatesView, stream: TextIO | None = None, interval_s: float | None = None,
                 ansi: bool | None = None, title: str = "okid-ros monitor") -> None:
        self.view = view
        self.stream = stream or sys.stdout
        self.ansi = bool(self.stream.isatty()) if ansi is None else ansi
        self.interval_s = (0.25 if self.ansi else 2.0) if interval_s is None else float(interval_s)
        if not self.interval_s > 0:
            raise ToolParameterError(f"--interval must be positive, got {self.interval_s}")
        self.title = title
        self._last_draw = -math.inf
        self._drawn_messages = -1
        self._drawn_stopped = False
        self.draws = 0

    def maybe_draw(self, now: float | None = None) -> bool:
        """Draw if the interval has passed and something new arrived; True if drawn."""
        now = time.monotonic() if now is None else now
        if now - self._last_draw < self.interval_s:
            return False
        stopped = self.view.silent_s(now) > STOPPED_AFTER_S
        if not self.ansi and self.view.messages == self._drawn_messages and stopped == self._drawn_stopped:
            return False
        self.draw(now)
        return True

    def draw(self, now: float | None = None) -> None:
        self._last_draw = time.monotonic() if now is None else now
        self._drawn_messages = self.view.messages
        self._drawn_stopped = self.view.silent_s(self._last_draw) > STOPPED_AFTER_S
        text = self.view.render(self.title, self._last_draw)
        self.stream.write((ANSI_HOME_CLEAR + text) if self.ansi else (text + "\n"))
        self.stream.flush()
        self.draws += 1


def _subscribe(node: Any, msg_type: type, topic: str, callback: Any, qos: Any) -> None:
    """``node.create_subscription``; ToolParameterError naming ``topic`` when it is not a valid name."""
    from rclpy.exceptions import InvalidTopicNameException

    try:
        node.create_subscription(msg_type, topic, callback, qos)
    except (InvalidTopicNameException, ValueError) as exc:  # ValueError: an unknown {substitution}
        raise ToolParameterError(f"--topic {topic!r}: cannot subscribe: {' '.join(str(exc).split())}") from None


_MODAL_STATES = "okid_msgs/msg/ModalStates"


def _silence_reason(node: Any, topic: str) -> str:
    """Why no ModalStates came, from the ROS graph as ``node`` sees it ("" when it shows nothing to say).

    A topic of another type got nothing, with nothing said but "no okid_msgs/ModalStates on
    /okid/io_sample" (rclpy matches no publisher of another type), and so did nodes in another
    namespace.
    """
    resolved = node.resolve_topic_name(topic)
    graph = dict(node.get_topic_names_and_types())
    other = [t for t in graph.get(resolved, []) if t != _MODAL_STATES]
    if other and node.count_publishers(resolved):
        return f": {resolved} carries {', '.join(other)} (the wrong --topic?)"
    elsewhere = [name for name, types in graph.items()
                 if name != resolved and _MODAL_STATES in types and node.count_publishers(name)]
    if elsewhere:
        return f"; ModalStates are published on {', '.join(sorted(elsewhere))} (another --topic or --namespace?)"
    return ""


def run_monitor(topic: str = "/okid/modal_states", *, once: bool = False, duration_s: float | None = None,
                interval_s: float | None = None, window_samples: int = 250, trend_window_s: float = 10.0,
                stream: TextIO | None = None, ansi: bool | None = None) -> ModalStatesView:
    """Subscribe to ``topic`` and draw until Ctrl-C, ``duration_s``, or (``once``) the first message.

    Raises
    ------
    ReplayError
        rclpy or okid_msgs cannot be imported.
    DataError
        ``once`` and no message within ``duration_s`` (default 30 s).
    """
    from okid_ros.errors import DataError
    from okid_ros.tools.errors import ReplayError

    if duration_s is not None and not duration_s > 0:
        raise ToolParameterError(f"--duration must be a positive number of seconds, got {duration_s}")
    try:
        import rclpy
        from rclpy.qos import qos_profile_sensor_data

        from okid_msgs.msg import ModalStates
    except ImportError as exc:
        raise ReplayError(f"ROS 2 is not available ({exc}); run `make setup` or source ROS") from None

    stream = stream or sys.stdout
    arrows = ("\u2191", "\u2193", "\u2192")
    if "utf" not in (getattr(stream, "encoding", None) or "utf-8").lower():
        arrows = ("^", "v", "=")
    view = ModalStatesView(window_samples, trend_window_s, arrows=arrows)
    monitor = TerminalMonitor(view, stream, interval_s, ansi)
    if once and duration_s is None:
        duration_s = 30.0
    context = ros_context()
    try:
        node = rclpy.create_node("okid_monitor", context=context)
        _subscribe(node, ModalStates, topic, view.update, qos_profile_sensor_data)
        from rclpy.executors import SingleThreadedExecutor

        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        end = None if duration_s is None else time.monotonic() + duration_s
        if monitor.ansi and not once:
            monitor.draw()
        while end is None or time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
            if once:
                if view.messages:
                    executor.spin_once(timeout_sec=0.0)
                    monitor.ansi = False
                    monitor.draw()
                    return view
                continue
            monitor.maybe_draw()
        if once:
            why = _silence_reason(node, topic)
            raise DataError(f"no okid_msgs/ModalStates on {topic} within {duration_s:g} s{why}")
        monitor.draw()
        return view
    finally:
        context.try_shutdown()
