#!/usr/bin/env python3
"""Node 1 under a flood of structural changes: its window restarts, against the old code, in one run.

A replayed or misbehaving ``StructuralChange`` publisher: after every sample of one second (1000
samples at 1 kHz) a change with a new, increasing stamp ``--lead`` samples back, among the window's
rows (window 2000, ARX order 40, p = m = 2: the node's tests' size), while node 1 solves every
``--solve-every`` samples (250: 4 Hz, as node 1 in the DDS tests; node 1's default is 1 Hz). Node 1's
service is driven as the node drives it (``restart_at`` per message, ``capture`` / solve / ``accept``
per publish; the node holds its input thread's lock through both), one second of samples before the
flood and one after. Columns: the changes' replays (``window_restarts``), the CPU time (of the thread,
so that other load on the machine does not count) in ``restart_at`` and in ``capture`` (the old code
replays in the first, the new in the second, once per solve), the longest of either call (what the
input thread waits for at once), all within the flood's second, and the snapshots' ARX coefficients
of the whole run compared old against new.

The real change (``--real``, ~1 min): both services over the switched 2-mode structure of
``test_service_change.py`` (6 and 21 Hz, 250 Hz, frequencies 6 % down at sample 5000, order 40,
window 2000, a model every 250 samples): node 1's models, node 2's change events and the restarts,
old against new.

Each code version runs in a worker process (``--worker``, ``PYTHONPATH`` at that version's tree),
old and new alternating, one BLAS thread. The old code is a ``git archive`` of ``--old-ref``
(default: the merge base with ``main``).

Usage::

    python bench/change_flood.py                 # ~1 min: 2 rounds of the flood
    python bench/change_flood.py --real          # and the real change
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

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"  # before numpy loads, here and in the workers

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DT, ORDER, WINDOW = 0.001, 40, 2000
WARM, FLOOD, AFTER = 3000, 1000, 1000  # samples before, during and after the flood


def _flood_service(solve_every: int):
    from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
    from okid_ros.service.params import ARX_NODE, resolve_parameters

    values = {"sample_time_s": DT, "arx.order": ORDER, "arx.window_length": WINDOW,
              "publish_rate_hz": 1.0 / (solve_every * DT)}
    return ArxIdentificationService(ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, values)))


def _flood_worker(out: Path, solve_every: int, lead: int) -> dict:
    """The flood with the code on PYTHONPATH; its timings (the snapshots' coefficients saved to ``out``)."""
    from okid_ros.service.arx_solve import solve_capture
    from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

    n = WARM + FLOOD + AFTER
    model = paper_model()
    u = lowpass_input(n, 2, 50.0, model.sample_time_s, seed=3)
    y, _ = simulate_innovation(model, u, seed=4)
    svc = _flood_service(solve_every)
    res = {"restart_s": 0.0, "restart_max_s": 0.0, "capture_s": 0.0, "capture_max_s": 0.0,
           "capture_quiet_s": 0.0, "push_s": 0.0}
    thetas, valid = [], []
    for k in range(n):
        flooding = WARM <= k < WARM + FLOOD
        start = time.thread_time()
        svc.push(k * DT, u[k], y[k])
        res["push_s"] += (time.thread_time() - start) * flooding
        if flooding:
            start = time.thread_time()
            svc.restart_at((k - lead) * DT)
            took = time.thread_time() - start
            res["restart_s"] += took
            res["restart_max_s"] = max(res["restart_max_s"], took)
        if k % solve_every == solve_every - 1:
            start = time.thread_time()
            capture = svc.capture()
            took = time.thread_time() - start
            if flooding:
                res["capture_s"] += took
                res["capture_max_s"] = max(res["capture_max_s"], took)
            elif k >= WARM + FLOOD:
                res["capture_quiet_s"] += took
            snap = svc.accept(capture, solve_capture(capture))
            thetas.append(snap.fit.theta if snap.fit is not None else np.full((1, 1), np.nan))
            valid.append(snap.valid)
    np.savez(out, *thetas, valid=np.array(valid))
    d = svc.diagnostics()
    res.update({key: d[key] for key in ("window_restarts", "window_restarts_ignored", "window_restarts_ignored_why",
                                        "last_restart_stamp_s")})
    res["snapshots"], res["valid"] = len(valid), int(sum(valid))
    return res


def _real_worker(out: Path) -> dict:
    """Both services over the switched structure of ``test_service_change.py``; node 1's models saved to ``out``."""
    from okid_bench.switching import added_mass_structure, simulate_switched
    from okid_ros.service.estimation import ModalEstimationParams, ModalEstimationService
    from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
    from okid_ros.sim.inputs import lowpass_input

    dt, change, n, every = 1.0 / 250.0, 5000, 8000, 250
    before, after = added_mass_structure([6.0, 21.0], [0.01, 0.015], 2, 2, dt, frequency_factor=0.94, seed=1)
    u = lowpass_input(n, 2, 40.0, dt, seed=3)
    y = simulate_switched([before, after], change, u, seed=4)
    ident = ArxIdentificationService(ArxIdentificationParams(dt, ORDER, 2, 2, WINDOW, restart_min_fill=0.5))
    est = ModalEstimationService(ModalEstimationParams(dt, 2, 2, n_states=4, refine=False))
    thetas, events = [], []
    for k in range(n):
        t = 100.0 + k * dt
        ident.push(t, u[k], y[k])
        result = est.step(t, u[k], y[k])
        if result is not None and result.change is not None:
            events.append([k, result.change.change_stamp_s, sorted(m.frequency_hz for m in result.change.modes_after)])
            ident.restart_at(result.change.change_stamp_s)
        if k % every == every - 1:
            snap = ident.snapshot()
            thetas.append(snap.fit.theta if snap.fit is not None else np.full((1, 1), np.nan))
            if snap.valid:
                est.submit_arx(snap.fit, snap.stamp_s, snap.model_id, snap.window_rows)
                est.process_pending()
    np.savez(out, *thetas)
    d = ident.diagnostics()
    return {"events": events, "window_restarts": d["window_restarts"], "ignored": d["window_restarts_ignored"],
            "last_restart_stamp_s": d["last_restart_stamp_s"],
            "modes": sorted(m.frequency_hz for m in est.current_modes)}


def _old_tree(ref: str) -> Path:
    folder = Path(tempfile.mkdtemp(prefix="okid-base-"))
    archive = subprocess.run(["git", "-C", str(REPO), "archive", ref], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder


def _run_worker(tree: Path, case: str, out: Path, args: argparse.Namespace) -> dict:
    env = dict(os.environ, PYTHONPATH=f"{tree}:{tree / 'bench'}")
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", case, "--out", str(out),
           "--solve-every", str(args.solve_every), "--lead", str(args.lead)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"worker failed ({tree}): {done.stderr.strip().splitlines()[-3:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _same_arrays(old: Path, new: Path) -> str:
    """Whether two saved runs hold the same arrays bit for bit, or the largest relative difference."""
    with np.load(old) as a, np.load(new) as b:
        if sorted(a.files) != sorted(b.files):
            return f"different counts ({len(a.files)} / {len(b.files)})"
        worst = 0.0
        for key in a.files:
            x, z = a[key], b[key]
            if x.shape != z.shape:
                return f"{key}: shapes {x.shape} / {z.shape}"
            if not np.array_equal(x, z, equal_nan=True):
                worst = max(worst, float(np.nanmax(np.abs(x - z)) / max(np.nanmax(np.abs(x)), 1e-300)))
        return "bit for bit" if worst == 0.0 else f"to {worst:.1e} relative"


def _flood_table(runs: dict, same: str, args: argparse.Namespace) -> str:
    ms = lambda key, code: 1e3 * float(np.median([r[key] for r in runs[code]]))  # noqa: E731
    lines = [f"Flood: {FLOOD} changes, one after each sample of a second at 1 kHz, each stamped {args.lead} samples "
             f"back; a solve every {args.solve_every} samples; medians of {args.rounds} rounds.\n",
             "| code | replays (window_restarts) | ignored | in restart_at, CPU ms | longest restart_at, ms "
             "| in capture, ms (the quiet second after) | longest capture, ms | change handling, CPU ms a second "
             "| pushes, ms | models valid |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for code in ("old", "new"):
        r = runs[code][-1]
        handling = ms("restart_s", code) + ms("capture_s", code) - ms("capture_quiet_s", code)
        lines.append(f"| {code} | {r['window_restarts']} | {r['window_restarts_ignored']} | "
                     f"{ms('restart_s', code):.1f} | {ms('restart_max_s', code):.2f} | {ms('capture_s', code):.1f} "
                     f"({ms('capture_quiet_s', code):.1f}) | {ms('capture_max_s', code):.2f} | {handling:.0f} | "
                     f"{ms('push_s', code):.0f} | {r['valid']} of {r['snapshots']} |")
    lines.append(f"\nThe snapshots' ARX coefficients, old against new: {same}. New code's "
                 f"`window_restarts_ignored_why`: `{runs['new'][-1]['window_restarts_ignored_why']}`")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--solve-every", type=int, default=250, help="samples between solves (default 250: 4 Hz)")
    ap.add_argument("--lead", type=int, default=1500, help="samples each change is stamped back (default 1500)")
    ap.add_argument("--rounds", type=int, default=2, help="old/new worker pairs (default 2)")
    ap.add_argument("--real", action="store_true", help="also the real change, both services (~1 min)")
    ap.add_argument("--old-ref", default=None, help="git ref of the old code (default: merge base with main)")
    args = ap.parse_args()
    if args.worker:
        out = Path(args.out)
        res = _flood_worker(out, args.solve_every, args.lead) if args.worker == "flood" else _real_worker(out)
        print(json.dumps(res))
        return
    ref = args.old_ref or subprocess.run(["git", "-C", str(REPO), "merge-base", "HEAD", "main"], check=True,
                                         capture_output=True, text=True).stdout.strip()
    trees, folder = {"old": _old_tree(ref), "new": REPO}, Path(tempfile.mkdtemp(prefix="okid-flood-"))
    runs: dict = {"old": [], "new": []}
    for _ in range(args.rounds):
        for code, tree in trees.items():
            runs[code].append(_run_worker(tree, "flood", folder / f"flood_{code}.npz", args))
    print(f"Old code: {ref[:12]} (git archive); new: {REPO} working tree. One BLAS thread. "
          f"Load average at the end: {os.getloadavg()[0]:.2f}.\n")
    print(_flood_table(runs, _same_arrays(folder / "flood_old.npz", folder / "flood_new.npz"), args))
    if args.real:
        real = {code: _run_worker(tree, "real", folder / f"real_{code}.npz", args) for code, tree in trees.items()}
        same = _same_arrays(folder / "real_old.npz", folder / "real_new.npz")
        print(f"\nReal change: node 1's models old against new {same}; "
              f"node 2's events the same: {real['old']['events'] == real['new']['events']}.\n")
        for code in ("old", "new"):
            r = real[code]
            print(f"- {code}: events (sample, change stamp s, modes after Hz) {r['events']}; window_restarts "
                  f"{r['window_restarts']}, ignored {r['ignored']}, last restart at {r['last_restart_stamp_s']:.3f} s, "
                  f"final modes {[round(f, 4) for f in r['modes']]} Hz")


if __name__ == "__main__":
    main()
