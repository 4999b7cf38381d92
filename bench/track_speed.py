#!/usr/bin/env python3
"""`okid-ros track` of two checkouts side by side on the track benches' records: run times, and the lines the same.

The records and options of ``bench/track_watch.py`` (its nine records, order 20, window 800, every 250; its
``--timing`` record of 60000 samples, order 20, window 2000, every 10000, with and without change detection),
``bench/tracking.py`` (the added mass, seeds 0-2, window 4000, every 250) and ``bench/change_detection.py --part
track`` (its four cases, seed 0, order 100, window 4000, every 250). Each record is tracked by ``--old-tree``'s
checkout then by this one, one after the other; a row gives both run times (the whole command, and its own
"tracked ... in X s") and whether every JSON line is the same but for ``elapsed_s`` and the fields only one side
writes (``--ignore``). ``--gates``: instead, node 1's two gate loops alone in each checkout (their seconds, the
glitches and a digest of the samples out) on ``--timing``'s record, clean and with glitches::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD:$PWD/bench python bench/track_speed.py --old-tree OLD_CHECKOUT [--gates]
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

from okid_bench.changes import change_case
from okid_bench.switching import added_mass_case
from okid_ros.records import save_record
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

HERE = Path(__file__).resolve().parents[1]
CHANGE_CASES = ("frequency:0.06", "frequency:0.02", "damping:2", "stiffness:0.2")


def bench_records():
    """(name, u, y, dt, track options) of each bench's records (see the module docstring)."""
    sys.path.insert(0, str(HERE / "bench"))
    import track_watch

    model = paper_model()
    dt = model.sample_time_s
    for name, u, y in track_watch.records(model):
        yield f"track_watch: {name}", u, y, dt, ["--order", "20", "--window", "800", "--every", "250"]
    u = lowpass_input(60000, 2, 15.0, dt, seed=1)
    y, _ = simulate_innovation(model, u, seed=2)
    for extra in ([], ["--no-change-detection"]):
        yield (f"track_watch --timing{' (no change detection)' if extra else ''}", u, y, dt,
               ["--order", "20", "--window", "2000", "--every", "10000", *extra])
    case = added_mass_case()
    first = 4000 + case.arx_order - 1
    change = first + 6 * 250 - 1
    for seed in (0, 1, 2):
        u, y = case.simulate(change + 4000 + 2000, change, seed)
        yield (f"tracking: added mass, seed {seed}", u, y, case.sample_time_s,
               ["--order", str(case.arx_order), "--window", "4000", "--every", "250"])
    for text in CHANGE_CASES:
        kind, _, size = text.partition(":")
        case = change_case(kind, float(size))
        change = 4000 + 100 - 1 + 6 * 250 - 1
        u, y = case.simulate(change + 4500, change, 0)
        yield (f"change_detection: {case.name}, seed 0", u, y, case.sample_time_s,
               ["--order", "100", "--window", "4000", "--every", "250"])


def track(tree: Path, data: Path, options: list[str]) -> tuple[list[dict], float, float]:
    """The JSON lines of `okid-ros track` from checkout ``tree``, the command's seconds and its own tracking's."""
    out = data.with_suffix(f".{tree.name}.jsonl")
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    started = time.perf_counter()
    run = subprocess.run([str(tree / ".venv/bin/python"), "-m", "okid_ros.cli", "track", str(data), *options,
                          "--jsonl", str(out), "--no-progress", "--force"],
                         capture_output=True, text=True, env=env, cwd=tree, check=True)
    elapsed = time.perf_counter() - started
    tracking = float(run.stdout.strip().splitlines()[-1].split(" in ")[-1].split(" s ")[0])
    return [json.loads(line) for line in out.read_text().splitlines()], elapsed, tracking


