#!/usr/bin/env python3
"""Speed of the realization: ``okid-ros identify`` against the old code and one Hankel SVD.

Three cases (issue 17): the paper size (the published model, 2 inputs, 2 outputs, inputs
low-passed at 15 Hz, 3750 samples, ``--order 100``) and the steel subframe's samples 0-5999
(2 inputs, 28 outputs, ``--order 20``; ``../shared/data/real/daisy-steel-subframe``), the
latter also with identify's defaults (no ``--order``: the ARX order by GCV; the realization
and SVD columns then at the order it chose). ``--cases more-outputs`` adds a mid-size case:
the ``more-outputs`` benchmark structure (2 inputs, 6 accelerometers), 15000 samples, identify's
defaults, where the order search's least-squares refits are the cost. For each
case and each code version the command runs in a fresh worker process with one BLAS thread
(``python bench/realization_speed.py --worker``, with ``PYTHONPATH`` at that version's tree);
the worker times ``okid_ros.cli.main(["identify", ...])`` in-process (interpreter start and
imports excluded, one untimed warm-up run), then ``identify_from_arx`` alone on the record's ARX
fit (the realization: everything after the ARX fit, no JSON) and, in the same process, one SVD
of the case's weighted Hankel matrix (``scipy.linalg.svd`` of the size ``identify`` factors). Old and new
workers alternate, round after round; the table gives medians over all timed runs (the SVD's
pooled over the old and new workers of the case).

The old code is a checkout of the base commit (default ``main``'s merge base with this
branch), unpacked with ``git archive`` into a temporary directory, so it need not stay in the
product.

Usage::

    python bench/realization_speed.py                      # 3 rounds x 3 runs, ~2 min here
    python bench/realization_speed.py --rounds 5 --runs 3
    python bench/realization_speed.py --old-ref eb72dbe    # the base commit to compare with
    python bench/realization_speed.py --cases paper,more-outputs --old-ref HEAD~1
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"  # before numpy loads, here and in the workers

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
RECORD = REPO.parent / "shared" / "data" / "real" / "daisy-steel-subframe" / "steel_subframe.npz"
# name -> (label, ARX order; 0: identify's default, the order chosen by GCV)
CASES = {"paper": ("paper size: p = m = 2, N = 3750", 100), "subframe": ("steel subframe 0-5999: p = 28, m = 2", 20),
         "subframe-default": ("steel subframe 0-5999: p = 28, m = 2", 0),
         "more-outputs": ("more-outputs: p = 6, m = 2, N = 15000", 0)}


def _write_case_data(name: str, folder: Path) -> Path:
    """The case's record as an ``identify`` .npz (u, y, sample_time_s)."""
    path = folder / f"{name}.npz"
    if name == "paper":
        from okid_ros.sim.inputs import lowpass_input
        from okid_ros.sim.paper_model import paper_model
        from okid_ros.sim.simulators import simulate_innovation

        truth = paper_model()
        u = lowpass_input(3750, 2, 15.0, truth.sample_time_s, seed=3)
        y, _ = simulate_innovation(truth, u, seed=4)
        np.savez(path, u=u, y=y, sample_time_s=truth.sample_time_s)
    elif name == "more-outputs":  # a mid-size case: a few outputs, a long record (the refit's size)
        from identification_accuracy import simulate_record

        from okid_bench.cases import benchmark_case

        case = benchmark_case("more-outputs")
        u, y, _, _ = simulate_record(case, 15000, 0, 10)
        np.savez(path, u=u, y=y, sample_time_s=case.sample_time_s)
    else:  # the subframe cases
        data = np.load(RECORD)
        np.savez(path, u=data["u"][:6000], y=data["y"][:6000], sample_time_s=float(data["sample_time_s"]))
    return path


