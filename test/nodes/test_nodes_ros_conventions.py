"""ROS conventions over real DDS.

Two namespaced rigs in one domain, run-time parameters through
the standard parameter services, unknown names in parameter files.

The rigs get a small ARX problem (order 20, window 400 rows, ArxModel at 4 Hz, 6 states) so that
four nodes stay light on a shared machine; what is checked is where the messages go, not the
identification (test_nodes_integration.py checks that). Still, a rig's node 2 must accept a model
while its samples flow, or it publishes no modal states at all (a model applied after the last sample
has no sample to estimate): every window of the rigs' stream gives node 2 a model with a physical
mode (test_every_window_of_the_rigs_stream_gives_node_2_a_model).
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters, SetParametersAtomically
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import REPO_ROOT, ProbeNode, RosProcess, subprocess_env
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger

from okid_msgs.msg import ArxModel, IoSample, ModalStates
from okid_ros.nodes.common import SIM_CLOCK_SILENCE_S
from okid_ros.service.estimation import ModalEstimationService
from okid_ros.service.identification import ArxIdentificationService
from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation
from okid_ros.tools.node_parameters import load_node_parameters

# Each test over DDS says so (`make test` runs it after the rest, in one process); the check of every
# window of the rigs' stream runs node 1's and node 2's services in this process and runs with the rest.

DT = 0.008
RIGS = {"/rig1": 1000.0, "/rig2": 5000.0}  # namespace -> first stamp of its samples [s]
RIGS_SAMPLES = {"/rig1": 1500, "/rig2": 1100}  # different counts: each rig must count only its own
SMALL = """
/**:
  ros__parameters:
    diagnostics_rate_hz: 5.0
/**/okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: 4.0
    arx: {order: 20, window_length: 400}
/**/okid_modal_estimator:
  ros__parameters:
    realization: {n_states: 6, refine: false, worker: thread}
"""
SENSOR_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT)
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


# What a rig's node 2 said, in a failure message: the keys of its estimation diagnostics that tell
# where its ArxModels went, and the last lines of its log.
ESTIMATION_KEYS = ("samples", "buffer_samples", "arx_models_received", "arx_models_refused_why",
                   "arx_models_unchanged", "arx_models_replaced", "realizations", "models_accepted",
                   "models_rejected", "models_applied_idle", "last_reason", "last_realization_time_s",
                   "model_id", "busy", "arx_request_waiting")
LOG_LINES = 30


def rig_stream() -> tuple[np.ndarray, np.ndarray]:
    """The samples each rig gets, its first ``RIGS_SAMPLES`` of them: inputs (N, 2), outputs (N, 2)."""
    u = lowpass_input(max(RIGS_SAMPLES.values()), 2, 50.0, DT, seed=4)
    y, _ = simulate_innovation(paper_model(), u, seed=5)
    return u, y


def stamp_s(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class RigProbe(ProbeNode):
    """Publishes IoSample to each rig and keeps what each rig's nodes publish."""

    def __init__(self) -> None:
        super().__init__("okid_rigs_probe")
        self.arx: dict[str, list[ArxModel]] = {ns: [] for ns in RIGS}
        self.states: dict[str, list[ModalStates]] = {ns: [] for ns in RIGS}
        self.default_ns_messages = 0
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.io = {ns: self.node.create_publisher(IoSample, f"{ns}/io_sample", SENSOR_QOS) for ns in RIGS}
        for ns in RIGS:
            self.node.create_subscription(ArxModel, f"{ns}/arx_model", self.keep(self.arx[ns]), RELIABLE)
            self.node.create_subscription(ModalStates, f"{ns}/modal_states", self.keep(self.states[ns]), RELIABLE)
        self.node.create_subscription(ArxModel, "/okid/arx_model", self._count_default, RELIABLE)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, RELIABLE)
        self.start()

    def _count_default(self, msg) -> None:
        with self.lock:
            self.default_ns_messages += 1

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        with self.lock:
            for status in msg.status:
                self.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}



def value(kind: str, v) -> ParameterValue:
    if kind == "double":
        return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(v))
    if kind == "integer":
        return ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=int(v))
    if kind == "string":
        return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=str(v))
    return ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=bool(v))


@pytest.fixture(scope="module")
def small_params(tmp_path_factory):
    path = tmp_path_factory.mktemp("rigs") / "small.yaml"
    path.write_text(SMALL)
    return path


