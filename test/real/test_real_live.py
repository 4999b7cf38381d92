"""Both nodes live over real DDS on the measured steel-subframe record, at its own rate (1024 Hz).

`okid-ros up` runs the two nodes with 28 outputs, ARX order 20 and a window of 6000 rows;
`okid-ros replay` publishes the record as IoSample messages at 1024 Hz from a bag written with
rosbags alone (the record repeated with continuing stamps, see below) and is stopped once
enough has been seen; the test subscribes /okid/modal_states and /okid/state_space_model
(serialized bytes, decoded after the run, so that the test's own process stays light while
1024 ModalStates of ~8 kB arrive per second).

Settings and why:

- Passes of the record until one whole record length (8523 samples) has been estimated with a
  model, and at least 2 passes (16.6 s); at most 6. The first ArxModel is valid once the
  window holds 3000 rows (2.9 s of data); realizing a 28-output model of ~110 states takes
  1.3 s of CPU in the worker at best, 2-4 s on the shared machine, 8-12 s when other jobs
  keep the 2 cores busy (the worker runs at nice 10 below the test's), and once no model came
  within 25 s while another engineer's 1 kHz benchmark ran at a higher priority: a fixed
  number of passes is either long on a quiet machine or too short on a busy one. On a quiet
  machine the run stops after 2 passes. The passes continue the stamps (no jump back: a
  looped replay restarts both nodes, `reset_on_time_jump`), so the window and the model carry
  over the seams; each seam is one discontinuity in 6000 rows.
- `realization.max_states: 60`: BIC picks about 100-120 states on this record; from 60 the
  search reaches them with one doubling (60, 120), from the default 40 it needs two (40, 80,
  160), which costs a third more per realization (1.4 s against 2.1 s of CPU measured).
- `inputs.queue_depth: 10000` (10 s at 1024 Hz instead of the default 1 s): the nodes' input
  queues must cover the stalls of a node on a 2-core machine shared with other work while the
  realization worker, the other node, the replay and this test's subscriber all want a core.
- `change.enabled: false`: the record is one stationary test, but the change test still
  declares a "structural change" on it now and then: the seams between passes are taken for
  jumps of the state since the eighth session, but with some reference models the noisier
  stretch 4.35 s into the record is confirmed by the model-error check (seen in runs of this
  test with the change test on; docs/benchmarks-change.md); each false alarm restarts node 1's
  window and makes node 2 refuse models until a post-change window is valid, which would make
  the number and timing of the live models depend on that rather than on the live path under
  test.
- `qos_overrides./okid/modal_states.publisher.depth: 20000` on node 2 (the standard ROS QoS
  override; the node's default history is 100): after a stall node 2 drains its input queue
  and publishes the backlog's ModalStates in a burst, faster than this test's Python
  subscriber may take them, and a reliable keep-last writer drops the oldest of a full
  history, delivered or not; with 20 s of history every published ModalStates can arrive, so
  the drops counted are the nodes' own.

The innovation check is per sample: the RMS over the 28 channels of the innovation, each
channel divided by its output's RMS over the record (mean removed), must stay below 10, i.e.
the predictor never produces errors ten times the signal (it runs at a few percent here).
"""

from __future__ import annotations

import os
import re
import struct
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from real_helpers import (
    IO_TOPIC,
    load_record,
    matched_errors,
    node_parameters,
    normalized_innovation_rms,
    stamp_ns,
    write_record_bag,
)
from ros_helpers import REPO_ROOT, RosProcess, subprocess_env

from okid_msgs.msg import ModalStates, StateSpaceModel
from okid_ros.nodes.conversions import state_space_from_msg

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process

MIN_PASSES, MAX_PASSES = 2, 6
SETTINGS = dict(order=20, window=6000, max_states=60, publish_rate_hz=1.0, n_outputs=28)
EXTRA_SHARED = "    inputs:\n      queue_depth: 10000\n"
EXTRA_ESTIMATOR = """    change:
      enabled: false
    qos_overrides:
      /okid/modal_states:
        publisher:
          depth: 20000
"""
#: estimator.divergence_window_samples (the default): the unit of the drops allowed at a seam.
SEAM_WINDOW = 25
ESTIMATION = "okid_modal_estimator: estimation"  # node 2's DiagnosticStatus
CLK_TCK = os.sysconf("SC_CLK_TCK")


