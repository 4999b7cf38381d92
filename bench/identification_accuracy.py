#!/usr/bin/env python3
"""Identification accuracy against known truth: our pipeline and peers on the same data.

For each named test system (``okid_bench.cases.benchmark_cases``), each data length and
each noise seed, one identification record and one held-out validation record are simulated,
every method identifies a model from the record **given the true state dimension** (and the
case's ARX order where the method has one), and the models are scored against the truth:

* frequency error (%) and damping error (percentage points) per true mode, RMS over seeds
  (over the seeds where the mode was found);
* missed true modes and spurious physical modes (stable, damping < 20 %, below Nyquist,
  not matched within 5 % in frequency), totals over seeds: these score every pole of ``A``;
* ``listed: missed / spurious``: the same for the modes the model lists (okid_ros's physical
  modes after its selection: what ``identify`` reports), paired one to one, totals over seeds;
  ``n/a`` for peers, which list none;
* one-step prediction-error power on the held-out record divided by the oracle Kalman
  predictor's (1.0 is the limit), median and max over seeds; ``n/a`` for methods without a
  noise model (python-control's ERA);
* relative error of the stochastic Markov parameters ``C A^i K`` (i = 1..100, outputs scaled to
  unit innovation by the true ``Re^{-1/2}``), median;
* wall time of the identification call, median.

Usage::

    python bench/identification_accuracy.py                 # all cases, 3750 and 15000, 5 seeds
    python bench/identification_accuracy.py --quick         # 3 cases, 3750 samples, 2 seeds
    python bench/identification_accuracy.py --cases paper-lp15,paper-lp50 --lengths 3750 --seeds 3
    python bench/identification_accuracy.py --out /tmp/accuracy.md --json /tmp/raw.json [--force]

Methods: ``okid-default`` (``okid_ros.core.pipeline.identify`` with the product's defaults: ARX
order by GCV, model order by BIC; it is not given the true order), ``okid`` (the case's ARX
order and the true model order), ``okid-auto`` (the case's ARX order, model order by BIC),
``okid-ls`` (as okid-auto without the refinement), ``okid-riccati`` (as okid-auto with the
Riccati gain), ``paper`` (``identify(method="paper")``; a model it returns unstable is refused
and counted as failed) and the peers of ``okid_bench.peers``.  If ``okid_ros.core.pipeline``
cannot be imported, the bench
runs the peers alone.  BLAS threads default to 1 (``--threads``) so timings are comparable and
the machine stays usable.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable, Optional

import blas_threads  # noqa: F401  (sets the BLAS threads before numpy loads)
import checkout
import numpy as np  # noqa: E402

checkout.add()

from okid_bench.cases import BenchmarkCase, benchmark_cases  # noqa: E402
from okid_bench.peers import PEERS, available_peers, peer_identify  # noqa: E402
from okid_bench.report import add_output_options, refuse_existing, write_output  # noqa: E402
from okid_bench.scoring import (  # noqa: E402
    assign_by_frequency,
    match_modes,
    modes_of,
    physical_modes,
    prediction_error_ratio,
    stochastic_markov_error,
)
from okid_ros.sim.simulators import simulate  # noqa: E402

QUICK_CASES = ("paper-lp15", "paper-lp50", "close-pair")
MODE_TOL = 0.05
N_MARKOV_TERMS = 100

#: method(u, y, dt, n_states, order) -> model (dict or object with A, B, C, D and K or
#: predictor_gain); raise on failure.
Method = Callable[[np.ndarray, np.ndarray, float, int, int], object]


def _our_methods() -> tuple[dict[str, Method], str]:
    try:
        from okid_ros.core.pipeline import identify
    except Exception as exc:  # noqa: BLE001 - bench runs peers alone
        return {}, f"okid_ros.core.pipeline not importable ({type(exc).__name__}: {exc})"

    def okid(u, y, dt, n, q):
        return identify(u, y, dt, order=q, n_states=n)

    def okid_auto(u, y, dt, n, q):
        return identify(u, y, dt, order=q, n_states="auto")

    def paper(u, y, dt, n, q):
        return identify(u, y, dt, order=q, n_states=n, method="paper")

    def okid_ls(u, y, dt, n, q):
        return identify(u, y, dt, order=q, n_states="auto", refine=False)

    def okid_default(u, y, dt, n, q):
        return identify(u, y, dt)  # the product's defaults: ARX order by GCV, states by BIC

    def okid_riccati(u, y, dt, n, q):
        return identify(u, y, dt, order=q, n_states="auto", gain="riccati")

    return {"okid": okid, "paper": paper, "okid-auto": okid_auto, "okid-ls": okid_ls,
            "okid-default": okid_default, "okid-riccati": okid_riccati}, ""


def _peer_method(name: str) -> Method:
    def run(u, y, dt, n, q):
        model, why = peer_identify(name, u, y, dt, n)
        if model is None:
            raise RuntimeError(why)
        return model
    return run


def all_methods() -> tuple[dict[str, Method], str]:
    """Our methods (if importable) followed by the available peers."""
    ours, note = _our_methods()
    methods = dict(ours)
    for name in available_peers():
        methods[name] = _peer_method(name)
    return methods, note


DEFAULT_METHODS = ("okid-default", "okid-auto", "okid", "okid-ls", "okid-riccati", "paper", "control-era",
                   "sippy-n4sid", "sippy-moesp", "sippy-cva",
                   "nfoursid")


# ---------------------------------------------------------------------------
# One run
# ---------------------------------------------------------------------------


@dataclass
class RunResult:
    """One method's run on one case, seed and data length, with its scores."""

    method: str
    seed: int
    ok: bool
    reason: str = ""
    time_s: float = np.nan
    freq_err_pct: list = field(default_factory=list)
    damp_err_pp: list = field(default_factory=list)
    missed: int = 0
    spurious: int = 0
    ratio: Optional[float] = None
    markov_err: Optional[float] = None
    n_states: Optional[int] = None
    listed_missed: Optional[int] = None  # of the modes the model lists (okid_ros: what a user reads)
    listed_spurious: Optional[int] = None


