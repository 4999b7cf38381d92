"""The base both nodes share.

Parameters (declared, checked against the parameter files,
changed at run time), topic names in the rig namespace, the input frontend, the ``~/reset``
and ``~/enable`` services, the diagnostics timer with its health log, time jumps, shutdown.

A node subclasses :class:`OkidNode` and implements the hooks:

- ``on_sample(sample)``: one assembled :class:`~okid_ros.service.sample_grid.GridSample`;
- ``reset_state(reason)``: forget the window / model (``~/reset``, a time jump);
- ``set_enabled(on) -> str``: ``~/enable``; returns what is now on or off;
- ``check_parameters(values)``: build the node's settings from ``values`` (all parameters
  with the requested changes) and raise ValueError / ParameterError if they do not fit
  together; nothing may change yet;
- ``apply_parameters(values, changed)``: take the changed values (after the check);
- ``diagnostic_statuses() -> list``: the node's own DiagnosticStatus entries;
- ``build()``: create the node's service, publishers, subscriptions, timers and workers,
  ending with :meth:`OkidNode.start_inputs`;
- ``close()``: stop workers.

Unmanaged (the default), ``build`` runs in the constructor and the node is active at once.
Managed (``managed=True``, :func:`managed_node_class`; ``--lifecycle`` on the command line) the
node is an ``rclpy.lifecycle`` node: the constructor declares the parameters only, *configure*
builds, *activate* starts the identification and the publishing, *deactivate* stops both
(samples are dropped, nothing is published, the services still answer), *cleanup* destroys
what configure built, *shutdown* does the same from any state.

Threads: :func:`run_node` serves the input subscriptions on a thread of their own
(:class:`InputThread`, ``okid_samples``) and everything else (timers, services, parameters,
lifecycle, other subscriptions) on the executor in the main thread; the node's
:attr:`OkidNode.state_lock` keeps the two apart.
"""

from __future__ import annotations

import gc
import sys
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from typing import Any

import rclpy
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.guard_condition import GuardCondition
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import SetBool, Trigger

from okid_ros.errors import ParameterError
from okid_ros.nodes.audit import log_calls
from okid_ros.nodes.common import (
    DiagnosticsPublisher,
    InputFrontend,
    check_parameter_files,
    declare_parameters,
    name_thread,
    request_short_slice,
)
from okid_ros.service.params import node_params, read_only_reason, validate_value
from okid_ros.service.sample_grid import GridSample
from okid_ros.service.topics import resolve_topic

__all__ = ["InputThread", "OkidNode", "managed_node_class", "run_node"]


