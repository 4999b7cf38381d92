#!/usr/bin/env python3
"""Identification accuracy on the real steel-subframe record: okid_ros against the paper and SIPPY.

The record (``../shared/data/real/daisy-steel-subframe``: DaISy "flexible structure", 2 shaker
forces, 28 accelerometers, 1024 Hz, 8523 samples) has no published modal truth; its
``truth.json`` lists 15 reference modes that are the data folder's own stabilized-ERA estimates
("reference_estimates_not_published"). Every method identifies on samples 0-5999 and is scored
on the held-out samples 6000-8522:

* one-step prediction: the model's Kalman predictor runs causally from sample 0 (state 0) over
  the whole record and the score is the mean over the 28 outputs of ``var(e) / var(y)`` on
  6000+ (``inf`` when the predictor diverges);
* free-run simulation NRMSE: the deterministic response ``y = C x + D u`` from sample 0 (state
  0), mean over outputs of ``||y_sim - y|| / ||y - mean(y)||`` on 6000+;
* spectral radius of ``A`` and of the predictor ``A - L C`` (``L = A K`` in the paper's
  convention ``x_{k+1} = A x + B u + A K e``; SIPPY's ``K`` is ``L`` itself, see
  ``okid_bench.peers``);
* listed modes: okid_ros's own list (``model.modes``: its physical-mode filter); for the peers,
  the stable eigenvalue pairs of ``A`` with damping below 10 % (``okid_bench.scoring``);
* reference modes matched: one-to-one (Hungarian) within 0.5 % in frequency.

Everyone gets the same data: the means of samples 0-5999 are removed from ``u`` and ``y``
(okid_ros removes offsets again inside; they are then zero). Wall time of the identification
call only. BLAS threads default to 1 (``--threads``), set before numpy loads, as in
``bench/identification_accuracy.py`` (whose thread setup, peer wrapper and version line this
script reuses).

Usage::

    python bench/real_record.py                                   # the default methods, ~1 min
    python bench/real_record.py --repeat 3                        # time: shortest of 3, ~2.5 min
    python bench/real_record.py --methods okid-default,paper      # a subset, seconds
    python bench/real_record.py --out /tmp/real.md [--force]      # also write the markdown
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import sys
import time
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_RECORD = REPO.parent / "shared" / "data" / "real" / "daisy-steel-subframe"

# Loading the accuracy bench sets the BLAS thread variables from this process's --threads
# (default 1) before numpy is imported anywhere.
_spec = importlib.util.spec_from_file_location("identification_accuracy", REPO / "bench" / "identification_accuracy.py")
accuracy = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = accuracy  # its dataclasses look their module up
_spec.loader.exec_module(accuracy)

import numpy as np  # noqa: E402

from okid_bench.peers import PEERS, peer_identify  # noqa: E402
from okid_bench.report import add_output_options, refuse_existing, write_output  # noqa: E402
from okid_bench.scoring import Mode, match_modes, model_matrices, modes_of, physical_modes  # noqa: E402
from okid_ros.core.statespace import simulate, spectral_radius  # noqa: E402

TRAIN_SAMPLES = 6000
MATCH_TOL = 0.005
PEER_STATES = 40
PEER_HORIZON = 50
PEER_MAX_DAMPING = 0.10


def _okid_methods() -> dict:
    from okid_ros.core.pipeline import identify

    return {
        "okid-default": ("identify(u, y, dt): ARX order by GCV, states by BIC",
                         lambda u, y, dt: identify(u, y, dt)),
        "okid-q20": ("identify(u, y, dt, order=20): ARX order fixed, states by BIC",
                     lambda u, y, dt: identify(u, y, dt, order=20)),
        "okid-riccati": ('identify(u, y, dt, gain="riccati")',
                         lambda u, y, dt: identify(u, y, dt, gain="riccati")),
        "okid-whitening": ('identify(u, y, dt, gain="whitening"): the paper\'s gain',
                           lambda u, y, dt: identify(u, y, dt, gain="whitening")),
        "paper": ('identify(u, y, dt, order=20, method="paper"): as published, states by the largest '
                  "singular-value gap",
                  lambda u, y, dt: identify(u, y, dt, order=20, method="paper")),
    }


def _peer(name: str, n_states: int, horizon: int):
    def run(u, y, dt):
        model, why = peer_identify(name, u, y, dt, n_states, horizon=horizon)
        if model is None:
            raise RuntimeError(why)
        return model
    return run


def all_methods(n_states: int = PEER_STATES, horizon: int = PEER_HORIZON) -> dict:
    """Method name -> (description, callable(u, y, dt) -> model); peers of ``okid_bench.peers``."""
    methods = _okid_methods()
    for name in PEERS:
        if name.startswith("sippy-") or name == "nfoursid":
            methods[name] = (f"okid_bench.peers {name}, n = {n_states}, horizon {horizon}",
                             _peer(name, n_states, horizon))
    return methods


DEFAULT_METHODS = ("okid-default", "okid-q20", "okid-riccati", "okid-whitening", "paper",
                   "sippy-moesp", "sippy-n4sid")


def load_record(folder: Path) -> tuple[np.ndarray, np.ndarray, float, list[float]]:
    """Inputs (N, 2), outputs (N, 28), sample time and the 15 reference frequencies [Hz]."""
    data = np.load(folder / "steel_subframe.npz")
    truth = json.loads((folder / "truth.json").read_text())
    reference = [float(m["f_Hz"]) for m in truth["reference_estimates_not_published"]["modes"]]
    return np.asarray(data["u"], float), np.asarray(data["y"], float), float(data["sample_time_s"]), reference


def _listed_modes(model, dt: float) -> list[Mode]:
    """The modes a user is shown: okid_ros's own list, else stable pairs of A below 10 % damping."""
    own = getattr(model, "modes", None)
    if own is not None:
        return [Mode(complex(md.eigenvalue), float(md.frequency_rad_s), float(md.frequency_hz),
                     float(md.damping_ratio)) for md in own]
    A = model["A"] if isinstance(model, dict) else model.A
    return physical_modes(modes_of(A, dt), dt, PEER_MAX_DAMPING)


