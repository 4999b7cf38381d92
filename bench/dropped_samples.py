#!/usr/bin/env python3
"""Records with dropped readings: the longest run without them against the whole record filled.

A sensor stream over a best-effort transport, or a logger that skips a reading, leaves samples
missing at random. ``identify`` used to take the longest run without a missing sample (a few
hundred samples at 1 % lost); it now identifies the longest stretch whose gaps it can fill
(``okid_ros.records.bridged_run``), the ARX fit leaving out the rows that reach a missing sample
and the realization running with them filled by the ARX prediction, as node 2 fills its window.

For each drop rate, 5 (``--seeds``) records of the paper model (2 inputs low-passed at 15 Hz, 2
outputs, 125 Hz, ``--length`` samples), each sample of output 1 lost with that probability; both
ways identify with ``identify``'s defaults (ARX order by GCV, state order by BIC). Columns: the
samples used (median), frequency error % and damping error (points) RMS over the seeds of the
paper's two modes (5.90 Hz at 0.28 %, 7.34 Hz at 2.87 %), failures. Rate 0 is the clean record.

Output-only (``--output-only``): the koma shear frame (``../shared/data/oma/koma-shear-frame``, 5
outputs, 14400 samples), one output's samples lost at each rate, 3 seeds; the missing samples
filled by the prediction of a VAR (``core/gap_fill.fill_missing_outputs``) against the longest
run, and the same filled record with the filled samples in the output correlations (the code of
the fifteenth session; ``identify`` leaves them out). Columns: true modes found within 0.5 % of
the record's discrete-time values, spurious ones,
RMS frequency error % and damping error (relative %) of the found ones, failures.

Usage::

    python bench/dropped_samples.py                      # rates 0, 0.001, 0.005, 0.01, 0.03; ~2 min
    python bench/dropped_samples.py --rates 0.01 --seeds 10 --length 15000
    python bench/dropped_samples.py --output-only --seeds 3 --rates 0,0.005,0.01,0.03   # ~2 min
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import blas_threads  # noqa: F401  (sets the BLAS threads before numpy loads)
import numpy as np  # noqa: E402

from okid_ros.core.gap_fill import fill_missing_outputs  # noqa: E402
from okid_ros.core.output_only import identify_output_only  # noqa: E402
from okid_ros.core.pipeline import IdentificationError, identify  # noqa: E402
from okid_ros.records import Record, bridged_run, longest_present_run  # noqa: E402
from okid_ros.sim import lowpass_input, paper_model, paper_modes, simulate_innovation  # noqa: E402

SAMPLE_TIME_S = 0.008
KOMA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "oma" / "koma-shear-frame"


def _errors(model, truth: list[tuple[float, float]]) -> list[float]:
    """Frequency error % and damping error (points) of each true mode at the nearest listed one."""
    row = []
    for frequency_hz, damping in truth:
        mode = min(model.modes, key=lambda md: abs(md.frequency_hz - frequency_hz), default=None)
        row += [np.nan, np.nan] if mode is None else [100 * (mode.frequency_hz / frequency_hz - 1),
                                                      100 * (mode.damping_ratio - damping)]
    return row


def run_rate(rate: float, *, seeds: int, length: int) -> dict[str, dict]:
    """Both ways on ``seeds`` records with ``rate`` of output 1's samples lost."""
    truth = [(m["frequency_hz"], m["damping_ratio"]) for m in paper_modes()][:2]
    out = {way: {"used": [], "errors": [], "failed": 0} for way in ("longest run", "filled")}
    for seed in range(seeds):
        u = lowpass_input(length, 2, 15.0, SAMPLE_TIME_S, seed=seed)
        y, _ = simulate_innovation(paper_model(), u, seed=seed + 100)
        y[np.random.default_rng(seed).random(length) < rate, 0] = np.nan
        record = Record(u, y, SAMPLE_TIME_S)
        for way, result in out.items():
            if way == "filled":
                part, valid, _ = bridged_run(record)
            else:
                part, valid = longest_present_run(record)[0], None
            result["used"].append(part.u.shape[0])
            try:
                result["errors"].append(_errors(identify(part.u, part.y, SAMPLE_TIME_S, valid=valid), truth))
            except IdentificationError:
                result["failed"] += 1
    return out


