"""`okid-ros batch`: speed-up of 2 local workers, per-bag overhead, memory per worker, --plan of 1000 bags.

Run:  python bench/batch.py [--bags 20] [--duration 10] [--repeats 2] [--lengths 15 60 240] [--plan-bags 1000]

1. A campaign of ``--bags`` simulated bags (the paper-like structure of `okid-ros simulate`,
   ``--duration`` s each, ARX order 20, 500-row window, one model a second) is run by the CLI in
   a subprocess serially (``--workers 1``) and with ``--workers 2``, alternating, ``--repeats``
   times each, ``--force`` so every run does every bag; wall time of the whole command (start,
   imports, discovery, tables). Reported: median wall times and the speed-up (target >= 1.6x),
   and the per-bag overhead: (workers x wall - sum of the time process_bag itself took) / bags,
   i.e. everything a bag costs beyond its own processing (command start and imports shared out,
   metadata, temporary folder, reading back the shapes, result file, rename, journal, tables).
   Since the machine is shared, also an idle-core model of each run's wall time from CPU times
   alone: the run's CPU time outside the bag jobs (command start, pool, tables), plus the
   makespan of the bag jobs' CPU times given in order to the first free of N idle cores.
2. Peak RSS of one worker against the bag's length: each of ``--lengths`` bags is processed by
   ``run_bag_job`` in a fresh Python process; its ru_maxrss is read by the parent.
3. ``okid-ros batch DIR --plan`` over ``--plan-bags`` bags (90 % rosbag2 directories, 10 % bare
   .mcap files, copies of one short bag), wall time of the command.

The machine is shared: the speed-up depends on the other load (printed: load average).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import checkout

REPO = Path(__file__).resolve().parents[1]
checkout.add("", "test")  # the repository first, then its test helpers (as before)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from batch_helpers import PARAMS, write_good_bag  # noqa: E402


def _cli(*args: object) -> float:
    """Wall time of `okid-ros ARGS` in a subprocess (exit status 0 required)."""
    return _cli_times(*args)[0]


def _cli_times(*args: object) -> tuple[float, float]:
    """Wall time and CPU time (user + system, the command and all its worker processes) of `okid-ros ARGS`."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "OPENBLAS_NUM_THREADS": "1"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "okid_ros.cli", *map(str, args)], env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"okid-ros {' '.join(map(str, args))} failed ({done.returncode}):\n{done.stderr}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _bag_cpu_seconds(out_dir: Path) -> list[float]:
    """CPU time of each bag's job (run_bag_job, in its worker), in campaign order of the folders."""
    return [json.loads(p.read_text())["cpu_s"] for p in sorted((out_dir / "bags").glob("*/result.json"))]


def _makespan(durations: list[float], workers: int) -> float:
    """Wall time of running ``durations`` in order on ``workers`` idle cores, each job to the first free one."""
    free = [0.0] * workers
    for duration in durations:
        free[free.index(min(free))] += duration
    return max(free)


def _process_seconds(out_dir: Path) -> float:
    """Sum of process_bag's own time over the bags of a campaign directory."""
    total = 0.0
    for result in (out_dir / "bags").glob("*/result.json"):
        total += json.loads(result.read_text())["process_s"]
    return total


def speed(root: Path, n_bags: int, duration_s: float, repeats: int) -> None:
    bags = root / "bags"
    bags.mkdir()
    for i in range(n_bags):
        write_good_bag(bags / f"run_{i:03d}", i, duration_s)
    params = root / "params.yaml"
    params.write_text(PARAMS)
    walls: dict[int, list[float]] = {1: [], 2: []}
    cpus: dict[int, list[float]] = {1: [], 2: []}
    idle: dict[int, list[float]] = {1: [], 2: []}  # CPU-time model of the wall time on idle cores
    overheads: dict[int, list[float]] = {1: [], 2: []}
    for _ in range(repeats):
        for workers in (1, 2):
            out = root / f"out{workers}"
            load = os.getloadavg()[0]
            wall, cpu = _cli_times("batch", bags, "--params", params, "--out", out, "--workers", workers, "--force",
                                   "--no-progress")
            walls[workers].append(wall)
            cpus[workers].append(cpu)
            overheads[workers].append((workers * wall - _process_seconds(out)) / n_bags)
            bag_cpu = _bag_cpu_seconds(out)
            idle[workers].append(cpu - sum(bag_cpu) + _makespan(bag_cpu, workers))
            print(f"  run: --workers {workers}: wall {wall:.2f} s, CPU {cpu:.2f} s, load before {load:.2f}",
                  flush=True)
    same = (root / "out1" / "modes.parquet").read_bytes() == (root / "out2" / "modes.parquet").read_bytes()
    print(f"## {n_bags} bags of {duration_s:g} s, load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print("| engine | wall s (median) | runs | CPU s (median) | idle-core model s (median) "
          "| per-bag overhead s (median) |")
    print("|---|---|---|---|---|---|")
    for workers in (1, 2):
        print(f"| --workers {workers} | {statistics.median(walls[workers]):.2f} | "
              f"{', '.join(f'{w:.2f}' for w in walls[workers])} | {statistics.median(cpus[workers]):.2f} | "
              f"{statistics.median(idle[workers]):.2f} | {statistics.median(overheads[workers]):.3f} |")
    ratio = statistics.median(walls[1]) / statistics.median(walls[2])
    model = statistics.median(idle[1]) / statistics.median(idle[2])
    print(f"speed-up with 2 workers: measured {ratio:.2f}x, idle-core model {model:.2f}x (target >= 1.6x); "
          f"tables identical: {same}")
    started = time.perf_counter()
    _cli("batch", bags, "--params", params, "--out", root / "out1", "--no-progress")
    print(f"rerun with nothing changed: {time.perf_counter() - started:.2f} s")


