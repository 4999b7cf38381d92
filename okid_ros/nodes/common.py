"""What both nodes share.

Parameter declaration, input topics on the sample grid, diagnostics,
and the process entry point.
"""

from __future__ import annotations

import importlib
import math
import os
import re
import sys
import threading
import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions

from okid_ros.errors import ParameterError
from okid_ros.nodes.conversions import source_values
from okid_ros.service.inputs import sources_and_grid
from okid_ros.service.params import ParamSpec, read_only_reason, validate_value
from okid_ros.service.sample_grid import GridSample

__all__ = [
    "lower_priority",
    "ordinary_scheduling",
    "realtime_threads",
    "request_short_slice",
    "name_thread",
    "declare_parameters",
    "InputFrontend",
    "DiagnosticsPublisher",
    "reliable_qos",
    "sensor_qos",
]

_INT64_MAX = 2**63 - 1
#: Rounds (one message per input topic each) an input callback takes from the queues after
#: the message it was called with, or the input thread after a wait.
DRAIN_MAX = 50


def name_thread(name: str) -> None:
    """Give the calling thread an OS name (``top -H``, /proc/PID/task/TID/comm; Linux, <= 15 chars)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").prctl(15, name.encode()[:15], 0, 0, 0)  # PR_SET_NAME
    except (OSError, AttributeError):
        pass


def _thread_ids() -> list[int]:
    """The ids of this process's threads (Linux; OSError elsewhere)."""
    return [int(t) for t in os.listdir("/proc/self/task")]


def _threads_before_nodes() -> frozenset[int]:
    """Threads that run when this module loads, besides the loading one.

    OpenBLAS's worker pool (started when numpy loads, OPENBLAS_NUM_THREADS > 1) and rclpy's
    tracing listeners (LTTng-UST, started when its extension loads); no executor or DDS thread
    yet: the nodes import this module before ``rclpy.init``. They stay ordinary under
    ``realtime_priority``: at SCHED_FIFO a BLAS call of any ordinary thread would run real-time,
    and OpenBLAS workers spin while they wait for work (a real-time thread's own multi-threaded
    BLAS call then waits on ordinary workers: the nodes run one BLAS thread by default).
    """
    try:
        return frozenset(_thread_ids()) - {threading.get_native_id()}
    except OSError:
        return frozenset()


#: numpy and rclpy are loaded by the imports above: their threads run already.
_THREADS_AT_IMPORT = _threads_before_nodes()


def lower_priority(nice: int) -> None:
    """Nice every thread of this process to at least ``nice`` (Linux; else nothing).

    Linux nices a thread, not a process, and threads may already run (OpenBLAS starts its own
    when numpy is imported); threads started later inherit the value of the thread that
    starts them.
    """
    try:
        tasks = _thread_ids()
    except OSError:
        tasks = [0]
    for tid in tasks:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, max(nice, os.getpriority(os.PRIO_PROCESS, tid)))
        except OSError:
            pass


def realtime_threads(priority: int, *, only_this_thread: bool = False) -> str:
    """Threads of this process at SCHED_FIFO ``priority`` (1-99); "" or why not (Linux).

    Every thread that runs now (the executor, the DDS threads) but those that ran when this
    module loaded (a BLAS pool's: :data:`_THREADS_AT_IMPORT`), or ``only_this_thread``. With
    ``SCHED_RESET_ON_FORK`` nothing started from them later is real-time (Linux resets threads
    as well as processes): not the realization worker, not the side thread; the input thread
    asks for it itself. Needs CAP_SYS_NICE or an RLIMIT_RTPRIO of at least ``priority``
    (``ulimit -r``, /etc/security/limits.conf); without, nothing changes and the reason is
    returned.
    """
    policy = getattr(os, "SCHED_FIFO", None)
    if policy is None or not sys.platform.startswith("linux"):
        return "real-time scheduling is not available on this platform"
    try:
        tasks = [0] if only_this_thread else [tid for tid in _thread_ids() if tid not in _THREADS_AT_IMPORT]
    except OSError as exc:
        return f"the threads of this process cannot be listed ({exc})"
    for tid in tasks:
        try:
            os.sched_setscheduler(tid, policy | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
        except ProcessLookupError:
            continue  # the thread ended meanwhile
        except OSError as exc:
            for done in tasks[: tasks.index(tid)]:  # all or none
                ordinary_scheduling(done)
            return f"SCHED_FIFO priority {priority} refused ({exc.strerror or exc}; needs CAP_SYS_NICE or ulimit -r)"
    return ""


def ordinary_scheduling(tid: int = 0) -> None:
    """A thread (default: the calling one) back to SCHED_OTHER."""
    try:
        os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass


#: sched_setattr(2) system call numbers by machine (Linux).
_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}


