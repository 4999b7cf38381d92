#!/usr/bin/env python3
"""Calibration of the modes' standard deviations (okid_ros.core.uncertainty) against known truth.

For each case and seed, one record is simulated, identified with the default chain
(``okid_ros.core.pipeline.identify``, the case's ARX order or with ``--arx-order auto`` identify's own,
automatic model order), and
:func:`okid_ros.core.uncertainty.attach_mode_uncertainty` gives every mode a frequency and a
damping standard deviation. True and identified modes are paired one to one by frequency
(within 5 %; a close pair realized as one mode is one mode found, not two). Per true mode the
table gives:

* ``found``: records where the mode was identified (out of the seeds);
* ``f in 2 std``, ``zeta in 2 std``: fraction of those with ``|estimate - truth| <= 2 std``
  (a calibrated Gaussian estimate gives 95 %; the goal is 88-99 %), and the same within 1 std
  (68 % expected);
* ``RMS error / RMS std``: 1 when the standard deviations have the size of the actual errors;
* median standard deviations, and the median time of the identification and of the
  uncertainty step (the live node allows the uncertainty 25 % of the realization time).

Usage::

    python bench/mode_uncertainty.py                                  # both cases, 50 seeds
    python bench/mode_uncertainty.py --seeds 100 --out /tmp/uncertainty.md [--force]
    python bench/mode_uncertainty.py --cases close-pair --seeds 10 --length 15000
    python bench/mode_uncertainty.py --cases many-outputs --seeds 120 --length 6000 --arx-order auto

BLAS threads default to 1 (``--threads``).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time

import blas_threads  # noqa: F401  (sets the BLAS threads before numpy loads)
import checkout
import numpy as np  # noqa: E402

checkout.add()

from okid_bench.cases import benchmark_case  # noqa: E402
from okid_bench.report import add_output_options, refuse_existing, write_output  # noqa: E402
from okid_bench.scoring import assign_by_frequency, modes_of  # noqa: E402
from okid_ros.core.pipeline import IdentificationError, identify  # noqa: E402
from okid_ros.core.uncertainty import attach_mode_uncertainty  # noqa: E402
from okid_ros.sim.simulators import simulate  # noqa: E402

DEFAULT_CASES = ("paper-lp15", "close-pair")
MATCH_TOL = 0.05
INPUT_SEED_OFFSET = 0
NOISE_SEED_OFFSET = 10_000


def run_case(name: str, seeds: int, length: int, first_seed: int = 0, *, arx_order: str = "case") -> dict:
    """Per true mode: errors and standard deviations of every seed where it was found.

    ``arx_order``: "case" (the case's ARX order) or "auto" (``identify``'s own choice, by GCV).
    """
    case = benchmark_case(name)
    order = case.arx_order if arx_order == "case" else "auto"
    truth = modes_of(case.system.A, case.sample_time_s)
    rows = [{"frequency_hz": t.frequency_hz, "damping_ratio": t.damping_ratio, "f_err": [], "f_std": [],
             "z_err": [], "z_std": []} for t in truth]
    times_identify, times_uncertainty, failures, not_computed, methods = [], [], 0, [], set()
    for seed in range(first_seed, first_seed + seeds):
        u = case.make_input(length, INPUT_SEED_OFFSET + seed)
        y = simulate(case.system, u, seed=NOISE_SEED_OFFSET + seed)
        t0 = time.perf_counter()
        try:
            model = identify(u, y, case.sample_time_s, order=order)
        except IdentificationError:
            failures += 1
            continue
        t1 = time.perf_counter()
        result = model.uncertainty
        if result.method != "jackknife":  # timed again on its own (the jackknife runs inside identify)
            result = attach_mode_uncertainty(model, u, y)
            times_uncertainty.append(time.perf_counter() - t1)
        times_identify.append(t1 - t0)
        methods.add(result.method)
        if not result.computed:
            not_computed.append(result.reason)
            continue
        pairs = assign_by_frequency([md.frequency_hz for md in model.modes], [t.frequency_hz for t in truth],
                                    MATCH_TOL)
        for true, row, index in zip(truth, rows, pairs):
            if index is None:
                continue
            mode = model.modes[index]
            row["f_err"].append(mode.frequency_hz - true.frequency_hz)
            row["f_std"].append(mode.frequency_hz_std)
            row["z_err"].append(mode.damping_ratio - true.damping_ratio)
            row["z_std"].append(mode.damping_ratio_std)
    return {"case": name, "description": case.description, "seeds": seeds, "length": length, "modes": rows,
            "failures": failures, "not_computed": not_computed, "time_identify_s": times_identify,
            "time_uncertainty_s": times_uncertainty, "methods": sorted(methods)}


def _coverage(err: list, std: list, k: float) -> float:
    e, s = np.abs(np.asarray(err)), np.asarray(std)
    return float(np.mean(e <= k * s)) if e.size else float("nan")


def _ratio(err: list, std: list) -> float:
    e, s = np.asarray(err), np.asarray(std)
    return float(np.sqrt(np.mean(e**2) / np.mean(s**2))) if e.size else float("nan")


def table(results: list[dict]) -> str:
    lines = [
        "| case | true f [Hz] | true zeta [%] | found | f in 2 std | zeta in 2 std | f in 1 std | zeta in 1 std "
        "| RMS err / RMS std (f, zeta) | median std f [Hz] | median std zeta [%] |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for res in results:
        for row in res["modes"]:
            n = len(row["f_err"])
            lines.append(
                f"| {res['case']} | {row['frequency_hz']:.3f} | {100 * row['damping_ratio']:.2f} | {n}/{res['seeds']} "
                f"| {100 * _coverage(row['f_err'], row['f_std'], 2):.0f} % "
                f"| {100 * _coverage(row['z_err'], row['z_std'], 2):.0f} % "
                f"| {100 * _coverage(row['f_err'], row['f_std'], 1):.0f} % "
                f"| {100 * _coverage(row['z_err'], row['z_std'], 1):.0f} % "
                f"| {_ratio(row['f_err'], row['f_std']):.2f}, {_ratio(row['z_err'], row['z_std']):.2f} "
                f"| {np.median(row['f_std']) if n else float('nan'):.2e} "
                f"| {100 * np.median(row['z_std']) if n else float('nan'):.3f} |"
            )
    lines += ["", "| case | length | seeds | failed | std not computed | median identify [s] "
              "| median uncertainty [s] | ratio |",
              "|---|---|---|---|---|---|---|---|"]
    for res in results:
        ti = np.median(res["time_identify_s"])
        if res["time_uncertainty_s"]:
            tu = np.median(res["time_uncertainty_s"])
            timing = f"{tu:.4f} | {100 * tu / ti:.1f} %"
        else:
            timing = "in identify (jackknife) | "
        lines.append(f"| {res['case']} | {res['length']} | {res['seeds']} | {res['failures']} | "
                     f"{len(res['not_computed'])} | {ti:.3f} | {timing} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", default=",".join(DEFAULT_CASES), help="comma-separated case names")
    parser.add_argument("--seeds", type=int, default=50, help="records per case (default: %(default)s)")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--length", type=int, default=3750, help="samples per record (default: %(default)s)")
    parser.add_argument("--arx-order", choices=("case", "auto"), default="case",
                        help="the case's ARX order (default) or identify's own choice (auto: by GCV)")
    add_output_options(parser, json=True)
    parser.add_argument("--threads", default="1", help="BLAS threads (default: 1)")
    args = parser.parse_args(argv)
    refuse_existing(parser, args)
    results = []
    started = time.perf_counter()
    for name in args.cases.split(","):
        results.append(run_case(name.strip(), args.seeds, args.length, args.first_seed, arx_order=args.arx_order))
        print(f"{name}: done after {time.perf_counter() - started:.0f} s", file=sys.stderr)
    text = table(results)
    header = (f"`python bench/mode_uncertainty.py --cases {args.cases} --seeds {args.seeds} --length {args.length} "
              f"--arx-order {args.arx_order}` "
              f"({platform.machine()}, Python {platform.python_version()}, {time.strftime('%Y-%m-%d')}, "
              f"{time.perf_counter() - started:.0f} s)\n\n")
    print(header + text)
    write_output(args.out, header + text + "\n")
    if args.json:
        write_output(args.json, json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
