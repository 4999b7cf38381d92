"""Node 1 over DDS with one input silent (a disconnected force sensor): models from the other, the input named.

Truth: the paper's structure driven on input 0, input 1 exactly zero; `identify` and `track` identify such a
record from input 0 with a warning naming input 1, and node 1 refused every window as unexcited.
"""

from __future__ import annotations

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import ProbeNode, io_sample_rig, publish_io_samples, subprocess_env

from okid_msgs.msg import ArxModel, IoSample
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process

T0, N = 100.0, 3000
PARAMS = """
/**:
  ros__parameters:
    sample_time_s: 0.008
    diagnostics_rate_hz: 5.0
okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: 4.0
    arx:
      order: 10
      window_length: 600
"""
SENSOR_QOS = QoSProfile(depth=500, reliability=ReliabilityPolicy.BEST_EFFORT)
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


class Probe(ProbeNode):
    """Publishes the samples; records ArxModel validity and node 1's diagnostics."""

    def __init__(self) -> None:
        super().__init__("okid_silent_input_probe")
        self.arx: list[tuple[bool, int]] = []  # valid, window rows
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.io = self.node.create_publisher(IoSample, "/okid/io_sample", SENSOR_QOS)
        self.node.create_subscription(ArxModel, "/okid/arx_model", self._on_arx, RELIABLE)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, RELIABLE)
        self.start()

    def _on_arx(self, msg) -> None:
        with self.lock:
            self.arx.append((bool(msg.valid), int(msg.window_fill)))

    def _on_diagnostics(self, msg) -> None:
        with self.lock:
            for status in msg.status:
                self.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}


def test_node_1_fits_without_a_silent_input_names_it_and_counts_it(ros_domain_id, tmp_path):
    with io_sample_rig(Probe, PARAMS, tmp_path, subprocess_env(ros_domain_id)) as (procs, probe):
        truth = paper_model()
        u = lowpass_input(N, 2, 15.0, truth.sample_time_s, seed=7)
        u[:, 1] = 0.0
        y, _ = simulate_innovation(truth, u, seed=1007)
        publish_io_samples(probe.io, u, y, t0_s=T0, sample_time_s=truth.sample_time_s)
        probe.wait_until("a valid ArxModel", lambda: any(valid for valid, _ in probe.arx), 20)
        probe.wait_until("node 1's count of them", lambda: int(probe.diagnostics.get(
            "okid_arx_identifier: identification", {}).get("silent_input_snapshots", "0")) > 0, 10)
        with probe.lock:
            ident = dict(probe.diagnostics["okid_arx_identifier: identification"])
            refused = [rows for valid, rows in probe.arx if not valid and rows >= 600]  # full windows refused
        assert not refused, (refused, ident["last_reason"])
        assert "no excitation on input 1 (all zeros) in this window" in ident["last_silent_input_warning"]
        assert "fitted without its silent input(s): no excitation on input 1 (all zeros)" in procs["arx"].output()