#: Run in each checkout by ``--gates``: the record screened by node 1's input gate (``without_input_glitches``), then
#: every sample through both gates (``screened_block``) with an ARX fit of its first 2000 samples as the output gate's
#: model; the seconds of each and a digest of what came out.
GATES = """
import hashlib, json, sys, time
import numpy as np
from okid_ros.core.arx import fit_from_normal_equations
from okid_ros.core.input_glitches import without_input_glitches
from okid_ros.core.recursive import SlidingWindowArx
from okid_ros.records import load_record
from okid_ros.service.window_gates import WindowGates, screened_block
record = load_record(sys.argv[1])
u, y, q = record.u, record.y, 20
accepted = np.ones(len(y), bool)
started = time.perf_counter()
screened, input_glitches = without_input_glitches(u, accepted=accepted)
screen_s = time.perf_counter() - started
window = SlidingWindowArx(q, y.shape[1], u.shape[1], window=2000)
window.update(screened[:2000], y[:2000])
gates = WindowGates(q, y.shape[1], u.shape[1])
gates.set_model(fit_from_normal_equations(window.normal_equations(), q, y.shape[1], u.shape[1], "ridge", "gcv"))
out = (screened.copy(), y.copy())
started = time.perf_counter()
screened_block(gates, out, accepted, 0, len(y))
gates_s = time.perf_counter() - started
digest = hashlib.sha256(b"".join(a.tobytes() for a in (*out, input_glitches))).hexdigest()[:12]
print(json.dumps([screen_s, gates_s, gates.glitches, len(input_glitches), digest]))
"""


def gates_rows(trees: list[Path]) -> None:
    """The gate loops alone, each checkout's in turn, on the 60000 samples of ``--timing``, clean and glitched."""
    model = paper_model()
    u = lowpass_input(60000, 2, 15.0, model.sample_time_s, seed=1)
    y, _ = simulate_innovation(model, u, seed=2)
    rng = np.random.default_rng(3)
    glitched_u, glitched_y = u.copy(), y.copy()
    glitched_y[rng.choice(np.arange(2000, 60000), 60, replace=False), rng.integers(0, 2, 60)] += 8 * y.std()
    glitched_u[rng.choice(np.arange(2000, 60000), 20, replace=False), rng.integers(0, 2, 20)] += 1e12
    print("| record | checkout | without_input_glitches (s) | screened_block (s) | glitches | input glitches (screen) "
          "| digest |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, (u_r, y_r) in (("60000 samples", (u, y)), ("the same, 60 output and 20 input glitches",
                                                               (glitched_u, glitched_y))):
            data = Path(tmp) / "gates.npz"
            save_record(data, u_r, y_r, model.sample_time_s)
            for tree in trees:
                env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
                run = subprocess.run([str(tree / ".venv/bin/python"), "-c", GATES, str(data)], capture_output=True,
                                     text=True, env=env, cwd=tree, check=True)
                screen_s, gates_s, glitches, input_glitches, digest = json.loads(run.stdout)
                print(f"| {name} | {tree} | {screen_s:.3f} | {gates_s:.3f} | {glitches} | {input_glitches} | "
                      f"{digest} |")
                sys.stdout.flush()


def without(lines: list[dict], ignored: set[str]) -> str:
    """The lines but for the ``ignored`` fields, as JSON text (a NaN equal to itself)."""
    return json.dumps([{key: value for key, value in line.items() if key not in ignored} for line in lines])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old-tree", type=Path, required=True, help="the checkout to compare with")
    parser.add_argument("--ignore", nargs="*", default=["arx_identifier"],
                        help="fields left out of the comparison besides elapsed_s (default: arx_identifier)")
    parser.add_argument("--gates", action="store_true", help="instead, the gate loops alone (no identification)")
    args = parser.parse_args()
    if args.gates:
        gates_rows([args.old_tree, HERE])
        return
    ignored = {"elapsed_s", *args.ignore}
    print("| record | samples | updates | old run (s) | new run (s) | old tracking (s) | new tracking (s) "
          "| lines the same |")
    print("|---|---|---|---|---|---|---|---|")
    totals = np.zeros(4)
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, u, y, dt, options) in enumerate(bench_records()):
            data = Path(tmp) / f"record{i}.npz"
            save_record(data, u, y, dt)
            old, old_s, old_tracking = track(args.old_tree, data, options)
            new, new_s, new_tracking = track(HERE, data, options)
            same = without(old, ignored) == without(new, ignored)
            totals += (old_s, new_s, old_tracking, new_tracking)
            print(f"| {name} | {len(y)} | {len(new)} | {old_s:.1f} | {new_s:.1f} | {old_tracking:.1f} | "
                  f"{new_tracking:.1f} | {same} |")
            sys.stdout.flush()
    print(f"| total | | | {totals[0]:.1f} | {totals[1]:.1f} | {totals[2]:.1f} | {totals[3]:.1f} | |")


if __name__ == "__main__":
    main()
