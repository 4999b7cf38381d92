#!/usr/bin/env python3
"""A few missing samples against the clean record's own scatter: whether the gap path adds a mode.

``identify`` of a record holding a few NaN samples fills them by the ARX prediction and leaves
the rows that reach them out of the fit and the realization's Gram (``records.bridged_run``,
``core/pipeline.identify(valid=...)``). Each missing sample so costs about ``q + c`` rows of
20000. Whether that adds or moves a mode is judged against the clean record cut short by as
many rows (its first 50 or 200 samples), which changes the data as little.

The paper's structure (2 inputs low-passed at 15 Hz, 2 outputs, 125 Hz, ``--length`` samples,
``--seeds`` records; outputs ``simulate_innovation`` of seed + 1), ``identify``'s defaults. The
missing samples (``--counts``) are drawn per seed from samples 100 .. N - 2: NaN in one output
chosen per sample, in both outputs, or in one input. Columns: the paper's three modes found
within 0.5 % (one to one), the other modes listed (spurious, with their frequencies), RMS
frequency error % of the found modes, and the largest change of the 7.34 Hz mode's frequency
from the clean record's (percentage points).

Usage::

    python bench/few_missing_samples.py                       # 8 seeds, counts 1 4 10 40: ~2 min
    python bench/few_missing_samples.py --seeds 20 --counts 4
"""

from __future__ import annotations

import argparse
import sys

import blas_threads  # noqa: F401  (sets the BLAS threads before numpy loads)
import checkout

checkout.add()

import numpy as np  # noqa: E402

from okid_bench.report import add_output_options, print_table, refuse_existing  # noqa: E402
from okid_bench.scoring import assign_by_frequency  # noqa: E402
from okid_ros.core.pipeline import identify  # noqa: E402
from okid_ros.records import Record, bridged_run  # noqa: E402
from okid_ros.sim import lowpass_input, paper_model, paper_modes, simulate_innovation  # noqa: E402

TRUE_HZ = np.array([mode["frequency_hz"] for mode in paper_modes()])
MATCH = 0.005  # a true mode is found within 0.5 %


def _cases(counts: list[int]) -> list[str]:
    cases = ["clean", "clean, first 50 samples cut", "clean, first 200 samples cut"]
    for n in counts:
        cases.append(f"{n} NaN in one output")
    if 4 in counts:
        cases += ["4 NaN in both outputs", "4 NaN in one input"]
    return cases


def _record(case: str, u: np.ndarray, y: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The record of ``case``: the clean one cut short, or with NaN at a few samples."""
    u, y = u.copy(), y.copy()
    if case.startswith("clean, first"):
        cut = int(case.split()[2])
        return u[cut:], y[cut:]
    if "NaN" not in case:
        return u, y
    rng = np.random.default_rng(seed)
    for k in rng.choice(np.arange(100, y.shape[0] - 1), int(case.split()[0]), replace=False):
        if "input" in case:
            u[k, rng.integers(u.shape[1])] = np.nan
        elif "both" in case:
            y[k] = np.nan
        else:
            y[k, rng.integers(y.shape[1])] = np.nan
    return u, y


def _score(model) -> tuple[int, list[float], np.ndarray]:
    """Found true modes, the other modes' frequencies, the frequency error % of each true mode (NaN: missed)."""
    listed = np.array([mode.frequency_hz for mode in model.modes])
    pairs = assign_by_frequency(listed, TRUE_HZ, MATCH)
    errors = np.array([np.nan if c is None else 100 * (listed[c] / f - 1) for c, f in zip(pairs, TRUE_HZ)])
    others = [float(f) for j, f in enumerate(listed) if j not in pairs]
    return sum(c is not None for c in pairs), others, errors


def run(cases: list[str], seeds: int, length: int) -> dict[str, list]:
    truth = paper_model()
    dt = truth.sample_time_s
    scores: dict[str, list] = {case: [] for case in cases}
    for seed in range(1, seeds + 1):
        u = lowpass_input(length, 2, 15.0, dt, seed=seed)
        y, _ = simulate_innovation(truth, u, seed=seed + 1)
        for case in cases:
            part, valid, _ = bridged_run(Record(*_record(case, u, y, seed), dt))
            scores[case].append(_score(identify(part.u, part.y, dt, valid=valid)))
    return scores


def _rows(scores: dict[str, list]):
    clean = np.array([s[2] for s in scores["clean"]])
    for case, results in scores.items():
        errors = np.array([s[2] for s in results])
        others = [f"{f:.2f}" for s in results for f in s[1]]
        rms = np.sqrt(np.nanmean(errors**2, axis=0))
        moved = np.nanmax(np.abs(errors[:, 1] - clean[:, 1]))
        yield [case, f"{sum(s[0] for s in results)}/{3 * len(results)}",
               f"{len(others)}" + (f" ({', '.join(others)} Hz)" if others else ""),
               " / ".join(f"{v:.3f}" for v in rms), f"{moved:.3f}"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8, help="records (default 8)")
    parser.add_argument("--length", type=int, default=20_000, help="samples per record (default 20000)")
    parser.add_argument("--counts", type=int, nargs="+", default=[1, 4, 10, 40],
                        help="missing samples per record (default 1 4 10 40)")
    add_output_options(parser)
    args = parser.parse_args(argv)
    refuse_existing(parser, args)
    header = ["record", "found", "spurious", "f err % RMS (5.90 / 7.34 / 48.46 Hz)", "max |change| of 7.34 Hz (pp)"]
    print_table(header, _rows(run(_cases(args.counts), args.seeds, args.length)), args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
