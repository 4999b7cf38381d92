"""The end-to-end demo behind ``make demo`` / ``okid-ros demo``.

1. simulate the paper-like experiment into a bag (:mod:`.simulate_bag`, truth in its metadata);
2. start both nodes as ``okid-ros up --params config/okid.yaml`` (separate processes);
3. replay the bag live (``okid-ros replay``, its own process) while this process records the
   nodes' outputs (:class:`.recorder.LiveRecorder`) and shows the modes (:mod:`.monitor`);
4. stop the nodes, draw the figures from the recording (:mod:`.plots`);
5. print the modes of the last live model against the true ones.

Everything goes into a new run folder ``OUT_DIR/YYYYmmdd-HHMMSS`` (``OUT_DIR/latest`` points
to it). The ROS domain is ``ROS_DOMAIN_ID`` if set, otherwise a free one of 1..100 (the same
per-id lock files the test sessions take, so a demo never shares a domain with a test run);
discovery stays on this machine unless ``ROS_AUTOMATIC_DISCOVERY_RANGE`` says otherwise.
"""

from __future__ import annotations

import fcntl
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TextIO

from okid_ros.errors import OkidError
from okid_ros.jsonio import dumps

__all__ = ["DemoResult", "run_demo", "default_params_file", "compare_modes"]

REPO_ROOT = Path(__file__).resolve().parents[2]
OUTPUT_TOPICS = {
    "/okid/arx_model": "okid_msgs/msg/ArxModel",
    "/okid/state_space_model": "okid_msgs/msg/StateSpaceModel",
    "/okid/modal_states": "okid_msgs/msg/ModalStates",
}


def default_params_file(name: str = "okid.yaml") -> Path:
    """``config/NAME`` of the repository, else of the installed package (share/okid_ros/config)."""
    candidates = [REPO_ROOT / "config" / name, Path(sys.prefix) / "share" / "okid_ros" / "config" / name]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / "okid_ros" / "config" / name)
    for path in candidates:
        if path.is_file():
            return path
    raise OkidError(f"parameter file {name} not found (looked in {', '.join(str(c.parent) for c in candidates)})")


def _claim_domain_id() -> tuple[int, IO[str] | None]:
    """ROS_DOMAIN_ID from the environment, else a free id of 1..100 (locked while we run)."""
    if os.environ.get("ROS_DOMAIN_ID"):
        return int(os.environ["ROS_DOMAIN_ID"]), None
    lock_dir = Path(tempfile.gettempdir()) / "okid_ros_domain_locks"
    lock_dir.mkdir(exist_ok=True)
    start = (os.getpid() * 7) % 100
    for i in range(100):
        domain_id = 1 + (start + i) % 100
        handle = open(lock_dir / f"{domain_id}.lock", "w")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return domain_id, handle
    raise OkidError("all ROS domain ids 1..100 are taken on this machine; set ROS_DOMAIN_ID")


def compare_modes(true_modes: list[dict], identified: list[dict], tolerance: float = 0.05) -> list[dict]:
    """Match each true mode to the identified mode nearest in frequency (within ``tolerance``).

    Returns one row per true mode: the true mode, the match (or None), the relative frequency
    error and the damping error in percentage points.
    """
    rows = []
    used: set[int] = set()
    for true in true_modes:
        best = None
        for i, mode in enumerate(identified):
            if i in used:
                continue
            err = abs(mode["frequency_rad_s"] - true["frequency_rad_s"]) / true["frequency_rad_s"]
            if err <= tolerance and (best is None or err < best[1]):
                best = (i, err)
        row = {"true": true, "identified": None, "frequency_error": math.nan, "damping_error_pp": math.nan}
        if best is not None:
            used.add(best[0])
            mode = identified[best[0]]
            row.update(identified=mode, frequency_error=(mode["frequency_rad_s"] - true["frequency_rad_s"])
                       / true["frequency_rad_s"],
                       damping_error_pp=100 * (mode["damping_ratio"] - true["damping_ratio"]))
        rows.append(row)
    return rows


def format_comparison(rows: list[dict], extra: list[dict]) -> str:
    """The identified-against-true table as text."""
    lines = [
        f"{'':4}{'true f [Hz]':>12} {'zeta [%]':>9}   {'id':>3} {'f [Hz]':>9} {'zeta [%]':>9}   "
        f"{'f error':>9} {'zeta error':>11}",
    ]
    for k, row in enumerate(rows, 1):
        t, m = row["true"], row["identified"]
        left = f"{k:<4}{t['frequency_hz']:>12.4f} {100 * t['damping_ratio']:>9.3f}"
        if m is None:
            lines.append(f"{left}   {'-':>3} {'not found':>19}")
        else:
            lines.append(f"{left}   {m['id']:>3} {m['frequency_hz']:>9.4f} {100 * m['damping_ratio']:>9.3f}   "
                         f"{100 * row['frequency_error']:>+8.3f}% {row['damping_error_pp']:>+8.3f} pp")
        if not t.get("in_paper_table", True):
            lines[-1] += "   (48 Hz pair of the published A, not in the paper's table)"
    for m in extra:
        lines.append(f"{'':4}{'(no true mode)':>22}   {m['id']:>3} {m['frequency_hz']:>9.4f} "
                     f"{100 * m['damping_ratio']:>9.3f}")
    return "\n".join(lines)


