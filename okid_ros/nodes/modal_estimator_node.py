"""Node 2, ``okid_modal_estimator``: ERA realization, persistent modes and modal states.

Subscribes ``okid_msgs/ArxModel`` (``arx_model_topic``) and the same input sources as node 1
(``inputs.sources``, sensor-data QoS), buffers the assembled samples, realizes each valid ARX
model on a worker thread (:class:`okid_ros.service.estimation.ModalEstimationService`: weighted
ERA, refit of B, D and the gain, modal form, checks, warm start) off the sample path, and
publishes:

- ``okid_msgs/StateSpaceModel`` on ``state_space_model_topic`` (default
  ``/okid/state_space_model``; reliable, transient local: a late subscriber gets the current
  model) for every accepted model;
- ``okid_msgs/ModalStates`` on ``modal_states_topic`` (default ``/okid/modal_states``, reliable)
  for every incoming sample once a model exists.

Models that fail their checks (unstable, modes lost) are not used; the last good one stays and
the reason is in the diagnostics. Services: ``~/reset`` (std_srvs/Trigger) forgets the model,
the mode ids and the buffer; ``~/enable`` (std_srvs/SetBool) with false freezes the current
model (ARX models are ignored), true resumes.

The realization (~1 s at q = 100) runs in a worker process of its own at a lower priority
(``realization.worker: process``, the default), so it never holds this interpreter's lock;
only the last part of the warm start (the samples that arrived meanwhile, a few milliseconds)
runs here, on the pool's thread. With ``realization.worker: thread`` it runs on a thread, and
Python's thread switch interval is lowered to 0.2 ms so that the per-sample path gets the
interpreter quickly while the worker runs Python code.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import threading
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from std_srvs.srv import SetBool, Trigger

from okid_ros.errors import ParameterError
from okid_ros.nodes.common import (
    DiagnosticsPublisher,
    InputFrontend,
    declare_parameters,
    name_thread,
    make_status,
    reliable_qos,
    run_node,
)
from okid_ros.nodes.conversions import (
    arx_fit_from_msg,
    fill_modal_states,
    mode_msg,
    ros_message_types,
    state_space_model_msg,
)
from okid_ros.service.estimation import (
    ModalEstimationParams,
    ModalEstimationService,
    RealizationJob,
    RealizationOutcome,
    realize,
)
from okid_ros.service.params import ESTIMATOR_NODE, node_params
from okid_ros.service.sample_grid import RESTART_SKIP, GridSample

NODE_NAME = ESTIMATOR_NODE
SWITCH_INTERVAL_S = 2e-4


class ModalEstimatorNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values = declare_parameters(self, node_params(NODE_NAME))
        self.values = values
        params = ModalEstimationParams.from_parameters(values)
        try:
            self.service = ModalEstimationService(params)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self.types = ros_message_types()
        overrides = QoSOverridingOptions.with_default_policies()
        self.states_publisher = self.create_publisher(
            self.types.ModalStates, values["modal_states_topic"], reliable_qos(100),
            qos_overriding_options=overrides,
        )
        self.model_publisher = self.create_publisher(
            self.types.StateSpaceModel, values["state_space_model_topic"], reliable_qos(5, latched=True),
            qos_overriding_options=overrides,
        )
        self.create_subscription(
            self.types.ArxModel, values["arx_model_topic"], self._on_arx_model, reliable_qos(5),
            qos_overriding_options=overrides,
        )
        self.inputs = InputFrontend(self, values, self._on_sample)
        self.diagnostics = DiagnosticsPublisher(self)
        if values["realization.worker"] == "process":
            # A process of its own: the realization never holds this interpreter's lock.
            self._pool = ProcessPoolExecutor(
                max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                initializer=_worker_init, initargs=("okid_realize",),
            )
            self._pool.submit(_worker_warm_up)  # start it (and its imports) now, not at the first model
        else:
            self._pool = ThreadPoolExecutor(
                max_workers=1, thread_name_prefix="realization", initializer=name_thread, initargs=("okid_realize",)
            )
        self._job: Future | None = None
        self._running_job: RealizationJob | None = None
        self._mode_msgs: list = []
        self._updates_to_log: list = []
        self._states_msg = self.types.ModalStates()  # refilled and published for every sample
        self._arx_invalid = 0
        self._arx_malformed = 0
        self._last_logged_reason = ""
        self._lock = threading.Lock()
        self.create_timer(1.0 / float(values["diagnostics_rate_hz"]), self._on_diagnostics_timer)
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/enable", self._on_enable)
        topics = ", ".join(f"{s.topic} ({s.kind})" for s in self.inputs.specs)
        order = "auto" if params.n_states == 0 else str(params.n_states)
        self.get_logger().info(
            f"ready: states {order}, m={params.n_inputs}, p={params.n_outputs}, dt={params.sample_time_s:g} s; "
            f"inputs {topics}; models from {values['arx_model_topic']}; publishing "
            f"{values['modal_states_topic']} and {values['state_space_model_topic']}"
        )

    # ------------------------------------------------------------------ samples
    def _on_sample(self, sample: GridSample) -> None:
        skipped = RESTART_SKIP if sample.restart else sample.skipped
        result = self.service.step(sample.stamp_s, sample.u, sample.y, skipped)
        if result is not None:
            if result.update is not None:
                update = result.update
                self._mode_msgs = [mode_msg(m, self.types) for m in update.modes]
                self.model_publisher.publish(state_space_model_msg(update, self.types))
                self._updates_to_log.append(update)  # logged by the diagnostics timer: a log call costs ~1 ms
            self.states_publisher.publish(fill_modal_states(self._states_msg, result, self._mode_msgs))
        if self._job is None and self.service.has_request:
            self._start_job()

    # ------------------------------------------------------------------ models
    def _on_arx_model(self, msg) -> None:
        if not msg.valid:
            self._arx_invalid += 1
            return
        try:
            fit, stamp_s, rows = arx_fit_from_msg(msg)
        except ValueError as exc:
            self._arx_malformed += 1
            self.get_logger().warning(f"ArxModel {msg.model_id} ignored: {exc}")
            return
        self.service.submit_arx(fit, stamp_s, int(msg.model_id), rows)
        if self._job is None:
            self._start_job()

    def _start_job(self) -> None:
        job = self.service.take_job()
        if job is None:
            return
        self._running_job = job
        self._job = self._pool.submit(realize, job)
        self._job.add_done_callback(self._on_realized)

    def _on_realized(self, future: Future) -> None:
        """On the pool's thread: continue the warm start to the newest sample, hand it over."""
        try:
            outcome = self.service.follow(future.result())
        except Exception as exc:  # never lose the worker: report and go on
            outcome = RealizationOutcome(self._running_job, None, f"internal error in the realization: {exc!r}")
        self.service.deliver(outcome)
        self._job = None

    # ------------------------------------------------------------------ services
    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.service.reset()
        self.inputs.reset()
        self._mode_msgs = []
        self.get_logger().info("reset: model, mode ids and sample buffer cleared")
        response.success = True
        response.message = "estimator reset"
        return response

    def _on_enable(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        self.service.set_enabled(request.data)
        state = "on" if request.data else "off (current model frozen)"
        self.get_logger().info(f"model updates {state}")
        response.success = True
        response.message = f"model updates {state}"
        return response

    # ------------------------------------------------------------------ diagnostics
    def _on_diagnostics_timer(self) -> None:
        updates, self._updates_to_log = self._updates_to_log, []
        for update in updates:
            modes = ", ".join(f"#{m.id} {m.frequency_hz:.3f} Hz {100 * m.damping_ratio:.2f} %" for m in update.modes)
            self.get_logger().info(
                f"model {update.model_id} (ARX {update.arx_model_id}, {update.model.n_states} states, "
                f"realized in {update.realization_time_s:.2f} s): {modes}"
            )
        for change in self.inputs.update_health():
            if "stale" in change:
                self.get_logger().warning(change)
            else:
                self.get_logger().info(change)
        d = self.service.diagnostics()
        grid = self.inputs.grid.counters
        d["arx_models_invalid"] = self._arx_invalid
        d["arx_models_malformed"] = self._arx_malformed
        d["samples_rejected"] = d.pop("rejected_samples") + grid.rejected_messages
        d["samples_missing"] = grid.missing
        reason = d["last_reason"]
        if reason and reason != self._last_logged_reason:
            self.get_logger().warning(f"model not used: {reason}")
        self._last_logged_reason = reason
        if d["model_id"] == 0:
            level = DiagnosticStatus.WARN
            message = f"no model yet: {reason or 'waiting for a valid ArxModel'}"
        elif not d["last_model_accepted"]:
            level = DiagnosticStatus.WARN
            message = f"keeping model {d['model_id']}: {reason}"
        else:
            level = DiagnosticStatus.OK
            message = f"model {d['model_id']}: {d['n_modes']} modes, {d['n_states']} states"
        if not d["enabled"]:
            message += " (model updates off)"
        self.diagnostics.publish([
            make_status(f"{NODE_NAME}: estimation", level, message, d),
            self.inputs.status(NODE_NAME),
        ])

    def close(self) -> None:
        """Stop the worker (called at shutdown)."""
        self._pool.shutdown(wait=False, cancel_futures=True)


def _worker_init(name: str) -> None:
    """In the realization worker: a name for top/ps, Ctrl-C left to the node, lower priority so
    that the per-sample path wins when the cores are busy."""
    import signal
    import warnings

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    name_thread(name)
    # Numerical warnings of the realization (ill-conditioned refits of candidate orders) are
    # part of its normal work; a model that fails its checks is reported in the diagnostics.
    warnings.filterwarnings("ignore", module=r"okid_ros\.core\..*")
    warnings.filterwarnings("ignore", module=r"scipy\..*")
    try:
        os.nice(10)
    except OSError:
        pass


def _worker_warm_up() -> None:
    """Nothing: the worker process has imported the core when this returns."""


def main(args: list[str] | None = None) -> int:
    """Console script ``modal_estimator``."""
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    return run_node(ModalEstimatorNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
