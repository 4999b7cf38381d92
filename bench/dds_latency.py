"""Latency and CPU of both nodes over DDS at 1 kHz (p = 2, m = 2, q = 100).

Run:  .venv/bin/python bench/dds_latency.py [--duration 30] [--rate 1000] [--states 0]

What it does:

1. starts ``okid_arx_identifier`` and ``okid_modal_estimator`` as processes from
   config/okid.yaml with the sample time set to 1/rate (ARX order 100, window 4000 rows,
   a model per second, automatic order: the shipped defaults otherwise), in a ROS domain of
   its own (``ROS_DOMAIN_ID``, default 57) with localhost discovery;
2. a receiver process subscribes ``/okid/modal_states`` and stamps each arrival with
   CLOCK_MONOTONIC;
3. this process publishes ``okid_msgs/IoSample`` at ``--rate`` Hz (a 3-mode structure at 12, 35
   and 80 Hz driven by low-passed noise, header stamps on the sample grid), recording the
   CLOCK_MONOTONIC time of each publish call;
4. once the first model is in use it measures for ``--duration`` seconds: per sample, the
   latency from the publish call to the arrival of the ModalStates that carries it (matched by
   stamp), the samples without ModalStates (dropped), and the CPU time of each node with its
   worker (node 2's realization runs in a child process named okid_realize, node 1's solve on a
   thread named okid_arx_solve), its input thread (okid_samples, which takes the samples) and
   the rest (executor, DDS threads), and how long the input threads waited for a core
   (run-queue delay from /proc/PID/task/TID/schedstat).

Prints a markdown table; docs/benchmarks-nodes.md has the numbers of this machine.

``--compare`` runs the bare rclpy echo node (``--control``) and then the two nodes, one after
the other with the same options, prints both tables and last the line
``p99_ms=<nodes> control_p99_ms=<echo> ratio=<nodes/echo> drops=<nodes' dropped samples>
load_1min=<at the start of the echo run>..<at the end of the nodes' run>``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import checkout

REPO = Path(__file__).resolve().parent.parent
CLK_TCK = os.sysconf("SC_CLK_TCK")


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=30.0, help="measured seconds (default 30)")
    parser.add_argument("--rate", type=float, default=1000.0, help="samples per second (default 1000)")
    parser.add_argument("--order", type=int, default=100, help="ARX order q (default 100)")
    parser.add_argument("--window", type=int, default=4000, help="ARX window rows (default 4000)")
    parser.add_argument("--publish-rate", type=float, default=1.0, help="ArxModel rate [Hz] (default 1)")
    parser.add_argument("--states", type=int, default=0, help="realization order, 0 = auto (default)")
    parser.add_argument("--worker", default="process", choices=("process", "thread"),
                        help="realization.worker (default process)")
    parser.add_argument("--domain", type=int, default=57, help="ROS_DOMAIN_ID (default 57)")
    parser.add_argument("--control", action="store_true",
                        help="instead of the two nodes, a bare rclpy echo node (IoSample in, ModalStates out): "
                        "the floor of rclpy + Fast DDS + scheduling on this machine")
    parser.add_argument("--compare", action="store_true",
                        help="run --control, then the nodes, and print last a line "
                        "p99_ms=<nodes> control_p99_ms=<echo> ratio=<nodes/echo>")
    parser.add_argument("--probe-fifo", type=int, default=0, metavar="PRIORITY",
                        help="run the benchmark's own publisher and receiver (not the nodes, not the echo node) "
                        "at this SCHED_FIFO priority (1-99; needs CAP_SYS_NICE): the probe is then not held back "
                        "by the load of what it measures (default 0: ordinary scheduling)")
    parser.add_argument("--realtime-priority", type=int, default=0, metavar="PRIORITY",
                        help="node 2's realtime_priority parameter (default 0: ordinary scheduling)")
    parser.add_argument("--role", default="bench", choices=("bench", "receiver", "echo"), help=argparse.SUPPRESS)
    parser.add_argument("--out", default="", help=argparse.SUPPRESS)
    return parser.parse_args()


# ------------------------------------------------------------------------------ receiver process
def receiver(out: str) -> None:
    """Subscribe /okid/modal_states; on SIGINT write (stamp ns, arrival ns, model id) as JSON."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from okid_msgs.msg import ModalStates

    rclpy.init()
    node = Node("okid_bench_receiver")
    stamps: list[int] = []
    arrivals: list[int] = []
    models: list[int] = []
    clock = time.monotonic_ns

    def on_states(msg: ModalStates) -> None:
        arrivals.append(clock())
        stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        models.append(msg.model_id)

    node.create_subscription(ModalStates, "/okid/modal_states", on_states,
                             QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE))
    callbacks: dict[str, list[tuple[float, float]]] = {}

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if "input callback max_ms" in values:
                callbacks.setdefault(status.name.split(":")[0], []).append(
                    (float(values["input callback mean_us"]), float(values["input callback max_ms"])))

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
    print("receiver ready", flush=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    Path(out).write_text(json.dumps({"stamps": stamps, "arrivals": arrivals, "models": models, "callbacks": callbacks}))
    node.destroy_node()
    rclpy.try_shutdown()


# ------------------------------------------------------------------------------ control node
def echo() -> None:
    """The floor: a bare rclpy node that echoes each IoSample, no identification at all.

    It republishes each IoSample as an empty ModalStates with the same stamp (same QoS as the
    estimator node).
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from okid_msgs.msg import IoSample, ModalStates

    rclpy.init()
    node = Node("okid_bench_echo")
    out = ModalStates()
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    publisher = node.create_publisher(ModalStates, "/okid/modal_states", qos)

    def on_sample(msg: IoSample) -> None:
        out.header = msg.header
        publisher.publish(out)

    node.create_subscription(IoSample, "/okid/io_sample", on_sample,
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


# ------------------------------------------------------------------------------ CPU accounting
def _children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(entry.name))
            except (OSError, ValueError, IndexError):
                continue
    return out


def cpu_seconds(pid: int, children: bool = True) -> dict[str, float]:
    """CPU seconds (user + system) of a process and its child processes.

    Returns 'total' and the seconds per thread name (a child process's threads count under
    their names too).
    """
    out: dict[str, float] = {"total": 0.0}
    for proc in [pid, *(_children(pid) if children else [])]:
        try:
            tasks = list(Path(f"/proc/{proc}/task").iterdir())
        except OSError:
            continue
        for task in tasks:
            try:
                fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
                name = (task / "comm").read_text().strip()
            except OSError:
                continue
            seconds = (int(fields[11]) + int(fields[12])) / CLK_TCK
            out[name] = out.get(name, 0.0) + seconds
            out["total"] += seconds
    return out


def wait_seconds(pid: int) -> dict[str, float]:
    """Seconds each thread of a process (by name) waited on a run queue for a core (schedstat)."""
    out: dict[str, float] = {}
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return out
    for task in tasks:
        try:
            delay_ns = int((task / "schedstat").read_text().split()[1])
            name = (task / "comm").read_text().strip()
        except (OSError, ValueError, IndexError):
            continue
        out[name] = out.get(name, 0.0) + delay_ns * 1e-9
    return out


def cpu_share(
    before: dict[str, float], after: dict[str, float], wall: float, *threads: str
) -> tuple[float, ...]:
    """(whole process, each named thread, everything else) in cores."""
    total = (after["total"] - before["total"]) / wall
    named = [(after.get(name, 0.0) - before.get(name, 0.0)) / wall for name in threads]
    return (total, *named, total - sum(named))


# ------------------------------------------------------------------------------ compare
def compare(args: argparse.Namespace) -> int:
    """The echo floor, then the nodes, each in a process of its own; the summary line last."""
    passed = [a for a in sys.argv[1:] if a != "--compare"]
    results = {}
    for label, extra in (("control", ["--control"]), ("nodes", [])):
        run = subprocess.run([sys.executable, __file__, *passed, *extra], capture_output=True, text=True)
        sys.stdout.write(run.stdout)
        sys.stderr.write(run.stderr)
        p99 = re.search(r"\| latency p99 \[ms\] \| ([0-9.]+) \|", run.stdout)
        drops = re.search(r"\| dropped samples \| (\d+) ", run.stdout)
        if run.returncode != 0 or p99 is None:
            print(f"the {label} run failed (status {run.returncode})", file=sys.stderr)
            return 1
        load = re.search(r"\| load average \(1 min\) at start / end of the measurement \| ([0-9.]+) / ([0-9.]+)",
                         run.stdout)
        results[label] = (float(p99.group(1)), int(drops.group(1)) if drops else -1,
                          load.groups() if load else ("?", "?"))
    nodes, control = results["nodes"][0], results["control"][0]
    print(f"p99_ms={nodes:.3f} control_p99_ms={control:.3f} ratio={nodes / control:.2f} "
          f"drops={results['nodes'][1]} load_1min={results['control'][2][0]}..{results['nodes'][2][1]}")
    return 0


# ------------------------------------------------------------------------------ bench
def _probe_priority(priority: int) -> None:
    """Put the calling thread (and the threads it starts from now on) at SCHED_FIFO ``priority``; children not."""
    if priority:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
        except OSError as exc:
            raise SystemExit(f"--probe-fifo {priority}: {exc.strerror or exc} (needs CAP_SYS_NICE or ulimit -r)")


def main() -> int:
    args = parse_args()
    if args.compare and args.role == "bench":
        return compare(args)
    if args.role == "receiver":
        _probe_priority(args.probe_fifo)  # before rclpy starts the DDS threads, which inherit it
        receiver(args.out)
        return 0
    if args.role == "echo":
        echo()
        return 0
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")  # one BLAS thread, in the nodes too (set before the copy)
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(args.domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    env.pop("ROS_LOCALHOST_ONLY", None)
    os.environ.update(ROS_DOMAIN_ID=env["ROS_DOMAIN_ID"], ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")

    import numpy as np
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from okid_msgs.msg import IoSample

    checkout.add()
    from okid_ros.sim import lowpass_input, modal_structure, simulate

    dt = 1.0 / args.rate
    tmp = Path(tempfile.mkdtemp(prefix="okid_bench_"))
    overrides = tmp / "bench.yaml"
    overrides.write_text(
        f"/**:\n  ros__parameters:\n    sample_time_s: {dt!r}\n"
        f"okid_arx_identifier:\n  ros__parameters:\n    publish_rate_hz: {args.publish_rate!r}\n"
        f"    arx:\n      order: {args.order}\n      window_length: {args.window}\n"
        f"okid_modal_estimator:\n  ros__parameters:\n    realtime_priority: {args.realtime_priority}\n"
        f"    realization:\n      n_states: {args.states}\n"
        f"      worker: {args.worker}\n"
    )
    params = ["--ros-args", "--params-file", str(REPO / "config" / "okid.yaml"), "--params-file", str(overrides)]
    logs = {name: open(tmp / f"{name}.log", "w") for name in ("arx", "est", "receiver")}
    if args.control:
        nodes = [[sys.executable, "-c", "import time; time.sleep(1e9)"], [sys.executable, __file__, "--role", "echo"]]
    else:
        nodes = [[sys.executable, "-m", "okid_ros.nodes.arx_identifier_node", *params],
                 [sys.executable, "-m", "okid_ros.nodes.modal_estimator_node", *params]]
    procs = {
        "arx": subprocess.Popen(nodes[0], env=env, cwd=REPO, stdout=logs["arx"], stderr=subprocess.STDOUT),
        "est": subprocess.Popen(nodes[1], env=env, cwd=REPO, stdout=logs["est"], stderr=subprocess.STDOUT),
        "receiver": subprocess.Popen([sys.executable, __file__, "--role", "receiver", "--out", str(tmp / "rx.json"),
                                      "--probe-fifo", str(args.probe_fifo)],
                                     env=env, cwd=REPO, stdout=logs["receiver"], stderr=subprocess.STDOUT),
    }
    _probe_priority(args.probe_fifo)  # the publisher; the nodes started above keep ordinary scheduling
    try:
        return run_bench(args, procs, tmp, dt, np, rclpy, IoSample, Node, QoSProfile, ReliabilityPolicy,
                         lowpass_input, modal_structure, simulate)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in procs.values():
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
        for log in logs.values():
            log.close()


def run_bench(args, procs, tmp, dt, np, rclpy, IoSample, Node, QoSProfile, ReliabilityPolicy,
              lowpass_input, modal_structure, simulate) -> int:
    system = modal_structure([12.0, 35.0, 80.0], 0.02, 2, 2, dt, seed=3)
    warmup_s = 3.0 if args.control else (args.window + args.order) * dt + 15.0  # window, first model
    n = int((warmup_s + args.duration + 2.0) / dt)
    u = lowpass_input(n, 2, min(200.0, 0.4 / dt), dt, seed=1)
    y = simulate(system, u, seed=2)

    rclpy.init()
    node = Node("okid_bench_publisher")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
    publisher = node.create_publisher(IoSample, "/okid/io_sample", qos)
    deadline = time.monotonic() + 30.0
    while publisher.get_subscription_count() < (1 if args.control else 2):  # the nodes
        if time.monotonic() > deadline:
            print("the nodes did not subscribe /okid/io_sample within 30 s; logs in", tmp, file=sys.stderr)
            return 1
        time.sleep(0.1)
    time.sleep(2.0)  # the receiver's subscription of /okid/modal_states
    msgs = []
    t0_ns = (time.time_ns() // 1_000_000_000 + 1) * 1_000_000_000
    dt_ns = int(round(dt * 1e9))
    for k in range(n):
        msg = IoSample()
        stamp = t0_ns + k * dt_ns
        msg.header.stamp.sec, msg.header.stamp.nanosec = stamp // 1_000_000_000, stamp % 1_000_000_000
        msg.u = u[k].tolist()
        msg.y = y[k].tolist()
        msgs.append(msg)
    published = np.zeros(n, dtype=np.int64)
    cpu_before = cpu_after = None
    measure_from = None
    print(f"publishing {n} samples at {args.rate:g} Hz ({n * dt:.0f} s; "
          f"measuring the last {args.duration:g} s)", flush=True)
    start = time.monotonic_ns()
    clock = time.monotonic_ns
    for k in range(n):
        wait = start + k * dt_ns - clock()
        if wait > 0:
            time.sleep(wait * 1e-9)  # no busy wait: the publisher must not eat the nodes' CPU
        published[k] = clock()
        publisher.publish(msgs[k])
        if measure_from is None and k * dt >= warmup_s:
            measure_from = k
            cpu_before = {name: cpu_seconds(procs[name].pid) for name in ("arx", "est")}
            wait_before = {name: wait_seconds(procs[name].pid) for name in ("arx", "est")}
            harness_pids = (os.getpid(), procs["receiver"].pid)
            harness_before = sum(cpu_seconds(pid, children=False)["total"] for pid in harness_pids)
            load_before = os.getloadavg()[0]
            wall_before = time.monotonic()
    wall = time.monotonic() - wall_before
    cpu_after = {name: cpu_seconds(procs[name].pid) for name in ("arx", "est")}
    wait_after = {name: wait_seconds(procs[name].pid) for name in ("arx", "est")}
    harness_after = sum(cpu_seconds(pid, children=False)["total"] for pid in (os.getpid(), procs["receiver"].pid))
    harness = (harness_after - harness_before) / wall
    load_after = os.getloadavg()[0]
    time.sleep(2.0)
    node.destroy_node()
    rclpy.try_shutdown()
    procs["receiver"].send_signal(signal.SIGINT)
    procs["receiver"].wait(timeout=20)
    rx = json.loads((tmp / "rx.json").read_text())
    stamps = np.array(rx["stamps"], dtype=np.int64)
    arrivals = np.array(rx["arrivals"], dtype=np.int64)
    index = np.rint((stamps - t0_ns) / dt_ns).astype(np.int64)
    keep = (index >= measure_from) & (index < n)
    lat_ms = (arrivals[keep] - published[index[keep]]) * 1e-6
    expected = n - measure_from
    received = int(np.unique(index[keep]).size)
    models = sorted(set(rx["models"]))
    arx_total, arx_solve, arx_input, arx_rest = cpu_share(cpu_before["arx"], cpu_after["arx"], wall,
                                                          "okid_arx_solve", "okid_samples")
    est_total, est_real, est_input, est_rest = cpu_share(cpu_before["est"], cpu_after["est"], wall,
                                                         "okid_realize", "okid_samples")
    input_wait = {name: 1e3 * (wait_after[name].get("okid_samples", 0.0) - wait_before[name].get("okid_samples", 0.0))
                  / wall for name in ("arx", "est")}
    est_log = (tmp / "est.log").read_text()
    realize = [float(x) for x in re.findall(r"realized in ([0-9.]+) s", est_log)]
    np.savez(tmp / "latency.npz", index=index[keep], latency_ms=lat_ms, published_ns=published, t0_ns=t0_ns)
    print()
    if args.control:
        print(f"\nbench/dds_latency.py --control: rate {args.rate:g} Hz, a bare rclpy echo node instead of the "
              f"two okid nodes, measured {wall:.1f} s, {os.cpu_count()} cores")
    else:
        print(f"bench/dds_latency.py: rate {args.rate:g} Hz, p = 2, m = 2, q = {args.order}, window {args.window}, "
              f"ArxModel {args.publish_rate:g} Hz, states {'auto' if args.states == 0 else args.states}, "
              f"realization in a {args.worker}, "
              f"measured {wall:.1f} s, {os.cpu_count()} cores")
    print()
    print("| measure | value |")
    print("|---|---|")
    if lat_ms.size:
        q = np.percentile(lat_ms, [50, 90, 99, 99.9])
        print(f"| latency p50 [ms] | {q[0]:.3f} |")
        print(f"| latency p90 [ms] | {q[1]:.3f} |")
        print(f"| latency p99 [ms] | {q[2]:.3f} |")
        print(f"| latency p99.9 [ms] | {q[3]:.3f} |")
        print(f"| latency max [ms] | {lat_ms.max():.3f} |")
    print(f"| samples published (measured) | {expected} |")
    print(f"| ModalStates received | {received} |")
    print(f"| dropped samples | {expected - received} ({100 * (expected - received) / max(expected, 1):.3f} %) |")
    print(f"| CPU okid_arx_identifier [cores] | {arx_total:.3f} (solve thread {arx_solve:.3f}, "
          f"input thread {arx_input:.3f}, rest {arx_rest:.3f}) |")
    print(f"| CPU okid_modal_estimator [cores] | {est_total:.3f} "
          f"(realization worker {est_real:.3f}, input thread {est_input:.3f}, rest {est_rest:.3f}) |")
    if not args.control:
        print(f"| input threads waiting for a core [ms per s] | okid_arx_identifier {input_wait['arx']:.1f}, "
              f"okid_modal_estimator {input_wait['est']:.1f} |")
    first_id, last_id = (models[0], models[-1]) if models else ("-", "-")
    print(f"| models in use during the run | {len(models)} (ids {first_id}..{last_id}) |")
    for name, series in sorted(rx.get("callbacks", {}).items()):
        recent = series[-max(int(wall), 1):]  # about one diagnostics message per second measured
        if recent:
            print(f"| {name}: time in its input callback per message | mean {np.mean([a for a, _ in recent]):.0f} us, "
                  f"longest {max(b for _, b in recent):.1f} ms |")
    print(f"| CPU publisher + receiver (this benchmark) [cores] | {harness:.3f} |")
    print(f"| load average (1 min) at start / end of the measurement | {load_before:.2f} / {load_after:.2f} "
          f"({os.cpu_count()} cores) |")
    if realize:
        print(f"| realization time [s] | median {np.median(realize):.2f}, max {max(realize):.2f} "
              f"({len(realize)} models) |")
    print(f"\nlogs and per-sample latencies (latency.npz) in {tmp}")
    if not lat_ms.size:
        print("no ModalStates received", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