class OkidNode(Node):
    """See the module docstring.

    Parameters
    ----------
    node_name : the node's name (``okid_arx_identifier`` or ``okid_modal_estimator``).
    **kwargs : passed to :class:`rclpy.node.Node`.

    Raises
    ------
    ParameterError when a parameter is out of range or (``strict_parameters``) a parameter
    file names a parameter the node does not declare.
    """

    #: Time slice the input thread asks Linux for (:func:`~okid_ros.nodes.common.request_short_slice`)
    #: when the node's per-sample latency counts; None: the default slice.
    input_slice_s: float | None = None

    def __init__(self, node_name: str, *, managed: bool = False, **kwargs: Any) -> None:
        Node.__init__(self, node_name, **kwargs)
        self.managed = bool(managed)
        self.specs = {spec.name: spec for spec in node_params(node_name)}
        self.values = declare_parameters(self, list(self.specs.values()))
        check_parameter_files(self, bool(self.values["strict_parameters"]))
        self.inputs: InputFrontend | None = None
        self.diagnostics: DiagnosticsPublisher | None = None
        self._diagnostics_timer = None
        self._built_entities: tuple | None = None
        self.active = False
        self.time_jump_resets = 0
        # Held by the input thread while it handles samples and by the callbacks that change
        # the node's state (services, parameters, lifecycle, the nodes' own subscriptions and
        # timers): with the inputs on a thread of their own they would otherwise interleave.
        self.state_lock = threading.RLock()
        self.input_thread: InputThread | None = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        for service in self.services:  # rclpy's parameter services: changes are logged with the caller
            if service.srv_name.endswith(("/set_parameters", "/set_parameters_atomically")):
                log_calls(self, service)
        if not self.managed:
            self.configure()
            self.active = True

    # ------------------------------------------------------------------ build / tear down
    def configure(self) -> None:
        """Build the node (its entities are remembered, so :meth:`teardown` can destroy them).

        Raises ParameterError when the parameters do not fit together.
        """
        with self.state_lock:
            # Work off the per-sample path (diagnostics, log lines, model messages) runs on
            # this thread: on the thread that serves the samples it held back the samples
            # queued behind it for milliseconds; here it only shares the interpreter in short
            # slices.
            self._side = ThreadPoolExecutor(max_workers=1, thread_name_prefix="okid_side",
                                            initializer=name_thread, initargs=("okid_side",))
            self._side_pending = threading.Event()
            before = self._entities()
            self.diagnostics = DiagnosticsPublisher(self)
            self.build()
            now = self._entities()
            self._built_entities = tuple(n - b for n, b in zip(now, before))
        if self.input_thread is not None:
            self.input_thread.wake()  # new input subscriptions to wait on

    def teardown(self) -> None:
        """Stop the workers and destroy what :meth:`configure` created."""
        if self.input_thread is not None:
            self.input_thread.wake()  # out of its wait, so that the subscriptions can go
        with self.state_lock:
            self.active = False
            self.close()
            side = getattr(self, "_side", None)
            if side is not None:
                side.shutdown(wait=False, cancel_futures=True)
            if self._built_entities is not None:
                publishers, subscriptions, timers, services = self._built_entities
                for timer in timers:
                    self.destroy_timer(timer)
                for sub in subscriptions:
                    self.destroy_subscription(sub)
                for pub in publishers:
                    self.destroy_publisher(pub)
                for srv in services:
                    self.destroy_service(srv)
            self._built_entities = None
            self.inputs = None
            self.diagnostics = None
            self._diagnostics_timer = None

    def _entities(self) -> tuple[set, set, set, set]:
        return set(self.publishers), set(self.subscriptions), set(self.timers), set(self.services)

    # ------------------------------------------------------------------ names
    def topic(self, parameter: str) -> str:
        """Full name of the topic in parameter ``parameter`` (relative: in the rig namespace)."""
        return resolve_topic(self.values[parameter], self.get_namespace())

    @property
    def status_name(self) -> str:
        """Prefix of the node's DiagnosticStatus names.

        The node name, with its namespace when it
        has one (``rig1/okid_arx_identifier``), so that rigs in one domain stay apart.
        """
        return self.get_fully_qualified_name().lstrip("/")

    @property
    def frame_id(self) -> str:
        return str(self.values["frame_id"])

    # ------------------------------------------------------------------ start
    def start_inputs(self) -> None:
        """Subscribe the inputs, create the services and the diagnostics timer (call last)."""
        self.inputs = InputFrontend(self, self.values, self._on_grid_sample)
        self._diagnostics_timer = self.create_timer(
            1.0 / float(self.values["diagnostics_rate_hz"]), self._on_diagnostics_timer)
        log_calls(self, self.create_service(Trigger, "~/reset", self._on_reset))
        log_calls(self, self.create_service(SetBool, "~/enable", self._on_enable))

    def input_summary(self) -> str:
        return ", ".join(f"{s.topic} ({s.kind})" for s in self.inputs.specs) if self.inputs else ""

    # ------------------------------------------------------------------ samples
    def _on_grid_sample(self, sample: GridSample) -> None:
        if not self.active:
            return  # inactive (lifecycle): no identification
        if sample.time_jump and self.values["reset_on_time_jump"]:
            # A looped bag or a restarted simulation: start again as at the first start
            # instead of carrying a window / model across the jump.
            self.time_jump_resets += 1
            self.reset_state("time jump")
            self.get_logger().info(
                f"time jump back to {sample.stamp_s:.3f} s: restarted (reset_on_time_jump)")
        self.on_sample(sample)

    # ------------------------------------------------------------------ services
    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        with self.state_lock:
            message = self.reset_state("reset service")
            if self.inputs is not None:
                self.inputs.reset()
        self.get_logger().info(f"reset: {message}")
        response.success = True
        response.message = message
        return response

    def _on_enable(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        with self.state_lock:
            state = self.set_enabled(bool(request.data))
        self.get_logger().info(state)
        response.success = True
        response.message = state
        return response

    # ------------------------------------------------------------------ parameters
    def _on_set_parameters(self, parameters: Sequence[Parameter]) -> SetParametersResult:
        """Validate a run-time change like at the start; apply it only if all of it is valid."""
        with self.state_lock:
            return self._set_parameters(parameters)

    def _set_parameters(self, parameters: Sequence[Parameter]) -> SetParametersResult:
        changed: dict[str, Any] = {}
        for param in parameters:
            spec = self.specs.get(param.name)
            if spec is None:
                continue  # use_sim_time, qos_overrides.*: rclpy's own
            reason = read_only_reason(param.name)
            if reason:
                return SetParametersResult(successful=False, reason=f"{param.name} is read-only: {reason}")
            try:
                changed[param.name] = validate_value(spec, param.value)
            except ParameterError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        if not changed:
            return SetParametersResult(successful=True)
        values = {**self.values, **changed}
        try:
            self.check_parameters(values)
        except (ValueError, ParameterError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        old_values, self.values = self.values, values
        if self._built_entities is None:
            return SetParametersResult(successful=True)  # unconfigured: taken at configure
        if "diagnostics_rate_hz" in changed and self._diagnostics_timer is not None:
            self._diagnostics_timer.timer_period_ns = int(1e9 / float(values["diagnostics_rate_hz"]))
        if self.inputs is not None:
            self.inputs.apply_parameters(values)
        self.apply_parameters(values, changed)
        self.get_logger().info("parameters set: " + ", ".join(
            f"{k}: {old_values[k]!r} -> {v!r}" for k, v in changed.items()))
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ diagnostics
    def off_sample_path(self, work: Callable[[], None]) -> None:
        """Run ``work`` on the node's side thread (in order), not on the executor thread."""
        try:
            self._side.submit(self._guarded, work)
        except RuntimeError:
            pass  # shutting down

    def _guarded(self, work: Callable[[], None]) -> None:
        try:
            work()
        except Exception as exc:  # never lose the side thread: report and go on
            self.get_logger().error(f"internal error off the sample path: {exc!r}")

    def _on_diagnostics_timer(self) -> None:
        if not self.active or self._side_pending.is_set():
            return  # the previous diagnostics are still being built
        self._side_pending.set()
        self.off_sample_path(self._diagnostics)

    def _diagnostics(self) -> None:
        try:
            self._publish_diagnostics()
        finally:
            self._side_pending.clear()

    def _publish_diagnostics(self) -> None:
        if self.inputs is None or self.diagnostics is None:
            return
        self.before_diagnostics()
        if self.inputs is not None:
            for change, is_warning in self.inputs.update_health():
                # Separate calls: an rclpy log call site keeps the severity of its first call.
                if is_warning:
                    self.get_logger().warning(change)
                else:
                    self.get_logger().info(change)
        statuses = self.diagnostic_statuses()
        if self.inputs is not None:
            statuses.append(self.inputs.status(self.status_name))
        self.diagnostics.publish(statuses)

    # ------------------------------------------------------------------ hooks
    def build(self) -> None:
        raise NotImplementedError

    def on_sample(self, sample: GridSample) -> None:
        raise NotImplementedError

    def reset_state(self, reason: str) -> str:
        raise NotImplementedError

    def set_enabled(self, on: bool) -> str:
        raise NotImplementedError

    def check_parameters(self, values: dict[str, Any]) -> None:
        """Raise ValueError if ``values`` do not fit together (default: nothing to check)."""

    def apply_parameters(self, values: dict[str, Any], changed: dict[str, Any]) -> None:
        """Take changed run-time parameters (default: nothing)."""

    def before_diagnostics(self) -> None:
        """Work done on the diagnostics timer before the health log (default: nothing)."""

    def diagnostic_statuses(self) -> list:
        return []

    def close(self) -> None:
        """Stop workers (called at shutdown)."""


def managed_node_class(cls: type[OkidNode]) -> type:
    """The managed (rclpy.lifecycle) variant of a node class: see the module docstring."""
    from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn

    class Managed(LifecycleNodeMixin, cls):
        def __init__(self, **kwargs: Any) -> None:
            cls.__init__(self, managed=True, **kwargs)
            LifecycleNodeMixin.__init__(self, enable_communication_interface=True)

        def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
            try:
                self.configure()
            except (ParameterError, ValueError) as exc:
                self.get_logger().error(f"configure failed: {exc}")
                self.teardown()
                return TransitionCallbackReturn.FAILURE
            self.get_logger().info("configured (inactive: no identification, no publishing)")
            return TransitionCallbackReturn.SUCCESS

        def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
            with self.state_lock:
                self.reset_state("activate")  # start from the data that comes from now on
                if self.inputs is not None:
                    self.inputs.reset()
                self.active = True
            self.get_logger().info("active")
            return TransitionCallbackReturn.SUCCESS

        def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
            with self.state_lock:  # after a sample being handled, none is handled or published
                self.active = False
            self.get_logger().info("inactive: no identification, no publishing")
            return TransitionCallbackReturn.SUCCESS

        def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
            self.teardown()
            self.get_logger().info("cleaned up (unconfigured)")
            return TransitionCallbackReturn.SUCCESS

        def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
            self.teardown()
            return TransitionCallbackReturn.SUCCESS

        def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
            self.teardown()
            return TransitionCallbackReturn.SUCCESS

    Managed.__name__ = Managed.__qualname__ = f"Managed{cls.__name__}"
    return Managed


class _ExecutorWithoutInputs(SingleThreadedExecutor):
    """The executor of all but the node's input subscriptions and their event handlers.

    Those are :class:`InputThread`'s: an event handler of an input subscription left in this
    executor's wait set would wake it at every message of the subscription.
    """

    def __init__(self, node: OkidNode) -> None:
        super().__init__()
        self._okid_node = node

    def can_execute(self, entity: Any) -> bool:
        inputs = self._okid_node.inputs
        if inputs is not None and any(entity is sub or any(entity is h for h in sub.event_handlers)
                                      for sub in inputs.subscriptions):
            return False
        return super().can_execute(entity)


class InputThread:
    """Serves a node's input subscriptions on a thread of their own, ``okid_samples``.

    rclpy's executor builds a new wait set over every entity of the node (services, timers,
    the event handlers of each publisher and subscription, ...) at each wake: 0.2-0.3 ms of
    CPU per message on a 2-core machine, at 1 kHz more than the node's own work per sample,
    and what makes the samples queue when the cores are busy. This thread waits on the input
    subscriptions (and their QoS event handlers) only, with one wait set kept from wait to
    wait (as ``rclpy.wait_for_message`` does; about 0.06 ms per message), and hands what is
    queued to :meth:`~okid_ros.nodes.common.InputFrontend.take_all` under
    :attr:`OkidNode.state_lock`. The executor of :meth:`executor` serves the rest and leaves
    the inputs out.

    Parameters
    ----------
    node : the node; its ``inputs`` may come and go (lifecycle configure and cleanup).
    timeout_s : longest wait before the thread looks at the node's inputs again.
    """

    def __init__(self, node: OkidNode, timeout_s: float = 0.1) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation

        self._rclpy = rclpy_implementation
        self.node = node
        self.timeout_ns = int(timeout_s * 1e9)
        self.error: Exception | None = None  # what ended the thread, re-raised by run_node
        self._stop = False
        self._wake = GuardCondition(None, None, context=node.context)
        self._thread = threading.Thread(target=self._run, name="okid_samples", daemon=True)
        node.input_thread = self

    @staticmethod
    def supported() -> bool:
        """Whether this rclpy has the wait-set API the thread needs (else the executor serves the inputs)."""
        try:
            from rclpy.impl.implementation_singleton import rclpy_implementation
        except ImportError:
            return False
        return all(hasattr(rclpy_implementation.WaitSet, name) for name in (
            "clear_entities", "add_subscription", "add_guard_condition", "wait", "get_ready_entities"))

    def executor(self) -> SingleThreadedExecutor:
        """An executor for the node that leaves its inputs to this thread."""
        return _ExecutorWithoutInputs(self.node)

    def start(self) -> None:
        self._thread.start()

    def wake(self) -> None:
        """End the current wait (the inputs changed, or the thread is to stop)."""
        try:
            self._wake.trigger()
        except InvalidHandle:
            pass

    def stop(self) -> None:
        """Stop the thread and wait for it (a batch of samples being handled is finished first)."""
        self._stop = True
        self.wake()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self.node.input_thread = None
        self._wake.destroy()

    def _run(self) -> None:
        name_thread("okid_samples")
        if self.node.input_slice_s:
            request_short_slice(self.node.input_slice_s)
        node, context = self.node, self.node.context
        subs: tuple = ()
        events: list = []
        wait_set = None
        try:
            while not self._stop and context.ok():
                frontend = node.inputs
                current = tuple(frontend.subscriptions) if frontend is not None else ()
                if wait_set is None or len(current) != len(subs) or any(a is not b for a, b in zip(current, subs)):
                    subs = current
                    events = [handler for sub in subs for handler in sub.event_handlers]
                    wait_set = self._rclpy.WaitSet(len(subs), 1, 0, 0, 0, len(events), context.handle)
                try:
                    samples, ready_events = self._wait(wait_set, subs, events)
                except InvalidHandle:
                    with node.state_lock:  # a cleanup is destroying the inputs: let it finish
                        pass
                    continue
                for handler, data in ready_events:
                    handler.callback(data)  # QoS events of the inputs (default: a warning in the log)
                if samples and not self._stop:
                    with node.state_lock:
                        if node.inputs is frontend:
                            frontend.take_all()
        except Exception as exc:  # reported by run_node, as an exception in a callback would be
            if context.ok() and not self._stop:
                self.error = exc
                rclpy.try_shutdown(context=context)  # ends the executor's spin

    def _wait(self, wait_set: Any, subs: tuple, events: list) -> tuple[bool, list]:
        """Wait for messages on ``subs`` or a QoS event (or a wake).

        Returns whether a message is ready, and the (handler, event data) of the events taken.
        """
        with ExitStack() as in_use:  # a handle in use is not destroyed under the wait
            for entity in (*(sub.handle for sub in subs), *events, self._wake.handle):
                in_use.enter_context(entity)
            wait_set.clear_entities()
            for sub in subs:
                wait_set.add_subscription(sub.handle)
            for handler in events:
                handler.add_to_wait_set(wait_set)
            wait_set.add_guard_condition(self._wake.handle)
            wait_set.wait(self.timeout_ns)
            taken = [(h, h.take_data()) for h in events if h.is_ready(wait_set)]
            return bool(wait_set.get_ready_entities("subscription")), [(h, d) for h, d in taken if d]


def run_node(factory: Callable[..., Node], name: str, args: Sequence[str] | None = None) -> int:
    """Create the node, spin until Ctrl-C / SIGTERM / shutdown; 2 if the parameters are invalid.

    Options before ``--ros-args``: ``--lifecycle`` runs the node as a managed node
    (:func:`managed_node_class`), configured and activated at once unless
    ``--no-autostart`` is given too (then a lifecycle manager or ``ros2 lifecycle set`` does it).
    """
    from rclpy.lifecycle import TransitionCallbackReturn
    from rclpy.utilities import remove_ros_args

    argv = list(sys.argv if args is None else args)
    # A launch argument may carry several options in one string, or none ("").
    own = [word for arg in remove_ros_args(argv)[1:] for word in arg.split()]
    unknown = [a for a in own if a not in ("--lifecycle", "--no-autostart")]
    if unknown:
        print(f"[{name}] error: unknown option(s) {' '.join(unknown)}; options: --lifecycle [--no-autostart] "
              "before --ros-args", file=sys.stderr, flush=True)
        return 2
    managed = "--lifecycle" in own
    autostart = "--no-autostart" not in own
    from rclpy.impl.implementation_singleton import rclpy_implementation

    node = None
    input_thread: InputThread | None = None
    try:
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
        executor.spin()
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
        if input_thread is not None:
            input_thread.stop()
        if node is not None:
            close = getattr(node, "close", None)
            if close is not None:
                close()
            node.destroy_node()
        rclpy.try_shutdown()
