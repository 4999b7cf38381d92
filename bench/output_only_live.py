#!/usr/bin/env python3
"""Compute per model update of the live output-only nodes (n_inputs 0) on a real record.

The steel subframe's 28 accelerations at 1024 Hz (``../shared/data/real/daisy-steel-subframe``,
the shaker forces not used), a window of ``--window`` samples, the parameters of
``config/okid_output_only.yaml`` (node 1's VAR of order 10). For windows ending at several
points of the record, each part of one model update is timed as the nodes run it (the service
functions the nodes call, no DDS):

* ``node 1 solve``: node 1's snapshot of its VAR window (:meth:`ArxIdentificationService.snapshot`,
  the solve of its normal equations; its thread ``okid_arx_solve``);
* ``identify``: the realization proper, :func:`okid_ros.core.output_only.identify_output_only`
  on the window's outputs (node 2's worker process), wall time and, in brackets, the CPU
  time of this process (what the update costs when other processes share the cores);
* ``checks + warm start``: the rest of :func:`okid_ros.service.realization.realize` (stability
  checks, whitening, the new predictor run over the window);
* ``update``: node 2's worker total (``realize``), the compute per update that bounds the model rate;

and the per-sample estimator step (:class:`okid_ros.core.estimator.ModalStateEstimator`) of
the resulting model against the sample period. ``--profile`` adds the top functions of one
``identify_output_only`` call by cumulative time (what bounds it).

Usage::

    OPENBLAS_NUM_THREADS=1 python bench/output_only_live.py                   # 6000 samples, 4 windows
    OPENBLAS_NUM_THREADS=1 python bench/output_only_live.py --window 8000 --profile
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from pathlib import Path

import blas_threads  # noqa: F401  (sets the BLAS threads before numpy loads)
import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
RECORD = DATA / "real" / "daisy-steel-subframe" / "steel_subframe.npz"


def _services(p: int, dt: float, window: int):
    from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams
    from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, resolve_parameters

    values = {"sample_time_s": dt, "n_inputs": 0, "n_outputs": p}
    arx = resolve_parameters(ARX_NODE, {**values, "arx.order": 10, "arx.window_length": window})
    est = resolve_parameters(ESTIMATOR_NODE, values)
    return ArxIdentificationParams.from_parameters(arx), ModalEstimationParams.from_parameters(est)


def time_update(y: np.ndarray, dt: float, end: int, window: int) -> dict:
    """Seconds of each part of the model update of the window ending at sample ``end``."""
    from okid_ros.core.output_only import identify_output_only
    from okid_ros.service.identification import ArxIdentificationService
    from okid_ros.service.realization import realize
    from okid_ros.service.results import RealizationJob

    arx_params, est_params = _services(y.shape[1], dt, window)
    q = arx_params.order
    node1 = ArxIdentificationService(arx_params)
    start = end - window - q
    t0 = time.perf_counter()
    for k in range(start, end):
        node1.push(k * dt, np.zeros(0), y[k])
    push_us = 1e6 * (time.perf_counter() - t0) / (end - start)
    t0 = time.perf_counter()
    snapshot = node1.snapshot()
    solve = time.perf_counter() - t0
    y_w = y[start:end]
    job = RealizationJob(snapshot.fit, 1, (end - 1) * dt, np.zeros((y_w.shape[0], 0)), y_w, end - 1, est_params, 0)
    t0, c0 = time.perf_counter(), time.process_time()
    model = identify_output_only(y_w, dt)
    identify, identify_cpu = time.perf_counter() - t0, time.process_time() - c0
    t0 = time.perf_counter()
    outcome = realize(job)
    update = time.perf_counter() - t0
    if outcome.model is None:
        raise SystemExit(f"window ending at {end}: {outcome.reason}")
    step = _step_time(outcome, y_w)
    return {"end": end, "solve": solve, "identify": identify, "update": update,
            "rest": update - outcome.realization_time_s, "n_states": model.n_states, "modes": len(model.modes),
            "step_us": 1e6 * step, "push_us": push_us, "identify_cpu": identify_cpu}


def _step_time(outcome, y_w: np.ndarray, n: int = 2000) -> float:
    """Median seconds of one estimator step over ``n`` samples of the window."""
    from okid_ros.core.estimator import ModalStateEstimator

    estimator = ModalStateEstimator.from_model(outcome.model)
    u = np.zeros(0)
    times = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        estimator.step(u, y_w[i])
        times[i] = time.perf_counter() - t0
    return float(np.median(times))


def profile(y: np.ndarray, dt: float, top: int = 14) -> str:
    from okid_ros.core.output_only import identify_output_only

    profiler = cProfile.Profile()
    profiler.enable()
    identify_output_only(y, dt)
    profiler.disable()
    text = io.StringIO()
    pstats.Stats(profiler, stream=text).sort_stats("cumulative").print_stats(top)
    return text.getvalue()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--window", type=int, default=6000, help="window [samples] (default: %(default)s)")
    parser.add_argument("--ends", type=int, default=4, help="windows timed, ending evenly over the record")
    parser.add_argument("--profile", action="store_true", help="top functions of one identify_output_only call")
    args = parser.parse_args(argv)
    record = np.load(RECORD)
    y, dt = np.asarray(record["y"], float), float(record["sample_time_s"])
    first = args.window + 10
    ends = np.linspace(first, y.shape[0], args.ends).astype(int)
    print(f"steel subframe: {y.shape[1]} outputs at {1 / dt:g} Hz, window {args.window} samples "
          f"({args.window * dt:.2f} s), node 1 VAR order 10, updates timed: {len(ends)}")
    print("| window end | node 1 solve [s] | identify_output_only [s] (CPU [s]) | checks + warm start [s] | "
          "update (node 2 worker) [s] | n | modes | estimator step [us] | node 1 per sample [us] |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    rows = []
    for end in ends:
        row = time_update(y, dt, int(end), args.window)
        rows.append(row)
        print(f"| {row['end']} | {row['solve']:.3f} | {row['identify']:.3f} ({row['identify_cpu']:.3f}) | "
              f"{row['rest']:.3f} | "
              f"{row['update']:.3f} | {row['n_states']} | {row['modes']} | {row['step_us']:.0f} | "
              f"{row['push_us']:.0f} |")
    keys = ("solve", "identify", "identify_cpu", "rest", "update", "step_us", "push_us")
    med = {k: float(np.median([r[k] for r in rows])) for k in keys}
    print(f"| median | {med['solve']:.3f} | {med['identify']:.3f} ({med['identify_cpu']:.3f}) | {med['rest']:.3f} | "
          f"{med['update']:.3f} | | | "
          f"{med['step_us']:.0f} | {med['push_us']:.0f} |")
    print(f"per sample: estimator {med['step_us']:.0f} us, node 1's window {med['push_us']:.0f} us; the sample "
          f"period is {1e6 * dt:.0f} us")
    if args.profile:
        print(profile(y[-args.window:], dt))
    return 0


if __name__ == "__main__":
    sys.exit(main())
