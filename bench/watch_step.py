#!/usr/bin/env python3
"""Node 2's per-sample path (``InnovationWatch.step`` through ``RecordWatch.run``): its time and its verdicts.

Run:  OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD:$PWD/bench python bench/watch_step.py [--old-tree DIR] [--rounds 3]

Three records: the paper's structure (p = 2, m = 2; 60000 samples of a 15 Hz low-passed force, the
record of ``bench/track_watch.py --timing``; the model of its first 2000 rows, ARX order 20); the same
structure under a force of 0.01 with 12 blows of 1e6 after the model's window (``bench/track_watch.py``'s
hammer record, longer: divergences, restarts); and the DaISy steel subframe (p = 28, m = 2, 1/1024 s; the
model node 2's worker realizes of its first 3000 rows, ``bench/live_pace_profile.py``'s job). Each is
stepped by node 2's estimator and watch with node 2's defaults (change detection on) over every sample
after the model's window. Each checkout (this one and ``--old-tree``, in turn, ``--rounds`` times, one
process each) prints the CPU time per sample (the least over its rounds) and a digest of what the watch
decided at every sample (the estimator's state, the change statistic, the counts and the changes): the
digests of two checkouts are equal when every verdict is. ``--profile N``: instead, cProfile of this
checkout's run on the paper's record, the N functions of most own time.
"""

from __future__ import annotations

import argparse
import hashlib
import inspect
import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
WINDOW, ORDER = 2000, 20
#: The counts in the digest: the watch's, which every checkout since the forty-fifth session's has.
COUNTS = ("diverged_samples", "divergence_restarts", "state_jumps", "divergences_beyond_window", "estimator_restarts",
          "gaps_bridged", "change_glitches", "change_alarms_state_jump", "change_alarms_noise",
          "change_alarms_unconfirmed", "output_level_steps")


def _paper_case():
    """(u, y, dt, model, window end) of the paper's structure."""
    from okid_ros.core.pipeline import identify
    from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

    truth = paper_model()
    dt = truth.sample_time_s
    u = lowpass_input(60000, 2, 15.0, dt, seed=1)
    y, _ = simulate_innovation(truth, u, seed=2)
    end = WINDOW + ORDER
    return u, y, dt, identify(u[:end], y[:end], dt, order=ORDER), end


def _hammer_case():
    """(u, y, dt, model, window end) of the paper's structure, a force of 0.01, 12 blows of 1e6 after the window."""
    import numpy as np

    from okid_ros.core.pipeline import identify
    from okid_ros.sim import paper_model, simulate_innovation

    truth = paper_model()
    dt, end = truth.sample_time_s, WINDOW + ORDER
    rng = np.random.default_rng(4)
    u = 0.01 * rng.standard_normal((end + 6000, 2))
    u[rng.choice(np.arange(end + 300, end + 5900), 12, replace=False), rng.integers(0, 2, 12)] += 1e6
    y, _ = simulate_innovation(truth, u, seed=5)
    return u, y, dt, identify(u[:end], y[:end], dt, order=ORDER), end


def _daisy_case():
    """(u, y, dt, model, window end) of the steel subframe, its model as node 2's worker realizes it."""
    import numpy as np
    from live_pace_profile import RECORD, make_job

    from okid_ros.service import realization

    job = make_job(argparse.Namespace(record=str(RECORD), start=0, window=3000, order=20, order_hint=None))
    data = np.load(RECORD)
    u, y = np.asarray(data["u"], float), np.asarray(data["y"], float)
    return u, y, float(data["sample_time_s"]), realization.realize(job).model, job.u.shape[0]