@pytest.fixture(scope="module")
def rigs(ros_domain_id, small_params):
    """rig1 through `okid-ros up --namespace /rig1`, rig2 as two nodes with -r __ns:=/rig2."""
    env = subprocess_env(ros_domain_id)
    config = str(REPO_ROOT / "config" / "okid.yaml")
    procs = [RosProcess([sys.executable, "-m", "okid_ros.cli", "up", "--namespace", "/rig1",
                         "--params", config, "--params", str(small_params)], env)]
    for module in ("arx_identifier_node", "modal_estimator_node"):
        procs.append(RosProcess([sys.executable, "-m", f"okid_ros.nodes.{module}", "--ros-args",
                                 "--params-file", config, "--params-file", str(small_params),
                                 "-r", "__ns:=/rig2"], env))
    try:
        procs[0].wait_for_output(
            r"\[rig1\.okid_arx_identifier\]: ready: .*inputs /rig1/io_sample .*publishing /rig1/arx_model", 60)
        procs[0].wait_for_output(r"\[rig1\.okid_modal_estimator\]: ready: .*publishing /rig1/modal_states", 60)
        procs[1].wait_for_output(r"ready: .*inputs /rig2/io_sample .*publishing /rig2/arx_model", 60)
        procs[2].wait_for_output(r"ready: .*publishing /rig2/modal_states and /rig2/state_space_model", 60)
        yield procs
    finally:
        for proc in procs:
            proc.stop()


@pytest.fixture(scope="module")
def probe(ros_domain_id):
    p = RigProbe()
    yield p
    p.close()


@pytest.mark.dds
def test_two_namespaced_rigs_in_one_domain_never_cross(probe, rigs):
    probe.wait_until("both rigs to subscribe their io_sample",
                     lambda: all(pub.get_subscription_count() >= 2 for pub in probe.io.values()), 30)
    n = RIGS_SAMPLES
    u, y = rig_stream()
    start = time.monotonic()
    for k in range(max(n.values())):
        for ns, t0 in RIGS.items():
            if k < n[ns]:
                msg = IoSample()
                ns_stamp = int(round((t0 + k * DT) * 1e9))
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns_stamp, 1_000_000_000)
                msg.u = [float(v) for v in u[k]]
                msg.y = [float(v) for v in y[k]]
                probe.io[ns].publish(msg)
        wait = start + (k + 1) / 400.0 - time.monotonic()
        if wait > 0:
            time.sleep(wait)

    def window_seen(ns: str) -> bool:
        # Most of its samples (best-effort at 2 x 400 Hz: a loaded 2-core machine lost over 10 %
        # once in a full run); the isolation is the upper bound checked below.
        return any(m.samples_used >= 0.8 * n[ns] for m in probe.arx[ns])

    for ns in RIGS:
        probe.wait_until(f"{ns}'s ArxModel over its samples", lambda ns=ns: window_seen(ns), 30)
        probe.wait_until(f"{ns}'s modal states", lambda ns=ns: len(probe.states[ns]) > 0, 60,
                         explain=lambda ns=ns: estimator_said(probe, rigs, ns))
    time.sleep(1.0)
    with probe.lock:
        for ns, t0 in RIGS.items():
            end = t0 + (n[ns] - 1) * DT + 1e-6
            stamped = [stamp_s(m) for m in probe.arx[ns] if m.samples_used > 0]
            assert stamped and all(t0 <= s <= end for s in stamped), (ns, min(stamped), max(stamped))
            assert max(m.samples_used for m in probe.arx[ns]) <= n[ns]
            assert all(t0 <= stamp_s(m) <= end for m in probe.states[ns])
            for node in ("okid_arx_identifier", "okid_modal_estimator"):
                # Diagnostics carry the namespace in their names, and each rig counts its own input.
                inputs = probe.diagnostics[f"{ns[1:]}/{node}: inputs"]
                assert 0.8 * n[ns] <= int(inputs[f"{ns}/io_sample messages"]) <= n[ns], (ns, node, inputs)
        assert probe.default_ns_messages == 0, "a rig published on /okid/arx_model"
    # Services moved with the namespace: resetting rig1's node 1 leaves rig2's alone.
    with probe.lock:
        rig2_window = probe.arx["/rig2"][-1].samples_used
    answer = probe.call(Trigger, "/rig1/okid_arx_identifier/reset", Trigger.Request())
    assert answer.success
    with probe.lock:
        n1, n2 = len(probe.arx["/rig1"]), len(probe.arx["/rig2"])
    probe.wait_until("ArxModels after the reset",
                     lambda: len(probe.arx["/rig1"]) > n1 + 1 and len(probe.arx["/rig2"]) > n2 + 1, 10)
    with probe.lock:
        assert probe.arx["/rig1"][-1].samples_used == 0  # forgotten
        # Untouched: the window it had (what best-effort delivery left of its 1100 samples: 982
        # in one loaded full run, below the 0.9 x 1100 this compared with once).
        assert probe.arx["/rig2"][-1].samples_used >= rig2_window >= 0.8 * n["/rig2"]


