"""Node 1, ``okid_arx_identifier``: windowed ARX identification on live topics.

Subscribes the input sources of ``inputs.sources`` (sensor-data QoS), assembles samples on
the sample grid by header stamp, feeds them to
:class:`okid_ros.service.identification.ArxIdentificationService` and publishes
``okid_msgs/ArxModel`` on ``arx_model_topic`` (default ``/okid/arx_model``, reliable) at
``publish_rate_hz`` on the node clock (so ``use_sim_time`` works).

Subscribes ``okid_msgs/StructuralChange`` (``structural_change_topic``, default
``structural_change`` in the rig namespace, from node 2): the window restarts at the change
point before the next solve
(:meth:`~okid_ros.service.identification.ArxIdentificationService.restart_at`: the changes
between two solves cost one replay, of the newest); one it ignores or supersedes
(:mod:`okid_ros.service.change_restarts`) is counted by why, an ignored one logged at most once
per :data:`IGNORED_CHANGE_LOG_S`.

Services: ``~/reset`` (std_srvs/Trigger) forgets the window; ``~/enable`` (std_srvs/SetBool)
switches adaptation on and off (off: the window is frozen and the same model is republished).
Diagnostics on ``/diagnostics``. Parameters, services, namespaces, time jumps and run-time
parameter changes are handled by :class:`okid_ros.nodes.base.OkidNode`.

Run: ``ros2 run okid_ros arx_identifier --ros-args --params-file config/okid.yaml`` or
``python -m okid_ros.nodes.arx_identifier_node --ros-args --params-file config/okid.yaml``.

The solve runs on a worker thread, which also publishes the result; a lock keeps it apart from
``~/reset``.
"""

from __future__ import annotations

import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.qos_overriding_options import QoSOverridingOptions

from okid_ros.errors import ParameterError
from okid_ros.nodes.base import OkidNode
from okid_ros.nodes.common import lower_priority, make_status, name_thread, reliable_qos
from okid_ros.nodes.conversions import arx_model_msg, ros_message_types, stamp_to_seconds
from okid_ros.nodes.runner import run_node
from okid_ros.service.arx_solve import SolveResult, WindowCapture, solve_capture
from okid_ros.service.grid_samples import GridSample
from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
from okid_ros.service.params import ARX_NODE
from okid_ros.service.sample_steps import identification_step

NODE_NAME = ARX_NODE
#: At most one line per this many seconds of structural changes ignored (each is counted).
IGNORED_CHANGE_LOG_S = 10.0
#: Seconds between two log lines of models fitted without an input silent over their window.
SILENT_INPUT_LOG_S = 10.0