def score(model, u: np.ndarray, y: np.ndarray, dt: float, reference: list[float], start: int) -> dict:
    """Held-out scores of one model on the offset-free record (see the module docstring)."""
    mats = model_matrices(model)
    A, B, C, D, L = mats["A"], mats["B"], mats["C"], mats["D"], mats["L"]
    held = slice(start, None)
    y_held = y[held]
    var_y = np.var(y_held, axis=0)
    z = np.linalg.eigvals(A)
    out = {"n_states": int(A.shape[0]), "rho_A": spectral_radius(A), "rho_predictor": None,
           "one_step": None, "nrmse": None, "unstable_poles": sorted((complex(v) for v in z[np.abs(z) >= 1.0]),
                                                                     key=abs, reverse=True)}
    with np.errstate(all="ignore"):
        if L is not None:
            out["rho_predictor"] = spectral_radius(A - L @ C)
            # Predictor x+ = (A - L C) x + (B - L D) u + L y, yhat = C x + D u, from sample 0.
            p = C.shape[0]
            y_hat = simulate(A - L @ C, np.hstack([B - L @ D, L]), C, np.hstack([D, np.zeros((p, p))]),
                             np.hstack([u, y]))
            e = y_held - y_hat[held]
            ratio = np.var(e, axis=0) / var_y
            out["one_step"] = float(np.mean(ratio)) if np.all(np.isfinite(ratio)) else float("inf")
        y_sim = simulate(A, B, C, D, u)
        err = np.linalg.norm(y_sim[held] - y_held, axis=0) / np.linalg.norm(y_held - y_held.mean(axis=0), axis=0)
        out["nrmse"] = float(np.mean(err)) if np.all(np.isfinite(err)) else float("inf")
    listed = _listed_modes(model, dt)
    ref_modes = [Mode(0j, 2 * np.pi * f, f, 0.0) for f in reference]
    mm = match_modes(listed, ref_modes, MATCH_TOL)
    out["modes_listed"] = len(listed)
    out["matched"] = len(reference) - mm.missed
    out["missed_hz"] = [f for f, md in zip(reference, mm.matched) if md is None]
    out["matched_modes"] = [None if md is None else (md.frequency_hz, md.damping_ratio) for md in mm.matched]
    errs = np.abs(mm.frequency_error_pct[np.isfinite(mm.frequency_error_pct)])
    out["f_err_max_pct"] = float(errs.max()) if errs.size else None
    out["unmatched_hz"] = sorted(md.frequency_hz for md in mm.spurious)
    return out


