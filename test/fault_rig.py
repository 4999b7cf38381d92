"""The rig of test_nodes_faults.py: both nodes as processes, a feeder of samples, measures.

Importable from test modules as ``import fault_rig`` (pytest puts test/ on sys.path).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import REPO_ROOT, ProbeNode, RosProcess

from okid_msgs.msg import ArxModel, IoSample, ModalStates, StateSpaceModel
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

DT = 0.008
RATE_HZ = 1.0 / DT
T0 = 1000.0
SMALL = """
/**:
  ros__parameters:
    diagnostics_rate_hz: 4.0
/**/okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: 2.0
    arx: {order: 20, window_length: 800, min_window_fill: 0.25}
/**/okid_modal_estimator:
  ros__parameters:
    realization: {n_states: 6, refine: false}
    change: {enabled: false}  # the faults splice the record: no structural change by design
"""
SENSOR_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
MODULES = {"okid_arx_identifier": "arx_identifier_node", "okid_modal_estimator": "modal_estimator_node"}
N_RECORD = 40000  # 320 s of the simulated structure (the module uses about half)


def stamp_s(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def rss_mb(pid: int) -> float:
    """Resident set size of a process and its children (the realization worker) [MB]."""
    total = 0
    for p in [pid, *children(pid)]:
        try:
            with open(f"/proc/{p}/status") as f:
                total += next(int(line.split()[1]) for line in f if line.startswith("VmRSS:"))
        except (OSError, StopIteration):
            pass
    return total / 1024.0


def children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(c) for c in f.read().split()]
    except OSError:
        return []


class Feeder(ProbeNode):
    """Publishes the structure's samples at 125 Hz on a thread; records the outputs.

    Faults are switched by attributes the test sets: ``flood`` (messages per sample time, each
    stamped at its own instant, as a sensor configured to 10x its rate would), ``stamp_offset_s``
    (added to every stamp: a clock that jumped).
    """

    def __init__(self) -> None:
        super().__init__("okid_fault_feeder")
        u = lowpass_input(N_RECORD, 2, 50.0, DT, seed=1)
        y, _ = simulate_innovation(paper_model(), u, seed=2)
        self.u, self.y = u, y
        self.flood = 1
        self.stamp_offset_s = 0.0
        self.paused = False
        self.k = 0  # next sample of the record
        self.published = 0  # IoSample messages published
        self.last_stamp = 0.0
        self.states: list[tuple[float, float, int]] = []  # (wall time, stamp, model id)
        self.models: list[tuple[float, int, int]] = []  # (wall time, model id, arx model id)
        self.arx: list[tuple[float, int, bool]] = []  # (wall time, model id, valid)
        self.diagnostics: dict[str, dict[str, str]] = {}
        n = self.node
        self.io = n.create_publisher(IoSample, "/okid/io_sample", SENSOR_QOS)
        n.create_subscription(ModalStates, "/okid/modal_states", self._on_states, RELIABLE)
        n.create_subscription(StateSpaceModel, "/okid/state_space_model", self._on_model, RELIABLE)
        n.create_subscription(ArxModel, "/okid/arx_model", self._on_arx, RELIABLE)
        n.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, RELIABLE)
        self._stop = threading.Event()
        self._publisher_thread = threading.Thread(target=self._publish_loop, daemon=True)
        self.start()

    # -------------------------------------------------------------- outputs
    def _on_states(self, msg: ModalStates) -> None:
        with self.lock:
            self.states.append((time.monotonic(), stamp_s(msg), int(msg.model_id)))

    def _on_model(self, msg: StateSpaceModel) -> None:
        with self.lock:
            self.models.append((time.monotonic(), int(msg.model_id), int(msg.arx_model_id)))

    def _on_arx(self, msg: ArxModel) -> None:
        with self.lock:
            self.arx.append((time.monotonic(), int(msg.model_id), bool(msg.valid)))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        with self.lock:
            for status in msg.status:
                values = {kv.key: kv.value for kv in status.values}
                values["_message"] = status.message
                values["_wall"] = str(time.monotonic())
                self.diagnostics[status.name] = values

    def diag(self, name: str) -> dict[str, str]:
        with self.lock:
            return dict(self.diagnostics.get(name, {}))

    def fresh_diag(self, name: str, timeout_s: float = 5.0) -> dict[str, str]:
        """The first diagnostics of ``name`` published after now."""
        since = time.monotonic()
        self.wait_until(f"diagnostics of {name}", lambda: float(
            self.diagnostics.get(name, {}).get("_wall", "0")) > since + 0.05, timeout_s)
        return self.diag(name)

    # -------------------------------------------------------------- inputs
    def start_publishing(self) -> None:
        self.wait_until("both nodes to subscribe /okid/io_sample", lambda: self.io.get_subscription_count() >= 2, 30)
        self._publisher_thread.start()

    def _publish_loop(self) -> None:
        start = time.monotonic()
        while not self._stop.is_set():
            if self.paused:
                paused_at = time.monotonic()
                while self.paused and not self._stop.is_set():
                    time.sleep(0.005)
                start += time.monotonic() - paused_at  # no catch-up burst after a pause
            k, flood, offset = self.k, self.flood, self.stamp_offset_s
            for j in range(flood):
                msg = IoSample()
                stamp = T0 + (k + j / flood) * DT + offset
                ns = int(round(stamp * 1e9))
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
                # The sensor's value at its own instant: the record's sample of the nearest slot.
                i = (k + round(j / flood)) % N_RECORD
                msg.u = [float(v) for v in self.u[i]]
                msg.y = [float(v) for v in self.y[i]]
                self.io.publish(msg)
                self.published += 1
                self.last_stamp = stamp
                due = start + (k + (j + 1) / flood) * DT
                if flood > 1 and (wait := due - time.monotonic()) > 0:
                    time.sleep(wait)
            self.k = k + 1
            wait = start + self.k * DT - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            elif wait < -0.5:
                start -= wait  # fell behind (a loaded machine): keep the rate, not the catch-up

    def close(self) -> None:
        self._stop.set()
        if self._publisher_thread.is_alive():
            self._publisher_thread.join(timeout=5)
        super().close()

    # -------------------------------------------------------------- measures
    def states_rate_hz(self, span_s: float) -> float:
        """ModalStates per second over the last ``span_s`` seconds, measured by stamp span."""
        time.sleep(span_s)
        now = time.monotonic()
        with self.lock:
            recent = [s for w, s, _ in self.states if w >= now - span_s]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / span_s

    def lag_s(self) -> float:
        """Stamp of the newest sample published minus that of the newest ModalStates."""
        with self.lock:
            newest = self.states[-1][1] if self.states else float("nan")
        return self.last_stamp - newest


def start_node(name: str, env: dict[str, str], params: Path) -> RosProcess:
    proc = RosProcess([sys.executable, "-m", f"okid_ros.nodes.{MODULES[name]}", "--ros-args",
                       "--params-file", str(REPO_ROOT / "config" / "okid.yaml"), "--params-file", str(params)],
                      env, REPO_ROOT)
    proc.wait_for_output(r"ready:", timeout_s=60)
    return proc


class Rig:
    """Both nodes and the feeder; nodes can be killed and restarted by the tests."""

    def __init__(self, env: dict[str, str], params: Path) -> None:
        self.env, self.params = env, params
        self.nodes = {name: start_node(name, env, params) for name in MODULES}
        self.old: list[RosProcess] = []
        self.feeder = Feeder()

    def restart(self, name: str) -> RosProcess:
        self.old.append(self.nodes[name])
        self.nodes[name] = start_node(name, self.env, self.params)
        return self.nodes[name]

    def alive(self) -> None:
        for name, proc in self.nodes.items():
            assert proc.proc.poll() is None, f"{name} exited with {proc.proc.returncode}:\n{proc.output()[-3000:]}"
            assert "Traceback" not in proc.output(), f"{name}:\n{proc.output()[-3000:]}"

    def close(self) -> None:
        self.feeder.close()
        for proc in [*self.nodes.values(), *self.old]:
            proc.stop()


def figures(name: str, **values) -> None:
    text = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items())
    print(f"\nFIGURES {name}: {text}", flush=True)


def snapshot(feeder: Feeder) -> tuple[int, dict[str, dict[str, int]]]:
    """Messages published and both nodes' input counters, the feeder paused meanwhile (<= 0.5 s)."""
    feeder.paused = True
    try:
        time.sleep(0.05)  # what is on its way arrives
        return feeder.published, {name: counters(feeder, name) for name in MODULES}
    finally:
        feeder.paused = False