def _has_gain(model) -> bool:
    if isinstance(model, dict):
        return model.get("predictor_gain") is not None or model.get("K") is not None
    return getattr(model, "K", None) is not None


def _A_of(model) -> np.ndarray:
    return np.asarray(model["A"] if isinstance(model, dict) else model.A, dtype=float)


def simulate_record(case: BenchmarkCase, n_samples: int, seed: int, n_val: int):
    """Identification and validation records of one seed: (u, y, u_val, y_val)."""
    base = 1000 * (seed + 1)
    u = case.make_input(n_samples, base + 1)
    y = simulate(case.system, u, base + 2)
    u_val = case.make_input(n_val, base + 3)
    y_val = simulate(case.system, u_val, base + 4)
    return u, y, u_val, y_val


def score_model(model, case: BenchmarkCase, u_val, y_val, burn_in: int) -> dict:
    dt = case.sample_time_s
    true = modes_of(case.system.A, dt)
    ident = physical_modes(modes_of(_A_of(model), dt), dt, case.max_physical_damping)
    mm = match_modes(ident, true, MODE_TOL)
    out = {
        "freq_err_pct": mm.frequency_error_pct.tolist(),
        "damp_err_pp": mm.damping_error_pp.tolist(),
        "missed": mm.missed,
        "spurious": mm.n_spurious,
        "n_states": int(_A_of(model).shape[0]),
        "ratio": None,
        "markov_err": None,
    }
    listed = getattr(model, "modes", None)
    if listed is not None:  # okid_ros's listed (physical) modes, paired one to one with the true ones
        pairs = assign_by_frequency([md.frequency_hz for md in listed], [md.frequency_hz for md in true], MODE_TOL)
        out["listed_missed"] = sum(c is None for c in pairs)
        out["listed_spurious"] = len(listed) - sum(c is not None for c in pairs)
    if _has_gain(model):
        out["ratio"] = prediction_error_ratio(model, case.system, u_val, y_val, burn_in)
        out["markov_err"] = stochastic_markov_error(model, case.system, N_MARKOV_TERMS)
    return out


def run_case(case: BenchmarkCase, n_samples: int, seeds: list[int], methods: dict[str, Method],
             n_val: int, burn_in: int, log=print) -> list[RunResult]:
    results = []
    for seed in seeds:
        u, y, u_val, y_val = simulate_record(case, n_samples, seed, n_val)
        for name, fn in methods.items():
            t0 = time.perf_counter()
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    # copies: a method that scales its data in place must not touch the next's
                    model = fn(u.copy(), y.copy(), case.sample_time_s, case.n_states,
                               case.arx_order)
                dt_s = time.perf_counter() - t0
                with np.errstate(all="ignore"):
                    sc = score_model(model, case, u_val, y_val, burn_in)
                res = RunResult(name, seed, True, time_s=dt_s, **sc)
            except Exception as exc:  # noqa: BLE001 - a failure is a result
                dt_s = time.perf_counter() - t0
                msg = (str(exc).splitlines() or [""])[0]
                res = RunResult(name, seed, False, f"{type(exc).__name__}: {msg}"[:160], dt_s)
            results.append(res)
            r = "n/a" if res.ratio is None else f"{res.ratio:.4f}"
            log(f"  {case.name} N={n_samples} seed={seed} {name:12s} "
                f"{'ok ' if res.ok else 'ERR'} t={dt_s:6.2f}s ratio={r} missed={res.missed} "
                f"spurious={res.spurious} {res.reason}")
    return results