class RawListener:
    """Serialized messages with their receive times, kept by a node of its own on a spin thread."""

    def __init__(self, topics: dict[str, QoSProfile]) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context, args=[])
        self.node = rclpy.create_node("okid_real_live_listener", context=self.context)
        self.lock = threading.Lock()
        self.received: dict[str, list[tuple[float, bytes]]] = {topic: [] for topic in topics}
        for topic, qos in topics.items():
            msg_type = StateSpaceModel if topic.endswith("state_space_model") else ModalStates
            self.node.create_subscription(msg_type, topic, self._keep(topic), qos, raw=True)
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.previous: dict[str, dict[str, str]] = {}  # the status before each of these
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _keep(self, topic: str):
        store = self.received[topic]

        def callback(raw: bytes) -> None:
            store.append((time.monotonic(), raw))  # list.append is atomic: no lock on the hot path
        return callback

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        with self.lock:
            for status in msg.status:
                if status.name in self.diagnostics:
                    self.previous[status.name] = self.diagnostics[status.name]
                self.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}

    def _spin(self) -> None:
        while not self._stop and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def unchanged_windows(self) -> int:
        """Node 2's count of ArxModels ignored as an unchanged window, in its last status."""
        with self.lock:
            return int(self.diagnostics.get(ESTIMATION, {}).get("arx_models_unchanged", 0))

    def wait_settled(self, up: RosProcess, unchanged_before: int, quiet_s: float, timeout_s: float) -> None:
        """Wait until the nodes are done with what they had queued, or the timeout.

        Done: no ModalStates for ``quiet_s``; each node's two last statuses count the same
        samples (none taken for a diagnostics period, 1 s); node 2 has ignored node 1's
        republished last window as unchanged (more than ``unchanged_before``), runs no
        realization and has no ArxModel waiting (the last window's model is out, as
        `okid-ros demo` waits for it); node 2 has logged "realized in" for every model received.
        (Was: 3 s without ModalStates, then 2.5 s, two diagnostics periods, always.)
        """
        counted = {"okid_arx_identifier: inputs": "grid samples_emitted", ESTIMATION: "samples"}
        states, models = self.received["/okid/modal_states"], self.received["/okid/state_space_model"]

        def settled() -> bool:
            if not states or time.monotonic() - states[-1][0] < quiet_s:
                return False
            with self.lock:
                if any(name not in self.previous or self.previous[name].get(key) != self.diagnostics[name].get(key)
                       for name, key in counted.items()):
                    return False
                est = self.diagnostics[ESTIMATION]
                if (int(est.get("arx_models_unchanged", 0)) <= unchanged_before or est.get("busy") != "false"
                        or est.get("arx_request_waiting") != "false"):
                    return False
            return len(re.findall(r"realized in [0-9.]+ s", up.output())) == len(models)

        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not settled():
            time.sleep(0.1)

    def parameter(self, node: str, name: str, timeout_s: float = 20.0):
        """A parameter's value of another node, through its parameter services."""
        from rclpy.parameter_client import AsyncParameterClient

        client = AsyncParameterClient(self.node, node)
        if not client.wait_for_services(timeout_sec=timeout_s):
            pytest.fail(f"no parameter services of {node} within {timeout_s} s")
        future = client.get_parameters([name])
        deadline = time.monotonic() + timeout_s
        while not future.done():
            if time.monotonic() > deadline:
                pytest.fail(f"no answer from {node} about {name} within {timeout_s} s")
            time.sleep(0.05)
        value = future.result().values[0]
        return value.integer_value if value.type == 2 else value

    def wait_for_publishers(self, topics, timeout_s: float = 30.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not all(self.node.count_publishers(t) for t in topics):
            if time.monotonic() > deadline:
                pytest.fail(f"no publisher on {topics} within {timeout_s} s")
            time.sleep(0.05)

    def close(self) -> None:
        self._stop = True
        self.thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def _descendants(pid: int) -> list[int]:
    """``pid`` and every process below it (the nodes under `up`, the realization worker below node 2)."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            parents.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        current = todo.pop()
        out.append(current)
        todo.extend(parents.get(current, []))
    return out


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def node_cpu_seconds(up_pid: int) -> dict[str, float]:
    """CPU seconds (user + system) so far of each node with its child processes, by node module."""
    out = {"arx_identifier_node": 0.0, "modal_estimator_node": 0.0}
    for child in _descendants(up_pid)[1:]:
        name = next((n for n in out if n in _cmdline(child)), None)
        if name is None:
            continue
        for pid in _descendants(child):
            try:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            out[name] += (int(fields[11]) + int(fields[12])) / CLK_TCK
        # a node's descendants are counted with it; do not count them again as children of `up`
    return out


def raw_stamp_ns(raw: bytes) -> int:
    """Header stamp [ns] of a serialized message (CDR little endian: 4 bytes encapsulation, sec, nanosec)."""
    sec, nanosec = struct.unpack_from("<iI", raw, 4)
    return sec * 1_000_000_000 + nanosec


def grid_index(stamp: int, sample_time_s: float) -> int:
    """Index on the bag's sample grid (over all passes) of a stamp [ns]."""
    return int(round((stamp - int(stamp_ns(0, sample_time_s))) / (sample_time_s * 1e9)))


def stamp_of(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


@pytest.fixture(scope="module")
def live(tmp_path_factory, ros_domain_id):
    """Run the nodes on the record once; everything received, the logs and the CPU."""
    u, y, dt, reference = load_record()
    n = u.shape[0]
    root = tmp_path_factory.mktemp("real_live")
    params = root / "steel.yaml"
    params.write_text(node_parameters(**SETTINGS, sample_time_s=dt, extra_shared=EXTRA_SHARED,
                                      extra_estimator=EXTRA_ESTIMATOR))
    env = subprocess_env(ros_domain_id)
    up = RosProcess([sys.executable, "-m", "okid_ros.cli", "up", "--params", str(params)], env, REPO_ROOT)
    reliable = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50_000, reliability=ReliabilityPolicy.RELIABLE)
    latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    listener = RawListener({"/okid/modal_states": reliable, "/okid/state_space_model": latched})
    states = listener.received["/okid/modal_states"]
    replay = None
    try:
        bag = root / f"steel_subframe_x{MAX_PASSES}"  # written while the nodes start
        write_record_bag(bag, u, y, dt, passes=MAX_PASSES)
        up.wait_for_output(r"\[okid_arx_identifier\]: ready", 60)
        up.wait_for_output(r"\[okid_modal_estimator\]: ready", 60)
        listener.wait_for_publishers(["/okid/modal_states", "/okid/state_space_model"])
        history = listener.parameter("/okid_modal_estimator", "qos_overrides./okid/modal_states.publisher.depth")
        own_before = _own_cpu_s()
        replay = RosProcess([sys.executable, "-m", "okid_ros.cli", "replay", str(bag), "--topics", IO_TOPIC,
                             "--subscribers", "2", "--delay", "1.0"], env, REPO_ROOT)
        replay.wait_for_output(r"replay .* messages on 1 topics", 60)
        time.sleep(1.0)  # the replay's --delay: CPU is measured over the playing
        cpu_before, wall_before = node_cpu_seconds(up.proc.pid), time.monotonic()
        while replay.proc.poll() is None:  # until a record length after the first model, at least MIN_PASSES
            if states:
                first, newest = (grid_index(raw_stamp_ns(states[k][1]), dt) for k in (0, -1))
                if newest >= max(MIN_PASSES * n, first + n) - 1:
                    break
            time.sleep(0.2)
        cpu_after, wall_after = node_cpu_seconds(up.proc.pid), time.monotonic()
        own_after = _own_cpu_s()
        unchanged = listener.unchanged_windows()
        replay.stop()
        # The tail: ModalStates of the samples still queued in the nodes, the model of node 1's
        # last window, the last counters and "realized in" log lines.
        listener.wait_settled(up, unchanged, quiet_s=1.0, timeout_s=30.0)
    finally:
        if replay is not None:
            replay.stop()
        listener.close()
        up.stop()
    received_at = np.array([t for t, _ in states])
    models = [deserialize_message(raw, StateSpaceModel) for _, raw in listener.received["/okid/state_space_model"]]
    wall = wall_after - wall_before
    cpu = {name: (cpu_after[name] - cpu_before[name]) / wall for name in cpu_before}
    cpu["test_listener"] = (own_after - own_before) / wall
    return {
        "u": u, "y": y, "dt": dt, "reference": reference,
        "states": [deserialize_message(raw, ModalStates) for _, raw in states], "received_at": received_at,
        "models": models, "log": up.output(),
        "diagnostics": dict(listener.diagnostics), "cpu": cpu, "wall_s": wall, "history": history,
    }


def _own_cpu_s() -> float:
    times = os.times()
    return times.user + times.system


def received_indices(live) -> np.ndarray:
    """Index on the bag's grid (0 .. MAX_PASSES N - 1) of every ModalStates received, in arrival order."""
    dt = live["dt"]
    stamps = np.array([stamp_of(m) for m in live["states"]], dtype=np.int64)
    index = np.rint((stamps - stamp_ns(0, dt)) / (dt * 1e9)).astype(np.int64)
    # The nodes carry stamps as float seconds (resolution 238 ns at 1.7e9 s): each ModalStates
    # stamp is its sample's to within a microsecond, far inside the 244 us of the grid tolerance.
    offset_ns = np.abs(stamps - stamp_ns(index, dt))
    assert offset_ns.max() < 1000, ("ModalStates off the record's grid", offset_ns.max())
    return index


def test_the_nodes_ran_at_the_records_rate(live):
    """Live, not replayed in a burst: the ModalStates arrived over about the time their samples span.

    Allowed: 0.7-1.5 times. Stalls of the replay or of a node on the shared machine delay
    stretches of samples (up to 1.5 s measured under load, against at least 8.3 s spanned).
    """
    index = received_indices(live)
    assert index[-1] - index[0] >= live["u"].shape[0] - 1  # a record length from the first model on
    ratio = (live["received_at"][-1] - live["received_at"][0]) / ((index[-1] - index[0]) * live["dt"])
    span_s = (index[-1] - index[0]) * live["dt"]
    print(f"\nreal_live: ModalStates of {index[-1] - index[0] + 1} samples ({span_s:.1f} s of data) arrived over "
          f"{ratio:.2f} times that")
    assert 0.7 < ratio < 1.5, ratio


def test_the_last_live_model_finds_the_reference_modes(live):
    models = live["models"]
    assert models, f"no StateSpaceModel; node log:\n{live['log'][-4000:]}"
    found = [m.frequency_hz for m in models[-1].modes]
    errors = matched_errors(found, live["reference"])
    print(f"\nreal_live: last model {models[-1].model_id} ({models[-1].n_states} states, {len(found)} modes): "
          f"{(errors <= 0.005).sum()} of 15 reference modes within 0.5 %, largest error of those "
          f"{100 * errors[errors <= 0.005].max():.3f} %")
    assert (errors <= 0.005).sum() >= 14, (np.round(errors, 4), np.round(found, 2))


def test_every_live_model_is_stable(live):
    models = live["models"]
    assert models
    assert [m.model_id for m in models] == list(range(1, len(models) + 1))  # none missed (transient local, reliable)
    for msg in models:
        model = state_space_from_msg(msg)  # of its sizes and finite, or ValueError
        a, c, k = model["A"], model["C"], model["K"]
        assert msg.spectral_radius < 1.0 and msg.predictor_spectral_radius < 1.0, msg.model_id
        # the fields say what the matrices are
        assert msg.spectral_radius == pytest.approx(np.max(np.abs(np.linalg.eigvals(a))), rel=1e-9)
        assert msg.predictor_spectral_radius == pytest.approx(
            np.max(np.abs(np.linalg.eigvals(a - a @ k @ c))), rel=1e-9)


def test_innovations_stay_below_ten_times_the_outputs_at_every_sample(live):
    states, y = live["states"], live["y"]
    assert states
    output_rms = np.sqrt(np.mean((y - y.mean(axis=0)) ** 2, axis=0))
    innovations = np.array([m.innovation for m in states])
    assert innovations.shape == (len(states), 28) and np.all(np.isfinite(innovations))
    ratio = normalized_innovation_rms(innovations, output_rms)
    worst = int(np.argmax(ratio))
    at = int(received_indices(live)[worst])
    print(f"\nreal_live: innovation RMS / output RMS per sample: median {np.median(ratio):.4f}, "
          f"largest {ratio[worst]:.4f} at sample {at} ({at % y.shape[0]} into a pass; {len(states)} samples)")
    assert ratio[worst] < 10.0, (worst, ratio[worst], states[worst].model_id)


def test_a_modal_state_for_nearly_every_sample_after_the_first_model(live):
    """Drops: samples between the first and the last ModalStates without one, at the seams and elsewhere.

    At each seam between passes (after the first model) the signals jump from the record's end
    to its start; the estimator's innovations are then far beyond its innovation covariance and
    node 2's divergence watchdog withholds the estimates until the predictor has recovered
    (measured: 50 samples, two watchdog windows of estimator.divergence_window_samples = 25):
    at most 4 windows (100 samples) per seam. Elsewhere at most 0.5 %: the inputs are best
    effort, so a node that stalls on the shared 2-core machine can lose input messages in
    transport (its queue holds 10 s), and the ModalStates publisher's history (20000, set in
    the parameters) covers this subscriber falling behind; measured 0-5 samples (at most
    0.03 %) in 12 runs at load averages of 1 to 8.
    """
    assert live["history"] == 20000  # the QoS override of the parameter file took effect
    index = received_indices(live)
    n = live["u"].shape[0]
    assert np.all(np.diff(index) > 0), "ModalStates out of order or repeated"
    first, last = int(index[0]), int(index[-1])
    missing = np.setdiff1d(np.arange(first, last + 1), index)
    seams = [k * n for k in range(1, MAX_PASSES) if first < k * n <= last]
    at_seams = np.zeros(missing.shape, dtype=bool)
    for seam in seams:
        at_seams |= (missing >= seam) & (missing < seam + 4 * SEAM_WINDOW)
    elsewhere = missing[~at_seams]
    expected = last - first + 1
    diag = live["diagnostics"].get("okid_modal_estimator: estimation", {})
    print(f"\nreal_live: first ModalStates at sample {first} ({first * live['dt']:.2f} s), last {last}: "
          f"{len(index)} of {expected} received, dropped {len(missing)}: {int(at_seams.sum())} at "
          f"{len(seams)} seam(s), {len(elsewhere)} elsewhere ({100 * len(elsewhere) / expected:.3f} %); node 2 "
          f"counted {diag.get('diverged_samples', '?')} diverged of {diag.get('samples', '?')} samples received")
    for seam in seams:
        assert np.sum((missing >= seam) & (missing < seam + 4 * SEAM_WINDOW)) <= 4 * SEAM_WINDOW
    assert len(elsewhere) <= 0.005 * expected, elsewhere[:50]
    # Every ModalStates carries the modes of a published model.
    assert {m.model_id for m in live["states"]} <= {m.model_id for m in live["models"]}


def test_both_nodes_worked_and_their_cost_is_measured(live):
    """The numbers of docs/benchmarks-nodes.md ("28 channels live"), printed with -s."""
    times = [float(t) for t in re.findall(r"realized in ([0-9.]+) s", live["log"])]
    cpu = live["cpu"]
    # node 2 logs every accepted model with its realization time (on its diagnostics timer)
    assert len(times) == len(live["models"]) >= 1, (times, live["log"][-3000:])
    # both nodes did their per-sample work during the replay (node 1 alone: ~0.3 cores)
    assert cpu["arx_identifier_node"] > 0.05 and cpu["modal_estimator_node"] > 0.05, cpu
    print(f"\nreal_live: {len(times)} models, realization median {np.median(times):.2f} s, max {max(times):.2f} s; "
          f"CPU over the replay ({live['wall_s']:.1f} s): okid_arx_identifier {cpu['arx_identifier_node']:.2f}, "
          f"okid_modal_estimator {cpu['modal_estimator_node']:.2f} cores (with its realization worker), "
          f"this test's subscriber {cpu['test_listener']:.2f}; load average {os.getloadavg()[0]:.2f}")