def counters(feeder: Feeder, node: str) -> dict[str, int]:
    d = feeder.fresh_diag(f"{node}: inputs")
    return {k.removeprefix("grid "): int(v) for k, v in d.items()
            if k.startswith("grid ") or k == "/okid/io_sample messages"}


def first_after(feeder: Feeder, series: str, since: float, timeout_s: float, what: str, accept=lambda e: True):
    """Wall time of the first entry of feeder.<series> after ``since`` (waits for it)."""
    store = getattr(feeder, series)
    feeder.wait_until(what, lambda: any(e[0] > since and accept(e) for e in store), timeout_s)
    with feeder.lock:
        return next(e[0] for e in store if e[0] > since and accept(e))


def kill_node(proc: RosProcess) -> list[int]:
    """SIGKILL the node's process (not its group: as a crash would); return its children."""
    kids = children(proc.proc.pid)
    os.kill(proc.proc.pid, signal.SIGKILL)
    proc.proc.wait(timeout=10)
    return kids


def gone(pids: list[int], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not any(os.path.exists(f"/proc/{p}") and proc_state(p) != "Z" for p in pids):
            return True
        time.sleep(0.1)
    return False


def proc_state(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "Z"


def states_after(feeder: Feeder, stamps: tuple[float, float], since: float, timeout_s: float, what: str) -> float:
    """Wall time of the first ModalStates after ``since`` stamped in [stamps[0], stamps[1])."""
    return first_after(feeder, "states", since, timeout_s, what, lambda e: stamps[0] - 1e-6 <= e[1] < stamps[1])
