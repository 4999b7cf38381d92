#!/usr/bin/env python3
"""`identify` with its defaults on structures drawn at random: modes found, missed, spurious.

Each record is one structure of :func:`okid_bench.cases.random_case` (2-7 modes, 1-2 measured
white inputs, 1-8 sensors, 50-1000 Hz), its input a white-noise seed equal to its index. A
true mode (from the discrete system simulated) is *found* when a listed mode lies within 0.5 %
of its frequency (one each, paired by frequency and shape); listed modes not paired one to one with a true mode
within 2 % are *spurious*. Prints the totals, the share of found modes with damping within
30 %, the median time of one identification, and one line per record with a missed or
spurious mode. The thresholds of the mode selection were set on the named cases
(bench/identification_accuracy.py), not on these.

Usage::

    python bench/random_structures.py                  # 60 records, ~2 min with 2 jobs
    python bench/random_structures.py --records 180 --jobs 2
"""

from __future__ import annotations

import argparse
import sys
import time
from multiprocessing import Pool

import blas_threads  # noqa: F401  (sets the BLAS threads before numpy loads)
import numpy as np

from okid_bench.cases import random_record
from okid_bench.output_only_cases import score_modes, system_modes


def _run(index: int) -> dict:
    from okid_ros.core.pipeline import IdentificationError, identify

    case, u, y = random_record(index)
    started = time.perf_counter()
    try:
        model = identify(u, y, case.sample_time_s)
        found = [{"frequency_hz": m.frequency_hz, "damping_ratio": m.damping_ratio, "shape": m.shape}
                 for m in model.modes]
        error = ""
    except IdentificationError as exc:
        found, error = [], str(exc)
    truth = system_modes(case.system)
    strict = score_modes(found, truth, match_tolerance=0.005)
    return {"index": index, "description": case.description, "time": time.perf_counter() - started,
            "truth": [t["frequency_hz"] for t in truth], "found": [f["frequency_hz"] for f in found],
            "missed": sum(r["frequency_error"] != r["frequency_error"] for r in strict["modes"]),
            "damping_errors": [r["damping_error"] for r in strict["modes"] if r["damping_error"] == r["damping_error"]],
            "spurious": score_modes(found, truth, match_tolerance=0.02)["spurious"], "error": error}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--records", type=int, default=60)
    parser.add_argument("--start", type=int, default=0, help="index of the first structure")
    parser.add_argument("--jobs", type=int, default=2, help="processes (one BLAS thread each)")
    parser.add_argument("--threads", default="1", help="BLAS threads (read before numpy loads)")
    args = parser.parse_args(argv)
    indices = range(args.start, args.start + args.records)
    with Pool(args.jobs) as pool:
        results = pool.map(_run, indices, chunksize=1)
    n_true = sum(len(r["truth"]) for r in results)
    missed = sum(r["missed"] for r in results)
    damping = np.abs(np.concatenate([r["damping_errors"] for r in results] or [[]]))
    print(f"{len(results)} records, {n_true} true modes: found {n_true - missed}, missed {missed}, spurious "
          f"{sum(r['spurious'] for r in results)}, refused {sum(bool(r['error']) for r in results)}; damping within "
          f"30 % on {100 * np.mean(damping <= 0.3):.0f} % of the found; median time "
          f"{np.median([r['time'] for r in results]):.2f} s")
    for r in results:
        if r["missed"] or r["spurious"] or r["error"]:
            print(f"  random-{r['index']} ({r['description']}): true {', '.join(f'{f:.2f}' for f in r['truth'])}; "
                  f"found {', '.join(f'{f:.2f}' for f in r['found'])}; missed {r['missed']}, spurious "
                  f"{r['spurious']} {r['error']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