def test_every_window_of_the_rigs_stream_gives_node_2_a_model(small_params):
    # At order 10, 25 of the 45 windows ending at every 20th of rig2's 1100 samples were refused, "model has
    # no physical mode" (its modes not found again at the neighbouring orders), up to 6 in a row (ending at
    # 260-360, 640-740, 1000-1100); with samples lost too (best effort) every window node 2 realized while rig2's
    # samples flowed refused, and the rig published no modal states (docs/robustness-live.md).
    arx_values, est_values = load_node_parameters([REPO_ROOT / "config" / "okid.yaml", small_params],
                                                  namespace="/rig2")
    arx_params = ArxIdentificationParams.from_parameters(arx_values)
    est_params = ModalEstimationParams.from_parameters(est_values)
    u, y, t0 = *rig_stream(), RIGS["/rig2"]
    node1 = ArxIdentificationService(arx_params)
    refused, realized = {}, 0
    for k in range(RIGS_SAMPLES["/rig2"]):
        node1.push(t0 + k * DT, u[k], y[k])
        if (k + 1) % 20 or not (snapshot := node1.snapshot()).valid:
            continue
        node2 = ModalEstimationService(est_params)  # the window alone: no model to compare with
        first = max(0, k + 1 - snapshot.window_rows - arx_params.order)
        for j in range(first, k + 1):
            node2.step(t0 + j * DT, u[j], y[j])
        node2.submit_arx(snapshot.fit, snapshot.stamp_s, snapshot.model_id, snapshot.window_rows)
        outcome = node2.run_job(node2.take_job(), follow=False)
        realized += 1
        if outcome.model is None:
            refused[k + 1] = outcome.reason
    assert realized >= 40 and not refused, f"{len(refused)} of {realized} windows refused: {refused}"


def estimator_said(probe: RigProbe, rigs: list[RosProcess], ns: str) -> str:
    """Rig ``ns``'s node 2 in its own words: its estimation diagnostics and its log's last lines."""
    status = probe.diagnostics.get(f"{ns[1:]}/okid_modal_estimator: estimation")
    said = "no estimation diagnostics of node 2" if status is None else "; ".join(
        f"{key} {status.get(key)!r}" for key in ESTIMATION_KEYS)
    # rig1's two nodes log through `okid-ros up` (each line tagged), rig2's node 2 on its own.
    log = rigs[0] if ns == "/rig1" else rigs[2]
    tag = "[rig1.okid_modal_estimator]" if ns == "/rig1" else ""
    lines = [line for line in log.output().splitlines() if tag in line][-LOG_LINES:]
    ends = {rig: max((stamp_s(m) for m in probe.arx[rig]), default=None) for rig in RIGS}
    return (f"{ns} node 2's diagnostics: {said}\nnewest ArxModel stamps seen: {ends}\n"
            f"{ns} node 2's log, the last {len(lines)} lines:\n" + "\n".join(lines))


def set_params(probe: RigProbe, node: str, **values) -> list:
    params = [Parameter(name=name.replace("__", "."), value=value(*v)) for name, v in values.items()]
    return probe.call(SetParameters, f"{node}/set_parameters", SetParameters.Request(parameters=params)).results


def get_param(probe: RigProbe, node: str, name: str) -> ParameterValue:
    return probe.call(GetParameters, f"{node}/get_parameters", GetParameters.Request(names=[name])).values[0]