def run(methods: dict, u: np.ndarray, y: np.ndarray, dt: float, reference: list[float], train: int,
        log=print, repeat: int = 1) -> list[dict]:
    """Identify with each method on ``[:train]`` and score on ``[train:]``; a failure is a row.

    The time is the shortest of ``repeat`` identical identifications (the machine is shared).
    """
    rows = []
    for name, (description, fn) in methods.items():
        row = {"method": name, "description": description, "ok": False, "reason": ""}
        t0 = time.perf_counter()
        try:
            times = []
            for _ in range(max(repeat, 1)):
                t0 = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    model = fn(u[:train].copy(), y[:train].copy(), dt)
                times.append(time.perf_counter() - t0)
            row["time_s"] = min(times)
            row.update(score(model, u, y, dt, reference, train))
            row["ok"] = True
            arx = getattr(model, "arx", None)
            row["arx_order"] = None if arx is None else int(arx.order)
            offsets = [getattr(model, k, None) for k in ("input_offset", "output_offset")]
            row["max_offset"] = max((float(np.max(np.abs(o))) for o in offsets if o is not None), default=None)
        except Exception as exc:  # noqa: BLE001 - a failure is a result
            row["time_s"] = time.perf_counter() - t0
            msg = (str(exc).splitlines() or [""])[0]
            row["reason"] = f"{type(exc).__name__}: {msg}"[:200]
        rows.append(row)
        if row["ok"]:
            log(f"  {name:15s} ok  t={row['time_s']:7.2f}s n={row['n_states']} one-step={row['one_step']} "
                f"nrmse={row['nrmse']} rho={row['rho_A']:.4f}/{row['rho_predictor']} "
                f"modes={row['modes_listed']} matched={row['matched']}/{len(reference)}")
        else:
            log(f"  {name:15s} ERR t={row['time_s']:7.2f}s {row['reason']}")
    return rows


def _num(x, fmt: str) -> str:
    if x is None:
        return "n/a"
    if not np.isfinite(x):
        return "diverges"
    return format(x, fmt)


