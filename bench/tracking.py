"""Tracking a sudden 6 % frequency drop (an added mass) with `okid-ros track` (issue 4 item 4).

Run:  python bench/tracking.py [--seeds 0 1 2] [--offset 1] [--threads N]

The structure (``okid_bench.switching.added_mass_case``): modes at 1.8, 4.2, 7.9 Hz drop by
6 % in the middle of the record; 2 inputs, 3 accelerometers, 25 Hz. For each noise seed the
record is written to a temporary .npz and run through the `okid-ros track` command
(``--order 40 --window 4000 --every 250``, everything else at its defaults: ridge/GCV ARX, BIC
order search, refit and prediction-error refinement). The change is placed so that the first
update after it comes ``--offset`` samples after the change (default 1, the worst alignment
with the update grid: the last update no later than one window after the change is at
change + 3751, its window still holding 249 rows from before the change and the q = 40 lags of
the first new rows). The record runs one window plus 2000 samples past the change.

Per mode and seed: old/new true frequency, settling time after the change (the first update
from which on the frequency of the identified mode nearest to the new truth stays within
0.5 % of it for every later update) in samples and seconds, the largest error after settling,
and the largest error to the *old* truth before the change. Per seed also "clean": the first
update from which on the model lists exactly one mode per true mode (no mode of the old
structure left in the window, no spurious mode). Then, for the first seed, the trace of every
update: states of the model, modes listed, and the error of the nearest mode to each new true
frequency. The last line is the summary.
"""

from __future__ import annotations

import argparse
import os
import sys

import checkout

_parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
_parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="noise seeds (default 0 1 2)")
_parser.add_argument("--offset", type=int, default=1,
                     help="samples from the change to the first update after it, 0..249 (default 1)")
_parser.add_argument("--no-change-detection", action="store_true",
                     help="run track without structural change detection (the sliding window alone, as in issue 4)")
_parser.add_argument("--threads", type=int, default=1, help="BLAS threads (default 1)")
_args = _parser.parse_args()
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(_args.threads)

import contextlib  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

checkout.add()
from okid_bench.switching import added_mass_case, settling  # noqa: E402
from okid_ros.cli import main as okid_ros_main  # noqa: E402
from okid_ros.records import save_record  # noqa: E402

WINDOW, EVERY, TOLERANCE = 4000, 250, 0.005


def run_seed(case, seed: int, offset: int, workdir: Path) -> tuple[list, int, object, float, list]:
    q = case.arx_order
    first = WINDOW + q - 1  # first update: the window is full
    change = first + 6 * EVERY - offset  # 6 updates before the change, the 7th `offset` after it
    n_samples = change + WINDOW + 2000
    u, y = case.simulate(n_samples, change, seed)
    data, out = workdir / f"seed{seed}.npz", workdir / f"seed{seed}.jsonl"
    save_record(data, u, y, case.sample_time_s)
    started = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):  # the command's own summary lines
        status = okid_ros_main([
            "track", str(data), "--order", str(q), "--window", str(WINDOW), "--every", str(EVERY),
            "--jsonl", str(out), "--no-progress",
        ] + (["--no-change-detection"] if _args.no_change_detection else []))
    elapsed = time.perf_counter() - started
    if status != 0:
        raise SystemExit(f"okid-ros track failed on seed {seed} (status {status})")
    updates = [json.loads(line) for line in out.read_text().splitlines()]
    per_mode, clean = settling(updates, change, case.frequencies_hz, case.new_frequencies_hz, TOLERANCE)
    return per_mode, change, clean, elapsed, updates


def main() -> int:
    case = added_mass_case()
    dt = case.sample_time_s
    print(f"# {case.description}")
    print(f"# okid-ros track --order {case.arx_order} --window {WINDOW} --every {EVERY}; change "
          f"{_args.offset} sample(s) before an update; tolerance {100 * TOLERANCE:g} %; "
          f"limit one window = {WINDOW} samples = {WINDOW * dt:g} s")
    print()
    print("| seed | mode | old (Hz) | new (Hz) | settling (samples) | settling (s) | max error after settling (%) "
          "| max error to old truth before the change (%) |")
    print("|---|---|---|---|---|---|---|---|")
    worst, failures, cleans, rows, trace = 0, 0, [], [], None
    with tempfile.TemporaryDirectory() as tmp:
        for seed in _args.seeds:
            per_mode, change, clean, elapsed, updates = run_seed(case, seed, _args.offset, Path(tmp))
            n_updates = len(updates)
            if trace is None:
                trace = (seed, change, updates)
            for i, (old, mode) in enumerate(zip(case.frequencies_hz, per_mode)):
                if mode.settle_samples is None:
                    failures += 1
                    settle = "never"
                    settle_s = "-"
                else:
                    settle, settle_s = str(mode.settle_samples), f"{mode.settle_samples * dt:.1f}"
                    worst = max(worst, mode.settle_samples)
                    failures += mode.settle_samples > WINDOW
                print(f"| {seed} | {i + 1} | {old:.3f} | {mode.truth_hz:.3f} | {settle} | {settle_s} | "
                      f"{100 * mode.max_error_after:.3f} | {100 * mode.max_error_before:.3f} |")
            clean_samples = None if clean is None else clean - change
            cleans.append(clean_samples)
            rows.append((seed, change, n_updates, elapsed, clean_samples))
    print()
    print("| seed | change at sample | updates | track run (s) "
          "| clean: one mode per true mode from (samples after the change) |")
    print("|---|---|---|---|---|")
    for seed, change, n_updates, elapsed, clean_samples in rows:
        clean = clean_samples if clean_samples is not None else "never"
        print(f"| {seed} | {change} | {n_updates} | {elapsed:.1f} | {clean} |")
    print()
    seed, change, updates = trace
    print(f"trace of seed {seed}: error of the identified mode nearest to each new true frequency (%)")
    print()
    print("| update - change (samples) | states | modes listed | " + " | ".join(
        f"mode {i + 1} ({f:.3f} Hz)" for i, f in enumerate(case.new_frequencies_hz)) + " |")
    print("|---|---|---|" + "---|" * len(case.new_frequencies_hz))
    for entry in updates:
        freqs = np.array([m["frequency_hz"] for m in entry["modes"]])
        errors = [100 * (freqs[np.argmin(np.abs(freqs - f))] / f - 1) if freqs.size else float("nan")
                  for f in case.new_frequencies_hz]
        print(f"| {entry['sample_index'] - change} | {entry['n_states']} | {len(entry['modes'])} | "
              + " | ".join(f"{e:+.2f}" for e in errors) + " |")
    print()
    n_modes = len(_args.seeds) * len(case.frequencies_hz)
    clean = "never on some seed" if None in cleans else f"{max(cleans)} samples"
    print(f"summary: {n_modes - failures}/{n_modes} mode-seed pairs settled within {100 * TOLERANCE:g} % no later "
          f"than one window ({WINDOW} samples) after the change; worst settling {worst} samples "
          f"({worst * dt:.1f} s); one mode per true mode from at most {clean} after the change")
    return 0 if failures == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
