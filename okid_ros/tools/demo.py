"""The end-to-end demo behind ``make demo`` / ``okid-ros demo``.

1. simulate the paper-like experiment into a bag (:mod:`.simulate_bag`, truth in its metadata);
2. start both nodes as ``okid-ros up --params config/okid.yaml`` (separate processes);
3. replay the bag live (``okid-ros replay``, its own process) while this process records the
   nodes' outputs (:class:`.recorder.LiveRecorder`) and shows the modes (:mod:`.monitor`), then
   wait for node 2 to publish the model of node 1's last window (at most :data:`SETTLE_TIMEOUT_S`);
4. stop the nodes, draw the figures from the recording (:mod:`.plots`);
5. print the modes of the last live model against the true ones.

With ``output_only`` (``okid-ros demo --output-only``) the experiment is ambient vibration
(:mod:`.simulate_ambient`: a structure shaken by forces nobody measures, two Imu topics) and
the nodes run ``config/okid.yaml`` + ``config/okid_output_only.yaml`` (n_inputs 0) with the
window of :data:`OUTPUT_ONLY_DEMO_WINDOW` samples, so the first model comes within the demo.

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

from okid_ros.errors import OkidError, shown_path
from okid_ros.jsonio import dumps
from okid_ros.service.param_files import files_for_nodes
from okid_ros.tools.demo_options import (
    OUTPUT_ONLY_DEMO_WINDOW,
    OUTPUT_ONLY_OVERRIDES,
    DemoOptions,
    check_demo_options,
    default_params_file,
)
from okid_ros.tools.output_paths import prepare_output
from okid_ros.tools.ros_domain import check_ros_environment, ros_context
from okid_ros.tools.simulate_ambient import AMBIENT_IMU_TOPICS, simulate_ambient, write_ambient_bag
from okid_ros.tools.simulate_bag import Experiment, simulate_experiment, write_experiment_bag

__all__ = ["DemoOptions", "DemoResult", "OUTPUT_ONLY_DEMO_WINDOW", "run_demo", "default_params_file", "compare_modes"]

REPO_ROOT = Path(__file__).resolve().parents[2]
OUTPUT_TOPICS = {
    "/okid/arx_model": "okid_msgs/msg/ArxModel",
    "/okid/state_space_model": "okid_msgs/msg/StateSpaceModel",
    "/okid/modal_states": "okid_msgs/msg/ModalStates",
}


#: Longest wait after the replay for node 2 to apply the model of node 1's last window [s].
SETTLE_TIMEOUT_S = 30.0
#: Subscriptions on each input topic once the nodes are up: node 1 and node 2.
NODE_SUBSCRIPTIONS = 2
_ESTIMATION_STATUS = "okid_modal_estimator: estimation"  # node 2's DiagnosticStatus (after its namespace)

def _claim_domain_id() -> tuple[int, IO[str] | None]:
    """ROS_DOMAIN_ID from the environment, else a free id of 1..100 (locked while we run)."""
    if (domain_id := check_ros_environment()) is not None:  # checked: "abc" was a ValueError, an internal error
        return domain_id, None
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


def _new_run_dir(out_dir: Path) -> Path:
    """A new ``OUT_DIR/YYYYmmdd-HHMMSS``, with ``OUT_DIR/latest`` pointing to it."""
    run_dir = out_dir / time.strftime("%Y%m%d-%H%M%S")
    if run_dir.exists():
        raise OkidError(f"{shown_path(run_dir)} exists already; wait a second and run again")
    try:  # OUT_DIR a file, or not writable: one line, as for every output (was an internal error)
        prepare_output(run_dir, force=False, kind="run folder").mkdir()
    except OSError as exc:
        raise OkidError(f"{shown_path(run_dir)}: cannot create the run folder ({exc.strerror})") from None
    latest = out_dir / "latest"
    if latest.is_symlink() or not latest.exists():
        latest.unlink(missing_ok=True)
        latest.symlink_to(run_dir.name)
    return run_dir


class _DemoRun:
    """One demo run: its folder, ROS domain, processes and log files (all released by ``close``)."""

    def __init__(self, out_dir: Path, options: DemoOptions, stream: TextIO) -> None:
        self.options = options
        self.out = stream
        self.param_files = options.param_files
        self.domain_id, self._domain_lock = _claim_domain_id()  # before the run folder: a bad id leaves none
        self.run_dir = _new_run_dir(out_dir)
        if options.output_only and not options.params:
            overrides = self.run_dir / "output_only_demo.yaml"
            overrides.write_text(OUTPUT_ONLY_OVERRIDES)
            self.param_files.append(overrides)
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain_id), PYTHONUNBUFFERED="1")
        self.env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        self._saved_env = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
        for key in self._saved_env:  # the in-process recorder joins the same domain
            os.environ[key] = self.env[key]
        self.processes: list[subprocess.Popen] = []
        self._logs: list[IO[str]] = []
        self.context = None
        self.node = None  # the recorder's node and executor, made by _start_nodes
        self.executor = None
        self.last_model_id: object = "?"

    def say(self, text: str) -> None:
        self.out.write(text + "\n")
        self.out.flush()

    def start(self, args: list[str], log_name: str) -> subprocess.Popen:
        """``okid-ros ARGS`` in this run's domain, its output in ``log_name`` of the run folder."""
        log = open(self.run_dir / log_name, "w")
        self._logs.append(log)
        proc = subprocess.Popen([sys.executable, "-m", "okid_ros.cli", *args], env=self.env, stdout=log,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        self.processes.append(proc)
        return proc

    def close(self) -> None:
        for proc in reversed(self.processes):
            _stop_process(proc, grace_s=15.0)
        if self.context is not None:
            self.context.try_shutdown()
        for log in self._logs:
            log.close()
        for key, value in self._saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        if self._domain_lock is not None:
            self._domain_lock.close()


def run_demo(out_dir: str | Path = "out/demo", *, stream: TextIO | None = None, **options) -> DemoResult:
    """Run the demo (see the module docstring); returns when everything is stopped.

    Parameters
    ----------
    out_dir : parent of the run folders.
    stream : where the monitor and the report go (default stdout).
    **options : the fields of :class:`DemoOptions`: ``duration_s`` (length of the simulated
        experiment [s]; the replay takes duration_s / rate), ``rate`` (replay speed factor),
        ``params`` (the nodes' parameter files, later ones override; default config/okid.yaml,
        with ``sensors`` config/okid_imu_wrench.yaml), ``sensors`` (feed the nodes the Imu and
        WrenchStamped topics instead of IoSample), ``seed``, ``ansi`` (redraw the monitor in
        place; default: when ``stream`` is a terminal), ``startup_timeout_s``, ``output_only``
        (an ambient experiment on Imu topics, the nodes with n_inputs 0).

    Raises
    ------
    OkidError
        a step failed (the message says which; logs are in the run folder).
    """
    options = DemoOptions(**{**options, "params": tuple(Path(p) for p in options.get("params") or ())})
    started = time.monotonic()
    files_for_nodes(options.param_files)  # read as `up` reads them, before anything is simulated or started
    check_demo_options(options)
    simulate = simulate_ambient if options.output_only else simulate_experiment
    experiment = simulate(options.duration_s, seed=options.seed)  # before the run folder: none left on a refusal
    run = _DemoRun(Path(out_dir), options, stream or sys.stdout)
    run.say(f"okid-ros demo: run folder {shown_path(run.run_dir)} (ROS_DOMAIN_ID={run.domain_id}; watch from another "
            f"shell with ROS_DOMAIN_ID={run.domain_id} okid-ros monitor)")
    try:
        experiment_bag, truth = _write_experiment(run, experiment)
        nodes = _start_nodes(run)
        counts, live_bag = _replay_and_record(run, nodes, experiment_bag, truth)
        _stop_process(nodes, grace_s=15.0)
        figures = _draw_figures(run, live_bag, experiment_bag)
        rows = _compare_with_truth(run, live_bag, truth)
        wall = time.monotonic() - started
        run.say(f"okid-ros demo: done in {wall:.0f} s; outputs in {shown_path(run.run_dir)}")
        return DemoResult(run.run_dir, counts["models"], counts["states"], rows, figures, wall)
    finally:
        run.close()


def _input_topics(options: DemoOptions) -> list[str]:
    from okid_ros.tools.simulate_bag import IMU_TOPICS, IO_SAMPLE_TOPIC, THRUSTER_TOPICS

    if options.output_only:
        return list(AMBIENT_IMU_TOPICS)
    return list(THRUSTER_TOPICS) + list(IMU_TOPICS) if options.sensors else [IO_SAMPLE_TOPIC]


def _write_experiment(run: _DemoRun, experiment: Experiment) -> tuple[Path, dict]:
    """Step 1: the simulated experiment as a bag in the run folder; returns the bag and the truth."""
    experiment_bag = run.run_dir / "experiment"
    if run.options.output_only:
        write_ambient_bag(experiment_bag, experiment)
        what = "ambient vibration (no measured input, two Imu topics)"
    else:
        write_experiment_bag(experiment_bag, experiment)
        what = "the paper's experiment"
    truth_text = ", ".join(f"{m['frequency_hz']:.3f} Hz {100 * m['damping_ratio']:.2f} %"
                           for m in experiment.truth["modes"])
    run.say(f"[1/5] simulated {experiment.n_samples * experiment.sample_time_s:g} s of {what} "
            f"-> {shown_path(experiment_bag)} (true modes: {truth_text})")
    return experiment_bag, experiment.truth


def _start_nodes(run: _DemoRun) -> subprocess.Popen:
    """Step 2: both nodes (``okid-ros up``) and this process's recorder node, once they see each other."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    up_args = [arg for path in run.param_files for arg in ("--params", str(path))]
    nodes = run.start(["up", *up_args], "nodes.log")
    run.say(f"[2/5] started both nodes: okid-ros up {' '.join(up_args)} (log: {shown_path(run.run_dir / 'nodes.log')})")
    run.context = ros_context()
    run.node = rclpy.create_node("okid_demo", context=run.context)
    run.executor = SingleThreadedExecutor(context=run.context)
    run.executor.add_node(run.node)
    input_topics = _input_topics(run.options)
    deadline = time.monotonic() + run.options.startup_timeout_s
    while not (all(run.node.count_subscribers(t) >= NODE_SUBSCRIPTIONS for t in input_topics)
               and all(run.node.count_publishers(t) >= 1 for t in OUTPUT_TOPICS)):
        if nodes.poll() is not None:
            raise OkidError(f"the nodes exited with status {nodes.returncode}; "
                            f"see {shown_path(run.run_dir / 'nodes.log')}")
        if time.monotonic() > deadline:
            raise OkidError(f"the nodes did not come up within {run.options.startup_timeout_s:g} s; "
                            f"see {shown_path(run.run_dir / 'nodes.log')}")
        run.executor.spin_once(timeout_sec=0.2)
    return nodes


def _replay_and_record(run: _DemoRun, nodes: subprocess.Popen, experiment_bag: Path,
                       truth: dict) -> tuple[dict, Path]:
    """Step 3: replay the experiment live, record the nodes' outputs and show the modes."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message

    from okid_msgs.msg import ArxModel, ModalStates
    from okid_ros.tools.bagio import TRUTH_KEY, BagWriter
    from okid_ros.tools.monitor import ModalStatesView, TerminalMonitor
    from okid_ros.tools.recorder import LiveRecorder

    unicode = "utf" in (getattr(run.out, "encoding", None) or "utf-8").lower()
    view = ModalStatesView(arrows=("\u2191", "\u2193", "\u2192") if unicode else ("^", "v", "="))
    ansi = run.options.ansi
    monitor = TerminalMonitor(view, run.out, None if ansi is not False and run.out.isatty() else 5.0,
                              ansi=ansi, title="okid-ros demo (live)")
    counts = {"models": 0, "states": 0, "valid_arx_models": 0}
    last_output = [time.monotonic()]

    def on_output(topic: str, data: bytes, receive_ns: int) -> None:
        # Node 1 republishes its unchanged window after the replay: no ArxModel counts as an output
        # still on its way (it kept the settle below waiting its whole 5 s).
        if topic == "/okid/modal_states":
            last_output[0] = time.monotonic()
            counts["states"] += 1
            view.update(deserialize_message(data, ModalStates))
        elif topic == "/okid/state_space_model":
            last_output[0] = time.monotonic()
            counts["models"] += 1
        counts["valid_arx_models"] += topic == "/okid/arx_model" and deserialize_message(data, ArxModel).valid

    node_2: dict[str, str] = {}  # the values of node 2's last estimation status

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith(_ESTIMATION_STATUS):
                node_2.clear()
                node_2.update((kv.key, kv.value) for kv in status.values)

    run.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    live_bag = run.run_dir / "live"
    input_topics = _input_topics(run.options)
    rate = run.options.rate
    with BagWriter(live_bag) as writer:
        writer.set_custom_data(TRUTH_KEY, dumps(truth))
        LiveRecorder(run.node, writer, OUTPUT_TOPICS, on_message=on_output)
        replay = run.start(["replay", str(experiment_bag), "--rate", f"{rate:g}",
                            "--subscribers", str(NODE_SUBSCRIPTIONS),
                            "--delay", "0.5", "--topics", *input_topics], "replay.log")
        run.say(f"[3/5] replaying {', '.join(input_topics)} live at rate {rate:g} "
                f"({run.options.duration_s / rate:.0f} s); recording the nodes' outputs -> {shown_path(live_bag)}")
        if monitor.ansi:
            run.say("")
        while replay.poll() is None:
            run.executor.spin_once(timeout_sec=0.05)
            monitor.maybe_draw()
            if nodes.poll() is not None:
                raise OkidError(f"the nodes exited with status {nodes.returncode} during the replay; "
                                f"see {shown_path(run.run_dir / 'nodes.log')}")
        if replay.returncode != 0:
            raise OkidError(f"the replay failed with status {replay.returncode}; "
                            f"see {shown_path(run.run_dir / 'replay.log')}")
        if not _wait_for_last_model(run, nodes, node_2):
            run.say(_unsettled_note(counts["valid_arx_models"], run.options.duration_s))
        settle = time.monotonic() + 5.0  # let the last outputs arrive: until 1 s without a model or modal states
        while time.monotonic() < settle and time.monotonic() - last_output[0] < 1.0:
            run.executor.spin_once(timeout_sec=0.05)
        monitor.draw()
    run.say(f"recorded {counts['models']} StateSpaceModel and {counts['states']} ModalStates messages")
    return counts, live_bag


def _wait_for_last_model(run: _DemoRun, nodes: subprocess.Popen, node_2: dict[str, str]) -> bool:
    """After the replay, until node 2 has applied the model of node 1's last window; False on timeout.

    Node 2 applies the models due after the last sample once its input is idle, one after the
    other. Node 1 republishes its last window while no samples come: once node 2 has ignored
    that as unchanged, with no job running and no request waiting, the last window's model has
    been applied (or refused) and published. ``node_2``: its estimation status, kept current.
    """
    baseline = int(node_2.get("arx_models_unchanged", "0"))
    deadline = time.monotonic() + SETTLE_TIMEOUT_S
    while time.monotonic() < deadline and nodes.poll() is None:
        if (int(node_2.get("arx_models_unchanged", "0")) > baseline and node_2.get("busy") == "false"
                and node_2.get("arx_request_waiting") == "false"):
            return True
        run.executor.spin_once(timeout_sec=0.05)
    return False


def _unsettled_note(valid_arx_models: int, duration_s: float) -> str:
    """Why the wait for the last model timed out (it blamed node 2 when node 1 had no valid model)."""
    if not valid_arx_models:
        return (f"node 1 published no valid ArxModel: is the experiment ({duration_s:g} s) shorter than its first "
                "window (arx.window_length)? see nodes.log")
    return f"node 2 was still busy {SETTLE_TIMEOUT_S:g} s after the replay: the model of the last window may be missing"


def _draw_figures(run: _DemoRun, live_bag: Path, experiment_bag: Path) -> list:
    """Step 4: the figures of the recording."""
    from okid_ros.tools.plots import add_measured_outputs, read_plot_data, write_figures
    from okid_ros.tools.process import load_node_parameters

    data = read_plot_data(live_bag, window_s=5.0)
    add_measured_outputs(data, experiment_bag, load_node_parameters(run.param_files)[1])
    figures = write_figures(data, run.run_dir / "figures")
    run.say(f"[4/5] {len(figures)} figures -> {shown_path(run.run_dir / 'figures')}: "
            f"{', '.join(shown_path(p.name) for p in figures)}")
    run.last_model_id = data.state_space["model_id"] if data.state_space else "?"
    return figures


def _compare_with_truth(run: _DemoRun, live_bag: Path, truth: dict) -> list[dict]:
    """Step 5: the modes of the last live model against the true ones."""
    from okid_ros.tools.bagio import open_bag

    identified: list[dict] = []
    with open_bag(live_bag) as bag:
        if "/okid/state_space_model" in bag.topics:
            for _topic, _ns, msg in bag.messages(["/okid/state_space_model"]):
                identified = [{"id": int(m.id), "frequency_rad_s": float(m.frequency_rad_s),
                               "frequency_hz": float(m.frequency_hz), "damping_ratio": float(m.damping_ratio)}
                              for m in msg.modes]
    rows = compare_modes(truth["modes"], identified)
    matched = {id(r["identified"]) for r in rows if r["identified"] is not None}
    extra = [m for m in identified if id(m) not in matched]
    if identified:
        run.say(f"[5/5] modes of the last live model ({run.last_model_id}) against the truth:")
        run.say(format_comparison(rows, extra))
    else:
        run.say("[5/5] no model was identified live; see nodes.log")
    return rows