_RSS_CHILD = """
import json, resource, sys
from okid_ros.tools.campaign.worker import BagJob, run_bag_job
from okid_ros.tools.process import load_node_parameters
arx, est = load_node_parameters([sys.argv[2]])
result = run_bag_job(BagJob(bag=sys.argv[1], display=sys.argv[1], label="b", out_dir=sys.argv[3],
                            arx_values=arx, est_values=est))
assert result["status"] == "ok", result["reason"]
print(json.dumps({"samples": result["samples"], "process_s": result["process_s"],
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def memory(root: Path, lengths: list[float]) -> None:
    params = root / "params.yaml"
    params.write_text(PARAMS)
    print("\n## peak RSS of one worker against the bag's length")
    print("| bag length s | samples | input MB | process s | peak RSS MB |")
    print("|---|---|---|---|---|")
    env = {**os.environ, "PYTHONPATH": str(REPO), "OPENBLAS_NUM_THREADS": "1"}
    for i, length in enumerate(lengths):
        bag = write_good_bag(root / f"long_{i}", i, length)
        size = sum(p.stat().st_size for p in bag.iterdir()) / 1e6
        done = subprocess.run([sys.executable, "-c", _RSS_CHILD, str(bag), str(params), str(root / f"mem_{i}")],
                              env=env, capture_output=True, text=True, check=True)
        child = json.loads(done.stdout.strip().splitlines()[-1])
        print(f"| {length:g} | {child['samples']} | {size:.1f} | {child['process_s']:.1f} | {child['rss_mb']:.0f} |")


def plan(root: Path, n_bags: int) -> None:
    source = write_good_bag(root / "tiny", 0, 0.5)
    bags = root / "plan"
    bags.mkdir()
    n_files = n_bags // 10
    for i in range(n_bags - n_files):
        shutil.copytree(source, bags / f"bag_{i:04d}")
    mcap = next(source.glob("*.mcap"))
    for i in range(n_files):
        shutil.copy(mcap, bags / f"file_{i:04d}.mcap")
    walls = [_cli("batch", bags, "--plan") for _ in range(3)]
    print(f"\n## --plan over {n_bags} bags ({n_bags - n_files} rosbag2 directories, {n_files} bare .mcap)")
    print(f"wall s of `okid-ros batch DIR --plan`: median {statistics.median(walls):.2f} "
          f"({', '.join(f'{w:.2f}' for w in walls)}); target <= 10 s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bags", type=int, default=20)
    parser.add_argument("--duration", type=float, default=10.0, help="seconds per bag (default 10)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--lengths", type=float, nargs="+", default=[15.0, 60.0, 240.0])
    parser.add_argument("--plan-bags", type=int, default=1000)
    parser.add_argument("--skip", nargs="*", default=[], choices=("speed", "memory", "plan"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="okid_batch_bench_") as tmp:
        root = Path(tmp)
        if "speed" not in args.skip:
            (root / "speed").mkdir()
            speed(root / "speed", args.bags, args.duration, args.repeats)
        if "memory" not in args.skip:
            (root / "memory").mkdir()
            memory(root / "memory", args.lengths)
        if "plan" not in args.skip:
            (root / "planning").mkdir()
            plan(root / "planning", args.plan_bags)
    print(f"\nbench children peak RSS: {resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