def markdown(rows: list[dict], n_reference: int, command: str) -> str:
    """The results table, the per-mode table of the successful methods and the notes."""
    lines = [
        f"Command: `{command}`. {accuracy._versions()}; BLAS threads "
        f"{os.environ.get('OPENBLAS_NUM_THREADS', '?')}; {platform.machine()}, "
        f"{os.cpu_count()} CPUs.",
        "",
        "| method | time s | states | ARX q | one-step var(e)/var(y) | free-run NRMSE % | rho(A) | "
        "rho(A - AKC) | modes listed | reference matched (0.5 %) | max f err % |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if not r["ok"]:
            lines.append(f"| {r['method']} | {r['time_s']:.2f} | failed: {r['reason']} | | | | | | | | |")
            continue
        nrmse = None if r["nrmse"] is None else 100 * r["nrmse"]
        lines.append(
            f"| {r['method']} | {r['time_s']:.2f} | {r['n_states']} | {r['arx_order'] or 'n/a'} | "
            f"{_num(r['one_step'], '.3g')} | {_num(nrmse, '.1f')} | {_num(r['rho_A'], '.4f')} | "
            f"{_num(r['rho_predictor'], '.4f')} | {r['modes_listed']} | {r['matched']}/{n_reference} | "
            f"{_num(r['f_err_max_pct'], '.2f')} |")
    lines.append("")
    for r in rows:
        if r["ok"] and r["missed_hz"]:
            lines.append(f"- {r['method']} misses the reference modes at "
                         + ", ".join(f"{f:g}" for f in r["missed_hz"]) + " Hz.")
        if r["ok"] and r["unstable_poles"]:
            poles = ", ".join(f"{v.real:.3f}{v.imag:+.3f}j" for v in r["unstable_poles"][:6])
            lines.append(f"- {r['method']}: {len(r['unstable_poles'])} eigenvalue(s) of A on or outside the unit "
                         f"circle ({poles}), so its free-run simulation diverges.")
        if r["ok"] and r["unmatched_hz"]:
            lines.append(f"- {r['method']} also lists " + ", ".join(f"{f:.1f}" for f in r["unmatched_hz"])
                         + " Hz (no reference mode within 0.5 %).")
    lines.append("")
    return "\n".join(lines)


def mode_table(rows: list[dict], reference: list[float]) -> str:
    """Frequency (Hz) and damping (%) matched to each reference mode, per successful method."""
    ok, same = [], []
    for r in rows:
        if not (r["ok"] and r["matched"]):
            continue
        twin = next((o for o in ok if o["matched_modes"] == r["matched_modes"]), None)
        if twin is None:
            ok.append(r)
        else:
            same.append(f"{r['method']} as {twin['method']}")
    if not ok:
        return ""
    lines = ["| reference f Hz | " + " | ".join(f"{r['method']} f Hz / zeta %" for r in ok) + " |",
             "|---|" + "---|" * len(ok)]
    for i, f in enumerate(reference):
        cells = []
        for r in ok:
            md = r["matched_modes"][i]
            cells.append("-" if md is None else f"{md[0]:.2f} / {100 * md[1]:.2f}")
        lines.append(f"| {f:.2f} | " + " | ".join(cells) + " |")
    if same:
        lines += ["", "Same modes: " + "; ".join(same) + "."]
    lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--record", default=str(DEFAULT_RECORD),
                    help="folder with steel_subframe.npz and truth.json (default: ../shared/data/real/...)")
    ap.add_argument("--methods", default=None,
                    help=f"comma-separated methods (default: {','.join(DEFAULT_METHODS)}; also sippy-cva, nfoursid)")
    ap.add_argument("--train", type=int, default=TRAIN_SAMPLES,
                    help=f"identify on samples [0, train), score on the rest (default {TRAIN_SAMPLES})")
    ap.add_argument("--peer-states", type=int, default=PEER_STATES, help=f"peers' model order (default {PEER_STATES})")
    ap.add_argument("--peer-horizon", type=int, default=PEER_HORIZON,
                    help=f"peers' subspace horizon (block rows, default {PEER_HORIZON})")
    add_output_options(ap)
    ap.add_argument("--repeat", type=int, default=1,
                    help="identifications per method; the time reported is the shortest (default 1)")
    ap.add_argument("--threads", default="1", help="BLAS threads (default 1)")
    ap.add_argument("--quiet", action="store_true", help="no per-method progress on stderr")
    args = ap.parse_args(argv)

    available = all_methods(args.peer_states, args.peer_horizon)
    wanted = args.methods.split(",") if args.methods else list(DEFAULT_METHODS)
    unknown = [m for m in wanted if m not in available]
    if unknown:
        ap.error(f"unknown methods: {', '.join(unknown)} (known: {', '.join(available)})")
    refuse_existing(ap, args)
    folder = Path(args.record)
    if not (folder / "steel_subframe.npz").is_file() or not (folder / "truth.json").is_file():
        ap.error(f"{folder}: no steel_subframe.npz and truth.json there")

    u, y, dt, reference = load_record(folder)
    if not 0 < args.train < u.shape[0] - 1:
        ap.error(f"--train must be between 1 and {u.shape[0] - 2}, got {args.train}")
    # The same offset removal for everyone: the means of the identification samples.
    u = u - u[: args.train].mean(axis=0)
    y = y - y[: args.train].mean(axis=0)
    log = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    rows = run({m: available[m] for m in wanted}, u, y, dt, reference, args.train, log, args.repeat)

    command = "python bench/real_record.py " + " ".join(sys.argv[1:] if argv is None else argv)
    doc = [markdown(rows, len(reference), command.strip()), mode_table(rows, reference)]
    text = "\n".join(d for d in doc if d)
    print(text, flush=True)
    write_output(args.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