class ArxIdentifierNode(OkidNode):
    """See the module docstring."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)

    def build(self) -> None:
        """Service, publishers, worker, timers, inputs (at the start, or on configure)."""
        values = self.values
        params = ArxIdentificationParams.from_parameters(values)
        try:
            self.service = ArxIdentificationService(params)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self.types = ros_message_types()
        self.arx_model_topic = self.topic("arx_model_topic")
        self.publisher = self.create_publisher(
            self.types.ArxModel, self.arx_model_topic, reliable_qos(10),
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        # Node 2 declares structural changes: the window restarts at the change point.
        self.create_subscription(
            self.types.StructuralChange, self.topic("structural_change_topic"), self._on_structural_change,
            reliable_qos(10), qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        self._pool = ThreadPoolExecutor(
            max_workers=1, thread_name_prefix="arx_solve", initializer=name_thread, initargs=("okid_arx_solve",)
        )
        self._solving = False
        self._skipped_publishes = 0
        self._pending_change = (0, float("nan"))  # the id and stamp of the change the window restarts at next
        self._lock = threading.Lock()
        self._publish_timer = self.create_timer(1.0 / float(values["publish_rate_hz"]), self._on_publish_timer)
        self.start_inputs()
        self.get_logger().info(
            f"ready: ARX order {params.order}, window {params.window_length or 'forgetting'}, "
            f"m={params.n_inputs}, p={params.n_outputs}, dt={params.sample_time_s:g} s; inputs {self.input_summary()}; "
            f"publishing {self.arx_model_topic} at {values['publish_rate_hz']:g} Hz"
        )

    # ------------------------------------------------------------------ samples
    def on_sample(self, sample: GridSample) -> None:
        identification_step(self.service, sample)

    def _on_structural_change(self, msg) -> None:
        """Restart the window at the change point before the next solve; one ignored is logged throttled."""
        if not self.active:
            return
        stamp_s = stamp_to_seconds(msg.change_stamp)
        with self.state_lock, self._lock:  # the window is the input thread's too
            held = self.service.restart_at(stamp_s)
            ignored = self.service.last_ignored_change
        if held >= 0:  # logged when applied: a flood of them is one restart and one line per solve
            self._pending_change = (msg.change_id, stamp_s)
        else:  # a flood of them (a replay, a misbehaving publisher) is one line per IGNORED_CHANGE_LOG_S
            self.get_logger().info(f"structural change {msg.change_id} ignored: {ignored} (counted in "
                                   "window_restarts_ignored_why)", throttle_duration_sec=IGNORED_CHANGE_LOG_S)

    # ------------------------------------------------------------------ publishing
    def _on_publish_timer(self) -> None:
        if not self.active:
            return
        if self._solving:
            self._skipped_publishes += 1  # the previous solve is still running
            return
        # The input thread pushes into the window being copied; the worker checks its generation.
        with self.state_lock, self._lock:
            replayed = self.service.apply_pending_restart()
            capture = self.service.capture()
        self._log_restart(replayed)
        self._solving = True  # before submit: the worker clears it when done
        self._pool.submit(self._solve, capture)

    def _log_restart(self, replayed: int) -> None:
        """Say the window restarted at the pending change with ``replayed`` samples (-1: none was pending)."""
        if replayed >= 0:
            change_id, stamp_s = self._pending_change
            self.get_logger().info(f"structural change {change_id}: window restarted at {stamp_s:.3f} s "
                                   f"with {replayed} samples")

    def _solve(self, capture: WindowCapture) -> None:
        """On the worker thread: solve, then accept and publish (rclpy publishers are thread-safe)."""
        try:
            result = solve_capture(capture)
        except Exception as exc:  # never lose the worker: report and go on
            result = SolveResult(None, float("nan"), f"internal error in the solve: {exc!r}", 0.0)
        try:
            with self._lock:
                if not self.service.is_current(capture):
                    return  # solved before a reset or restart, or by the service before a reconfigure
                snapshot = self.service.accept(capture, result)
            self.publisher.publish(arx_model_msg(snapshot, self.types, frame_id=self.frame_id))
            if result.warning:  # a sensor that stays disconnected is one line per SILENT_INPUT_LOG_S
                self.get_logger().warning(f"model {snapshot.model_id} fitted without its silent input(s): "
                                          f"{result.warning} (counted in silent_input_snapshots)",
                                          throttle_duration_sec=SILENT_INPUT_LOG_S)
        finally:
            self._solving = False

    # ------------------------------------------------------------------ hooks of OkidNode
    def reset_state(self, reason: str) -> str:
        with self._lock:
            self.service.reset()  # a solve of the old window still running is then stale
        return "window, counters and model ids cleared"

    def set_enabled(self, on: bool) -> str:
        with self._lock:  # a pending restart is applied first (a new window generation), under the old adaptation
            replayed = self.service.apply_pending_restart()
            self.service.set_adaptation(on)
        self._log_restart(replayed)
        return f"adaptation {'on' if on else 'off (window frozen)'}"

    def check_parameters(self, values: dict[str, Any]) -> None:
        ArxIdentificationParams.from_parameters(values)

    def apply_parameters(self, values: dict[str, Any], changed: dict[str, Any]) -> None:
        # The solve reads the parameters from each capture: the next solve uses the new ones.
        with self._lock:
            self.service.set_params(ArxIdentificationParams.from_parameters(values))
        if "publish_rate_hz" in changed:
            self._publish_timer.timer_period_ns = int(1e9 / float(values["publish_rate_hz"]))

    def diagnostic_statuses(self) -> list:
        d = self.service.diagnostics()
        grid = self.inputs.grid.counters
        d["samples_rejected"] += grid.rejected_messages
        d["samples_missing"] = grid.missing
        d["skipped_publishes"] = self._skipped_publishes
        d["time_jump_resets"] = self.time_jump_resets
        if not d["has_good_model"]:
            level = DiagnosticStatus.WARN
            message = f"no model yet: {d['last_reason'] or 'waiting for samples'}"
        elif d["last_reason"]:
            level = DiagnosticStatus.WARN
            message = f"keeping the last good model: {d['last_reason']}"
        else:
            level = DiagnosticStatus.OK
            message = f"model {d['model_id']} valid, window {100 * d['window_fill']:.0f} % full"
        if not d["adaptation"]:
            message += " (adaptation off)"
        return [make_status(f"{self.status_name}: identification", level, message, d)]

    def close(self) -> None:
        pool = getattr(self, "_pool", None)  # None: never configured (lifecycle)
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)


#: Nice value of this node's threads (Linux): see :func:`main`.
NICE = 5


def main(args: list[str] | None = None) -> int:
    """Console script ``arx_identifier``.

    The node runs at nice :data:`NICE`: it has no per-sample output, so its samples can wait in
    their queue (1 s at 1 kHz) while the estimator's sample path, whose latency counts, takes
    the core. Both wake for every sample; on 2 cores a scheduler trace of
    ``bench/dds_latency.py`` put most of the estimator's waits for a core on this node's
    sample thread (its window update every 128 samples) and solve thread. Set before the
    node starts its threads, so that they inherit it.
    """
    lower_priority(NICE)
    return run_node(ArxIdentifierNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
