#!/usr/bin/env python3
"""Both services over impact-hammer records of an unchanged structure: the structural changes they declare.

Twelve blows of 50 or 1e6 at random samples over a quiet force of 0.01 or exactly 0, on the paper's
structure (seed 4 is the record of ``test/service/test_service_input_glitches.py``), node 1 as the live
fault rig runs it (LIVE: order 20, window 800, valid from 200 rows, a solve twice a second) or with a
model every 250 samples; every change declared is a false one. Run it under a tree's ``PYTHONPATH``
to compare versions (one BLAS thread)::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD:$PWD/bench python bench/hammer_changes.py
"""

from __future__ import annotations

import numpy as np

from okid_bench.live_chain import run_pipeline
from okid_bench.scoring import modes_of
from okid_ros.sim import paper_model, simulate_innovation

NODE_1 = {
    "LIVE": {"arx.order": 20, "arx.window_length": 800, "arx.min_window_fill": 0.25, "publish_rate_hz": 2.0},
    "every 250": {"arx.order": 20, "arx.window_length": 800, "publish_rate_hz": 0.5},
}


def hammer_record(model, blow: float, quiet: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(u (4000, 2), y (4000, 2)): 12 blows of ``blow`` over a quiet force of spread ``quiet``."""
    rng = np.random.default_rng(seed)
    u = quiet * rng.standard_normal((4000, 2))
    u[rng.choice(np.arange(300, 3900), 12, replace=False), rng.integers(0, 2, 12)] += blow
    y, _ = simulate_innovation(model, u, seed=seed + 1)
    return u, y


def run_chain(model, u: np.ndarray, y: np.ndarray, arx: dict) -> tuple[dict, int, int]:
    """Node 2's diagnostics, its model updates and the true modes they list (0.5 %), over the record."""
    dt = model.sample_time_s
    pipeline, _ = run_pipeline(u, y, dt, arx)
    true_hz = np.array([mode.frequency_hz for mode in modes_of(model.A, dt)])
    found = 0
    for line in pipeline.updates:
        hz = np.array([mode["frequency_hz"] for mode in line["modes"]])
        found += sum(bool(hz.size and np.any(np.abs(hz - f) < 0.005 * f)) for f in true_hz)
    return pipeline.est.diagnostics(), len(pipeline.updates), found


def main() -> None:
    model = paper_model()
    print("| node 1 | blow | quiet force | seed | changes declared | divergence restarts "
          "| divergences beyond the window | model updates | true modes found |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, arx in NODE_1.items():
        for blow in (50.0, 1e6):
            for quiet in (0.01, 0.0):
                for seed in (4, 7):
                    u, y = hammer_record(model, blow, quiet, seed)
                    d, updates, found = run_chain(model, u, y, arx)
                    beyond = d.get("divergences_beyond_window", "-")  # not counted before
                    print(f"| {name} | {blow:g} | {quiet:g} | {seed} | {d['changes_detected']} "
                          f"| {d['divergence_restarts']} | {beyond} | {updates} | {found} |")


if __name__ == "__main__":
    main()
