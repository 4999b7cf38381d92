#!/usr/bin/env python3
"""Glitches and node 2's estimator: its modal coordinates on a glitched record against the clean record's.

Run:  PYTHONPATH=.:bench .venv/bin/python bench/estimator_glitches.py [--seeds 5 6 7] [--repeats 7]

A glitch is one sample of an output far off (interference, a telemetry bit error): here ten
samples of output 0, 30 output spreads off, placed at random (``--seeds``) after the part of the
record the model is identified from. Two records: the paper's structure (2 outputs, 125 Hz,
20000 samples, the model of samples 0-3749 at ARX order 50) and the DaISy steel subframe
(28 outputs, 8523 samples, ``../shared/data/real/daisy-steel-subframe``, the model of samples
0-5999 at ARX order 20, no refinement: 122 states). The estimator
(:class:`okid_ros.core.estimator.ModalStateEstimator`) runs over the whole record from zero, on
the clean and on the glitched record, with the glitch rule (:mod:`okid_ros.core.glitches`) and
without it (``reject_glitches=False``: the filter of before the thirty-fourth session, the same
operations). Compared after the model's part: the RMS of the modal coordinates' error over
their RMS, the worst mode's (each mode's error over its own RMS), the largest error in the 200
samples after a glitch over the RMS (median and largest over the seeds), and the glitches
counted (a glitch not counted is taken as an event: the filter without the rule). Then the per-sample cost of
``step`` on the steel subframe's samples after 0-5999 with and without the rule (alternated,
one BLAS thread; the best and the median of ``--repeats`` runs).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as in the nodes (before numpy is imported)

import numpy as np  # noqa: E402

from okid_ros.core.arx import fit_arx  # noqa: E402
from okid_ros.core.estimator import ModalStateEstimator  # noqa: E402
from okid_ros.core.pipeline import identify_from_arx  # noqa: E402
from okid_ros.sim.inputs import lowpass_input  # noqa: E402
from okid_ros.sim.paper_model import paper_model  # noqa: E402
from okid_ros.sim.simulators import simulate_innovation  # noqa: E402

REAL_RECORD = Path(__file__).resolve().parents[2] / "shared/data/real/daisy-steel-subframe/steel_subframe.npz"
AFTER = 200  # samples after a glitch whose largest error is reported


def records() -> list[tuple[str, object, np.ndarray, np.ndarray, int]]:
    """``(name, model, u, y, fit)`` of the two records (``fit``: the model's samples)."""
    truth = paper_model()
    u = lowpass_input(20_000, 2, 15.0, truth.sample_time_s, seed=1)
    y, _ = simulate_innovation(truth, u, seed=2)
    out = [("paper structure", identify_from_arx(fit_arx(u[:3750], y[:3750], 50, center=True), u[:3750], y[:3750],
                                                 truth.sample_time_s), u, y, 3750)]
    data = np.load(REAL_RECORD)
    u, y, dt = data["u"], data["y"], float(data["sample_time_s"])
    model = identify_from_arx(fit_arx(u[:6000], y[:6000], 20, center=True), u[:6000], y[:6000], dt, refine=False)
    return [*out, ("steel subframe", model, u, y, 6000)]


def compare(model, u: np.ndarray, y: np.ndarray, fit: int, seed: int, reject: bool) -> tuple[float, float, float, int]:
    """The glitched record's modal coordinates against the clean one's.

    Returns (RMS error / RMS, worst mode's, largest error after a glitch / RMS, glitches counted).
    """
    rng = np.random.default_rng(seed)
    glitches = np.sort(rng.choice(np.arange(fit + 50, u.shape[0] - AFTER, 5), 10, replace=False))
    glitched = y.copy()
    glitched[glitches, 0] += 30 * y[:, 0].std()
    clean = ModalStateEstimator.from_model(model, reject_glitches=reject).run(u, y).modal_coordinates[fit:]
    est = ModalStateEstimator.from_model(model, reject_glitches=reject)
    error = est.run(u, glitched).modal_coordinates[fit:] - clean
    rms = np.sqrt(np.mean(clean ** 2))
    modes = np.sqrt(np.mean(error ** 2, axis=(0, 2)) / np.mean(clean ** 2, axis=(0, 2)))
    after = max(float(np.abs(error[k - fit:k - fit + AFTER]).max()) for k in glitches) / rms
    return float(np.sqrt(np.mean(error ** 2)) / rms), float(modes.max()), after, est.glitches


def step_cost(model, u: np.ndarray, y: np.ndarray, repeats: int) -> dict[bool, list[float]]:
    """Microseconds per ``step`` with (True) and without the rule, alternated."""
    times: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(repeats):
        for reject in (False, True):
            est = ModalStateEstimator.from_model(model, reject_glitches=reject)
            start = time.perf_counter()
            for k in range(u.shape[0]):
                est.step(u[k], y[k])
            times[reject].append((time.perf_counter() - start) / u.shape[0] * 1e6)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(10)), help="glitch placements (0-9)")
    parser.add_argument("--repeats", type=int, default=7, help="timed runs of step per code (default 7)")
    args = parser.parse_args()
    print(f"bench/estimator_glitches.py: ten glitches of 30 output spreads in output 0, seeds {args.seeds}, "
          f"load average (1 min) {os.getloadavg()[0]:.2f}\n")
    print("| record | rule | RMS error / RMS: median, largest over the seeds | worst mode: median | "
          "largest error after a glitch / RMS: median | glitches counted | seeds with all counted |")
    print("|---|---|---|---|---|---|---|")
    steel = None
    for name, model, u, y, fit in records():
        for reject in (False, True):
            rows = np.array([compare(model, u, y, fit, seed, reject) for seed in args.seeds])
            print(f"| {name} | {'on' if reject else 'off'} | {np.median(rows[:, 0]):.2g}, {rows[:, 0].max():.2g} | "
                  f"{np.median(rows[:, 1]):.2g} | {np.median(rows[:, 2]):.3g} | {int(rows[:, 3].sum())} of "
                  f"{10 * len(args.seeds)} | {int(np.sum(rows[:, 3] == 10))} of {len(args.seeds)} |")
        steel = (model, u[fit:], y[fit:])
    times = step_cost(*steel, args.repeats)
    print(f"\nstep on the steel subframe ({steel[0].n_outputs} outputs, {steel[0].n_states} states), "
          f"{steel[1].shape[0]} samples, {args.repeats} runs each [us per sample]:")
    for reject in (False, True):
        print(f"  rule {'on ' if reject else 'off'}: best {min(times[reject]):.1f}, "
              f"median {statistics.median(times[reject]):.1f}")


if __name__ == "__main__":
    main()
