"""Node 1, ``okid_arx_identifier``: windowed ARX identification on live topics.

Subscribes the input sources of ``inputs.sources`` (sensor-data QoS), assembles samples on
the sample grid by header stamp, feeds them to
:class:`okid_ros.service.identification.ArxIdentificationService` and publishes
``okid_msgs/ArxModel`` on ``arx_model_topic`` (default ``/okid/arx_model``, reliable) at
``publish_rate_hz`` on the node clock (so ``use_sim_time`` works).

Services: ``~/reset`` (std_srvs/Trigger) forgets the window; ``~/enable`` (std_srvs/SetBool)
switches adaptation on and off (off: the window is frozen and the same model is republished).
Diagnostics on ``/diagnostics``.

Run: ``ros2 run okid_ros arx_identifier --ros-args --params-file config/okid.yaml`` or
``python -m okid_ros.nodes.arx_identifier_node --ros-args --params-file config/okid.yaml``.

The solve runs on a worker thread, which also publishes the result; a lock keeps it apart from
``~/reset``.
"""

from __future__ import annotations

import sys
import threading
from concurrent.futures import ThreadPoolExecutor

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
from okid_ros.nodes.conversions import arx_model_msg, ros_message_types
from okid_ros.service.identification import (
    ArxIdentificationParams,
    ArxIdentificationService,
    SolveResult,
    WindowCapture,
    solve_capture,
)
from okid_ros.service.params import ARX_NODE, node_params
from okid_ros.service.sample_grid import GridSample

NODE_NAME = ARX_NODE


class ArxIdentifierNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values = declare_parameters(self, node_params(NODE_NAME))
        self.values = values
        params = ArxIdentificationParams.from_parameters(values)
        try:
            self.service = ArxIdentificationService(params)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self.types = ros_message_types()
        self.publisher = self.create_publisher(
            self.types.ArxModel, values["arx_model_topic"], reliable_qos(10),
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        self.inputs = InputFrontend(self, values, self._on_sample)
        self.diagnostics = DiagnosticsPublisher(self)
        self._pool = ThreadPoolExecutor(
            max_workers=1, thread_name_prefix="arx_solve", initializer=name_thread, initargs=("okid_arx_solve",)
        )
        self._solving = False
        self._generation = 0
        self._skipped_publishes = 0
        self._lock = threading.Lock()
        self.create_timer(1.0 / float(values["publish_rate_hz"]), self._on_publish_timer)
        self.create_timer(1.0 / float(values["diagnostics_rate_hz"]), self._on_diagnostics_timer)
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/enable", self._on_enable)
        topics = ", ".join(f"{s.topic} ({s.kind})" for s in self.inputs.specs)
        self.get_logger().info(
            f"ready: ARX order {params.order}, window {params.window_length or 'forgetting'}, "
            f"m={params.n_inputs}, p={params.n_outputs}, dt={params.sample_time_s:g} s; inputs {topics}; "
            f"publishing {values['arx_model_topic']} at {values['publish_rate_hz']:g} Hz"
        )

    # ------------------------------------------------------------------ samples
    def _on_sample(self, sample: GridSample) -> None:
        self.service.push(sample.stamp_s, sample.u, sample.y, gap_before=sample.gap_before)

    # ------------------------------------------------------------------ publishing
    def _on_publish_timer(self) -> None:
        if self._solving:
            self._skipped_publishes += 1  # the previous solve is still running
            return
        capture = self.service.capture()
        self._solving = True  # before submit: the worker clears it when done
        self._pool.submit(self._solve, self._generation, capture)

    def _solve(self, generation: int, capture: WindowCapture) -> None:
        """On the worker thread: solve, then accept and publish (rclpy publishers are thread-safe)."""
        try:
            result = solve_capture(capture)
        except Exception as exc:  # never lose the worker: report and go on
            result = SolveResult(None, float("nan"), f"internal error in the solve: {exc!r}", 0.0)
        try:
            with self._lock:
                if generation != self._generation:
                    return  # solved before a reset
                snapshot = self.service.accept(capture, result)
            self.publisher.publish(arx_model_msg(snapshot, self.types))
        finally:
            self._solving = False

    # ------------------------------------------------------------------ services
    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        with self._lock:
            self._generation += 1
            self.service.reset()
            self.inputs.reset()
        self.get_logger().info("reset: window, counters and model ids cleared")
        response.success = True
        response.message = "ARX window reset"
        return response

    def _on_enable(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        self.service.set_adaptation(request.data)
        state = "on" if request.data else "off (window frozen)"
        self.get_logger().info(f"adaptation {state}")
        response.success = True
        response.message = f"adaptation {state}"
        return response

    # ------------------------------------------------------------------ diagnostics
    def _on_diagnostics_timer(self) -> None:
        for change in self.inputs.update_health():
            if "stale" in change:
                self.get_logger().warning(change)
            else:
                self.get_logger().info(change)
        d = self.service.diagnostics()
        grid = self.inputs.grid.counters
        d["samples_rejected"] += grid.rejected_messages
        d["samples_missing"] = grid.missing
        d["skipped_publishes"] = self._skipped_publishes
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
        self.diagnostics.publish([
            make_status(f"{NODE_NAME}: identification", level, message, d),
            self.inputs.status(NODE_NAME),
        ])

    def close(self) -> None:
        """Stop the worker (called at shutdown)."""
        self._pool.shutdown(wait=False, cancel_futures=True)


def main(args: list[str] | None = None) -> int:
    """Console script ``arx_identifier``."""
    return run_node(ArxIdentifierNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
