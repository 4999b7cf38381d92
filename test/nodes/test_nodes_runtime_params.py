"""Run-time parameters change what a running node does at once, over real DDS.

Both nodes run as processes (module scope); the test process publishes IoSample of the
paper's structure (125 Hz, modes at 5.9, 7.3 and 48.5 Hz) at 500 samples/s, node 1 on a topic
of its own (``io_clean``) so that a spike reaches node 2 only. Each parameter is changed with
the standard SetParameters service and the behaviour it governs is observed in what node 2
publishes (StateSpaceModel mode ids, StructuralChange, the estimation diagnostics). The tests
run in file order on the same nodes: each leaves them running for the next.
"""

from __future__ import annotations

import sys
import threading
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import REPO_ROOT, ProbeNode, RosProcess, subprocess_env

from okid_msgs.msg import IoSample, StateSpaceModel, StructuralChange
from okid_ros.core.change_detection import DEFAULT_REFERENCE_SAMPLES, calibration_scale, cusum_threshold
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process

T0 = 2000.0
RATE = 500.0  # samples per second of wall time
N = 600_000  # 20 min at RATE: more than the module ever takes, even on a loaded machine
EST = "/okid_modal_estimator"
STATUS = "okid_modal_estimator: estimation"
PARAMS = """
/**:
  ros__parameters:
    diagnostics_rate_hz: 5.0
/**/okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: 4.0
    inputs: {sources: ["io_sample io_clean"]}
    arx: {order: 20, window_length: 1000}
/**/okid_modal_estimator:
  ros__parameters:
    realization: {n_states: 6, refine: false, worker: thread}
    tracking: {min_matched_fraction: 0.0}
    change: {enabled: false}
"""
SPIKE_SAMPLES = 5  # a few, so that one lost best-effort message cannot hide the spike
SENSOR_QOS = QoSProfile(depth=500, reliability=ReliabilityPolicy.BEST_EFFORT)
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


class Probe(ProbeNode):
    """Publishes the samples on a thread; keeps models, changes and node 2's diagnostics."""

    def __init__(self) -> None:
        super().__init__("okid_runtime_probe")
        self.models: list[StateSpaceModel] = []
        self.changes: list[StructuralChange] = []
        self.status: dict[str, str] = {}
        self.status_count = 0
        self.spike = 0.0  # added to y of the next SPIKE_SAMPLES samples of node 2's topic
        self.spike_left = 0
        self.io = self.node.create_publisher(IoSample, "/okid/io_sample", SENSOR_QOS)
        self.clean = self.node.create_publisher(IoSample, "/okid/io_clean", SENSOR_QOS)
        self.node.create_subscription(StateSpaceModel, "/okid/state_space_model", self.keep(self.models), RELIABLE)
        self.node.create_subscription(StructuralChange, "/okid/structural_change", self.keep(self.changes), RELIABLE)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, RELIABLE)
        self._stop = threading.Event()
        self.start()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        with self.lock:
            for status in msg.status:
                if status.name == STATUS:
                    self.status = {kv.key: kv.value for kv in status.values}
                    self.status_count += 1

    def publish_samples(self) -> None:
        model = paper_model()
        u = lowpass_input(N, 2, 50.0, model.sample_time_s, seed=7)
        y, _ = simulate_innovation(model, u, seed=8)
        start = time.monotonic()
        for k in range(N):
            if self._stop.is_set():
                return
            msg = IoSample()
            ns = int(round((T0 + k * model.sample_time_s) * 1e9))
            msg.header.stamp.sec, msg.header.stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
            msg.u, msg.y = [float(v) for v in u[k]], [float(v) for v in y[k]]
            self.clean.publish(msg)
            with self.lock:
                spike = self.spike if self.spike_left > 0 else 0.0
                self.spike_left -= 1
            msg.y = [v + spike for v in msg.y]
            self.io.publish(msg)
            wait = start + (k + 1) / RATE - time.monotonic()
            if wait > 0:
                time.sleep(wait)

    def set(self, **values) -> None:
        """Set parameters of node 2 (``a__b`` for ``a.b``) with the SetParameters service."""
        params = [Parameter(name.replace("__", "."), value=value).to_parameter_msg() for name, value in values.items()]
        answer = self.call(SetParameters, f"{EST}/set_parameters", SetParameters.Request(parameters=params))
        for result in answer.results:
            assert result.successful, result.reason

    def models_after(self, count: int) -> list[StateSpaceModel]:
        with self.lock:
            return self.models[count:]

    def wait_model(self, what: str, predicate, timeout_s: float = 60.0) -> StateSpaceModel:
        """The first model published from now on for which ``predicate(model)`` holds."""
        with self.lock:
            count = len(self.models)
        self.wait_until(what, lambda: any(predicate(m) for m in self.models[count:]), timeout_s)
        return next(m for m in self.models_after(count) if predicate(m))

    def max_id_before(self, model: StateSpaceModel) -> int:
        """The largest mode id of the models received before ``model`` (called under the lock)."""
        earlier = self.models[:next(i for i, m in enumerate(self.models) if m is model)]
        return max((max(ids(m), default=0) for m in earlier), default=0)

    def fresh_status(self) -> dict[str, str]:
        """Node 2's diagnostics published after this call."""
        with self.lock:
            count = self.status_count
        self.wait_until("fresh diagnostics", lambda: self.status_count > count + 1, 10)
        with self.lock:
            return dict(self.status)


