"""Where node 2's realization worker spends a model update at 28 channels (issue 17 item 3).

Run:  .venv/bin/python bench/live_pace_profile.py [--window 6000] [--repeats 3] [--top 25]

Builds the job node 2 hands its worker process for one window of the DaISy steel-subframe
record (``--start``, ``--window`` rows + ARX order q samples; an ARX fit of the window as
node 1 makes it: ridge prior, penalty by GCV, intercept for the offsets), with node 2's
options from the parameter table at p = 28, m = 2, 1/1024 s (the default realization
settings), then times the worker's function
(:func:`okid_ros.service.realization.realize`: ``identify_window`` -> ``identify_from_arx``,
the model's checks, the warm start over the window; ``--order-hint`` the order of the model in use, as
the node passes it) ``--repeats`` times with one BLAS thread
and profiles one more run under cProfile. Prints the wall times and the functions with the
most cumulative and the most own time.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import sys
import time
from pathlib import Path

import checkout

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as in the nodes' worker (before numpy is imported)

REPO = Path(__file__).resolve().parent.parent
RECORD = REPO.parent / "shared" / "data" / "real" / "daisy-steel-subframe" / "steel_subframe.npz"


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--window", type=int, default=6000, help="ARX window rows (default 6000)")
    parser.add_argument("--order", type=int, default=20, help="ARX order q (default 20)")
    parser.add_argument("--start", type=int, default=0, help="first sample of the window (default 0)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs before the profiled one (default 3)")
    parser.add_argument("--top", type=int, default=25, help="functions listed per table (default 25)")
    parser.add_argument("--record", default=str(RECORD), help="record .npz with u, y, sample_time_s")
    parser.add_argument("--order-hint", type=int, default=None,
                        help="the order of the model in use, as the node passes it (warm-started order "
                             "search; default none: a cold search, as for the first model)")
    return parser.parse_args()


def make_job(args: argparse.Namespace):
    """The worker's job for one window of the record, with node 2's default options."""
    import numpy as np

    from okid_ros.core.arx import fit_arx
    from okid_ros.service.options import ModalEstimationParams
    from okid_ros.service.results import RealizationJob

    data = np.load(args.record)
    stop = args.start + args.window + args.order
    if stop > data["u"].shape[0]:
        raise SystemExit(f"live_pace_profile.py: the record has {data['u'].shape[0]} samples, "
                         f"the window needs {stop}")
    u, y = data["u"][args.start:stop], data["y"][args.start:stop]
    dt = float(data["sample_time_s"])
    params = ModalEstimationParams(sample_time_s=dt, n_inputs=u.shape[1], n_outputs=y.shape[1])
    fit = fit_arx(u, y, args.order, "ridge", "gcv", center=True)
    return RealizationJob(fit, 1, stop * dt, u.copy(), y.copy(), stop - 1, params, order_hint=args.order_hint)


def main() -> int:
    args = parse_args()
    checkout.add()
    import numpy as np

    from okid_ros.service.realization import realize

    job = make_job(args)
    print(f"bench/live_pace_profile.py: p = {job.y.shape[1]}, m = {job.u.shape[1]}, q = {args.order}, "
          f"window {args.window} rows (samples {args.start}..{args.start + args.window + args.order - 1}), "
          f"order search {'warm-started at ' + str(args.order_hint) if args.order_hint else 'cold'}, "
          f"one BLAS thread, load average (1 min) {os.getloadavg()[0]:.2f}\n")
    walls = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        outcome = realize(job)
        walls.append(time.perf_counter() - t0)
        print(f"realize: {walls[-1]:.3f} s wall (identify_window {outcome.realization_time_s:.3f} s), "
              f"{0 if outcome.model is None else outcome.model.n_states} states, "
              f"{0 if outcome.model is None else len(outcome.model.modes)} modes {outcome.reason}")
    if walls:
        print(f"median {np.median(walls):.3f} s over {len(walls)} runs")
    profiler = cProfile.Profile()
    profiler.enable()
    realize(job)
    profiler.disable()
    for key in ("cumulative", "tottime"):
        out = io.StringIO()
        pstats.Stats(profiler, stream=out).sort_stats(key).print_stats(args.top)
        text = out.getvalue()
        print(f"\n## by {key}\n")
        print(text[text.index("ncalls"):] if "ncalls" in text else text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