@pytest.mark.dds
def test_tunables_change_at_run_time_with_the_start_checks_and_structure_stays(probe, rigs):
    est, arx = "/rig2/okid_modal_estimator", "/rig2/okid_arx_identifier"
    [ok] = set_params(probe, est, tracking__min_mac=("double", 0.8))
    assert ok.successful, ok.reason
    assert get_param(probe, est, "tracking.min_mac").double_value == 0.8
    [bad] = set_params(probe, est, tracking__min_mac=("double", 1.5))
    assert not bad.successful and "tracking.min_mac" in bad.reason
    assert get_param(probe, est, "tracking.min_mac").double_value == 0.8
    [bad] = set_params(probe, est, realization__gain=("string", "kalman"))
    assert not bad.successful and "refit, riccati, whitening" in bad.reason
    # Options that do not fit together are refused with the reason, the old value kept (the
    # limit of the order search was taken, and the node ran with it raised to max_states).
    [bad] = set_params(probe, est, realization__max_states_limit=("integer", 10))
    assert not bad.successful and "realization.max_states_limit 10 is below realization.max_states 40" in bad.reason
    assert get_param(probe, est, "realization.max_states_limit").integer_value == 160
    for start, limit in ((30, 30), (40, 160)):  # both at once: checked together
        params = [Parameter(name="realization.max_states", value=value("integer", start)),
                  Parameter(name="realization.max_states_limit", value=value("integer", limit))]
        result = probe.call(SetParametersAtomically, f"{est}/set_parameters_atomically",
                            SetParametersAtomically.Request(parameters=params)).result
        assert result.successful, result.reason
    assert get_param(probe, est, "realization.max_states_limit").integer_value == 160
    [bad] = set_params(probe, arx, arx__order=("integer", 50))
    assert not bad.successful and "read-only" in bad.reason
    assert get_param(probe, arx, "arx.order").integer_value == 20
    [desc] = probe.call(DescribeParameters, f"{arx}/describe_parameters",
                        DescribeParameters.Request(names=["arx.order"])).descriptors
    assert desc.read_only and "structural" in desc.description
    # The publish rate changes the ArxModel rate: 4 Hz -> 20 Hz.
    results = set_params(probe, arx, publish_rate_hz=("double", 20.0), frame_id=("string", "rig2_truss"))
    assert all(r.successful for r in results), [r.reason for r in results]
    time.sleep(0.5)
    with probe.lock:
        count = len(probe.arx["/rig2"])
    time.sleep(2.0)
    with probe.lock:
        recent = probe.arx["/rig2"][count:]
    assert len(recent) >= 20, len(recent)  # 40 expected at 20 Hz; 8 at the old 4 Hz
    assert all(m.header.frame_id == "rig2_truss" for m in recent)
    [ok] = set_params(probe, arx, publish_rate_hz=("double", 4.0))
    assert ok.successful


@pytest.mark.dds
@pytest.mark.dds_startup
def test_unknown_parameter_names_are_reported_and_refused_when_strict(spawn_ros, tmp_path):
    typo = tmp_path / "typo.yaml"
    typo.write_text("/**/okid_arx_identifier:\n  ros__parameters:\n    arx: {ordr: 50}\n")
    config = str(REPO_ROOT / "config" / "okid.yaml")
    node = spawn_ros("-m", "okid_ros.nodes.arx_identifier_node", "--ros-args", "--params-file", config,
                     "--params-file", str(typo), "-r", "__ns:=/rig9")
    node.wait_for_output(r"WARN.*typo\.yaml: section '/\*\*/okid_arx_identifier': unknown parameter\(s\) arx\.ordr", 30)
    node.wait_for_output(r"ready:", 30)
    strict = spawn_ros("-m", "okid_ros.nodes.arx_identifier_node", "--ros-args", "--params-file", config,
                       "--params-file", str(typo), "-p", "strict_parameters:=true")
    assert strict.proc.wait(timeout=30) == 2
    strict.wait_for_output(r"unknown parameter\(s\) arx\.ordr .*strict_parameters", 5)


