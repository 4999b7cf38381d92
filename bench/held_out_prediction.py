#!/usr/bin/env python3
"""Held-out one-step prediction on real records: ``identify``'s defaults against SIPPY's BIC.

The check of issue 17 on records of any structure: each record is split once per
``--train-fractions`` value; every method identifies on the first part and is scored on the
rest. Methods:

* ``okid``: ``okid_ros.core.pipeline.identify(u, y, dt)`` with its defaults (the ARX order by
  GCV, the state order by BIC: what ``okid-ros identify`` does);
* ``sippy-n4sid``, ``sippy-moesp``, ``sippy-cva``: SIPPY's subspace methods with their own order
  choice (``IC="BIC"``, orders 1..``--peer-max-order``, past and future horizons
  ``--peer-horizon``; ``okid_bench.peers``).

Score: the model's one-step predictor ``x+ = (A - L C) x + (B - L D) u + L y`` runs from state 0
over the whole record; per output ``var(e) / var(y)`` on the held-out part, averaged over the
outputs (lower is better; ``inf`` when it diverges). ``ratio``: against the best SIPPY method on
the same split. Every method gets the same data: the training part's means removed.

``--order-grid N1,N2,...`` adds, for okid, the held-out score at each state order (same ARX
order as its default run): how far the state order chosen by BIC is from the best one on data
it did not see.

``--unrefined`` adds the method ``okid-unrefined``: identify's defaults without the
prediction-error refinement (``refine=False``), to see what the refinement does out of sample.
``--tc`` adds ``okid-tc``: identify's defaults with the TC kernel for the ARX fit
(``regularization="tc"``, its decay by GCV) instead of the ridge prior.

``--held-out-choice F`` adds the method ``okid-held-out``: the state order chosen by held-out
prediction instead of BIC, within the training part alone. The first fraction ``F`` of the
training part is identified at each state order of ``--order-grid`` (default 2, 4, .., 40; the
ARX order of identify's default run on that part), each model is scored on the rest of the
training part, and the best order is identified on the whole training part (the ARX order of
the ``okid`` row) and scored on the held-out part like every other method.

Records: an ``identify`` ``.npz`` (``u``, ``y``, ``sample_time_s``), or a whitespace-separated
text file with the input columns first, named ``path.dat:M[:DT[:K]]`` (``M`` inputs, sample time
``DT`` seconds, default 1; the DaISy layout), where ``K`` leading columns (a time column, as in
several DaISy files) are dropped first.

Usage::

    python bench/held_out_prediction.py rec.npz flutter.dat:1 CD_player_arm.dat:2
    python bench/held_out_prediction.py rec.npz --train-fractions 0.5 0.67 0.8 --order-grid 2,4,8,16
    python bench/held_out_prediction.py rec.npz --held-out-choice 0.75
    python bench/held_out_prediction.py rec.npz --out /tmp/held-out.md [--force]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # before numpy loads

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from okid_bench.peers import BIC, peer_identify  # noqa: E402
from okid_bench.report import add_output_options, refuse_existing, write_output  # noqa: E402
from okid_bench.scoring import model_matrices  # noqa: E402
from okid_ros.core.pipeline import IdentificationError, identify  # noqa: E402
from okid_ros.core.statespace import simulate, spectral_radius  # noqa: E402

PEER_METHODS = ("sippy-n4sid", "sippy-moesp", "sippy-cva")
HELD_OUT_GRID = list(range(2, 42, 2))  # identify's automatic search covers 2..40


def load_record(spec: str) -> tuple[str, np.ndarray, np.ndarray, float]:
    """(name, u (N, m), y (N, p), sample_time_s) of ``path.npz`` or ``path.dat:M[:DT[:K]]``."""
    path, _, rest = spec.partition(":")
    name = Path(path).stem
    if path.endswith(".npz"):
        data = np.load(path)
        if "u" not in data:
            raise SystemExit(f"{path}: no inputs 'u' (this check compares input-output methods)")
        return name, np.asarray(data["u"], float).reshape(len(data["u"]), -1), \
            np.asarray(data["y"], float).reshape(len(data["y"]), -1), float(data["sample_time_s"])
    fields = rest.split(":") if rest else []
    if not fields:
        raise SystemExit(f"{spec}: give the number of input columns, e.g. {path}:1")
    n_inputs, dt = int(fields[0]), float(fields[1]) if len(fields) > 1 else 1.0
    skip = int(fields[2]) if len(fields) > 2 else 0
    table = np.loadtxt(path, ndmin=2)[:, skip:]
    return name, table[:, :n_inputs], table[:, n_inputs:], dt


def held_out_score(model, u: np.ndarray, y: np.ndarray, start: int) -> dict:
    """One-step prediction ``var(e) / var(y)`` on ``[start:]`` (mean over outputs) and the radii."""
    mats = model_matrices(model)
    A, B, C, D, L = mats["A"], mats["B"], mats["C"], mats["D"], mats["L"]
    out = {"n_states": int(A.shape[0]), "rho_A": spectral_radius(A), "rho_predictor": float("nan"),
           "one_step": float("inf")}
    if L is None:
        return out
    p = C.shape[0]
    out["rho_predictor"] = spectral_radius(A - L @ C)
    with np.errstate(all="ignore"):
        y_hat = simulate(A - L @ C, np.hstack([B - L @ D, L]), C, np.hstack([D, np.zeros((p, p))]), np.hstack([u, y]))
        ratio = np.var(y[start:] - y_hat[start:], axis=0) / np.var(y[start:], axis=0)
    if np.all(np.isfinite(ratio)):
        out["one_step"] = float(np.mean(ratio))
    return out


def _okid(u, y, dt, **options):
    model = identify(u, y, dt, **options)
    return model, {"arx_order": model.arx.order}


def _okid_held_out_order(u, y, dt, *, inner_fraction: float, order_grid: list[int], arx_order: int):
    """The model identified at the state order that predicts the last ``1 - inner_fraction`` of ``u, y`` best.

    The orders are fitted on the first ``inner_fraction`` (its means removed, as for the record).
    """
    fit = int(inner_fraction * u.shape[0])
    u_in, y_in = u - u[:fit].mean(axis=0), y - y[:fit].mean(axis=0)
    inner_arx_order = identify(u_in[:fit], y_in[:fit], dt).arx.order
    scores = {}
    for n in order_grid:
        try:
            model = identify(u_in[:fit], y_in[:fit], dt, order=inner_arx_order, n_states=n)
            scores[n] = held_out_score(model, u_in, y_in, fit)["one_step"]
        except IdentificationError:
            continue
    if not scores or not np.isfinite(min(scores.values())):
        raise RuntimeError("no state order predicts the validation part")
    chosen = min(scores, key=scores.get)
    model = identify(u, y, dt, order=arx_order, n_states=chosen)
    return model, {"arx_order": arx_order, "validation_states": chosen}


def run_split(name: str, u: np.ndarray, y: np.ndarray, dt: float, fraction: float, *, peer_horizon: int,
              peer_max_order: int, order_grid: list[int], held_out_choice: float | None = None,
              unrefined: bool = False, tc: bool = False,
              log=print) -> list[dict]:
    """Every method on one split of one record: a row each (a failure is a row too)."""
    train = int(fraction * u.shape[0])
    u = u - u[:train].mean(axis=0)
    y = y - y[:train].mean(axis=0)
    flat = np.flatnonzero(np.var(y[train:], axis=0) <= 1e-12 * np.var(y[:train], axis=0))
    if flat.size:  # var(e) / var(y) means nothing there (flutter.dat's last samples are constant)
        log(f"{name} {fraction:.2f}: skipped, output(s) {flat.tolist()} constant over the held-out part")
        return []
    rows = []
    methods = [("okid", lambda: _okid(u[:train], y[:train], dt))]
    if unrefined:
        methods.append(("okid-unrefined", lambda: _okid(u[:train], y[:train], dt, refine=False)))
    if tc:
        methods.append(("okid-tc", lambda: _okid(u[:train], y[:train], dt, regularization="tc")))
    methods += [(peer, lambda peer=peer: _peer(peer, u[:train], y[:train], dt, peer_horizon, peer_max_order))
                for peer in PEER_METHODS]
    for method, fit in methods:
        row = {"record": name, "fraction": fraction, "train": train, "method": method}
        started = time.perf_counter()
        try:
            model, info = fit()
            row.update(held_out_score(model, u, y, train), **info)
        except (IdentificationError, RuntimeError) as exc:
            row.update(failed=str(exc)[:160])
        row["seconds"] = time.perf_counter() - started
        rows.append(row)
    if held_out_choice is not None and "failed" not in rows[0]:
        row = {"record": name, "fraction": fraction, "train": train, "method": "okid-held-out"}
        started = time.perf_counter()
        try:
            model, info = _okid_held_out_order(u[:train], y[:train], dt, inner_fraction=held_out_choice,
                                               order_grid=order_grid or HELD_OUT_GRID,
                                               arx_order=rows[0]["arx_order"])
            row.update(held_out_score(model, u, y, train), **info)
        except (IdentificationError, RuntimeError) as exc:
            row.update(failed=str(exc)[:160])
        row["seconds"] = time.perf_counter() - started
        rows.insert(1, row)
    peers = [r["one_step"] for r in rows if r["method"] in PEER_METHODS and np.isfinite(r.get("one_step", np.inf))]
    best = min(peers) if peers else float("nan")
    for row in rows:
        row["ratio"] = row.get("one_step", float("inf")) / best
        log(_line(row))
    okid = rows[0]
    if order_grid and "failed" not in okid:
        okid["grid"] = {}
        for n in order_grid:
            try:
                model = identify(u[:train], y[:train], dt, order=okid["arx_order"], n_states=n)
                okid["grid"][n] = held_out_score(model, u, y, train)["one_step"]
            except IdentificationError:
                okid["grid"][n] = float("nan")
        log("  okid by state order: " + " ".join(f"{n}:{v:.4g}" for n, v in okid["grid"].items()))
    return rows


def _peer(method, u, y, dt, horizon, max_order):
    model, why = peer_identify(method, u, y, dt, BIC, horizon=horizon, max_order=max_order)
    if model is None:
        raise RuntimeError(why)
    return model, {}


def _line(row: dict) -> str:
    if "failed" in row:
        return f"{row['record']} {row['fraction']:.2f} {row['method']}: failed: {row['failed']}"
    return (f"{row['record']} {row['fraction']:.2f} {row['method']}: n {row['n_states']}, one-step "
            f"{row['one_step']:.4g}, ratio {row['ratio']:.3f}, rho(A) {row['rho_A']:.4f}, "
            f"rho(A-LC) {row['rho_predictor']:.4f}, {row['seconds']:.2f} s")


def markdown(rows: list[dict]) -> str:
    """The results table, and the order grid's table when there is one."""
    lines = ["| record | train fraction | method | states | ARX q | held-out one-step var(e)/var(y) | "
             "ratio to best SIPPY | rho(A) | rho(A - LC) | time s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "failed" in r:
            lines.append(f"| {r['record']} | {r['fraction']:.2f} | {r['method']} | failed: {r['failed']} |||||||")
            continue
        lines.append(f"| {r['record']} | {r['fraction']:.2f} | {r['method']} | {r['n_states']} | "
                     f"{r.get('arx_order', '')} | {r['one_step']:.4g} | {r['ratio']:.3f} | {r['rho_A']:.4f} | "
                     f"{r['rho_predictor']:.4f} | {r['seconds']:.2f} |")
    grids = [r for r in rows if r.get("grid")]
    if grids:
        lines += ["", "| record | train fraction | states by BIC | its held-out | best state order on the grid | "
                  "its held-out | BIC / best |", "|---|---|---|---|---|---|---|"]
        for r in grids:
            finite = {n: v for n, v in r["grid"].items() if np.isfinite(v)}
            n_best = min(finite, key=finite.get) if finite else None
            best = finite[n_best] if finite else float("nan")
            lines.append(f"| {r['record']} | {r['fraction']:.2f} | {r['n_states']} | {r['one_step']:.4g} | "
                         f"{n_best} | {best:.4g} | {r['one_step'] / best:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("records", nargs="+",
                        help="path.npz, or path.dat:M[:DT[:K]] (M input columns first, after K columns dropped)")
    parser.add_argument("--train-fractions", type=float, nargs="+", default=[0.67])
    parser.add_argument("--peer-horizon", type=int, default=20)
    parser.add_argument("--peer-max-order", type=int, default=20)
    parser.add_argument("--order-grid", default="", help="comma-separated state orders for okid (e.g. 2,4,8,16)")
    parser.add_argument("--held-out-choice", type=float, default=None, metavar="F",
                        help="add okid-held-out: the state order by held-out prediction on the last 1-F of "
                             "the training part (e.g. 0.75)")
    parser.add_argument("--unrefined", action="store_true",
                        help="add okid-unrefined: identify's defaults without the prediction-error refinement")
    parser.add_argument("--tc", action="store_true", help="add okid-tc: identify's defaults with the TC kernel")
    add_output_options(parser)
    args = parser.parse_args(argv)
    refuse_existing(parser, args)
    if not all(0.1 <= f <= 0.9 for f in args.train_fractions):
        parser.error("train fractions must be within [0.1, 0.9]")
    if args.held_out_choice is not None and not 0.3 <= args.held_out_choice <= 0.95:
        parser.error("--held-out-choice must be within [0.3, 0.95]")
    grid = [int(n) for n in args.order_grid.split(",") if n.strip()]
    rows = []
    for spec in args.records:
        name, u, y, dt = load_record(spec)
        for fraction in args.train_fractions:
            rows += run_split(name, u, y, dt, fraction, peer_horizon=args.peer_horizon,
                              peer_max_order=args.peer_max_order, order_grid=grid,
                              held_out_choice=args.held_out_choice, unrefined=args.unrefined, tc=args.tc)
    table = markdown(rows)
    print()
    print(table)
    write_output(args.out, table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