# ---------------------------------------------------------------------------
# Aggregation and markdown
# ---------------------------------------------------------------------------


def _rms(values) -> float:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    return float(np.sqrt(np.mean(v ** 2))) if v.size else np.nan


def _fmt(x: Optional[float], digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and np.isnan(x)):
        return "n/a"
    if np.isinf(x):
        return "inf"
    if abs(x) >= 1000:
        return f"{x:.3g}"
    return f"{x:.{digits}f}"


def aggregate(results: list[RunResult], n_modes: int) -> dict[str, dict]:
    by: dict[str, list[RunResult]] = {}
    for r in results:
        by.setdefault(r.method, []).append(r)
    table = {}
    for name, rs in by.items():
        ok = [r for r in rs if r.ok]
        row = {"runs": len(rs), "failures": len(rs) - len(ok),
               "reasons": sorted({r.reason for r in rs if not r.ok})}
        row["freq_rms_pct"] = [_rms([r.freq_err_pct[i] for r in ok]) for i in range(n_modes)]
        row["damp_rms_pp"] = [_rms([r.damp_err_pp[i] for r in ok]) for i in range(n_modes)]
        row["missed"] = sum(r.missed for r in ok)
        row["spurious"] = sum(r.spurious for r in ok)
        listed = [r for r in ok if r.listed_missed is not None]
        row["listed"] = ((sum(r.listed_missed for r in listed), sum(r.listed_spurious for r in listed))
                         if listed else None)
        ratios = [r.ratio for r in ok if r.ratio is not None]
        row["ratio_median"] = float(np.median(ratios)) if ratios else None
        row["ratio_max"] = float(np.max(ratios)) if ratios else None
        mk = [r.markov_err for r in ok if r.markov_err is not None]
        row["markov_median"] = float(np.median(mk)) if mk else None
        times = [r.time_s for r in ok]
        row["time_median_s"] = float(np.median(times)) if times else None
        table[name] = row
    return table