@pytest.mark.dds
@pytest.mark.dds_startup
def test_a_parameter_given_dotted_and_nested_is_refused_and_a_low_time_jump_is_told(spawn_ros, tmp_path):
    # rcl takes the later of `inputs.sources` and `inputs: {sources}` in silence; the node refuses
    # the file as `okid-ros process` does. A time-jump threshold set below the grid's latency is
    # raised, and said once in the log (service/inputs.time_jump_note).
    both = tmp_path / "both.yaml"
    both.write_text('/**:\n  ros__parameters:\n    inputs.sources: ["io_sample /okid/io_sample"]\n'
                    '    inputs:\n      sources: ["imu /accel/tip1/imu linear_acceleration.x=y0"]\n')
    refused = spawn_ros("-m", "okid_ros.nodes.arx_identifier_node", "--ros-args", "--params-file", str(both))
    assert refused.proc.wait(timeout=30) == 2
    refused.wait_for_output(r"both\.yaml: section '/\*\*': parameter inputs\.sources is given twice, as "
                            r"'inputs\.sources' and as 'inputs: \{sources\}'", 5)
    low = spawn_ros("-m", "okid_ros.nodes.arx_identifier_node", "--ros-args", "-p", "inputs.time_jump_s:=0.001",
                    "-r", "__ns:=/rig8")
    low.wait_for_output(r"WARN.*parameter inputs\.time_jump_s 0\.001 s raised to 0\.056 s", 30)
    low.wait_for_output(r"ready:", 30)


@pytest.mark.dds
def test_use_sim_time_switched_on_without_a_clock_is_told(spawn_ros, probe):
    # The node clock then stands at 0 and node 1's ArxModel and both nodes' diagnostics stop: the
    # change was answered `successful` and the node fell silent with nothing said.
    node = spawn_ros("-m", "okid_ros.nodes.arx_identifier_node", "--ros-args", "-r", "__ns:=/rig7")
    node.wait_for_output(r"ready:", 30)
    [ok] = set_params(probe, "/rig7/okid_arx_identifier", use_sim_time=("bool", True))
    assert ok.successful, ok.reason
    node.wait_for_output(r"WARN.*use_sim_time set to true, but nothing publishes /clock: the node clock stands "
                         r"still, and with it this node's timers", 10)
    [ok] = set_params(probe, "/rig7/okid_arx_identifier", use_sim_time=("bool", False))
    assert ok.successful, ok.reason
    # With a /clock publisher in the graph (a replay's --clock) nothing is said.
    clock = probe.node.create_publisher(Clock, "/clock", 10)
    probe.wait_until("node 1 to see the /clock publisher",
                     lambda: probe.node.count_publishers("/clock") >= 1, 10)
    time.sleep(1.0)  # the node's view of the graph too
    [ok] = set_params(probe, "/rig7/okid_arx_identifier", use_sim_time=("bool", True))
    assert ok.successful, ok.reason
    time.sleep(1.0)
    assert node.output().count("nothing publishes /clock") == 1, node.output()
    probe.node.destroy_publisher(clock)


@pytest.mark.dds
def test_use_sim_time_given_at_the_start_without_a_clock_is_told_once_samples_come(spawn_ros, probe):
    # Given at the start (-p, a parameter file) the clock stood at 0 from the first moment: the
    # node's timers never ran (no ArxModel, no diagnostics) and nothing was said, as samples came.
    node = spawn_ros("-m", "okid_ros.nodes.arx_identifier_node", "--ros-args", "-r", "__ns:=/rig9",
                     "-p", "use_sim_time:=true")
    node.wait_for_output(r"ready:", 30)
    io = probe.node.create_publisher(IoSample, "/rig9/io_sample", SENSOR_QOS)
    probe.wait_until("node 1 to subscribe /rig9/io_sample", lambda: io.get_subscription_count() >= 1, 10)
    told = "nothing publishes /clock"
    k = 0

    def feed_until(deadline: float, stop) -> None:
        nonlocal k
        while not stop() and time.monotonic() < deadline:
            msg = IoSample()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round((100.0 + k * DT) * 1e9)), 10**9)
            msg.u, msg.y = [0.1 * (k % 7), -0.2], [0.3, 0.01 * (k % 5)]
            io.publish(msg)
            k += 1
            time.sleep(DT)

    feed_until(time.monotonic() + SIM_CLOCK_SILENCE_S + 10.0, lambda: told in node.output())
    node.wait_for_output(r"WARN.*use_sim_time set to true, but nothing publishes /clock: the node clock stands "
                         r"still, and with it this node's timers", 1)
    feed_until(time.monotonic() + 1.0, lambda: False)  # samples go on coming: said once
    assert node.output().count(told) == 1, node.output()
    probe.node.destroy_publisher(io)