def ids(model) -> list[int]:
    return sorted(int(mode.id) for mode in model.modes)


def high_ids(model) -> list[int]:
    return [int(mode.id) for mode in model.modes if mode.frequency_hz > 30.0]


@pytest.fixture(scope="module")
def probe(ros_domain_id, tmp_path_factory):
    params = tmp_path_factory.mktemp("runtime") / "params.yaml"
    params.write_text(PARAMS)
    env = subprocess_env(ros_domain_id)
    args = ["--ros-args", "--params-file", str(REPO_ROOT / "config" / "okid.yaml"), "--params-file", str(params)]
    procs = [RosProcess([sys.executable, "-m", f"okid_ros.nodes.{module}", *args], env, REPO_ROOT)
             for module in ("arx_identifier_node", "modal_estimator_node")]
    probe = Probe()
    publisher = threading.Thread(target=probe.publish_samples, daemon=True)
    try:
        for proc in procs:
            proc.wait_for_output(r"ready:", timeout_s=30)
        probe.wait_until("the nodes to subscribe", lambda: probe.io.get_subscription_count() >= 1
                         and probe.clean.get_subscription_count() >= 1, 20)
        publisher.start()
        # Two models in a row with the three modes and the same ids: tracking runs.
        probe.wait_until("two models with the same three modes", lambda: len(probe.models) >= 2 and len(
            probe.models[-1].modes) == 3 and ids(probe.models[-1]) == ids(probe.models[-2]), 90)
        yield probe
    finally:
        probe._stop.set()
        publisher.join(timeout=5)
        probe.close()
        for proc in procs:
            proc.stop()


@pytest.mark.parametrize("name, strict, default", [("tracking__min_mac", 1.0, 0.7),
                                                   ("tracking__max_frequency_change", 1e-6, 0.05)])
def test_a_tracking_criterion_decides_the_ids_of_the_next_models(probe, name, strict, default):
    with probe.lock:
        before = max(max(ids(m), default=0) for m in probe.models)
    probe.set(**{name: strict})
    fresh = probe.wait_model("a model whose modes all have fresh ids",
                             lambda m: len(m.modes) == 3 and min(ids(m)) > before)
    probe.set(**{name: default})
    # Models realized before the node took the default may still arrive, each with fresh ids of
    # its own: the one awaited has no id that an earlier model did not have.
    probe.wait_model("a model matched again (no fresh id)",
                     lambda m: len(m.modes) == 3 and m.model_id > fresh.model_id
                     and max(ids(m)) <= probe.max_id_before(m))


def _drop_and_restore(probe: Probe) -> tuple[int, int]:
    """The 48 Hz mode filtered out of a model, then back: its id before and after."""
    with probe.lock:
        [high] = high_ids(probe.models[-1])
    probe.set(modes__max_nyquist_fraction=0.5)
    probe.wait_model("a model without the 48 Hz mode", lambda m: m.modes and not high_ids(m))
    probe.set(modes__max_nyquist_fraction=0.95)
    back = probe.wait_model("the 48 Hz mode back", lambda m: len(high_ids(m)) == 1)
    return high, high_ids(back)[0]