@dataclass
class DemoResult:
    """What the demo did (for tests and the exit status)."""

    run_dir: Path
    models_received: int
    modal_states_received: int
    rows: list
    figures: list
    wall_time_s: float

    @property
    def structural_modes_found(self) -> bool:
        """Both modes of the paper's table were identified within 5 %."""
        return all(r["identified"] is not None for r in self.rows if r["true"].get("in_paper_table", True))


def _stop_process(proc: subprocess.Popen, grace_s: float) -> None:
    """SIGINT, then SIGTERM, then SIGKILL, to the process (and its session, if still there)."""
    for sig, wait_s in ((signal.SIGINT, grace_s), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        if proc.poll() is not None:
            return
        try:
            proc.send_signal(sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            continue


def run_demo(out_dir: str | Path = "out/demo", duration_s: float = 60.0, rate: float = 1.0,
             params: list[str | Path] | None = None, sensors: bool = False, seed: int = 1,
             stream: TextIO | None = None, ansi: bool | None = None, startup_timeout_s: float = 90.0) -> DemoResult:
    """Run the demo (see the module docstring); returns when everything is stopped.

    Args:
        out_dir: parent of the run folders.
        duration_s: length of the simulated experiment [s] (the replay takes duration_s / rate).
        rate: replay speed factor.
        params: the nodes' parameter files, later ones override (default config/okid.yaml;
            with ``sensors`` config/okid_imu_wrench.yaml).
        sensors: feed the nodes the Imu and WrenchStamped topics instead of IoSample.
        seed: seed of the simulation.
        stream: where the monitor and the report go (default stdout).
        ansi: redraw the monitor in place (default: when ``stream`` is a terminal).
        startup_timeout_s: how long the nodes may take to come up.

    Raises
    ------
        OkidError: a step failed (message says which; logs are in the run folder).
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.serialization import deserialize_message

    from okid_msgs.msg import ModalStates
    from okid_ros.tools.bagio import TRUTH_KEY, BagWriter, open_bag
    from okid_ros.tools.monitor import ModalStatesView, TerminalMonitor
    from okid_ros.tools.plots import add_measured_outputs, read_plot_data, write_figures
    from okid_ros.tools.process import load_node_parameters
    from okid_ros.tools.recorder import LiveRecorder
    from okid_ros.tools.simulate_bag import (
        IMU_TOPICS,
        IO_SAMPLE_TOPIC,
        THRUSTER_TOPICS,
        simulate_experiment,
        write_experiment_bag,
    )

    out = stream or sys.stdout
    started = time.monotonic()

    def say(text: str) -> None:
        out.write(text + "\n")
        out.flush()

    param_files = [Path(p) for p in params] if params else [
        default_params_file("okid_imu_wrench.yaml" if sensors else "okid.yaml")]
    for path in param_files:
        if not path.is_file():
            raise OkidError(f"parameter file {path} does not exist")
    run_dir = Path(out_dir) / time.strftime("%Y%m%d-%H%M%S")
    if run_dir.exists():
        raise OkidError(f"{run_dir} exists already; wait a second and run again")
    run_dir.mkdir(parents=True)
    latest = Path(out_dir) / "latest"
    if latest.is_symlink() or not latest.exists():
        if latest.is_symlink():
            latest.unlink()
        latest.symlink_to(run_dir.name)

    domain_id, domain_lock = _claim_domain_id()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED="1")
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    saved_env = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
    say(f"okid-ros demo: run folder {run_dir} (ROS_DOMAIN_ID={domain_id}; watch from another shell with "
        f"ROS_DOMAIN_ID={domain_id} okid-ros monitor)")

    processes: list[subprocess.Popen] = []
    logs: list[IO[str]] = []
    context = None
    try:
        # 1. the experiment
        experiment_bag = run_dir / "experiment"
        experiment = simulate_experiment(duration_s, seed=seed)
        write_experiment_bag(experiment_bag, experiment)
        truth_text = ", ".join(f"{m['frequency_hz']:.3f} Hz {100 * m['damping_ratio']:.2f} %"
                               for m in experiment.truth["modes"])
        say(f"[1/5] simulated {experiment.n_samples * experiment.sample_time_s:g} s of the paper's experiment "
            f"-> {experiment_bag} (true modes: {truth_text})")

        # 2. the nodes
        cli = [sys.executable, "-m", "okid_ros.cli"]
        nodes_log = open(run_dir / "nodes.log", "w")
        logs.append(nodes_log)
        up_args = [arg for path in param_files for arg in ("--params", str(path))]
        nodes = subprocess.Popen(cli + ["up", *up_args], env=env, stdout=nodes_log,
                                 stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        processes.append(nodes)
        say(f"[2/5] started both nodes: okid-ros up {' '.join(up_args)} (log: {run_dir / 'nodes.log'})")

        context = rclpy.Context()
        rclpy.init(context=context, args=[])
        node = rclpy.create_node("okid_demo", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        input_topics = list(THRUSTER_TOPICS) + list(IMU_TOPICS) if sensors else [IO_SAMPLE_TOPIC]
        deadline = time.monotonic() + startup_timeout_s
        while not (all(node.count_subscribers(t) >= 2 for t in input_topics)
                   and all(node.count_publishers(t) >= 1 for t in OUTPUT_TOPICS)):
            if nodes.poll() is not None:
                raise OkidError(f"the nodes exited with status {nodes.returncode}; see {run_dir / 'nodes.log'}")
            if time.monotonic() > deadline:
                raise OkidError(
                    f"the nodes did not come up within {startup_timeout_s:g} s; see {run_dir / 'nodes.log'}"
                )
            executor.spin_once(timeout_sec=0.2)

        # 3. replay, record, monitor
        arrows = ("\u2191", "\u2193", "\u2192") if "utf" in (getattr(out, "encoding", None) or "utf-8").lower() \
            else ("^", "v", "=")
        view = ModalStatesView(arrows=arrows)
        monitor = TerminalMonitor(view, out, None if ansi is not False and out.isatty() else 5.0,
                                  ansi=ansi, title="okid-ros demo (live)")
        counts = {"models": 0, "states": 0}
        last_output = [time.monotonic()]

        def on_output(topic: str, data: bytes, receive_ns: int) -> None:
            last_output[0] = time.monotonic()
            if topic == "/okid/modal_states":
                counts["states"] += 1
                view.update(deserialize_message(data, ModalStates))
            elif topic == "/okid/state_space_model":
                counts["models"] += 1

        live_bag = run_dir / "live"
        with BagWriter(live_bag) as writer:
            writer.set_custom_data(TRUTH_KEY, dumps(experiment.truth))
            LiveRecorder(node, writer, OUTPUT_TOPICS, on_message=on_output)
            replay_log = open(run_dir / "replay.log", "w")
            logs.append(replay_log)
            replay = subprocess.Popen(
                cli + ["replay", str(experiment_bag), "--rate", f"{rate:g}", "--wait-for-subscribers", "--delay", "0.5",
                       "--topics", *input_topics],
                env=env, stdout=replay_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
            processes.append(replay)
            say(f"[3/5] replaying {', '.join(input_topics)} live at rate {rate:g} "
                f"({duration_s / rate:.0f} s); recording the nodes' outputs -> {live_bag}")
            if monitor.ansi:
                say("")
            while replay.poll() is None:
                executor.spin_once(timeout_sec=0.05)
                monitor.maybe_draw()
                if nodes.poll() is not None:
                    raise OkidError(f"the nodes exited with status {nodes.returncode} during the replay; "
                                    f"see {run_dir / 'nodes.log'}")
            if replay.returncode != 0:
                raise OkidError(f"the replay failed with status {replay.returncode}; see {run_dir / 'replay.log'}")
            # let the last outputs arrive
            settle = time.monotonic() + 5.0
            while time.monotonic() < settle and time.monotonic() - last_output[0] < 1.0:
                executor.spin_once(timeout_sec=0.05)
            monitor.draw()
        say(f"recorded {counts['models']} StateSpaceModel and {counts['states']} ModalStates messages")
        _stop_process(nodes, grace_s=15.0)

        # 4. figures
        data = read_plot_data(live_bag, window_s=5.0)
        add_measured_outputs(data, experiment_bag, load_node_parameters(param_files)[1])
        figures = write_figures(data, run_dir / "figures")
        say(f"[4/5] {len(figures)} figures -> {run_dir / 'figures'}: {', '.join(p.name for p in figures)}")

        # 5. identified against true
        identified: list[dict] = []
        with open_bag(live_bag) as bag:
            if "/okid/state_space_model" in bag.topics:
                for _topic, _ns, msg in bag.messages(["/okid/state_space_model"]):
                    identified = [{"id": int(m.id), "frequency_rad_s": float(m.frequency_rad_s),
                                   "frequency_hz": float(m.frequency_hz), "damping_ratio": float(m.damping_ratio)}
                                  for m in msg.modes]
        rows = compare_modes(experiment.truth["modes"], identified)
        matched = {id(r["identified"]) for r in rows if r["identified"] is not None}
        extra = [m for m in identified if id(m) not in matched]
        if identified:
            say(f"[5/5] modes of the last live model ({data.state_space['model_id'] if data.state_space else '?'}) "
                f"against the truth:")
            say(format_comparison(rows, extra))
        else:
            say("[5/5] no model was identified live; see nodes.log")
        wall = time.monotonic() - started
        say(f"okid-ros demo: done in {wall:.0f} s; outputs in {run_dir}")
        return DemoResult(run_dir, counts["models"], counts["states"], rows, figures, wall)
    finally:
        for proc in reversed(processes):
            _stop_process(proc, grace_s=15.0)
        if context is not None:
            context.try_shutdown()
        for log in logs:
            log.close()
        for key, value in saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        if domain_lock is not None:
            domain_lock.close()