def markdown_table(case: BenchmarkCase, n_samples: int, seeds: list[int], table: dict) -> str:
    dt = case.sample_time_s
    true = modes_of(case.system.A, dt)
    lines = [f"### {case.name}, N = {n_samples} ({len(seeds)} seeds)", "", case.description, ""]
    lines.append("True modes: " + "; ".join(
        f"m{i + 1} {md.frequency_hz:.3f} Hz ({md.frequency_rad_s:.2f} rad/s) {100 * md.damping_ratio:.2f} %"
        for i, md in enumerate(true)) + f". n = {case.n_states}, ARX order q = {case.arx_order}, "
        f"{1 / dt:g} Hz sampling.")
    lines.append("")
    mode_hdr = " / ".join(f"m{i + 1}" for i in range(len(true)))
    lines.append(f"| method | f err % RMS ({mode_hdr}) | zeta err pp RMS ({mode_hdr}) | missed | "
                 f"spurious | ratio median | ratio max | C A^i K err | time s | failed | listed: missed / spurious |")
    lines.append("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, row in table.items():
        f = " / ".join(_fmt(v, 3) for v in row["freq_rms_pct"])
        z = " / ".join(_fmt(v, 3) for v in row["damp_rms_pp"])
        lines.append(
            f"| {name} | {f} | {z} | {row['missed']} | {row['spurious']} | "
            f"{_fmt(row['ratio_median'], 4)} | {_fmt(row['ratio_max'], 4)} | "
            f"{_fmt(row['markov_median'], 3)} | {_fmt(row['time_median_s'], 2)} | "
            f"{row['failures']}/{row['runs']} | "
            f"{'n/a' if row['listed'] is None else '{} / {}'.format(*row['listed'])} |")
    reasons = {name: row["reasons"] for name, row in table.items() if row["reasons"]}
    if reasons:
        lines.append("")
        for name, rs in reasons.items():
            lines.append(f"- {name} failed: " + "; ".join(rs[:3]))
    lines.append("")
    return "\n".join(lines)


def _versions() -> str:
    import importlib.metadata as md

    parts = [f"python {platform.python_version()}", f"numpy {np.__version__}"]
    for pkg in ("scipy", "control", "sippy-unipi", "nfoursid"):
        try:
            parts.append(f"{pkg} {md.version(pkg)}")
        except Exception:  # noqa: BLE001
            pass
    return ", ".join(parts)


def header(args, note: str, methods: list[str]) -> str:
    cmd = "python bench/identification_accuracy.py " + " ".join(sys.argv[1:])
    lines = [
        "## Identification accuracy against known truth",
        "",
        f"Command: `{cmd.strip()}`. {_versions()}; BLAS threads "
        f"{os.environ.get('OPENBLAS_NUM_THREADS', '?')}; {platform.machine()}, "
        f"{os.cpu_count()} CPUs.",
        "",
        "Every method gets the same records and the true state dimension n. Frequency error in "
        "% and damping error in percentage points are RMS over the seeds in which the mode was "
        f"found (match: within {MODE_TOL:.0%} in frequency, one-to-one); missed and spurious "
        "(physical: stable, damping < 20 %, below Nyquist, unmatched) are totals over seeds. "
        "Ratio: one-step prediction-error power on a held-out record of "
        f"{args.val_samples} samples (first {args.burn_in} skipped) over the oracle Kalman "
        "predictor's; 1.0 is the limit. C A^i K err: relative Frobenius error of i = 1..100 with "
        "outputs scaled to unit innovation (Re^-1/2 M Re^1/2), median. "
        "n/a: the method gives no noise model.",
        "",
        "Methods: " + ", ".join(methods) + ".",
    ]
    if note:
        lines += ["", f"Note: {note}."]
    lines.append("")
    return "\n".join(lines)


def main(argv: Optional[list[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=None, help="noise seeds per case (default 5; quick 2)")
    ap.add_argument("--quick", action="store_true", help=f"cases {','.join(QUICK_CASES)}, N = 3750, 2 seeds")
    ap.add_argument("--cases", default=None, help="comma-separated case names (default: all)")
    ap.add_argument("--lengths", default=None, help="comma-separated record lengths (default: each case's)")
    ap.add_argument("--methods", default=None,
                    help=f"comma-separated methods (default: {','.join(DEFAULT_METHODS)}; also okid-auto)")
    ap.add_argument("--val-samples", type=int, default=10000, help="held-out record length")
    ap.add_argument("--burn-in", type=int, default=500, help="predictor start-up samples skipped")
    add_output_options(ap, json=True, out_help="write the markdown report here")
    ap.add_argument("--threads", default="1", help="BLAS threads (default 1)")
    ap.add_argument("--quiet", action="store_true", help="no per-run progress on stderr")
    args = ap.parse_args(argv)
    refuse_existing(ap, args)

    available, note = all_methods()
    wanted = args.methods.split(",") if args.methods else list(DEFAULT_METHODS)
    unknown = [m for m in wanted if m not in available and m not in ("okid", "paper", "okid-auto", "okid-ls")
               and m not in PEERS]
    if unknown:
        ap.error(f"unknown methods: {', '.join(unknown)}")
    methods = {m: available[m] for m in wanted if m in available}
    skipped = [m for m in wanted if m not in available]
    if skipped:
        note = "; ".join(x for x in (note, f"not available, skipped: {', '.join(skipped)}") if x)

    names = args.cases.split(",") if args.cases else (list(QUICK_CASES) if args.quick else None)
    try:
        cases = benchmark_cases(names)
    except KeyError as exc:
        ap.error(str(exc.args[0]))
    n_seeds = args.seeds if args.seeds is not None else (2 if args.quick else 5)
    seeds = list(range(n_seeds))
    log = (lambda *a: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))

    doc = [header(args, note, list(methods))]
    print(doc[0], flush=True)
    raw = []
    for case in cases:
        if args.lengths:
            lengths = [int(x) for x in args.lengths.split(",")]
        else:
            lengths = [3750] if args.quick else list(case.n_samples)
        for n_samples in lengths:
            results = run_case(case, n_samples, seeds, methods, args.val_samples, args.burn_in, log)
            table = aggregate(results, len(modes_of(case.system.A, case.sample_time_s)))
            md = markdown_table(case, n_samples, seeds, table)
            print(md, flush=True)
            doc.append(md)
            raw.append({"case": case.name, "n_samples": n_samples,
                        "results": [r.__dict__ for r in results], "table": table})
    write_output(args.out, "\n".join(doc))
    if args.json:
        def default(o):
            if isinstance(o, (np.floating, np.integer)):
                return o.item()
            return str(o)
        write_output(args.json, json.dumps(raw, indent=1, default=default))
    return 0


if __name__ == "__main__":
    sys.exit(main())
