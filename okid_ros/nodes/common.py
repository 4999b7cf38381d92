"""What both nodes share.

Parameter declaration, QoS, thread scheduling, diagnostics and the parameter-file checks
(the input topics: :mod:`okid_ros.nodes.input_frontend`).
"""

from __future__ import annotations

import math
import os
import re
import sys
import threading
from collections.abc import Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from okid_ros.errors import ParameterError
from okid_ros.service.params import ParamSpec, read_only_reason, validate_value

__all__ = [
    "lower_priority",
    "ordinary_scheduling",
    "realtime_threads",
    "request_short_slice",
    "name_thread",
    "declare_parameters",
    "DiagnosticsPublisher",
    "reliable_qos",
    "sensor_qos",
    "SIM_CLOCK_SILENCE_S",
    "SIM_TIME_WITHOUT_CLOCK",
]

_INT64_MAX = 2**63 - 1

#: What a node says when ``use_sim_time`` is true and nothing publishes /clock (switched on at run
#: time, or given at the start with samples arriving and the node clock still at 0).
SIM_TIME_WITHOUT_CLOCK = (
    "use_sim_time set to true, but nothing publishes /clock: the node clock stands still, "
    "and with it this node's timers (its outputs on a rate, the diagnostics) until /clock comes "
    "(e.g. okid-ros replay --clock); set use_sim_time false to run on the system clock")
#: How long samples may arrive while the node clock stands at 0 (``use_sim_time``, no /clock message
#: yet) before :data:`SIM_TIME_WITHOUT_CLOCK` is said [s]: a replay publishes /clock from its first
#: message on, so a clock still at 0 seconds after the samples started is not coming by itself.
SIM_CLOCK_SILENCE_S = 3.0


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
