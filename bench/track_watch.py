#!/usr/bin/env python3
"""`okid-ros track` against node 2 on records of an unchanged structure: the structural changes each declares.

The paper's structure, 6000 samples (order 20, window 800, an update every 250 samples; node 2 as
``okid-ros process`` runs it, a model every 250 samples): one input sample 1e3 times its channel's
spread at sample 3000 + seed over a 15 Hz low-passed force or a quiet force of 0.01, as a glitch of
the measured input (the structure never felt it) or a blow (it did); output-only, every output 1e3
spreads off at that sample over the quiet force; and the hammer record of docs/robustness-live.md (i)
(12 blows of 1e6 over 0.01, 4000 samples). Every change declared is a false one. ``--old-tree DIR``
adds a column of `track` run from another checkout (its own ``.venv``), to compare versions.
``--timing``: instead, the seconds `track` takes over 60000 samples of the structure (a 15 Hz
low-passed force; order 20, window 2000, an update every 10000 samples, so that the identifications
weigh little), with and without change detection, from this checkout and ``--old-tree``::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD:$PWD/bench python bench/track_watch.py [--old-tree DIR] [--timing]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from okid_bench.live_chain import run_pipeline
from okid_ros.records import save_record
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

N, Q, WINDOW, EVERY = 6000, 20, 800, 250
WATCH = ("diverged_samples", "divergence_restarts", "state_jumps", "divergences_beyond_window")
HERE = Path(__file__).resolve().parents[1]


def records(model):
    """(name, u (N, m), y (N, p)) of each record (see the module docstring)."""
    dt = model.sample_time_s
    for seed in (4, 7):
        for force in ("low-passed", "quiet"):
            for kind in ("glitch", "blow"):
                rng = np.random.default_rng(seed)
                u = lowpass_input(N, 2, 15.0, dt, seed=seed) if force == "low-passed" else (
                    0.01 * rng.standard_normal((N, 2)))
                size = 1e3 * u[:, 1].std()
                u[3000 + seed, 1] += size if kind == "blow" else 0.0
                y, _ = simulate_innovation(model, u, seed=seed + 1)
                u[3000 + seed, 1] += size if kind == "glitch" else 0.0  # the structure never felt it
                yield f"input {kind} 1e3, {force}, seed {seed}", u, y
        u = 0.01 * np.random.default_rng(seed).standard_normal((N, 2))
        y, _ = simulate_innovation(model, u, seed=seed + 1)
        y[3000 + seed] += 1e3 * y.std(axis=0)
        yield f"output-only, every output 1e3, quiet, seed {seed}", np.zeros((N, 0)), y
    rng = np.random.default_rng(4)
    u = 0.01 * rng.standard_normal((4000, 2))
    u[rng.choice(np.arange(300, 3900), 12, replace=False), rng.integers(0, 2, 12)] += 1e6
    y, _ = simulate_innovation(model, u, seed=5)
    yield "hammer: 12 blows of 1e6 over 0.01", u, y


def track(tree: Path, data: Path) -> tuple[list[int], dict]:
    """`okid-ros track` of ``data`` from checkout ``tree``: the samples changes were declared at, the last watch."""
    out = data.with_suffix(f".{tree.name}.jsonl")
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    subprocess.run([str(tree / ".venv/bin/python"), "-m", "okid_ros.cli", "track", str(data), "--order", str(Q),
                    "--window", str(WINDOW), "--every", str(EVERY), "--jsonl", str(out), "--no-progress", "--force"],
                   capture_output=True, text=True, env=env, cwd=tree, check=True)
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    return [line["change_declared_index"] for line in lines if line["change_detected"]], lines[-1].get("watch", {})


def timing(model, trees: list[Path]) -> None:
    """The seconds `track` takes over 60000 samples from each checkout, with and without change detection."""
    dt = model.sample_time_s
    u = lowpass_input(60000, 2, 15.0, dt, seed=1)
    y, _ = simulate_innovation(model, u, seed=2)
    print("| checkout | change detection | run (s) | of it tracking (s) |")
    print("|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "long.npz"
        save_record(data, u, y, dt)
        for tree in trees:
            for extra in ([], ["--no-change-detection"]):
                env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
                started = time.perf_counter()
                run = subprocess.run([str(tree / ".venv/bin/python"), "-m", "okid_ros.cli", "track", str(data),
                                      "--order", "20", "--window", "2000", "--every", "10000", "--jsonl",
                                      str(data.with_suffix(".jsonl")), "--no-progress", "--force", *extra],
                                     capture_output=True, text=True, env=env, cwd=tree, check=True)
                tracking = run.stdout.strip().splitlines()[-1].split(" in ")[-1].split(" s ")[0]
                print(f"| {tree} | {'off' if extra else 'on'} | {time.perf_counter() - started:.1f} | {tracking} |")
                sys.stdout.flush()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old-tree", type=Path, default=None, help="another checkout whose track to compare")
    parser.add_argument("--timing", action="store_true", help="the seconds track takes over a long record")
    args = parser.parse_args()
    model = paper_model()
    if args.timing:
        timing(model, [args.old_tree, HERE] if args.old_tree else [HERE])
        return
    dt = model.sample_time_s
    old = "track (old tree): changes at | " if args.old_tree else ""
    print(f"| record | {old}track: changes at | track: {', '.join(WATCH)} | node 2: changes | node 2: the same |")
    print("|---|" + ("---|" if args.old_tree else "") + "---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, u, y) in enumerate(records(model)):
            data = Path(tmp) / f"record{i}.npz"
            save_record(data, u, y, dt)
            before = f"{track(args.old_tree, data)[0] or '-'} | " if args.old_tree else ""
            changes, watch = track(HERE, data)
            pipeline, _ = run_pipeline(u, y, dt, {"arx.order": Q, "arx.window_length": WINDOW,
                                                  "publish_rate_hz": 1.0 / (EVERY * dt)})
            node_2 = pipeline.est.diagnostics()
            print(f"| {name} | {before}{changes or '-'} | {', '.join(str(watch.get(k, '-')) for k in WATCH)} | "
                  f"{node_2['changes_detected']} | {', '.join(str(node_2[k]) for k in WATCH)} |")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