def run_output_only_rate(rate: float, *, seeds: int) -> dict[str, dict]:
    """Both ways on the koma frame with ``rate`` of one output's samples lost (output ``seed % 5``)."""
    record = np.load(KOMA / "shear_frame.npz")
    y0, dt = record["y"], float(record["sample_time_s"])
    truth = json.loads((KOMA / "truth.json").read_text())["modes"]
    ways = ("longest run", "filled, fills in the correlations", "filled")
    out = {way: {"used": [], "scores": [], "failed": 0} for way in ways}
    for seed in range(seeds):
        y = y0.copy()
        y[np.random.default_rng(seed).random(len(y)) < rate, seed % y.shape[1]] = np.nan
        record = Record(np.zeros((len(y), 0)), y, dt)
        for way, result in out.items():
            valid = None
            if way.startswith("filled"):
                part, valid, _ = bridged_run(record, use_inputs=False)
                y_used = part.y if valid is None else fill_missing_outputs(part.y, valid)
            else:
                y_used = longest_present_run(record, use_inputs=False)[0].y
            result["used"].append(len(y_used))
            try:
                # What identify --output-only does: the filled samples out of the correlations.
                model = identify_output_only(y_used, dt, valid=valid if way == "filled" else None)
            except IdentificationError:
                result["failed"] += 1
                continue
            result["scores"].append(_koma_score(model, truth))
    return out


def _koma_score(model, truth: list[dict]) -> tuple[int, int, list[float], list[float]]:
    """Found, spurious, and the found modes' frequency errors % and damping errors (relative %)."""
    frequencies = np.array([mode.frequency_hz for mode in model.modes])
    f_err, z_err = [], []
    for mode in truth:
        f, z = mode["discrete_frequency_hz"], mode["discrete_damping_ratio"]
        near = int(np.argmin(np.abs(frequencies - f))) if frequencies.size else -1
        if near >= 0 and abs(frequencies[near] / f - 1) < 0.005:
            f_err.append(100 * (frequencies[near] / f - 1))
            z_err.append(100 * (model.modes[near].damping_ratio / z - 1))
    return len(f_err), len(model.modes) - len(f_err), f_err, z_err


def _print_output_only(args) -> None:
    n_samples = len(np.load(KOMA / "shear_frame.npz")["y"])
    print("| drop rate | identified on | samples used (median) | found (of 5 x seeds) | spurious "
          "| f err % RMS | zeta err % RMS | failed |")
    print("|---|---|---|---|---|---|---|---|")
    for rate in (float(r) for r in args.rates.split(",")):
        for way, result in run_output_only_rate(rate, seeds=args.seeds).items():
            found = sum(score[0] for score in result["scores"])
            spurious = sum(score[1] for score in result["scores"])
            f_rms, z_rms = (np.sqrt(np.mean(np.square([e for score in result["scores"] for e in score[k]])))
                            if found else np.nan for k in (2, 3))
            print(f"| {rate:g} | {way} | {int(np.median(result['used']))} of {n_samples} | {found}/{5 * args.seeds} "
                  f"| {spurious} | {f_rms:.3f} | {z_rms:.1f} | {result['failed']}/{args.seeds} |")
            if rate == 0:
                break


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", default="0,0.001,0.005,0.01,0.03", help="drop probabilities, comma separated")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--length", type=int, default=8000)
    parser.add_argument("--threads", default="1", help="BLAS threads (default 1)")
    parser.add_argument("--output-only", action="store_true", help="the koma frame, output-only")
    args = parser.parse_args(argv)
    if args.output_only:
        _print_output_only(args)
        return 0
    print("| drop rate | identified on | samples used (median) | f err % RMS (5.90 / 7.34 Hz) "
          "| zeta err pp RMS (5.90 / 7.34 Hz) | failed |")
    print("|---|---|---|---|---|---|")
    for rate in (float(r) for r in args.rates.split(",")):
        for way, result in run_rate(rate, seeds=args.seeds, length=args.length).items():
            errors = np.array(result["errors"]).reshape(-1, 4)
            rms = np.sqrt(np.nanmean(errors**2, axis=0)) if errors.size else np.full(4, np.nan)
            print(f"| {rate:g} | {way} | {int(np.median(result['used']))} of {args.length} | {rms[0]:.3f} / "
                  f"{rms[2]:.3f} | {rms[1]:.3f} / {rms[3]:.3f} | {result['failed']}/{args.seeds} |")
            if rate == 0:
                break  # nothing is missing: both ways are the same
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