def request_short_slice(slice_s: float) -> bool:
    """Ask Linux for a short time slice for the calling thread (EEVDF, Linux >= 6.12).

    With a slice shorter than the others' (1.4 ms by default on a 2-core machine), a thread
    that wakes gets the core sooner: its virtual deadline comes earlier, and the running task
    is protected for a shorter time. For an input thread, which wakes at every sample and runs
    for a fraction of a millisecond. Returns False where not supported (the thread keeps the
    default slice).
    """
    number = _SCHED_SETATTR.get(os.uname().machine)
    if number is None or not sys.platform.startswith("linux"):
        return False
    if os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK != os.SCHED_OTHER:
        return False  # real-time (realtime_priority): a slice would make it ordinary again
    try:
        import ctypes
        import struct

        # struct sched_attr: size, policy (SCHED_OTHER), flags, nice, priority, runtime (the
        # slice), deadline, period, util_min, util_max.
        nice = os.getpriority(os.PRIO_PROCESS, 0)
        attr = struct.pack("IIQiIQQQII", 56, 0, 0, nice, 0, int(slice_s * 1e9), 0, 0, 0, 0)
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.syscall(number, 0, ctypes.create_string_buffer(attr, len(attr)), 0) == 0
    except (OSError, AttributeError):
        return False


def reliable_qos(depth: int = 10, latched: bool = False) -> QoSProfile:
    """Reliable output QoS (transient local when ``latched``: late subscribers get the last one)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def sensor_qos(depth: int) -> QoSProfile:
    """Sensor-data QoS (best effort, volatile) with a queue of ``depth`` messages."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def _descriptor(spec: ParamSpec) -> ParameterDescriptor:
    kind = spec.kind
    types = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
             float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
             list: ParameterType.PARAMETER_STRING_ARRAY}
    reason = read_only_reason(spec.name)
    description = spec.full_description() + (f"; read-only: {reason}" if reason else "; can change at run time")
    desc = ParameterDescriptor(
        name=spec.name, type=types[kind], description=description, read_only=bool(reason),
    )
    if spec.choices:
        desc.additional_constraints = "one of: " + ", ".join(spec.choices)
    if kind is float and (spec.low is not None or spec.high is not None):
        desc.floating_point_range = [FloatingPointRange(
            from_value=float(-sys.float_info.max if spec.low is None else spec.low),
            to_value=float(sys.float_info.max if spec.high is None else spec.high), step=0.0,
        )]
    if kind is int and (spec.low is not None or spec.high is not None):
        desc.integer_range = [IntegerRange(
            from_value=int(-_INT64_MAX if spec.low is None else spec.low),
            to_value=int(_INT64_MAX if spec.high is None else spec.high), step=1,
        )]
    return desc


def declare_parameters(node: Node, specs: Sequence[ParamSpec]) -> dict[str, Any]:
    """Declare every parameter with its descriptor; return the validated values.

    Raises
    ------
    ParameterError naming the parameter and its valid range (the node must not start).
    """
    values: dict[str, Any] = {}
    for spec in specs:
        unit = f" {spec.unit}" if spec.unit else ""
        try:
            param = node.declare_parameter(spec.name, spec.default, _descriptor(spec))
        except InvalidParameterValueException as exc:
            found = re.search(r"value \((.*?)\)", str(exc))
            value = found.group(1) if found else "the given value"
            raise ParameterError(
                f"parameter {spec.name} = {value} is out of range; valid range {spec.range_text()}{unit}"
            ) from None
        except InvalidParameterTypeException as exc:
            want = {bool: "true or false", int: "an integer", float: "a floating-point number (e.g. 1.0, not 1)",
                    str: "a string", list: "a list of strings"}[spec.kind]
            raise ParameterError(f"parameter {spec.name} must be {want}: {exc}") from None
        values[spec.name] = validate_value(spec, param.value)
    return values


