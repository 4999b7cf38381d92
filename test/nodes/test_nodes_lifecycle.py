"""Both nodes as managed nodes (`okid-ros up --lifecycle --no-autostart`).

Driven through the
standard lifecycle services over DDS: unconfigured -> configure -> inactive (no identification,
no publishing) -> activate -> active -> deactivate -> cleanup -> shutdown.
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import REPO_ROOT, ProbeNode, RosProcess, subprocess_env

from okid_msgs.msg import ArxModel, IoSample
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process

NS = "/lc"
NODES = (f"{NS}/okid_arx_identifier", f"{NS}/okid_modal_estimator")
SMALL = """
/**:
  ros__parameters:
    diagnostics_rate_hz: 5.0
/**/okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: 5.0
    arx: {order: 10, window_length: 400}
"""
DT = 0.008


class Probe(ProbeNode):
    """A client node with the lifecycle service clients of both nodes."""

    def __init__(self) -> None:
        super().__init__("okid_lifecycle_probe")
        self.arx: list[ArxModel] = []
        self.diagnostics: list[str] = []
        self.io = self.node.create_publisher(IoSample, f"{NS}/io_sample",
                                             QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(ArxModel, f"{NS}/arx_model", self._on_arx, reliable)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, reliable)
        self.start()
        self.stamp = 100.0
        u = lowpass_input(2000, 2, 50.0, DT, seed=2)
        self.u, (self.y, _) = u, simulate_innovation(paper_model(), u, seed=3)
        self.k = 0

    def _on_arx(self, msg: ArxModel) -> None:
        with self.lock:
            self.arx.append(msg)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        with self.lock:
            self.diagnostics += [s.name for s in msg.status]

    def publish(self, n: int, rate_hz: float = 500.0) -> None:
        for _ in range(n):
            msg = IoSample()
            ns = int(round(self.stamp * 1e9))
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
            msg.u = [float(v) for v in self.u[self.k % 2000]]
            msg.y = [float(v) for v in self.y[self.k % 2000]]
            self.io.publish(msg)
            self.stamp += DT
            self.k += 1
            time.sleep(1.0 / rate_hz)

    def state(self, node: str) -> int:
        return self.call(GetState, f"{node}/get_state", GetState.Request()).current_state.id

    def transition(self, node: str, transition_id: int) -> None:
        """Request one transition; a lost request is sent again only if the node did not move."""
        before = self.state(node)
        request = ChangeState.Request(transition=Transition(id=transition_id))
        for _ in range(4):
            try:
                answer = self.call(ChangeState, f"{node}/change_state", request, attempts=1)
            except AssertionError:
                if self.state(node) != before:  # the reply was lost, the transition was not
                    return
                continue
            assert answer.success, (node, transition_id)
            return
        raise AssertionError(f"{node}: transition {transition_id} never answered")

    def refused(self, node: str, transition_id: int) -> None:
        """A transition the node's state does not have is answered False and changes nothing."""
        before = self.state(node)
        request = ChangeState.Request(transition=Transition(id=transition_id))
        answer = self.call(ChangeState, f"{node}/change_state", request)
        assert not answer.success and self.state(node) == before, (node, transition_id)

    def counts(self) -> tuple[int, int]:
        with self.lock:
            est = sum(1 for name in self.diagnostics if name.startswith("lc/okid_modal_estimator"))
            return len(self.arx), est



@pytest.fixture
def probe(ros_domain_id):
    p = Probe()
    yield p
    p.close()


