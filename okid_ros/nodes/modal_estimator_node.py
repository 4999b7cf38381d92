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
  for every incoming sample once a model exists (not for samples where the estimator diverged);
- ``okid_msgs/StructuralChange`` on ``structural_change_topic`` (default ``structural_change``
  in the rig namespace, reliable) when the innovation monitor declares a structural change, and
  again when the first model of the new structure is accepted; node 1 restarts its window at
  the change.

A model realized from a window is applied at the next sample; when no sample comes (the end of a
replayed bag, a sensor pause) a timer applies it after half a second or so
(:meth:`~okid_ros.service.estimation.ModalEstimationService.apply_ready_if_idle`), publishes it and
starts the realization of the ArxModel that waited meanwhile, so that the model of the last
window is published too.

Models that fail their checks (unstable, modes lost) are not used; the last good one stays and
the reason is in the diagnostics. Services: ``~/reset`` (std_srvs/Trigger) forgets the model,
the mode ids and the buffer; ``~/enable`` (std_srvs/SetBool) with false freezes the current
model (ARX models are ignored), true resumes.

The realization (~1 s at q = 100) runs in a worker process of its own at a lower priority
(``realization.worker: process``, the default), so it never holds this interpreter's lock; only
the last part of the warm start (the samples that arrived meanwhile, a fraction of a
millisecond) runs here, on the pool's thread. With ``realization.worker: thread`` it runs on a
thread, and Python's thread switch interval is lowered to 0.2 ms so that the per-sample path
gets the interpreter quickly while the worker runs Python code.

The samples are served by the node's input thread (:class:`okid_ros.nodes.input_thread.InputThread`),
which asks Linux for a short time slice (``input_slice_s``) so that it gets a core soon after
each sample arrives; the ArxModel subscription, services and timers by the executor.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import threading
from collections import deque
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.qos_overriding_options import QoSOverridingOptions

from okid_ros.errors import ParameterError
from okid_ros.nodes.base import OkidNode
from okid_ros.nodes.common import (
    lower_priority,
    make_status,
    name_thread,
    realtime_threads,
    reliable_qos,
)
from okid_ros.nodes.conversions import (
    estimator_arx_fit,
    mode_msg,
    ros_message_types,
    state_space_model_msg,
    structural_change_msg,
)
from okid_ros.nodes.runner import run_node
from okid_ros.nodes.serialized_states import ModalStatesBytes
from okid_ros.service.estimation import (
    IdleSwitch,
    ModalEstimationParams,
    ModalEstimationService,
    ModelUpdate,
    RealizationJob,
    RealizationOutcome,
    StructuralChangeEvent,
    realize,
)
from okid_ros.service.grid_samples import GridSample
from okid_ros.service.params import ESTIMATOR_NODE
from okid_ros.service.sample_steps import estimation_step
from okid_ros.tools.parent_death import die_with_parent

NODE_NAME = ESTIMATOR_NODE
SWITCH_INTERVAL_S = 2e-4
#: Period of the look for an idle sample stream [s]: a model delivered after the last sample is
#: published within :func:`okid_ros.service.idle.idle_after_s` plus this.
IDLE_CHECK_PERIOD_S = 0.25
#: Longest wait at shutdown for the realization pool's manager thread to end [s] (:meth:`close`).
MANAGER_JOIN_TIMEOUT_S = 2.0


