#!/usr/bin/env python3
"""CPU time of output-only identification: two trees of okid_ros (and koma) called in turn on the same records.

Each method runs in its own worker process (this script again, ``--worker``), which loads the
records once and answers one call at a time with its CPU seconds (``time.process_time``, BLAS
1 thread). The driver warms every worker up on every record, then calls them in turn, record
by record, switching the order of the two trees every repeat, so that the machine's load falls
on both alike. Printed per record group: the median CPU seconds per call of each, and the
median and range of the per-call ratio new / base; the same for the wall time (what a user
waits: the new tree may use threads, :mod:`okid_ros.core.worker_threads`). Records: ``koma`` (the koma frame),
``subframe`` (the steel subframe's outputs), a simulated case of
:mod:`okid_bench.output_only_cases` with its seed, ``low-modes:0``, or a structure of
``--cases random`` or ``physical`` with its number, ``physical:2`` (a beam). ``--method``: the
okid_ros method both trees run (``okid-ssi-cov`` by default, or ``okid-ssi-cva``). The peers'
wrappers and block rows are those of ``bench/output_only.py``.

Usage::

    # base: git archive <commit> | tar -x -C BASE, with BASE/../shared the data (as this tree's)
    python bench/output_only_side_by_side.py --base BASE --records low-modes:0,low-modes:1 --repeat 8 --koma
    python bench/output_only_side_by_side.py --base BASE --method okid-ssi-cva --records physical:2,subframe --repeat 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _worker(tree: str, method: str) -> None:
    """Answer ``record`` lines on stdin with a JSON line of the call's CPU seconds."""
    sys.path[:0] = [tree, f"{tree}/bench"]
    from output_only import _koma, _subframe
    from output_only_peers import run_method

    from okid_bench.output_only_cases import output_only_case, random_case
    from okid_bench.physical_cases import physical_case
    from okid_ros.core.output_covariance import choose_block_rows, reference_channels

    records = {}
    print("ready", flush=True)
    for line in sys.stdin:
        name = line.strip()
        if name not in records:
            if name in ("koma", "subframe"):
                y, dt = (_koma if name == "koma" else _subframe)()[:2]
            else:
                kind, seed = name.rsplit(":", 1)
                structures = {"random": random_case, "physical": physical_case}
                case = structures[kind](int(seed)) if kind in structures else output_only_case(kind)
                y, dt = case.simulate(int(seed)), case.sample_time_s
            y = y - y.mean(axis=0)
            rows, _ = choose_block_rows(y, dt, n_references=reference_channels(y, 12).size, max_states=100)
            records[name] = (y, dt, rows)
        y, dt, rows = records[name]
        started, clock = time.process_time(), time.perf_counter()
        run_method(method, y, dt, rows, 100)
        print(json.dumps({"cpu": time.process_time() - started, "wall": time.perf_counter() - clock}), flush=True)


def _start(tree: str, method: str) -> subprocess.Popen:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    process = subprocess.Popen([sys.executable, __file__, "--worker", tree, method], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    if process.stdout.readline().strip() != "ready":
        raise SystemExit(f"worker {tree} {method} did not start")
    return process


def _call(process: subprocess.Popen, record: str) -> dict[str, float]:
    process.stdin.write(record + "\n")
    process.stdin.flush()
    return json.loads(process.stdout.readline())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--base", help="the other tree (its okid_ros and bench); required")
    parser.add_argument("--records", default="low-modes:0,low-modes:1,low-modes:2,low-modes:3,low-modes:4")
    parser.add_argument("--repeat", type=int, default=8)
    parser.add_argument("--koma", action="store_true", help="also koma (this tree's wrapper)")
    parser.add_argument("--method", default="okid-ssi-cov", choices=["okid-ssi-cov", "okid-ssi-cva"],
                        help="the okid_ros method both trees run")
    parser.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        _worker(*args.worker)
        return 0
    if not args.base:
        parser.error("--base is required")
    workers = {"base": _start(args.base, args.method), "new": _start(str(HERE.parent), args.method)}
    if args.koma:
        workers["koma"] = _start(str(HERE.parent), "koma")
    records = args.records.split(",")
    for record in records:
        for process in workers.values():
            _call(process, record)  # warm-up: the record loaded, the first call's imports
    times: dict[str, list[dict[str, float]]] = {name: [] for name in workers}
    for repeat in range(args.repeat):
        order = ["base", "new"] if repeat % 2 == 0 else ["new", "base"]
        for record in records:
            for name in order + (["koma"] if args.koma else []):
                times[name].append(_call(workers[name], record))
    for clock, what in (("cpu", "CPU"), ("wall", "wall")):
        ratios = [new[clock] / base[clock] for new, base in zip(times["new"], times["base"])]
        text = ", ".join(f"{name} {statistics.median(t[clock] for t in values):.3f}" for name, values in times.items())
        print(f"{args.records}: {text} s {what} per call (median of {len(ratios)}); new / base "
              f"{statistics.median(ratios):.2f} ({min(ratios):.2f}-{max(ratios):.2f})")
    for process in workers.values():
        process.stdin.close()
        process.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