def _hankel_svd_seconds(data_path: Path, order: int, runs: int) -> tuple[float, float, tuple[int, int]]:
    """Median wall and CPU time of one SVD of the weighted Hankel matrix ``identify`` factors here."""
    from scipy import linalg

    from okid_ros.core.arx import fit_from_normal_equations, normal_equations
    from okid_ros.core.era import block_hankel, default_hankel_size
    from okid_ros.core.regressors import arx_regressors

    data = np.load(data_path)
    u, y = data["u"] - data["u"].mean(0), data["y"] - data["y"].mean(0)
    phi, targets, _ = arx_regressors(u, y, order)
    arx = fit_from_normal_equations(normal_equations(phi, targets), order, y.shape[1], u.shape[1], "ridge")
    rows, cols = default_hankel_size(arx.observer_markov.shape[0] - 1)
    h0 = block_hankel(arx.observer_markov, rows, cols)
    past = arx_regressors(u, y, cols)[0][:, u.shape[1]:]
    weight = linalg.cholesky(past.T @ past / past.shape[0] + 1e-10 * np.eye(past.shape[1]), lower=True)
    weighted = h0 @ weight
    times, cpu = [], []
    for _ in range(4 * runs + 1):  # milliseconds each: more repeats for a steady median
        start, start_cpu = time.perf_counter(), time.process_time()
        linalg.svd(weighted, full_matrices=False)
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return float(np.median(times[1:])), float(np.median(cpu[1:])), weighted.shape


def _worker(data_path: Path, order: int, runs: int) -> dict:
    """Time ``okid-ros identify`` in this process (the code on PYTHONPATH) and one Hankel SVD."""
    from okid_ros.cli import main

    out = Path(tempfile.mkdtemp(prefix="okid-speed-")) / "model.json"
    order_args = ["--order", str(order)] if order else []  # 0: the ARX order by GCV, as identify's default
    argv = ["identify", str(data_path), *order_args, "--json", str(out), "--force"]
    times = []
    for i in range(runs + 1):
        start = time.perf_counter()
        status = main(argv)
        elapsed = time.perf_counter() - start
        if status != 0:
            raise SystemExit(f"identify failed with status {status}")
        if i:
            times.append(elapsed)
    model = json.loads(out.read_text())
    order = order or int(model["arx_order"])  # the SVD and the realization at the order identify chose
    svd_s, svd_cpu_s, shape = _hankel_svd_seconds(data_path, order, runs)
    realization_s, realization_cpu_s = _realization_seconds(data_path, order, runs)
    return {"identify_s": times, "realization_s": realization_s, "realization_cpu_s": realization_cpu_s,
            "svd_s": svd_s, "svd_cpu_s": svd_cpu_s, "hankel_shape": list(shape), "n_states": model["n_states"],
            "modes": len(model["modes"])}


def _realization_seconds(data_path: Path, order: int, runs: int) -> tuple[list[float], list[float]]:
    """Wall and CPU times of ``identify_from_arx`` alone (the realization, without the ARX fit and the JSON).

    The CPU time of this one-threaded process is what the load of other jobs on the machine
    changes least (they stretch the wall time by waiting for a core).
    """
    from okid_ros.core.arx import fit_from_normal_equations, normal_equations
    from okid_ros.core.pipeline import identify_from_arx
    from okid_ros.core.regressors import arx_regressors

    data = np.load(data_path)
    u, y, dt = data["u"], data["y"], float(data["sample_time_s"])
    phi, targets, _ = arx_regressors(u, y, order)
    arx = fit_from_normal_equations(normal_equations(phi, targets), order, y.shape[1], u.shape[1], "ridge",
                                    center=True)
    times, cpu = [], []
    for i in range(runs + 1):
        start, start_cpu = time.perf_counter(), time.process_time()
        identify_from_arx(arx, u, y, dt)
        if i:
            times.append(time.perf_counter() - start)
            cpu.append(time.process_time() - start_cpu)
    return times, cpu