def _watch(u, y, dt, model, end):
    """A RecordWatch over the record with node 2's defaults, the model of its first ``end`` samples in use."""
    from okid_ros.service.options import ModalEstimationParams
    from okid_ros.service.params import ESTIMATOR_NODE, resolve_parameters
    from okid_ros.service.record_watch import RecordWatch
    from okid_ros.service.tracked_record import TrackedRecord

    params = replace(ModalEstimationParams.from_parameters(resolve_parameters(ESTIMATOR_NODE)), sample_time_s=dt,
                     n_inputs=u.shape[1], n_outputs=y.shape[1])
    watch = RecordWatch(TrackedRecord(u.copy(), y.copy(), ORDER), params, capacity=8192)
    watch.run(0, end)
    first = {"first": 0} if "first" in inspect.signature(watch.new_model).parameters else {}
    refused = watch.new_model(model, u[:end], y[:end], end - ORDER, **first)
    if refused:
        raise SystemExit(f"watch_step.py: the model is refused: {refused}")
    return watch


def worker(case: str, rounds: int) -> dict:
    """The least CPU time per sample over ``rounds`` runs of the checkout imported, and the verdicts' digest."""
    import numpy as np

    u, y, dt, model, end = {"paper": _paper_case, "hammer": _hammer_case, "daisy": _daisy_case}[case]()
    times = []
    for _ in range(rounds):
        watch = _watch(u, y, dt, model, end)
        started = time.process_time()
        with np.errstate(over="ignore"):
            watch.run(end, u.shape[0])
        times.append(time.process_time() - started)
    watch, digest, changes = _watch(u, y, dt, model, end), hashlib.sha256(), []
    for k in range(end, u.shape[0]):  # the same steps one sample at a time, each one's outcome hashed
        alarm = watch.run(k, k + 1)
        digest.update(watch.active.estimator.state.tobytes())
        digest.update(np.float64(watch.monitor.statistic).tobytes())
        changes += [] if alarm is None else [(alarm.alarm_index, alarm.change_index)]
    counts = {name: watch.counts()[name] for name in COUNTS}
    digest.update(json.dumps([counts, changes]).encode())
    return {"us_per_sample": 1e6 * min(times) / (u.shape[0] - end), "samples": u.shape[0] - end,
            "digest": digest.hexdigest()[:16], "changes": changes,
            "counts": {k: v for k, v in counts.items() if v}}


def profile(top: int) -> None:
    """The functions of most own time in one run over the paper's record (cProfile)."""
    import cProfile
    import pstats

    import numpy as np

    u, y, dt, model, end = _paper_case()
    watch = _watch(u, y, dt, model, end)
    prof = cProfile.Profile()
    with np.errstate(over="ignore"):
        prof.runcall(watch.run, end, u.shape[0])
    pstats.Stats(prof).sort_stats("tottime").print_stats(top)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old-tree", type=Path, default=None, help="another checkout to time beside this one")
    parser.add_argument("--rounds", type=int, default=3, help="runs per checkout and record (default 3)")
    parser.add_argument("--profile", type=int, default=0, metavar="N", help="profile this checkout instead")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker, args.rounds)))
        return
    if args.profile:
        profile(args.profile)
        return
    trees = [args.old_tree.resolve(), HERE] if args.old_tree else [HERE]
    print(f"load average (1 min) {os.getloadavg()[0]:.2f}\n")
    print("| record | checkout | samples | CPU per sample (us) | verdicts' digest | counts not 0 |")
    print("|---|---|---|---|---|---|")
    for case in ("paper", "hammer", "daisy"):
        for tree in trees:
            env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), str(tree / "bench"), str(HERE / "bench")]),
                   "OPENBLAS_NUM_THREADS": "1"}
            run = subprocess.run([str(tree / ".venv/bin/python"), str(Path(__file__).resolve()), "--worker", case,
                                  "--rounds", str(args.rounds)], capture_output=True, text=True, env=env, cwd=tree)
            if run.returncode:
                raise SystemExit(run.stderr)
            out = json.loads(run.stdout.strip().splitlines()[-1])
            print(f"| {case} | {tree.name} | {out['samples']} | {out['us_per_sample']:.1f} | {out['digest']} | "
                  f"{', '.join(f'{k} {v}' for k, v in out['counts'].items())} |")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