class ModalEstimatorNode(OkidNode):
    """See the module docstring."""

    #: About the time one sample takes. With the default slice a woken input thread waited for
    #: the realization worker (nice 10) to finish its slice, up to 4 ms in a scheduler trace of
    #: bench/dds_latency.py (three quarters of its waits longer than 0.5 ms); with this one the
    #: worker's part of those waits fell from ~150 to ~4 ms in 4-5 s of trace.
    input_slice_s = 0.3e-3

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)

    def build(self) -> None:
        """Service, publishers, worker, timers, inputs (at the start, or on configure)."""
        values = self.values
        params = ModalEstimationParams.from_parameters(values)
        # The change test's confirmations by the modes (output-only references): off the sample path.
        self._confirm_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="confirm",
                                                initializer=name_thread, initargs=("okid_confirm",))
        try:
            self.service = ModalEstimationService(params, confirm_executor=self._confirm_pool)
        except ValueError as exc:
            self._confirm_pool.shutdown(wait=False)  # (no thread started: none was submitted)
            raise ParameterError(str(exc)) from None
        self.types = ros_message_types()
        overrides = QoSOverridingOptions.with_default_policies()
        self.topics = {key: self.topic(key) for key in (
            "arx_model_topic", "state_space_model_topic", "modal_states_topic", "structural_change_topic")}
        self.states_publisher = self.create_publisher(
            self.types.ModalStates, self.topics["modal_states_topic"], reliable_qos(100),
            qos_overriding_options=overrides,
        )
        self.model_publisher = self.create_publisher(
            self.types.StateSpaceModel, self.topics["state_space_model_topic"], reliable_qos(5, latched=True),
            qos_overriding_options=overrides,
        )
        self.change_publisher = self.create_publisher(
            self.types.StructuralChange, self.topics["structural_change_topic"], reliable_qos(10),
            qos_overriding_options=overrides,
        )
        self.create_subscription(
            self.types.ArxModel, self.topics["arx_model_topic"], self._on_arx_model, reliable_qos(5),
            qos_overriding_options=overrides,
        )
        if values["realization.worker"] == "process":
            # A process of its own: the realization never holds this interpreter's lock.
            self._pool = ProcessPoolExecutor(
                max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                initializer=_worker_init, initargs=("okid_realize", os.getpid()),
            )
            # Started now (and its imports), not at the first model, with Ctrl-C blocked (the mask is
            # inherited): a terminal's Ctrl-C reaches the whole process group, and a worker still
            # importing the core, before _worker_init ignores it, printed a traceback.
            blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            try:
                self._pool.submit(_worker_warm_up)
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        else:
            self._pool = ThreadPoolExecutor(
                max_workers=1, thread_name_prefix="realization", initializer=name_thread, initargs=("okid_realize",)
            )
        self._job: Future | None = None
        self._running_job: RealizationJob | None = None
        self._mode_msgs: list = []
        self._updates_to_log: deque = deque()  # appended on the executor thread, logged on the side thread
        self._changes_to_log: deque = deque()
        self._states_bytes = ModalStatesBytes(self.types.ModalStates)  # a template per model, written per sample
        self._arx_invalid = 0
        self._arx_malformed = 0
        self._last_logged_reason = ""
        self._lock = threading.Lock()
        # A timer of its own, not the diagnostics timer: that one's rate is a parameter (down to
        # 0.01 Hz). Each look costs a lock and a comparison while samples flow.
        self.create_timer(IDLE_CHECK_PERIOD_S, self._on_idle_timer)
        if values["realtime_priority"]:
            # The node's own threads (samples, executor, DDS) before the realization worker
            # and node 1 on a loaded machine; the worker process keeps its ordinary scheduling.
            refused = realtime_threads(int(values["realtime_priority"]))
            if refused:
                self.get_logger().warning(f"realtime_priority not applied: {refused}; ordinary scheduling")
        self.start_inputs()
        if ignored := params.output_only_ignored():  # as `process` and `batch` say it
            self.get_logger().warning(ignored)
        order = "auto" if params.n_states == 0 else str(params.n_states)
        if params.n_inputs == 0:  # the realization's order options do not apply
            order = f"auto, output-only ({params.output_only_method})"
        self.get_logger().info(
            f"ready: states {order}, m={params.n_inputs}, p={params.n_outputs}, dt={params.sample_time_s:g} s; "
            f"inputs {self.input_summary()}; models from {self.topics['arx_model_topic']}; publishing "
            f"{self.topics['modal_states_topic']} and {self.topics['state_space_model_topic']}"
        )

    # ------------------------------------------------------------------ samples
    def on_sample(self, sample: GridSample) -> None:
        result = estimation_step(self.service, sample)
        if result is not None:
            if result.update is not None:
                self._publish_update(result.update)
            if result.change is not None:
                self._publish_change(result.change, result.stamp_s)
            self.states_publisher.publish(self._states_bytes.message(result, self._mode_msgs, self.frame_id))
        if self._job is None and self.service.has_request:
            self._start_job()

    def _on_idle_timer(self) -> None:
        """With no samples coming, apply and publish a delivered model, then start the waiting job."""
        if not self.active:
            return
        with self.state_lock:  # the input thread may be handling samples, starting a job
            switch = self.service.apply_ready_if_idle()
            if switch is not None:
                self._publish_update(switch.update, switch)
                if switch.change is not None:
                    self._publish_change(switch.change, switch.stamp_s)
            if self._job is None and self.service.has_request:
                self._start_job()

    def _publish_update(self, update: ModelUpdate, idle: IdleSwitch | None = None) -> None:
        """An accepted model: its modes for the ModalStates, its StateSpaceModel, its log line.

        ``idle``: the switch was made while no samples arrived (noted in the log).
        """
        self._mode_msgs = [mode_msg(m, self.types) for m in update.modes]
        # The StateSpaceModel (matrices, modes) is built and published off the sample path.
        self.off_sample_path(lambda: self.model_publisher.publish(
            state_space_model_msg(update, self.types, frame_id=self.frame_id)))
        self._updates_to_log.append((update, idle))  # logged with the diagnostics: a log call costs ~1 ms

    def _publish_change(self, change: StructuralChangeEvent, stamp_s: float) -> None:
        self.off_sample_path(lambda: self.change_publisher.publish(
            structural_change_msg(change, stamp_s, self.types, frame_id=self.frame_id)))
        self._changes_to_log.append(change)

    # ------------------------------------------------------------------ models
    def _on_arx_model(self, msg) -> None:
        if not self.active:
            return
        if not msg.valid:
            self._arx_invalid += 1
            return
        try:
            fit, stamp_s, rows = estimator_arx_fit(msg, self.service.params)
        except ValueError as exc:
            self._arx_malformed += 1
            self.get_logger().warning(str(exc))
            return
        with self.state_lock:  # the input thread may be starting a job too
            try:
                self.service.submit_arx(fit, stamp_s, int(msg.model_id), rows)
            except MemoryError:  # a window too large for this machine: refused, the node goes on
                self._arx_malformed += 1
                self.get_logger().warning(f"ArxModel {msg.model_id} ignored: a window of {rows} rows does "
                                          "not fit in memory")
                return
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

    # ------------------------------------------------------------------ hooks of OkidNode
    def reset_state(self, reason: str) -> str:
        self.service.reset()
        self._mode_msgs = []
        self._last_logged_reason = ""
        return "model, mode ids and sample buffer cleared"

    def set_enabled(self, on: bool) -> str:
        self.service.set_enabled(on)
        return f"model updates {'on' if on else 'off (current model frozen)'}"

    def check_parameters(self, values: dict[str, Any]) -> None:
        ModalEstimationParams.from_parameters(values).realization_options()  # ValueError with the reason

    def apply_parameters(self, values: dict[str, Any], changed: dict[str, Any]) -> None:
        # The service hands each option to the part that uses it: at once.
        params = ModalEstimationParams.from_parameters(values)
        self.service.set_params(params)
        if set(changed) & set(params.output_only_ignored_names()):  # a change the output-only route ignores
            self.get_logger().warning(params.output_only_ignored())

    def before_diagnostics(self) -> None:
        while self._changes_to_log:
            change = self._changes_to_log.popleft()
            modes = ", ".join(f"#{m.id} {m.frequency_hz:.3f} Hz" for m in (change.modes_after or change.modes_before))
            what = "identified, modes after" if change.modes_after else "declared, modes before"
            self.get_logger().warning(
                f"structural change {change.change_id} at {change.change_stamp_s:.3f} s "
                f"(statistic {change.statistic:.1f} > {change.threshold:.1f}) {what}: {modes}"
            )
        while self._updates_to_log:
            update, idle = self._updates_to_log.popleft()
            modes = ", ".join(f"#{m.id} {m.frequency_hz:.3f} Hz {100 * m.damping_ratio:.2f} %" for m in update.modes)
            when = "" if idle is None else f", applied after the last sample at {idle.stamp_s:.3f} s"
            self.get_logger().info(
                f"model {update.model_id} (ARX {update.arx_model_id}, {update.model.n_states} states, "
                f"realized in {update.realization_time_s:.2f} s{when}): {modes}"
            )

    def diagnostic_statuses(self) -> list:
        d = self.service.diagnostics()
        grid = self.inputs.grid.counters
        d["arx_models_invalid"] = self._arx_invalid
        d["arx_models_malformed"] = self._arx_malformed
        d["time_jump_resets"] = self.time_jump_resets
        d["samples_rejected"] = d.pop("rejected_samples") + grid.rejected_messages
        d["samples_missing"] = grid.missing
        reason = d["last_reason"]
        # Once per distinct reason, numbers left out (a count that grows is the same reason).
        reason_kind = "".join(c for c in reason if not c.isdigit())
        if reason and reason_kind != self._last_logged_reason:
            self.get_logger().warning(f"model not used: {reason}")
        self._last_logged_reason = reason_kind
        if d["model_id"] == 0:
            level = DiagnosticStatus.WARN
            message = f"no model yet: {reason or 'waiting for a valid ArxModel'}"
        elif not d["last_model_accepted"]:
            level = DiagnosticStatus.WARN
            message = f"keeping model {d['model_id']}: {reason}"
        else:
            level = DiagnosticStatus.OK
            message = f"model {d['model_id']}: {d['n_modes']} modes, {d['n_states']} states"
        if d["change_waiting_for_model"]:
            level = DiagnosticStatus.WARN
            message += (f"; structural change at {d['last_change_stamp_s']:.3f} s, "
                        "waiting for a model of the new structure")
        if d["order_limit_reached"]:
            message += "; the automatic model order stopped at its limit (realization.max_states_limit)"
        if not d["enabled"]:
            message += " (model updates off)"
        return [make_status(f"{self.status_name}: estimation", level, message, d)]

    def close(self) -> None:
        confirm = getattr(self, "_confirm_pool", None)
        if confirm is not None:
            confirm.shutdown(wait=False, cancel_futures=True)
        pool = getattr(self, "_pool", None)  # None: never configured (lifecycle)
        if pool is None:
            return
        if isinstance(pool, ProcessPoolExecutor):
            stop_process_pool(pool)
        else:
            pool.shutdown(wait=False, cancel_futures=True)


