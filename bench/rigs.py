"""N rigs on one machine over DDS: CPU per rig, p99 latency and drops (each rig in its namespace).

Run:  .venv/bin/python bench/rigs.py [--rigs 1 2 4] [--duration 15] [--rate 1000]

For each N: starts N pairs of nodes (`okid-ros up --namespace /rigI`, the shipped defaults with
the sample time 1/rate: p = m = 2, q = 100, window 4000 rows, a model per second), a receiver
process subscribing every ``/rigI/modal_states``, and publishes ``/rigI/io_sample`` at ``--rate``
for every rig from this process (a 3-mode structure, stamps on the grid, each rig its own
seed). Once every rig has a model it measures ``--duration`` seconds: per rig the latency from
the publish call to the arrival of its ModalStates (matched by stamp), the samples without one
(dropped), and the CPU of the rig's two node processes with their workers. Prints a markdown
table, one row per N (the worst rig's p99 and drops, the mean CPU per rig).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import signal
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


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rigs", type=int, nargs="+", default=[1, 2, 4], help="rig counts (default 1 2 4)")
    parser.add_argument("--duration", type=float, default=15.0, help="measured seconds per N (default 15)")
    parser.add_argument("--rate", type=float, default=1000.0, help="samples per second per rig (default 1000)")
    parser.add_argument("--domain", type=int, default=58, help="ROS_DOMAIN_ID (default 58)")
    parser.add_argument("--role", default="bench", choices=("bench", "receiver"), help=argparse.SUPPRESS)
    parser.add_argument("--topics", nargs="*", default=[], help=argparse.SUPPRESS)
    parser.add_argument("--out", default="", help=argparse.SUPPRESS)
    return parser.parse_args()


def receiver(topics: list[str], out: str) -> None:
    """Subscribe each topic; on SIGINT write {topic: [[stamp ns, arrival ns], ...]}."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from okid_msgs.msg import ModalStates

    rclpy.init()
    node = Node("okid_rigs_receiver")
    got: dict[str, list] = {t: [] for t in topics}
    clock = time.monotonic_ns
    for topic in topics:
        def on_states(msg, store=got[topic]) -> None:
            store.append((msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec, clock()))
        node.create_subscription(ModalStates, topic, on_states,
                                 QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE))
    print("receiver ready", flush=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    Path(out).write_text(json.dumps(got))
    rclpy.try_shutdown()


def run_n(args: argparse.Namespace, n_rigs: int, env: dict, tmp: Path) -> dict:
    import numpy as np
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from okid_msgs.msg import IoSample
    from okid_ros.sim import lowpass_input, modal_structure, simulate

    dt = 1.0 / args.rate
    overrides = tmp / "rigs.yaml"
    overrides.write_text(f"/**:\n  ros__parameters:\n    sample_time_s: {dt!r}\n")
    rigs = [f"/rig{i + 1}" for i in range(n_rigs)]
    logs = [open(tmp / f"up{n_rigs}_{i}.log", "w") for i in range(n_rigs)]
    ups = [subprocess.Popen([sys.executable, "-m", "okid_ros.cli", "up", "--namespace", ns, "--params",
                             str(REPO / "config" / "okid.yaml"), "--params", str(overrides)],
                            env=env, cwd=REPO, stdout=log, stderr=subprocess.STDOUT) for ns, log in zip(rigs, logs)]
    rx_out = tmp / f"rx{n_rigs}.json"
    rx = subprocess.Popen([sys.executable, __file__, "--role", "receiver", "--out", str(rx_out),
                           "--topics", *[f"{ns}/modal_states" for ns in rigs]], env=env, cwd=REPO,
                          stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    try:
        system = modal_structure([12.0, 35.0, 80.0], 0.02, 2, 2, dt, seed=3)
        warmup_s = (4000 + 100) * dt + 15.0 + 3.0 * n_rigs
        n = int((warmup_s + args.duration + 2.0) / dt)
        data = []
        for i in range(n_rigs):
            u = lowpass_input(n, 2, min(200.0, 0.4 / dt), dt, seed=10 + i)
            data.append((u, simulate(system, u, seed=20 + i)))
        rclpy.init()
        node = Node("okid_rigs_publisher")
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
        pubs = [node.create_publisher(IoSample, f"{ns}/io_sample", qos) for ns in rigs]
        deadline = time.monotonic() + 60.0
        while any(p.get_subscription_count() < 2 for p in pubs):
            if time.monotonic() > deadline:
                raise RuntimeError(f"the rigs did not subscribe within 60 s; logs in {tmp}")
            time.sleep(0.1)
        time.sleep(2.0)
        t0_ns = (time.time_ns() // 1_000_000_000 + 1) * 1_000_000_000
        dt_ns = int(round(dt * 1e9))
        msgs = []
        for u, y in data:
            rig_msgs = []
            for k in range(n):
                msg = IoSample()
                stamp = t0_ns + k * dt_ns
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
                msg.u, msg.y = u[k].tolist(), y[k].tolist()
                rig_msgs.append(msg)
            msgs.append(rig_msgs)
        published = np.zeros(n, dtype=np.int64)
        measure_from = None
        clock = time.monotonic_ns
        start = clock()
        for k in range(n):
            wait = start + k * dt_ns - clock()
            if wait > 0:
                time.sleep(wait * 1e-9)
            published[k] = clock()
            for pub, rig_msgs in zip(pubs, msgs):
                pub.publish(rig_msgs[k])
            if measure_from is None and k * dt >= warmup_s:
                measure_from = k
                nodes_pids = [[c for c in dds_latency._children(up.pid)] for up in ups]
                cpu_before = [sum(dds_latency.cpu_seconds(p)["total"] for p in pids) for pids in nodes_pids]
                wall_before = time.monotonic()
                load_before = os.getloadavg()[0]
        wall = time.monotonic() - wall_before
        cpu_after = [sum(dds_latency.cpu_seconds(p)["total"] for p in pids) for pids in nodes_pids]
        load_after = os.getloadavg()[0]
        time.sleep(2.0)
        node.destroy_node()
        rclpy.try_shutdown()
        rx.send_signal(signal.SIGINT)
        rx.wait(timeout=30)
        got = json.loads(rx_out.read_text())
        p99, drops = [], []
        expected = n - measure_from
        for ns in rigs:
            pairs = np.array(got[f"{ns}/modal_states"], dtype=np.int64).reshape(-1, 2)
            index = np.rint((pairs[:, 0] - t0_ns) / dt_ns).astype(np.int64)
            keep = (index >= measure_from) & (index < n)
            lat = (pairs[keep, 1] - published[index[keep]]) * 1e-6
            p99.append(float(np.percentile(lat, 99)) if lat.size else float("nan"))
            drops.append(expected - int(np.unique(index[keep]).size))
        cpu = [(a - b) / wall for a, b in zip(cpu_after, cpu_before)]
        return {"n": n_rigs, "cpu_per_rig": float(np.mean(cpu)), "p99_ms": max(p99), "p99_each": p99,
                "drops": max(drops), "expected": expected, "load": (load_before, load_after)}
    finally:
        for up in ups:
            if up.poll() is None:
                up.send_signal(signal.SIGINT)
        for proc in (*ups, rx):
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
        for log in logs:
            log.close()


def main() -> int:
    args = parse_args()
    if args.role == "receiver":
        receiver(args.topics, args.out)
        return 0
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(args.domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    env.pop("ROS_LOCALHOST_ONLY", None)
    os.environ.update(ROS_DOMAIN_ID=env["ROS_DOMAIN_ID"], ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    checkout.add()
    tmp = Path(tempfile.mkdtemp(prefix="okid_rigs_"))
    rows = [run_n(args, n, env, tmp) for n in args.rigs]
    print(f"\nbench/rigs.py: {args.rate:g} Hz per rig, p = m = 2, q = 100, window 4000, ArxModel 1 Hz, "
          f"measured {args.duration:g} s per N, {os.cpu_count()} cores\n")
    print("| rigs | CPU per rig [cores] | worst rig p99 [ms] | p99 per rig [ms] | worst rig drops "
          "| load avg start/end |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        each = ", ".join(f"{v:.2f}" for v in r["p99_each"])
        print(f"| {r['n']} | {r['cpu_per_rig']:.2f} | {r['p99_ms']:.2f} | {each} | {r['drops']} of {r['expected']} "
              f"| {r['load'][0]:.1f} / {r['load'][1]:.1f} |")
    print(f"\nlogs in {tmp}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
