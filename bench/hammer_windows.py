#!/usr/bin/env python3
"""Node 1's windows over impact-hammer records: refused beyond the condition bound (a cause named or not), or solved.

Node 1's service (:mod:`okid_ros.service.identification`) takes each record sample by sample and solves
its window at the snapshots given (the live fault rig's node 1: ARX order 20, window 800). Records: the
tests' hammer record (12 blows of 50 or 1e6 on the paper's structure over a force of 0.01 or exactly 0,
a snapshot twice a second), one blow (and a second on the other input 37 samples on) of 1e3 to 1e6 on the
paper's structure and on a 3-mode structure (0.8, 3, 9 Hz at 5 %, displacement outputs) with snapshots
every 3 samples from 30 before the blow to 900 after, one at node 1's defaults (ARX order 100, window
4000), and a low-passed record of the paper's structure with innovations of 1e-6. Columns: snapshots;
valid; refused beyond ``arx.max_condition_number`` naming a cause, naming none; and of the valid windows
beyond the bound (every 4th), node 2's chain (``identify_from_arx``) against the truth: models with an
unstable A or predictor, modes found within 3 % of a true frequency and missed, the median frequency and
damping errors. Run it on an older tree (``PYTHONPATH=OLD``) for the code before.

Usage::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python bench/hammer_windows.py          # ~2.5 min
"""

from __future__ import annotations

import warnings

import numpy as np

from okid_ros.core.pipeline import identify_from_arx
from okid_ros.core.statespace import spectral_radius
from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
from okid_ros.service.params import ARX_NODE, resolve_parameters
from okid_ros.sim import lowpass_input, paper_model, paper_modes, simulate_innovation, simulate_noisy
from okid_ros.sim.models import modal_structure

LIVE = {"arx.order": 20, "arx.window_length": 800}
PAPER = [(m["frequency_hz"], m["damping_ratio"]) for m in paper_modes()]
MODAL = [(0.8, 0.05), (3.0, 0.05), (9.0, 0.05)]


def _fixture(blow: float, quiet: float):
    """The hammer record of test_service_input_glitches: 12 blows on the paper's structure."""
    rng = np.random.default_rng(4)
    u = quiet * rng.standard_normal((4000, 2))
    u[rng.choice(np.arange(300, 3900), 12, replace=False), rng.integers(0, 2, 12)] += blow
    y, _ = simulate_innovation(paper_model(), u, seed=5)
    return u, y


def _single(kind: str, blow: float, both: bool, n: int = 2200, at: int = 1200):
    rng = np.random.default_rng(1007)
    u = 0.01 * rng.standard_normal((n, 2))
    u[at, 0] += blow
    if both:
        u[at + 37, 1] += blow
    if kind == "paper":
        return paper_model().sample_time_s, u, simulate_innovation(paper_model(), u, seed=7)[0]
    structure = modal_structure([0.8, 3.0, 9.0], 0.05, 2, 3, 0.01, seed=1, output="displacement", disturbance_std=0.05)
    return 0.01, u, simulate_noisy(structure, u, seed=7)


def records():
    """(name, sample time, u, y, node 1's parameters, snapshot samples or None: when due, truth modes)."""
    dt = paper_model().sample_time_s
    for blow in (50.0, 1e6):
        for quiet in (0.01, 0.0):
            yield (f"tests' hammer record, blows {blow:g}, force {quiet:g} between", dt, *_fixture(blow, quiet),
                   {**LIVE, "arx.min_window_fill": 0.25, "publish_rate_hz": 2.0}, None, PAPER)
    for kind, truth in (("paper", PAPER), ("3-mode", MODAL)):
        for blow in (1e3, 1e4, 1e5, 1e6):
            for both in (False, True):
                dt, u, y = _single(kind, blow, both)
                yield (f"{kind}: one blow of {blow:g}{' and one on input 1' if both else ''}", dt, u, y, LIVE,
                       range(1170, 2100, 3), truth)
    dt, u, y = _single("paper", 1e6, True, n=9000, at=4200)
    yield "paper: one blow of 1e6 and one on input 1, node 1's defaults", dt, u, y, {}, range(4150, 8500, 50), PAPER
    quiet = paper_model(1e-12)
    u = lowpass_input(3000, 2, 15.0, dt, seed=3)
    yield ("paper: low-passed inputs, innovations of 1e-6", dt, u, simulate_innovation(quiet, u, seed=4)[0], LIVE,
           range(900, 3000, 50), PAPER)


def _check(snapshot, service, dt: float, truth) -> tuple[bool, int, list[float], list[float]]:
    """Node 2's chain on a window: stable, modes missed, frequency and damping errors of those found."""
    uw, yw, _ = service.window_samples()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_from_arx(snapshot.fit, uw, yw, dt)
    stable = spectral_radius(model.A) < 1 and spectral_radius(model.A - model.A @ model.K @ model.C) < 1
    missed, df, dz = 0, [], []
    for f, z in truth:
        near = [mode for mode in model.modes if abs(mode.frequency_hz - f) < 0.03 * f]
        if not near:
            missed += 1
            continue
        best = min(near, key=lambda mode: abs(mode.frequency_hz - f))
        df.append(abs(best.frequency_hz - f) / f)
        dz.append(abs(best.damping_ratio - z) / z)
    return stable, missed, df, dz


def sweep(dt: float, u: np.ndarray, y: np.ndarray, over: dict, at, truth) -> dict:
    params = ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, {
        "sample_time_s": dt, "n_inputs": u.shape[1], "n_outputs": y.shape[1], **over}))
    service, row = ArxIdentificationService(params), {"snapshots": 0, "valid": 0, "named": 0, "unnamed": 0,
                                                      "checked": 0, "unstable": 0, "missed": 0, "df": [], "dz": []}
    at, beyond = (set(at) if at is not None else None), 0
    for k in range(u.shape[0]):
        service.push(k * dt, u[k], y[k])
        if not (service.due(k * dt) if at is None else k in at):
            continue
        snapshot = service.snapshot()
        row["snapshots"] += 1
        row["valid"] += snapshot.valid
        if snapshot.reason.startswith("unexcited window"):
            row["named" if ";" in snapshot.reason else "unnamed"] += 1
        elif snapshot.valid and snapshot.condition_number > params.max_condition_number:
            beyond += 1
            if beyond % 4 == 1:
                stable, missed, df, dz = _check(snapshot, service, dt, truth)
                row["checked"] += 1
                row["unstable"] += not stable
                row["missed"] += missed
                row["df"] += df
                row["dz"] += dz
    return row


def main() -> None:
    print("| record | snapshots | valid | refused beyond the bound, a cause named | none named | valid beyond the "
          "bound checked | unstable | modes found / missed | frequency error (median) | damping error (median) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, dt, u, y, over, at, truth in records():
        r = sweep(dt, u, y, over, at, truth)
        errors = (f"{np.median(r['df']):.1e} | {np.median(r['dz']):.1e}" if r["df"] else "- | -")
        print(f"| {name} | {r['snapshots']} | {r['valid']} | {r['named']} | {r['unnamed']} | {r['checked']} | "
              f"{r['unstable']} | {len(r['df'])} / {r['missed']} | {errors} |", flush=True)


if __name__ == "__main__":
    main()