def stop_process_pool(pool: ProcessPoolExecutor, *, timeout_s: float = MANAGER_JOIN_TIMEOUT_S) -> None:
    """End the realization worker now and wait (at most ``timeout_s``) for the pool's manager thread.

    A realization under way is of no use any more: without the terminate the process waited for
    it at exit (seconds), and a Ctrl-C meanwhile was ignored (nodes/runner.py). Python 3.11's exit
    handler wakes the pool's manager thread without the pool's lock, and printed "OSError: Bad
    file descriptor" when that thread was closing its wake-up pipe at the same moment (fixed in
    3.12); once the thread has ended (quickly: no worker is left to wait for) the handler no
    longer sees it. ``shutdown(wait=False)`` drops the pool's reference to the thread, so it is
    taken first.
    """
    manager = getattr(pool, "_executor_manager_thread", None)
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()
    pool.shutdown(wait=False, cancel_futures=True)
    if manager is not None and manager is not threading.current_thread():
        manager.join(timeout=timeout_s)


def _worker_init(name: str, node_pid: int | None = None) -> None:
    """Set up the realization worker process.

    A name for top/ps, Ctrl-C left to the node, an end with the node's process, lower priority
    so that the per-sample paths win when the cores are busy.
    """
    import warnings

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A node killed (SIGKILL, the OOM killer) cannot stop its pool: without this the worker and
    # multiprocessing's resource tracker lived on, orphaned, one pair per crash (Linux only).
    die_with_parent(node_pid)
    name_thread(name)
    # Numerical warnings of the realization (ill-conditioned refits of candidate orders) are
    # part of its normal work; a model that fails its checks is reported in the diagnostics.
    warnings.filterwarnings("ignore", module=r"okid_ros\.core\..*")
    warnings.filterwarnings("ignore", module=r"scipy\..*")
    # Nice 10 on every thread. Not the idle scheduling class: measured, it kept the worker out
    # of the sample thread's way no better than that thread's short slice does (input_slice_s),
    # and with other work on the machine the realizations then took 8-9 s (median) instead of
    # 1.2-4 s.
    lower_priority(10)


def _worker_warm_up() -> None:
    """Nothing: the worker process has imported the core when this returns."""


def main(args: list[str] | None = None) -> int:
    """Console script ``modal_estimator``."""
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    return run_node(ModalEstimatorNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