def test_lifecycle_transitions_over_dds(probe, ros_domain_id, tmp_path):
    params = tmp_path / "small.yaml"
    params.write_text(SMALL)
    up = RosProcess([sys.executable, "-m", "okid_ros.cli", "up", "--lifecycle", "--no-autostart", "--namespace", NS,
                     "--params", str(REPO_ROOT / "config" / "okid.yaml"), "--params", str(params)],
                    subprocess_env(ros_domain_id))
    try:
        for node in NODES:
            assert probe.state(node) == State.PRIMARY_STATE_UNCONFIGURED
        assert probe.node.count_publishers(f"{NS}/arx_model") == 0  # nothing built yet
        probe.refused(NODES[0], Transition.TRANSITION_ACTIVATE)  # rclpy's service raised: the node ended
        for node in NODES:
            probe.transition(node, Transition.TRANSITION_CONFIGURE)
            assert probe.state(node) == State.PRIMARY_STATE_INACTIVE
        deadline = time.monotonic() + 10
        while probe.io.get_subscription_count() < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert probe.io.get_subscription_count() == 2 and probe.node.count_publishers(f"{NS}/arx_model") == 1
        # Inactive: samples arrive, nothing is identified or published (diagnostics neither).
        probe.publish(500)
        time.sleep(1.0)
        assert probe.counts() == (0, 0)
        for node in NODES:
            probe.transition(node, Transition.TRANSITION_ACTIVATE)
            assert probe.state(node) == State.PRIMARY_STATE_ACTIVE
        probe.refused(NODES[1], Transition.TRANSITION_ACTIVATE)  # active already
        probe.publish(600)
        deadline = time.monotonic() + 1.0  # the last ArxModel and diagnostics, if still on their way (was: 1 s)
        while not (probe.arx and max(m.samples_used for m in probe.arx) >= 400 and probe.counts()[1] > 0) \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        with probe.lock:
            used = [m.samples_used for m in probe.arx]
        assert used and max(used) >= 400, used  # identified from the samples after activate only
        assert max(used) <= 600, used
        assert probe.counts()[1] > 0
        for node in NODES:
            probe.transition(node, Transition.TRANSITION_DEACTIVATE)
            assert probe.state(node) == State.PRIMARY_STATE_INACTIVE
        time.sleep(0.5)
        before = probe.counts()
        probe.publish(300)
        time.sleep(1.0)
        assert probe.counts() == before  # inactive again: silence
        for node in NODES:
            probe.transition(node, Transition.TRANSITION_CLEANUP)
            assert probe.state(node) == State.PRIMARY_STATE_UNCONFIGURED
        deadline = time.monotonic() + 0.5  # the graph without them (was: 0.5 s)
        while (probe.node.count_publishers(f"{NS}/arx_model") or probe.io.get_subscription_count()) \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        assert probe.node.count_publishers(f"{NS}/arx_model") == 0
        assert probe.io.get_subscription_count() == 0
        # Configure again after a cleanup, then shut down: the finalized node's process ends (0)
        # (test_a_finalized_node_ends_its_process: each node from each state); `up` leaves the other
        # running (was: stopped it and exited 1), and ends with 0 once both are shut down.
        probe.transition(NODES[0], Transition.TRANSITION_CONFIGURE)
        assert probe.state(NODES[0]) == State.PRIMARY_STATE_INACTIVE
        probe.transition(NODES[0], Transition.TRANSITION_INACTIVE_SHUTDOWN)
        up.wait_for_output(r"okid-ros up: okid_arx_identifier exited with status 0 \(its lifecycle shutdown, or a "
                           r"signal\); the other node runs on", 10)
        assert probe.state(NODES[1]) == State.PRIMARY_STATE_UNCONFIGURED
        probe.transition(NODES[1], Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
        assert up.proc.wait(timeout=10) == 0, up.output()
        assert "Traceback" not in up.output(), up.output()
    finally:
        up.stop()


@pytest.mark.dds_startup
@pytest.mark.parametrize("module, start, shutdown", [
    ("modal_estimator_node", (), Transition.TRANSITION_ACTIVE_SHUTDOWN),
    ("modal_estimator_node", ("--no-autostart",), Transition.TRANSITION_UNCONFIGURED_SHUTDOWN),
    ("arx_identifier_node", (), Transition.TRANSITION_ACTIVE_SHUTDOWN),
    ("arx_identifier_node", ("--no-autostart",), Transition.TRANSITION_UNCONFIGURED_SHUTDOWN),
])
def test_a_finalized_node_ends_its_process(probe, spawn_ros, module, start, shutdown):
    # After the shutdown transition (finalized: nothing more it can do) the process kept running
    # until killed; a user or a lifecycle manager expects it to end.
    node = spawn_ros("-m", f"okid_ros.nodes.{module}", "--lifecycle", *start, "--ros-args", "-r", f"__ns:={NS}")
    name = NODES[0] if module == "arx_identifier_node" else NODES[1]
    if not start:
        node.wait_for_output(r"ready:", 30)
    request = ChangeState.Request(transition=Transition(id=shutdown))
    try:
        answer = probe.call(ChangeState, f"{name}/change_state", request)
    except AssertionError:
        # A reply lost over DDS is sent again, but a node that took the request has finalized and
        # gone (a loaded machine, full suite): its own log says whether it did.
        if "shut down (finalized): the process ends" not in node.output():
            raise
    else:
        assert answer.success
    try:
        code = node.proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{module} finalized, but its process still runs 10 s later:\n{node.output()}")
    assert code == 0 and "Traceback" not in node.output(), node.output()
    assert "shut down (finalized): the process ends" in node.output()