def _old_tree(ref: str) -> Path:
    folder = Path(tempfile.mkdtemp(prefix="okid-base-"))
    archive = subprocess.run(["git", "-C", str(REPO), "archive", ref], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder


def _run_worker(tree: Path, data_path: Path, order: int, runs: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", str(data_path), "--order", str(order),
           "--runs", str(runs)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"worker failed ({tree}): {done.stderr.strip().splitlines()[-1:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _table(results: dict) -> str:
    lines = [
        "| case | Hankel | code | states | modes | identify s (median) | one Hankel SVD s | identify / SVD "
        "| speed-up | realization s | realization / SVD | speed-up | realization CPU s | SVD CPU s "
        "| realization / SVD (CPU) | speed-up (CPU) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, runs in results.items():
        label, order = CASES[name]
        old, new = runs["old"], runs["new"]
        old_t, new_t = np.median(old["identify_s"]), np.median(new["identify_s"])
        old_r, new_r = np.median(old["realization_s"]), np.median(new["realization_s"])
        old_c, new_c = (np.median(res.get("realization_cpu_s") or [np.nan]) for res in (old, new))
        svd = np.median(old["svd_s"] + new["svd_s"])  # the same matrix: pooled over all workers
        svd_cpu = np.median(old.get("svd_cpu_s", []) + new.get("svd_cpu_s", []) or [np.nan])
        for code, res, t, r, c in (("old", old, old_t, old_r, old_c), ("new", new, new_t, new_r, new_c)):
            shape = "x".join(str(s) for s in res["hankel_shape"][0])
            speed = "" if code == "old" else f"{old_t / t:.1f}x"
            speed_r = "" if code == "old" else f"{old_r / r:.1f}x"
            speed_c = "" if code == "old" else f"{old_c / c:.1f}x"
            option = f"--order {order}" if order else "no --order (ARX order by GCV)"
            lines.append(f"| {label}, {option} | {shape} | {code} | {res['n_states'][0]} | {res['modes'][0]} | "
                         f"{t:.3f} | {svd:.4f} | {t / svd:.0f} | {speed} | {r:.3f} | {r / svd:.0f} | {speed_r} "
                         f"| {c:.3f} | {svd_cpu:.4f} | {c / svd_cpu:.0f} | {speed_c} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--order", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--runs", type=int, default=3, help="timed runs per worker (default 3, plus one warm-up)")
    ap.add_argument("--rounds", type=int, default=3, help="old/new worker pairs per case (default 3)")
    ap.add_argument("--old-ref", default=None, help="git ref of the old code (default: merge base with main)")
    ap.add_argument("--cases", default="paper,subframe,subframe-default",
                    help=f"comma-separated, of {','.join(CASES)} (default: the first three)")
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(_worker(Path(args.worker), args.order, args.runs)))
        return
    ref = args.old_ref or subprocess.run(["git", "-C", str(REPO), "merge-base", "HEAD", "main"], check=True,
                                         capture_output=True, text=True).stdout.strip()
    old_tree = _old_tree(ref)
    folder = Path(tempfile.mkdtemp(prefix="okid-speed-data-"))
    results: dict = {}
    for name in args.cases.split(","):
        _, order = CASES[name]
        data_path = _write_case_data(name, folder)
        runs = {"old": {}, "new": {}}
        for _ in range(args.rounds):
            for code, tree in (("old", old_tree), ("new", REPO)):
                res = _run_worker(tree, data_path, order, args.runs)
                slot = runs[code]
                slot.setdefault("identify_s", []).extend(res["identify_s"])
                slot.setdefault("realization_s", []).extend(res["realization_s"])
                slot.setdefault("realization_cpu_s", []).extend(res["realization_cpu_s"])
                slot.setdefault("svd_s", []).append(res["svd_s"])
                slot.setdefault("svd_cpu_s", []).append(res["svd_cpu_s"])
                for key in ("hankel_shape", "n_states", "modes"):
                    slot.setdefault(key, []).append(res[key])
            print(f"{name}: old {np.median(runs['old']['identify_s']):.3f} s, new "
                  f"{np.median(runs['new']['identify_s']):.3f} s", file=sys.stderr)
        results[name] = runs
    print(f"Old code: {ref[:12]} (git archive); new: {REPO} working tree. One BLAS thread; "
          f"{args.rounds} rounds x {args.runs} timed runs per code version, alternating; medians. "
          f"Load average at the end: {os.getloadavg()[0]:.2f}.\n")
    print(_table(results))


if __name__ == "__main__":
    main()
