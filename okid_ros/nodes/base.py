"""The base both nodes share.

Parameters (declared, checked against the parameter files,
changed at run time), topic names in the rig namespace, the input frontend, the ``~/reset``
and ``~/enable`` services, the diagnostics timer with its health log, time jumps, shutdown.

A node subclasses :class:`OkidNode` and implements the hooks:

- ``on_sample(sample)``: one assembled :class:`~okid_ros.service.grid_samples.GridSample`;
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
Managed (``managed=True``, :func:`okid_ros.nodes.lifecycle.managed_node_class`; ``--lifecycle`` on the command line) the
node is an ``rclpy.lifecycle`` node: the constructor declares the parameters only, *configure*
builds, *activate* starts the identification and the publishing, *deactivate* stops both
(samples are dropped, nothing is published, the services still answer), *cleanup* destroys
what configure built, *shutdown* does the same from any state and ends the process.

Split by concern: this module is the node base; :mod:`okid_ros.nodes.lifecycle` its managed
variant, :mod:`okid_ros.nodes.input_thread` the thread that serves its inputs,
:mod:`okid_ros.nodes.runner` the entry point :func:`~okid_ros.nodes.runner.run_node`.

Threads: :func:`~okid_ros.nodes.runner.run_node` serves the input subscriptions on a thread of their own
(:class:`InputThread`, ``okid_samples``) and everything else (timers, services, parameters,
lifecycle, other subscriptions) on the executor in the main thread; the node's
:attr:`OkidNode.state_lock` keeps the two apart.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import SetBool, Trigger

from okid_ros.errors import ParameterError
from okid_ros.nodes.audit import log_calls
from okid_ros.nodes.common import (
    SIM_TIME_WITHOUT_CLOCK,
    DiagnosticsPublisher,
    check_parameter_files,
    declare_parameters,
    name_thread,
)
from okid_ros.nodes.input_frontend import InputFrontend
from okid_ros.service.grid_samples import GridSample
from okid_ros.service.params import node_params, read_only_reason, validate_value
from okid_ros.service.topics import resolve_topic

__all__ = ["OkidNode"]


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
        self.finalized = False  # the lifecycle shutdown ran: the process ends (nodes/runner.py)
        self.time_jump_resets = 0
        # Held by the input thread while it handles samples and by the callbacks that change
        # the node's state (services, parameters, lifecycle, the nodes' own subscriptions and
        # timers): with the inputs on a thread of their own they would otherwise interleave.
        self.state_lock = threading.RLock()
        self.input_thread: Any = None  # its InputThread (okid_ros.nodes.input_thread), once one serves it
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
        return resolve_topic(self.values[parameter], self.get_namespace(), parameter=parameter)

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
                if param.name == "use_sim_time" and param.value is True:
                    self._tell_sim_time_without_clock()
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

    def _tell_sim_time_without_clock(self) -> None:
        """Warn when ``use_sim_time`` is switched on while nothing publishes /clock.

        The node clock then stands at 0 and every timer on it stops (node 1's ArxModel, the
        diagnostics, the staleness check, node 2's idle timer): the node fell silent with the
        change answered ``successful`` and nothing said. rclpy takes the change as it should (a
        replay's /clock may come later), so it is told, not refused. Given at the start, the input
        frontend tells it once samples arrive with the clock still at 0
        (:meth:`~okid_ros.nodes.input_frontend.InputFrontend.note_clock_at_zero`).
        """
        if self.count_publishers("/clock") == 0:
            self.get_logger().warning(SIM_TIME_WITHOUT_CLOCK)
            if self.inputs is not None:
                self.inputs.sim_clock_told = True  # not said again when samples come with the clock at 0

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
            if not self.context.ok():
                return  # stopping (Ctrl-C shuts the context down first): a publish fails, nothing to report
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
