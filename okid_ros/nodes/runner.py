"""The entry point of both nodes: :func:`run_node` (options, lifecycle, input thread, spin, shutdown)."""

from __future__ import annotations

import gc
import signal
import sys
import threading
from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from okid_ros.errors import ParameterError
from okid_ros.nodes.input_thread import InputThread
from okid_ros.nodes.lifecycle import managed_node_class

__all__ = ["run_node"]


def run_node(factory: Callable[..., Node], name: str, args: Sequence[str] | None = None) -> int:
    """Create the node, spin until Ctrl-C / SIGTERM / the lifecycle shutdown (0); 2 if the parameters are invalid.

    Options before ``--ros-args``: ``--lifecycle`` runs the node as a managed node
    (:func:`managed_node_class`), configured and activated at once unless
    ``--no-autostart`` is given too (then a lifecycle manager or ``ros2 lifecycle set`` does it).
    """
    from rclpy.impl.implementation_singleton import rclpy_implementation
    from rclpy.lifecycle import TransitionCallbackReturn
    from rclpy.utilities import remove_ros_args

    argv = list(sys.argv if args is None else args)
    try:
        # A launch argument may carry several options in one string, or none ("").
        own = [word for arg in remove_ros_args(argv)[1:] for word in arg.split()]
    except rclpy_implementation.RCLError as exc:  # rcl parses --params-file here: not YAML, ...
        print(f"[{name}] error: {' '.join(str(exc).split())}", file=sys.stderr, flush=True)
        return 2
    unknown = [a for a in own if a not in ("--lifecycle", "--no-autostart")]
    if unknown:
        print(f"[{name}] error: unknown option(s) {' '.join(unknown)}; options: --lifecycle [--no-autostart] "
              "before --ros-args", file=sys.stderr, flush=True)
        return 2
    managed = "--lifecycle" in own
    autostart = "--no-autostart" not in own

    node = None
    input_thread: InputThread | None = None
    try:
        _interrupt_once()  # before rclpy.init, whose handler passes the signal on to this one
        rclpy.init(args=argv)
        if managed:
            node = managed_node_class(factory)()
            if autostart:
                if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                    raise ParameterError("configure failed (see the log above)")
                node.trigger_activate()
        else:
            node = factory()
        # Everything allocated so far (modules, the node) is permanent: keep it out of the
        # cyclic collector, whose full passes over it otherwise stall the sample path by
        # 10-20 ms now and then.
        gc.freeze()
        if InputThread.supported():
            input_thread = InputThread(node)
            executor = input_thread.executor()
        else:
            executor = SingleThreadedExecutor()
        executor.add_node(node)
        if input_thread is not None:
            input_thread.start()
        # Until the lifecycle shutdown has finalized the node (its answer sent by the spin_once that
        # ran it): a finalized node can do nothing more, and its process lived on until killed.
        while executor.context.ok() and not node.finalized:
            executor.spin_once()
        return 0
    except ParameterError as exc:
        print(f"[{name}] error: {exc}", file=sys.stderr, flush=True)
        return 2
    except rclpy_implementation.RCLError as exc:
        if node is not None:
            raise
        # ROS refused to start (e.g. ROS_SECURITY_STRATEGY=Enforce without the enclave's keys,
        # or a Fast DDS without security): one line, not a traceback.
        print(f"[{name}] error: cannot start: {' '.join(str(exc).split())}", file=sys.stderr, flush=True)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        if input_thread is not None and input_thread.error is not None:
            raise input_thread.error from None  # the input thread failed: as if in a callback
        return 0  # Ctrl-C or SIGTERM, also while starting
    finally:
        _ignore_interrupts()  # also after a SIGTERM or an error
        if input_thread is not None:
            input_thread.stop()
        if node is not None:
            close = getattr(node, "close", None)
            if close is not None:
                close()
            node.destroy_node()
        rclpy.try_shutdown()


def _interrupt_once() -> None:
    """The first Ctrl-C stops the node (KeyboardInterrupt); a further one changes nothing, prints nothing.

    A second Ctrl-C (a terminal's, or ``ros2 launch`` passing one on while it stops the nodes)
    raised KeyboardInterrupt inside the shutdown, or in the interpreter's wait for the worker
    threads at exit, and printed a traceback (the exit status 0, or -2 when it came late). Now
    the stop finishes as after one Ctrl-C: the same status, the realization worker and the DDS
    participant ended properly. It waits for nothing long (node 2 ends its realization worker
    instead of waiting for it), and SIGTERM or SIGKILL still end a process that hangs.
    """
    if threading.current_thread() is not threading.main_thread():
        return  # signal handlers are the main thread's (a test running the node on a thread)

    def first(signum, frame) -> None:
        _ignore_interrupts()  # from the first moment on: a second one may follow within microseconds
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, first)


def _ignore_interrupts() -> None:
    """Ignore Ctrl-C from now on (the node is stopping)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
