#!/usr/bin/env python3
"""What a real record's faults do to `identify`: drift, clipping, a dropout, an unmeasured harmonic, spikes.

The paper's structure (2 inputs low-passed at 15 Hz, 2 outputs, 3750 samples, its three modes
known) identified with the product's defaults, clean and with one fault of a real record added
to the same samples:

- ``drift``: a straight line rising by one output standard deviation over the record on both
  outputs (8-22 % of their variance);
- ``clipped``: output 0 clipped at 80 % of its peak (a sensor's range; 1-3 % of its samples);
- ``dropout``: output 1 at 0 over samples 1000-1599 (a loose cable), output 0 responding;
- ``hum``: a 20 Hz sinusoid in both outputs at half their spread, not in the inputs (mains, a
  machine's rotation);
- ``hum-gaps``: ``hum`` with 20 output samples dropped (NaN) at random, as a real acquisition
  drops them;
- ``spikes``: five samples of output 0, at random, 30 of its spreads off (glitches: interference,
  a telemetry bit error);
- ``level-shift``, ``level-shift-10``: one output's level stepping by 3 (10) of its spreads at a
  random sample and staying (a sensor re-zeroed, an amplifier's range switched);
- ``forced``: the same sinusoid in the inputs (a shaker's sine on its noise), the outputs its
  response: a harmonic the model must keep.

Per case over ``--seeds`` records: true modes found within 0.5 %, listed modes more than 2 % from
every true one (spurious), the frequency RMS error of the found ones, and how many records got
a warning naming the fault. Run it with ``PYTHONPATH`` at an older tree to compare (``checkout``).

Usage::

    python bench/record_faults.py                      # 10 seeds, about a minute
    python bench/record_faults.py --seeds 20 --out /tmp/faults.md [--force]
"""

from __future__ import annotations

import argparse
import sys

import blas_threads  # noqa: F401  (sets the BLAS threads before numpy loads)
import checkout

checkout.add()

import numpy as np  # noqa: E402

from okid_bench.report import add_output_options, print_table, refuse_existing  # noqa: E402
from okid_ros.core.pipeline import identify  # noqa: E402
from okid_ros.sim.inputs import lowpass_input  # noqa: E402
from okid_ros.sim.paper_model import paper_model  # noqa: E402
from okid_ros.sim.simulators import simulate_innovation  # noqa: E402

CASES = ("clean", "drift", "clipped", "dropout", "hum", "hum-gaps", "spikes", "level-shift", "level-shift-10", "forced")
#: A warning names the fault when it holds this word (none for the clean and forced records).
NAMED_BY = {"drift": "drifts", "clipped": "clipped", "dropout": "dropped out", "hum": "harmonic disturbance",
            "hum-gaps": "harmonic disturbance", "spikes": "jumps far beyond", "level-shift": "changes level",
            "level-shift-10": "changes level"}
#: The level shifts' sizes, in output standard deviations.
SHIFT_SPREADS = {"level-shift": 3.0, "level-shift-10": 10.0}
#: Output samples dropped in the ``hum-gaps`` record.
DROPPED = 20
HUM_HZ = 20.0


def _record(case: str, seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    truth = paper_model()
    dt = truth.sample_time_s
    u = lowpass_input(3750, 2, 15.0, dt, seed=seed)
    sine = np.sqrt(2.0) * np.sin(2 * np.pi * HUM_HZ * np.arange(u.shape[0]) * dt + 0.3)[:, None]
    if case == "forced":
        u = u + 0.5 * u.std(axis=0) * sine
    y, _ = simulate_innovation(truth, u, seed=seed + 1000)
    if case == "drift":
        y = y + np.linspace(0.0, 1.0, y.shape[0])[:, None] * y.std(axis=0).max()
    elif case == "clipped":
        level = 0.8 * np.abs(y[:, 0]).max()
        y = np.column_stack([np.clip(y[:, 0], -level, level), y[:, 1:]])
    elif case == "dropout":
        y = y.copy()
        y[1000:1600, 1] = 0.0
    elif case in ("hum", "hum-gaps"):
        y = y + 0.5 * y.std(axis=0) * sine
    if case == "spikes":
        rng = np.random.default_rng(seed)
        y = y.copy()
        y[rng.choice(np.arange(50, y.shape[0] - 50), 5, replace=False), 0] += 30 * y[:, 0].std()
    if case in SHIFT_SPREADS:
        rng = np.random.default_rng(seed)
        output, first = int(rng.integers(0, y.shape[1])), int(rng.integers(y.shape[0] // 10, 9 * y.shape[0] // 10))
        y = y.copy()
        y[first:, output] += SHIFT_SPREADS[case] * y[:, output].std()
    if case == "hum-gaps":
        rng = np.random.default_rng(seed)
        y[rng.choice(np.arange(100, y.shape[0] - 100), DROPPED, replace=False), rng.integers(0, 2)] = np.nan
    return u, y, dt


def _true_hz() -> np.ndarray:
    truth = paper_model()
    poles = np.linalg.eigvals(truth.A)
    hz = np.abs(np.log(poles[poles.imag > 0])) / (2 * np.pi * truth.sample_time_s)
    return np.sort(hz)


def _score(case: str, seeds: int) -> dict:
    true_hz = _true_hz()
    found, spurious, errors, named = 0, 0, [], 0
    for seed in range(seeds):
        u, y, dt = _record(case, seed)
        present = np.all(np.isfinite(y), axis=1)
        model = identify(u, y, dt, valid=None if present.all() else present)
        listed = np.array([m.frequency_hz for m in model.modes])
        for f in true_hz:
            near = listed[np.abs(listed / f - 1) <= 0.005] if listed.size else listed
            if near.size:
                found += 1
                errors.append(100 * (near[np.argmin(np.abs(near - f))] / f - 1))
        spurious += int(sum(np.all(np.abs(f / true_hz - 1) > 0.02) for f in listed))
        word = NAMED_BY.get(case)
        named += bool(word and any(word in w for w in model.warnings))
    rms = float(np.sqrt(np.mean(np.square(errors)))) if errors else float("nan")
    return {"case": case, "found": f"{found}/{len(true_hz) * seeds}", "spurious": spurious,
            "f_rms_pct": rms, "named": f"{named}/{seeds}" if case in NAMED_BY else "-"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10, help="records per case (default 10)")
    add_output_options(parser)
    args = parser.parse_args(argv)
    refuse_existing(parser, args)
    rows = (_score(case, args.seeds) for case in CASES)
    print_table(["case", "found", "spurious", "f RMS %", "warning names it"],
                ([row["case"], row["found"], row["spurious"], f"{row['f_rms_pct']:.3f}", row["named"]] for row in rows),
                args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