class InputFrontend:
    """Subscriptions of the input sources, assembly on the sample grid, rates and staleness.

    ``on_sample`` is called (on the executor thread) with every complete
    :class:`~okid_ros.service.sample_grid.GridSample`.
    """

    def __init__(self, node: Node, values: dict[str, Any], on_sample: Callable[[GridSample], None]) -> None:
        self.node = node
        self.m, self.p = int(values["n_inputs"]), int(values["n_outputs"])
        self.specs, self.grid = sources_and_grid(values, node.get_namespace())
        self.stale_timeout_ns = int(float(values["inputs.stale_timeout_s"]) * 1e9)
        self.on_sample = on_sample
        self._clock = node.get_clock()
        n = len(self.specs)
        self.last_arrival_ns: list[int | None] = [None] * n
        self.stale = [False] * n
        self._counts = [0] * n
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
        for i, spec in enumerate(self.specs):
            msg_type = _import_type(spec.msg_type)
            self.subscriptions.append(node.create_subscription(
                msg_type, spec.topic, partial(self._on_message, i), qos,
                qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            ))

    def _on_message(self, index: int, msg: Any) -> None:
        """Subscription callback (when an executor serves the inputs): this message, then the queue."""
        start = time.perf_counter()
        self._handle(index, msg)
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
        # catches up quickly after any stall.
        for _ in range(DRAIN_MAX):
            taken_any = False
            for i, sub in enumerate(self.subscriptions):
                try:
                    with sub.handle:
                        taken = sub.handle.take_message(sub.msg_type, False)
                except Exception:  # destroyed while shutting down, or an rclpy without this API
                    return
                if taken is not None:
                    taken_any = True
                    self._handle(i, taken[0])
            if not taken_any:
                break

    def _account(self, start: float) -> None:
        took = time.perf_counter() - start
        self._busy_s += took
        self._busy_max_s = max(self._busy_max_s, took)

    def _handle(self, index: int, msg: Any) -> None:
        now_ns = self._clock.now().nanoseconds
        self.last_arrival_ns[index] = now_ns
        self._counts[index] += 1
        stamp, values = source_values(msg, self.specs[index], self.m, self.p)
        if stamp is None:
            stamp = now_ns * 1e-9
        for sample in self.grid.add(index, stamp, values):
            self.on_sample(sample)

    def reset(self) -> None:
        self.grid.reset()

    def apply_parameters(self, values: dict[str, Any]) -> None:
        """Take the run-time tunable ``inputs.*`` parameters (already validated)."""
        self.stale_timeout_ns = int(float(values["inputs.stale_timeout_s"]) * 1e9)
        self.grid.tolerance = float(values["inputs.stamp_tolerance"])
        self.grid.latency_samples = int(values["inputs.latency_samples"])
        self.grid.time_jump_s = float(values["inputs.time_jump_s"])

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
        return changes

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
        for key, value in self.grid.counters.as_dict().items():
            values[f"grid {key}"] = value
        values["input callback mean_us"] = round(self.callback_stats[0], 1)
        values["input callback max_ms"] = round(self.callback_stats[1], 3)
        stale = [s.topic for s, flag in zip(self.specs, self.stale) if flag]
        waiting = [s.topic for s, last in zip(self.specs, self.last_arrival_ns) if last is None]
        level = DiagnosticStatus.WARN if stale else DiagnosticStatus.OK
        if stale:
            message = "stale: " + ", ".join(stale)
        elif waiting:
            message = "waiting for the first message on " + ", ".join(waiting)
        else:
            message = f"{len(self.specs)} input(s) receiving"
        return make_status(f"{node_name}: inputs", level, message, values)


def make_status(name: str, level: bytes, message: str, values: dict[str, Any]) -> DiagnosticStatus:
    """A DiagnosticStatus with its values as KeyValue strings."""
    def text(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "nan" if math.isnan(v) else f"{v:.6g}"
        return str(v)

    return DiagnosticStatus(
        level=level, name=name, message=message, hardware_id="okid_ros",
        values=[KeyValue(key=k, value=text(v)) for k, v in values.items()],
    )


class DiagnosticsPublisher:
    """Publishes DiagnosticArray on /diagnostics (diagnostic_updater is not available as a wheel)."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.publisher = node.create_publisher(DiagnosticArray, "/diagnostics", reliable_qos(10))

    def publish(self, statuses: list[DiagnosticStatus]) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = statuses
        self.publisher.publish(msg)


def _import_type(name: str) -> type:
    """'sensor_msgs/msg/Imu' -> the rclpy message class."""
    package, kind, type_name = name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), type_name)


def check_parameter_files(node: Node, strict: bool, argv: Sequence[str] | None = None) -> None:
    """Warn about (or, ``strict``, refuse) unknown names in the node's parameter files.

    Names it does not
    declare, and sections naming it that do not apply in its namespace (rcl ignores both).

    Raises
    ------
    ParameterError when ``strict`` and there is a problem.
    """
    from okid_ros.service.param_files import (
        file_report,
        node_fqn,
        node_values_from_tree,
        params_files_from_args,
        read_files,
    )
    from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, node_params, validate_value

    names = {n: [s.name for s in node_params(n)] for n in (ARX_NODE, ESTIMATOR_NODE)}
    specs = {s.name: s for s in node_params(node.get_name())} if node.get_name() in names else {}
    namespace = node.get_namespace()
    files = read_files(params_files_from_args(sys.argv if argv is None else argv))
    for label, tree in files:
        # A value of the wrong kind in a later file is dropped by rcl's merge without a word
        # (the earlier file's value stays; the same file alone is refused): refuse it here.
        for name, value in node_values_from_tree(tree, node_fqn(node.get_name(), namespace)).items():
            if name in specs:
                try:
                    validate_value(specs[name], value)
                except ParameterError as exc:
                    raise ParameterError(f"{label}: {exc}") from None
    problems = [
        problem
        for label, tree in files
        for problem in file_report(tree, label, names, namespace, for_node=node.get_name())
    ]
    if problems and strict:
        raise ParameterError("; ".join(problems) + " (strict_parameters is true)")
    for problem in problems:
        node.get_logger().warning(problem)