def test_mode_memory_decides_whether_a_mode_that_was_gone_gets_its_id_back(probe):
    high, back = _drop_and_restore(probe)
    assert back == high  # remembered (mode_memory 10)
    probe.set(tracking__mode_memory=0)
    high, back = _drop_and_restore(probe)
    assert back > high  # forgotten at once: a fresh id
    probe.set(tracking__mode_memory=10)


def test_the_riccati_gain_is_taken_at_run_time(probe):
    with probe.lock:
        last = probe.models[-1].model_id
    probe.set(realization__gain="riccati")  # was refused at run time
    probe.wait_model("models realized with the Riccati gain", lambda m: m.model_id >= last + 2)
    assert probe.fresh_status()["last_reason"] == ""
    probe.set(realization__gain="refit")


def _monitoring_threshold(probe: Probe) -> float:
    """The change test's threshold once it is calibrated and no longer re-armed."""
    deadline = time.monotonic() + 30
    previous = None
    while time.monotonic() < deadline:
        status = probe.fresh_status()
        threshold = float(status["change_threshold"])
        if status["change_monitor"] == "monitoring" and threshold == previous:
            return threshold
        previous = threshold
    pytest.fail(f"the change test did not settle: {status}")


def test_the_variance_ratio_retunes_the_change_test_at_once(probe):
    # Off until here: the ids the tests above observe do not depend on the change test.
    probe.set(change__enabled=True)
    threshold = _monitoring_threshold(probe)
    probe.set(change__variance_ratio=3.0)
    scale = calibration_scale(DEFAULT_REFERENCE_SAMPLES, 2)  # the threshold allows for the calibration's error
    ratio = cusum_threshold(1e7, 2, 3.0, scale=scale) / cusum_threshold(1e7, 2, 1.5, scale=scale)
    status = probe.fresh_status()
    assert float(status["change_threshold"]) == pytest.approx(threshold * ratio, rel=1e-3)
    probe.set(change__variance_ratio=1.5)


def test_the_false_alarm_rate_sets_the_threshold_the_change_test_uses(probe):
    with probe.lock:
        assert not probe.changes, "no change on a stationary structure at the default rate"
    refused = int(probe.fresh_status()["change_alarms_unconfirmed"])
    probe.set(change__false_alarm_samples=100.0)
    # A false alarm of the power test about every 100 samples: the model-error check refuses
    # them (counted) or, rarely, confirms one (a StructuralChange).
    probe.wait_until("a (false) alarm about every 100 samples",
                     lambda: probe.changes or int(probe.status["change_alarms_unconfirmed"]) > refused, 30)
    probe.set(change__false_alarm_samples=1e7)


def test_the_divergence_ratio_decides_which_spike_is_divergence(probe):
    probe.set(change__enabled=False)  # a spike here is not a structural change
    probe.set(estimator__divergence_nis_ratio=1e12)
    diverged = int(probe.fresh_status()["diverged_samples"])
    with probe.lock:  # 1000 standard deviations of the innovations of the model in use
        covariance = probe.models[-1].innovation_covariance
        spike = probe.spike = 1e3 * max(covariance[0], covariance[-1]) ** 0.5
        probe.spike_left = SPIKE_SAMPLES
    assert int(probe.fresh_status()["diverged_samples"]) == diverged
    probe.set(estimator__divergence_nis_ratio=100.0)
    # The first spike was not divergence, so node 2's next models are realized over windows that
    # hold it: their innovation covariance is up to 1 + SPIKE_SAMPLES * 1e6 / 500 (the shortest
    # window) times larger, and the same spike whitened by it stays under the ratio. 100 times
    # larger, it is divergence under any model node 2 may be using.
    with probe.lock:
        probe.spike, probe.spike_left = 100.0 * spike, SPIKE_SAMPLES
    probe.wait_until("a diverged sample", lambda: int(probe.status["diverged_samples"]) > diverged, 10)
