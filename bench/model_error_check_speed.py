#!/usr/bin/env python3
"""Speed of the model-error check's judgement: the stacked fits against lstsq per output.

Run:  .venv/bin/python bench/model_error_check_speed.py [--repeats 20]

When the change test's CUSUM crosses its threshold, node 2 judges the alarm on its sample path
(:class:`okid_ros.core.model_error_check.ModelErrorCheck`): one least-squares fit per output of
the tested residuals on the inputs' lags and the output's own lags
(:func:`~okid_ros.core.model_error_check.explained_fraction`), again every ``judge_period``
samples while the excursion lasts. Timed side by side, alternated, one BLAS thread: the code
before the twenty-ninth session (numpy's lstsq per output, kept as
:func:`okid_bench.changes.explained_fraction_by_lstsq`) and the product's, on random residuals
of the check's sizes: 10 lags, 2 inputs, 2 outputs (the paper model) and 28 (the steel subframe),
the fewest rows judged (``min_samples`` + lags) and a long excursion of 2000 rows. Median wall
time per judgement; the largest difference of the two fractions.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as in the nodes (before numpy is imported)

import numpy as np  # noqa: E402

from okid_bench.changes import explained_fraction_by_lstsq  # noqa: E402
from okid_ros.core.model_error_check import DEFAULT_CHECK_LAGS, ModelErrorCheck, explained_fraction  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20, help="timed judgements per size and code (default 20)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    lags, m = DEFAULT_CHECK_LAGS, 2
    print(f"bench/model_error_check_speed.py: {lags} lags, {m} inputs, {args.repeats} repeats, "
          f"load average (1 min) {os.getloadavg()[0]:.2f}\n")
    print("| outputs | rows judged | lstsq per output [ms] | stacked fits [ms] | speed-up | largest difference |")
    print("|---|---|---|---|---|---|")
    for p in (2, 28):
        for rows in (ModelErrorCheck(p, m).min_samples, 2000):
            w, u = rng.standard_normal((rows + lags, p)), rng.standard_normal((rows + lags, m))
            w[1:] += 0.5 * w[:-1]
            codes = {"old": explained_fraction_by_lstsq, "new": explained_fraction}
            times: dict[str, list[float]] = {name: [] for name in codes}
            for _ in range(args.repeats):
                for name, function in codes.items():
                    start = time.perf_counter()
                    function(w, u, lags)
                    times[name].append(time.perf_counter() - start)
            old, new = (statistics.median(times[name]) for name in codes)
            difference = abs(explained_fraction_by_lstsq(w, u, lags)[0] - explained_fraction(w, u, lags)[0])
            print(f"| {p} | {rows} | {old * 1e3:.2f} | {new * 1e3:.2f} | {old / new:.1f}x | {difference:.1e} |")


if __name__ == "__main__":
    main()
