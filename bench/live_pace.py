"""Does the live chain keep its pace at 28 channels? Both nodes on the steel subframe at 1024 Hz.

Run:  .venv/bin/python bench/live_pace.py [--duration 60] [--window 6000 3000] [--synthetic 200]

Issue 17 item 3: at 28 channels, 1024 Hz, ARX order 20, window 6000, with the default
realization settings and change detection on, every ArxModel after the first is realized and
published before the next one. What it does, for each ``--window``:

1. starts ``okid_arx_identifier`` and ``okid_modal_estimator`` as processes from
   config/okid.yaml with a parameter override (p = 28 outputs, m = 2 inputs, sample time 1/1024 s,
   ARX order ``--order``, window ``--window`` rows; everything else as shipped: automatic model
   order, refinement, refit gain, realization in a worker process, change detection on, an
   ArxModel per second), in a ROS domain of its own with localhost discovery. One transport
   setting is added: node 2's ModalStates history (``qos_overrides``, 20000 messages instead of
   100), so that a burst after a stall cannot overwrite messages this benchmark's receiver has
   not taken yet, and the drops counted are the nodes' own;
2. a receiver process subscribes ``/okid/modal_states``, ``/okid/arx_model`` and
   ``/okid/state_space_model`` (serialized, decoded after the run) and ``/diagnostics``, each
   arrival stamped with CLOCK_MONOTONIC;
3. this process publishes the DaISy steel-subframe record (``../shared/data/real/
   daisy-steel-subframe``, 8523 samples) as ``okid_msgs/IoSample`` in real time, looped with
   continuing stamps (no time jump: the window and the model carry over each seam); with
   ``--synthetic SECONDS`` instead that many seconds of the record's identified model driven by
   white noise (:func:`synthetic_record`: the same channels and dynamics without the seam, where
   the jump from the record's last sample to its first is a transient the nodes react to);
4. from the first StateSpaceModel on it measures ``--duration`` seconds (the samples go on
   :data:`GRACE_S` longer, unmeasured, so that the last ArxModel can be published): the ArxModels and
   StateSpaceModels published, how many ArxModels were realized and published before the next
   ArxModel arrived (the issue's criterion), the realization time of each model (node 2's log;
   node 2's diagnostics ``last_realization_time_s`` for the rejected ones too), the samples
   without ModalStates (drops), the latency from the publish call to the arrival of the
   sample's ModalStates, and the CPU of each node with its workers (as bench/dds_latency.py:
   /proc, node 2 with its realization process).

``--imu`` publishes the channels as sensor drivers do instead of one IoSample per sample: the
outputs three by three as ``sensor_msgs/Imu`` (a triaxial accelerometer's
``linear_acceleration``; 10 topics at 28 outputs), the inputs on one ``WrenchStamped``; the
nodes read them through ``inputs.sources``.

``--output-only`` publishes the accelerations alone (``u`` empty, ``n_inputs: 0``): node 1 fits
a vector autoregression, node 2 realizes by the output-only front end (issue 18 item 6: a model
every publish period, at most 1 s of compute per update at 28 channels).

Prints a markdown table, one column per window; docs/benchmarks-nodes.md has the numbers of
this machine ("28 channels at 1024 Hz (issue 17 item 3)").
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import signal
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import checkout

REPO = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("dds_latency", REPO / "bench" / "dds_latency.py")
dds_latency = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(dds_latency)

RECORD = REPO.parent / "shared" / "data" / "real" / "daisy-steel-subframe" / "steel_subframe.npz"
ESTIMATION_KEYS = ("arx_models_received", "arx_models_replaced", "arx_models_unchanged", "arx_models_invalid",
                   "realizations", "models_accepted", "models_rejected", "changes_detected",
                   "windows_refused_for_change", "samples_missing", "diverged_samples")
MODEL_LOG = re.compile(r"model (\d+) \(ARX (\d+), (\d+) states, realized in ([0-9.]+) s\)")


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0,
                        help="measured seconds after the first StateSpaceModel (default 60)")
    parser.add_argument("--window", type=int, nargs="+", default=[6000],
                        help="ARX window rows, one run each (default 6000)")
    parser.add_argument("--order", type=int, default=20, help="ARX order q (default 20)")
    parser.add_argument("--no-change-detection", action="store_true",
                        help="change.enabled false in node 2 (to tell its false alarms from the pace)")
    parser.add_argument("--first-model-timeout", type=float, default=180.0,
                        help="seconds of publishing to wait for the first StateSpaceModel (default 180)")
    parser.add_argument("--record", default=str(RECORD), help="record .npz with u, y, sample_time_s")
    parser.add_argument("--synthetic", type=float, default=0.0, metavar="SECONDS",
                        help="publish instead SECONDS of the record's identified model driven by white noise "
                             "(no seam; see synthetic_record)")
    parser.add_argument("--output-only", action="store_true",
                        help="n_inputs 0: the accelerations alone, the shaker forces not published (issue 18 "
                             "item 6: node 1 a vector autoregression, node 2 the output-only realization)")
    parser.add_argument("--imu", action="store_true",
                        help="the outputs three by three on sensor_msgs/Imu topics (linear_acceleration.x/y/z, as "
                             "triaxial accelerometers publish) and the inputs on a geometry_msgs/WrenchStamped "
                             "(force.x/y): 11 messages per sample instead of one IoSample")
    parser.add_argument("--domain", type=int, default=61, help="ROS_DOMAIN_ID of the first run (default 61)")
    parser.add_argument("--role", default="bench", choices=("bench", "receiver"), help=argparse.SUPPRESS)
    parser.add_argument("--out", default="", help=argparse.SUPPRESS)
    return parser.parse_args()


# ------------------------------------------------------------------------------ receiver process
def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def receiver(out: str) -> None:
    """Keep every message of the chain with its arrival time; on SIGINT write them to ``out`` (JSON).

    ModalStates are cut to their stamp (the first 8 bytes after the CDR encapsulation), the
    models are decoded after the run: the receiver must keep up with 1024 ModalStates of ~8 kB
    per second. The first StateSpaceModel creates ``out + '.first'``.
    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import ExternalShutdownException
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message

    from okid_msgs.msg import ArxModel, ModalStates, StateSpaceModel, StructuralChange

    rclpy.init()
    node = Node("okid_pace_receiver")
    clock = time.monotonic_ns
    states: list[tuple[int, int]] = []
    raw: dict[str, list] = {"arx": [], "ssm": [], "change": []}
    diagnostics: list[tuple[int, str, dict]] = []
    first = Path(out + ".first")

    def on_states(data: bytes) -> None:
        sec, nanosec = struct.unpack_from("<iI", data, 4)
        states.append((sec * 1_000_000_000 + nanosec, clock()))

    def on_model(data: bytes) -> None:
        raw["ssm"].append((clock(), data))
        if len(raw["ssm"]) == 1:
            first.touch()

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            diagnostics.append((clock(), status.name, {kv.key: kv.value for kv in status.values}))

    reliable = QoSProfile(depth=20000, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(ModalStates, "/okid/modal_states", on_states, reliable, raw=True)
    node.create_subscription(ArxModel, "/okid/arx_model", lambda d: raw["arx"].append((clock(), d)), 50, raw=True)
    node.create_subscription(StateSpaceModel, "/okid/state_space_model", on_model, 50, raw=True)
    node.create_subscription(StructuralChange, "/okid/structural_change",
                             lambda d: raw["change"].append((clock(), d)), 50, raw=True)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
    print("receiver ready", flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    arx = [deserialize_message(d, ArxModel) for _, d in raw["arx"]]
    ssm = [deserialize_message(d, StateSpaceModel) for _, d in raw["ssm"]]
    changes = [deserialize_message(d, StructuralChange) for _, d in raw["change"]]
    Path(out).write_text(json.dumps({
        "states": states,
        "arx": [(t, m.model_id, m.valid, m.window_fill + m.order, _ns(m.header.stamp))
                for (t, _), m in zip(raw["arx"], arx)],
        "changes": [(t, _ns(m.change_stamp), m.identified) for (t, _), m in zip(raw["change"], changes)],
        "ssm": [(t, m.model_id, m.arx_model_id, m.n_states) for (t, _), m in zip(raw["ssm"], ssm)],
        "diagnostics": diagnostics,
    }))
    node.destroy_node()
    rclpy.try_shutdown()


# ------------------------------------------------------------------------------ one run
def start_chain(args: argparse.Namespace, window: int, dt: float, tmp: Path, env: dict) -> dict:
    """Both nodes and the receiver as processes; returns {name: Popen} (logs in ``tmp``)."""
    overrides = tmp / "pace.yaml"
    overrides.write_text(
        f"/**:\n  ros__parameters:\n    sample_time_s: {dt!r}\n    n_inputs: {0 if args.output_only else 2}\n"
        f"    n_outputs: 28\n"
        + (_sensor_sources(0 if args.output_only else 2, 28) if args.imu else "")
        + f"/**/okid_arx_identifier:\n  ros__parameters:\n"
        f"    arx:\n      order: {args.order}\n      window_length: {window}\n"
        f"/**/okid_modal_estimator:\n  ros__parameters:\n"
        f"    qos_overrides:\n      /okid/modal_states:\n        publisher:\n          depth: 20000\n"
        + ("    change:\n      enabled: false\n" if args.no_change_detection else "")
    )
    params = ["--ros-args", "--params-file", str(REPO / "config" / "okid.yaml"), "--params-file", str(overrides)]
    commands = {
        "arx": [sys.executable, "-m", "okid_ros.nodes.arx_identifier_node", *params],
        "est": [sys.executable, "-m", "okid_ros.nodes.modal_estimator_node", *params],
        "receiver": [sys.executable, __file__, "--role", "receiver", "--out", str(tmp / "rx.json")],
    }
    procs = {}
    for name, command in commands.items():
        with open(tmp / f"{name}.log", "w") as log:
            procs[name] = subprocess.Popen(command, env=env, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
    return procs


IMU_TOPIC, WRENCH_TOPIC = "/pace/accel_{}", "/pace/force"
AXES = ("x", "y", "z")


def _sensor_topics(m: int, p: int) -> list[tuple[str, str, list[tuple[str, int]]]]:
    """``--imu``: (kind, topic, [(field, channel), ...]) of each sensor topic.

    The inputs on one WrenchStamped (force.x, .y, .z), the outputs three by three on Imu topics
    (linear_acceleration.x, .y, .z), as triaxial accelerometers publish them; channels count
    ``[u; y]``.
    """
    topics = [("wrench", WRENCH_TOPIC, [(f"force.{AXES[i]}", i) for i in range(m)])] if m else []
    for first in range(0, p, 3):
        fields = [(f"linear_acceleration.{AXES[j - first]}", m + j) for j in range(first, min(first + 3, p))]
        topics.append(("imu", IMU_TOPIC.format(first // 3), fields))
    return topics


def _sensor_sources(m: int, p: int) -> str:
    """``inputs.sources`` of both nodes for ``--imu``, as lines of the parameter file's ``/**``."""
    sources = [f"{kind} {topic} " + " ".join(f"{field}={'u' if ch < m else 'y'}{ch if ch < m else ch - m}"
                                            for field, ch in fields)
               for kind, topic, fields in _sensor_topics(m, p)]
    return "    inputs:\n      sources: [" + ", ".join(f'"{s}"' for s in sources) + "]\n"


class SensorSender:
    """``--imu``: a sample as a message per sensor topic, each from its topic's serialized template.

    The benchmark's own CPU must stay small beside the nodes' (11 messages per sample at 28
    outputs): each topic's message is serialized once by rclpy with marker values in its fields,
    and a sample writes its stamp and values into those bytes, which rclpy publishes raw.
    """

    def __init__(self, node, msgs: list, m: int, p: int, qos) -> None:
        from geometry_msgs.msg import WrenchStamped
        from rclpy.serialization import serialize_message
        from sensor_msgs.msg import Imu

        self.values = [list(msg.u) + list(msg.y) for msg in msgs]
        self.publishers, self.templates = [], []
        for kind, topic, fields in _sensor_topics(m, p):
            msg = WrenchStamped() if kind == "wrench" else Imu()
            group = msg.wrench.force if kind == "wrench" else msg.linear_acceleration
            markers = [1.2345678901234567e-300 * (k + 1) for k in range(len(fields))]
            for (field, _), marker in zip(fields, markers):
                setattr(group, field[-1], marker)
            data = serialize_message(msg)
            places = [(data.find(struct.pack("<d", marker)), channel) for (_, channel), marker in zip(fields, markers)]
            self.templates.append((bytearray(data), places))
            self.publishers.append(node.create_publisher(type(msg), topic, qos))

    def ready(self) -> bool:
        return all(pub.get_subscription_count() >= 2 for pub in self.publishers)

    def send(self, k: int, sec: int, nanosec: int) -> None:
        values = self.values[k % len(self.values)]
        for pub, (data, places) in zip(self.publishers, self.templates):
            struct.pack_into("<iI", data, 4, sec, nanosec)
            for at, channel in places:
                struct.pack_into("<d", data, at, values[channel])
            pub.publish(bytes(data))


def make_messages(record: Path, *, output_only: bool = False):
    """One IoSample per sample of the record and the sample time.

    Stamps are set when published; ``u`` is empty with ``output_only``.
    """
    import numpy as np

    from okid_msgs.msg import IoSample

    data = np.load(record)
    msgs = []
    for u, y in zip(data["u"], data["y"]):
        msg = IoSample()
        msg.u, msg.y = ([] if output_only else u.tolist()), y.tolist()
        msgs.append(msg)
    return msgs, float(data["sample_time_s"])


def synthetic_record(record: Path, seconds: float, folder: Path) -> Path:
    """A seam-free stand-in for the looped record: ``seconds`` of its identified model, simulated.

    The record is identified with ``identify``'s defaults (on this record: 122 states, its 15
    reference modes); the model is driven by white-noise inputs of the record's input spread
    (the shakers' forces were white noise) and by innovations of its covariance, with the
    record's offsets. Same channels, rate and dynamics, and no seam where a looped record jumps
    from its last sample back to its first (which the nodes rightly take for a transient).
    """
    import numpy as np

    from okid_ros.core.pipeline import identify
    from okid_ros.sim.simulators import simulate_innovation

    data = np.load(record)
    u, y, dt = np.asarray(data["u"], float), np.asarray(data["y"], float), float(data["sample_time_s"])
    model = identify(u, y, dt)
    n_samples = int(seconds / dt)
    rng = np.random.default_rng(17)
    u_sim = rng.standard_normal((n_samples, u.shape[1])) * u.std(axis=0)
    y_sim, _ = simulate_innovation(model, u_sim, seed=18)
    path = folder / "synthetic.npz"
    np.savez(path, u=u_sim + model.input_offset, y=y_sim + model.output_offset, sample_time_s=dt)
    print(f"synthetic record: {seconds:g} s of the identified model ({model.n_states} states, "
          f"{len(model.modes)} modes listed) driven by white noise", flush=True)
    return path


def snapshot(procs: dict) -> dict:
    """CPU seconds per node (with its children) and of the harness, load, CLOCK_MONOTONIC now."""
    harness = sum(dds_latency.cpu_seconds(pid, children=False)["total"]
                  for pid in (os.getpid(), procs["receiver"].pid))
    return {"cpu": {name: dds_latency.cpu_seconds(procs[name].pid) for name in ("arx", "est")},
            "harness": harness, "load": os.getloadavg()[0], "t_ns": time.monotonic_ns()}


#: Samples go on this long after the measurement: node 2 hands a new model over at the next
#: sample, so without them the last ArxModel measured could never be published in time.
GRACE_S = 3.0


def publish(args: argparse.Namespace, msgs: list, dt: float, procs: dict, marker: Path) -> dict:
    """Publish the record looped in real time until ``--duration`` s after the first StateSpaceModel.

    Returns the publish times, the first measured sample index and the snapshots at the
    start and end of the measurement.
    """
    import numpy as np
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from okid_msgs.msg import IoSample

    node = Node("okid_pace_publisher")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
    sender = None
    if args.imu:
        sender = SensorSender(node, msgs, 0 if args.output_only else 2, 28, qos)
        ready = sender.ready
    else:
        publisher = node.create_publisher(IoSample, "/okid/io_sample", qos)
        ready = lambda: publisher.get_subscription_count() >= 2  # noqa: E731
    deadline = time.monotonic() + 30.0
    while not ready() or node.count_subscribers("/okid/modal_states") < 1:
        if time.monotonic() > deadline:
            raise RuntimeError("the nodes or the receiver did not come up within 30 s")
        time.sleep(0.1)
    time.sleep(2.0)
    dt_ns = int(round(dt * 1e9))
    limit = int((args.first_model_timeout + args.duration + GRACE_S + 1.0) / dt)
    published = np.zeros(limit, dtype=np.int64)
    t0_ns = (time.time_ns() // 1_000_000_000 + 1) * 1_000_000_000
    clock = time.monotonic_ns
    measure_from, end, before, after = None, limit, None, None
    grace = int(round(GRACE_S / dt))
    print(f"publishing {len(msgs)} samples looped at {1 / dt:g} Hz until {args.duration:g} s after the "
          f"first StateSpaceModel (and {GRACE_S:g} s more, not measured)", flush=True)
    start = clock()
    k = 0
    while k < min(end + grace, limit):
        if k == end:
            after = snapshot(procs)
        wait = start + k * dt_ns - clock()
        if wait > 0:
            time.sleep(wait * 1e-9)  # no busy wait: the publisher must not eat the nodes' CPU
        sec, nanosec = divmod(t0_ns + k * dt_ns, 1_000_000_000)
        if sender is not None:
            sender.send(k, sec, nanosec)  # the sample is complete with its last message
            published[k] = clock()
        else:
            msg = msgs[k % len(msgs)]
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
            published[k] = clock()
            publisher.publish(msg)
        k += 1
        if measure_from is None and k % 64 == 0 and marker.exists():
            measure_from, before = k, snapshot(procs)
            end = k + int(round(args.duration / dt))
    after = after or snapshot(procs)
    node.destroy_node()
    if measure_from is None:
        raise RuntimeError(f"no StateSpaceModel within {args.first_model_timeout:g} s of samples")
    return {"published": published[:end], "t0_ns": t0_ns, "dt_ns": dt_ns, "measure_from": measure_from,
            "end": end, "before": before, "after": after, "loop_samples": len(msgs)}


def run_window(args: argparse.Namespace, window: int, domain: int, msgs: list, dt: float) -> dict:
    """One run of the chain with an ARX window of ``window`` rows; the row of the table."""
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    env.pop("ROS_LOCALHOST_ONLY", None)
    os.environ.update(ROS_DOMAIN_ID=str(domain))
    import rclpy

    tmp = Path(tempfile.mkdtemp(prefix=f"okid_pace_{window}_"))
    procs = start_chain(args, window, dt, tmp, env)
    rclpy.init()
    try:
        run = publish(args, msgs, dt, procs, tmp / "rx.json.first")
        time.sleep(5.0)  # the last samples' ModalStates and the next ArxModel
        procs["receiver"].send_signal(signal.SIGINT)
        procs["receiver"].wait(timeout=60)
        rx = json.loads((tmp / "rx.json").read_text())
        row = analyse(run, rx, (tmp / "est.log").read_text(), save=tmp / "latency.npz")
        row.update(window=window, logs=str(tmp))
        return row
    finally:
        rclpy.try_shutdown()
        for proc in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in procs.values():
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()


# ------------------------------------------------------------------------------ analysis
SEAM_S = 0.1  # a declared change this close to the loop's seam is put down to the seam


def pace(rx: dict, dt_ns: int, t_start: int, t_end: int, *, t0_ns: int, loop_samples: int) -> dict:
    """The issue's criterion over the ArxModels that arrived in [t_start, t_end).

    An ArxModel counts as in time when a StateSpaceModel realized from it arrived before the
    next ArxModel did (the last one of the interval is judged against the first one after it).
    One that is not is put down to a structural change when its window (samples ``rows`` back
    from its stamp) spans the stamp of a declared change (node 2 refuses such windows once the
    change is declared), else to the pace: published too late, or never (replaced by a newer
    ArxModel while the worker was busy, or rejected). ``to_model_s``: from the arrival of each
    ArxModel to the arrival of its StateSpaceModel. ``at_seam``: declared changes whose change
    point lies within ``SEAM_S`` of a seam of the loop (the record's last sample followed by its
    first, a jump no structure makes).
    """
    arx, ssm = rx["arx"], rx["ssm"]
    declared = [(t, stamp) for t, stamp, identified in rx["changes"] if not identified]
    ssm_arrival: dict[int, int] = {}
    for t, _, arx_id, _ in ssm:
        ssm_arrival.setdefault(arx_id, t)
    measured = [i for i, (t, *_rest) in enumerate(arx) if t_start <= t < t_end]
    valid = [i for i in measured if i + 1 < len(arx) and arx[i][2]]
    in_time, late, change, missed = [], [], [], []
    for i in valid:
        _, arx_id, _, rows, end_ns = arx[i]
        deadline = arx[i + 1][0]
        if ssm_arrival.get(arx_id, deadline) < deadline:
            in_time.append(i)
        elif any(end_ns - rows * dt_ns < stamp <= end_ns for _, stamp in declared):
            change.append(i)
        elif arx_id in ssm_arrival:
            late.append(i)
        else:
            missed.append(i)
    ssm_in = [t for t, *_rest in ssm if t_start <= t < t_end]
    return {"arx": len(measured), "arx_valid": sum(1 for i in measured if arx[i][2]), "judged": len(valid),
            "in_time": len(in_time), "late": len(late), "change": len(change), "missed": len(missed),
            "ssm": len(ssm_in), "ssm_interval_s": [(b - a) * 1e-9 for a, b in zip(ssm_in, ssm_in[1:])],
            "states": [n for t, _, _, n in ssm if t_start <= t < t_end],
            "declared": sum(1 for t, _ in declared if t_start <= t < t_end),
            "at_seam": sum(1 for t, stamp in declared if t_start <= t < t_end
                           and _from_seam_s(stamp, t0_ns, dt_ns, loop_samples) < SEAM_S),
            "to_model_s": [(ssm_arrival[arx[i][1]] - arx[i][0]) * 1e-9 for i in measured
                           if arx[i][1] in ssm_arrival]}


def _from_seam_s(stamp_ns: int, t0_ns: int, dt_ns: int, loop_samples: int) -> float:
    """Time from a sample stamp to the nearest seam of the loop [s]."""
    phase = round((stamp_ns - t0_ns) / dt_ns) % loop_samples
    return min(phase, loop_samples - phase) * dt_ns * 1e-9


def diagnostics_delta(diagnostics: list, t_start: int, t_end: int) -> dict:
    """Node 2's counters over [t_start, t_end) and every ``last_realization_time_s`` seen in it."""
    est = [(t, v) for t, name, v in diagnostics if name.endswith(": estimation")]
    first = next((v for t, v in reversed(est) if t < t_start), est[0][1] if est else {})
    last = next((v for t, v in reversed(est) if t < t_end), {})
    delta = {key: int(float(last.get(key, 0))) - int(float(first.get(key, 0))) for key in ESTIMATION_KEYS}
    times = {float(v["last_realization_time_s"]) for t, v in est
             if t_start <= t < t_end and v.get("last_realization_time_s", "nan") != "nan"}
    delta["diagnosed_times_s"] = sorted(times)
    return delta


def analyse(run: dict, rx: dict, est_log: str, *, save: Path | None = None) -> dict:
    """Everything the table prints, from the publish times, the receiver's record and node 2's log.

    ``save``: an .npz for the per-sample latencies (sample index, latency [ms], arrival) and t0.
    """
    import numpy as np

    before, after = run["before"], run["after"]
    t_start, t_end = before["t_ns"], after["t_ns"]
    wall = (t_end - t_start) * 1e-9
    published = run["published"]
    states = np.array(rx["states"], dtype=np.int64).reshape(-1, 2)
    index = np.rint((states[:, 0] - run["t0_ns"]) / run["dt_ns"]).astype(np.int64)
    keep = (index >= run["measure_from"]) & (index < run["end"])
    latency_ms = (states[keep, 1] - published[index[keep]]) * 1e-6
    expected = run["end"] - run["measure_from"]
    if save is not None:
        np.savez(save, index=index[keep], latency_ms=latency_ms, arrival_ns=states[keep, 1], t0_ns=run["t0_ns"],
                 dt_ns=run["dt_ns"], measure_from=run["measure_from"])
    received = int(np.unique(index[keep]).size)
    row = pace(rx, run["dt_ns"], t_start, t_end, t0_ns=run["t0_ns"], loop_samples=run["loop_samples"])
    row["diag"] = diagnostics_delta(rx["diagnostics"], t_start, t_end)
    measured_arx_ids = {arx_id for t, _, arx_id, _ in rx["ssm"] if t_start <= t < t_end}
    row["realization_s"] = [float(s) for _, arx_id, _, s in MODEL_LOG.findall(est_log)
                            if int(arx_id) in measured_arx_ids]
    row["cpu_arx"] = dds_latency.cpu_share(before["cpu"]["arx"], after["cpu"]["arx"], wall,
                                           "okid_arx_solve", "okid_samples")
    row["cpu_est"] = dds_latency.cpu_share(before["cpu"]["est"], after["cpu"]["est"], wall,
                                           "okid_realize", "okid_samples")
    row.update(wall_s=wall, expected=expected, dropped=expected - received,
               latency_ms=np.percentile(latency_ms, [50, 99]).tolist() + [float(latency_ms.max())]
               if latency_ms.size else [float("nan")] * 3,
               harness=(after["harness"] - before["harness"]) / wall,
               load=(before["load"], after["load"]),
               first_model_s=run["measure_from"] * run["dt_ns"] * 1e-9)
    return row


def _stats(values: list, unit: str = "", digits: int = 2) -> str:
    if not values:
        return "-"
    import numpy as np

    return f"median {np.median(values):.{digits}f}{unit}, max {max(values):.{digits}f}{unit} ({len(values)})"


def print_table(args: argparse.Namespace, rows: list[dict], dt: float) -> None:
    """The markdown table: one column per window."""
    source = (f"the steel subframe's identified model simulated for {args.synthetic:g} s" if args.synthetic > 0
              else "steel subframe looped")
    source += ", Imu topics (3 outputs each) and a WrenchStamped" if args.imu else ", one IoSample per sample"
    print(f"\nbench/live_pace.py: {source}, {1 / dt:g} Hz, p = 28, m = {0 if args.output_only else 2}, "
          f"q = {args.order}{' (output-only: node 1 a VAR)' if args.output_only else ''}, "
          f"defaults otherwise (ArxModel 1 Hz, automatic order, change detection "
          f"{'off' if args.no_change_detection else 'on'}), "
          f"measured {args.duration:g} s after the first StateSpaceModel, {os.cpu_count()} cores\n")
    print("| measure | " + " | ".join(f"window {r['window']}" for r in rows) + " |")
    print("|---|" + "---|" * len(rows))
    lines = {
        "first StateSpaceModel after [s of samples]": lambda r: f"{r['first_model_s']:.1f}",
        "ArxModels published (valid)": lambda r: f"{r['arx']} ({r['arx_valid']})",
        "StateSpaceModels published": lambda r: f"{r['ssm']}",
        "valid ArxModels realized and published before the next ArxModel": lambda r: (
            f"**{r['in_time']} of {r['judged']}** ({100 * r['in_time'] / max(r['judged'], 1):.0f} %)"),
        "the others: window spans a declared change / published late / never published": lambda r: (
            f"{r['change']} / {r['late']} / {r['missed']}"),
        "node 2: ArxModels replaced while waiting / realizations / rejected": lambda r: (
            f"{r['diag']['arx_models_replaced']} / {r['diag']['realizations']} / {r['diag']['models_rejected']}"),
        "from an ArxModel to its StateSpaceModel (arrivals) [s]": lambda r: _stats(r["to_model_s"]),
        "realization time per published model [s] (node 2's log)": lambda r: _stats(r["realization_s"]),
        "realization time, node 2's diagnostics [s]": lambda r: _stats(r["diag"]["diagnosed_times_s"]),
        "interval between StateSpaceModels [s]": lambda r: _stats(r["ssm_interval_s"]),
        "model states": lambda r: _stats(r["states"], digits=0),
        "structural changes declared (on a stationary record) / windows refused for a change": lambda r: (
            f"{r['declared']} / {r['diag']['windows_refused_for_change']}"),
        f"of those changes, at a seam of the loop (within {SEAM_S:g} s)": lambda r: f"{r['at_seam']}",
        "samples published (measured)": lambda r: f"{r['expected']}",
        "samples without ModalStates (drops)": lambda r: (
            f"{r['dropped']} ({100 * r['dropped'] / max(r['expected'], 1):.2f} %)"),
        "node 2: samples missing / diverged (not published)": lambda r: (
            f"{r['diag']['samples_missing']} / {r['diag']['diverged_samples']}"),
        "latency sample -> ModalStates p50 / p99 / max [ms]": lambda r: " / ".join(
            f"{v:.2f}" for v in r["latency_ms"]),
        "CPU okid_arx_identifier [cores] (solve thread, input thread, rest)": lambda r: (
            "{:.2f} ({:.2f}, {:.2f}, {:.2f})".format(*r["cpu_arx"])),
        "CPU okid_modal_estimator with its worker [cores] (worker, input thread, rest)": lambda r: (
            "{:.2f} ({:.2f}, {:.2f}, {:.2f})".format(*r["cpu_est"])),
        "CPU publisher + receiver (this benchmark) [cores]": lambda r: f"{r['harness']:.2f}",
        "load average (1 min) at start / end of the measurement": lambda r: f"{r['load'][0]:.2f} / {r['load'][1]:.2f}",
    }
    for label, cell in lines.items():
        print(f"| {label} | " + " | ".join(cell(r) for r in rows) + " |")
    print("\nlogs: " + ", ".join(r["logs"] for r in rows))


def main() -> int:
    args = parse_args()
    if args.role == "receiver":
        receiver(args.out)
        return 0
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")  # one BLAS thread, in the nodes too (set before the copy)
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    checkout.add()
    print(f"load average (1 min) before starting: {os.getloadavg()[0]:.2f}", flush=True)
    record = Path(args.record)
    if args.synthetic > 0:
        record = synthetic_record(record, args.synthetic, Path(tempfile.mkdtemp(prefix="okid_pace_record_")))
    msgs, dt = make_messages(record, output_only=args.output_only)
    rows = []
    for i, window in enumerate(args.window):
        try:
            rows.append(run_window(args, window, args.domain + i, msgs, dt))
        except RuntimeError as exc:
            print(f"bench/live_pace.py: window {window}: {exc}", file=sys.stderr)
            return 1
    print_table(args, rows, dt)
    return 0


if __name__ == "__main__":
    sys.exit(main())
