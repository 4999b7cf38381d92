#!/usr/bin/env python3
"""Output-only identification: okid_ros against pyOMA2 and koma on records with known truth.

Records:

* ``koma``: the koma shear frame (``../shared/data/oma/koma-shear-frame``), 5 outputs, 12 Hz,
  1200 s; scored against the record's own (Tustin-shifted) ``discrete_frequency_hz`` /
  ``discrete_damping_ratio`` and the shapes of ``truth.json``;
* ``subframe``: the steel subframe's 28 accelerations alone (``../shared/data/real/
  daisy-steel-subframe``, the shaker forces not used), against its 15 input-output reference
  modes (frequency only; the listed uncertain poles near 368 and 485-496 Hz are not counted as
  spurious);
* the simulated cases of :mod:`okid_bench.output_only_cases` (bench/okid_bench) (truth from the discrete system
  simulated), ``--seeds`` noise seeds each;
* ``random`` (a case of ``--cases``, not in the default list): ``--seeds`` structures drawn at
  random, one record each (:func:`okid_bench.output_only_cases.random_case`: 2-8 modes, 1-16
  outputs, 0.3-4 % damping, 50-1000 Hz), to measure the selection on records it was not tuned on;
* ``physical`` (idem): ``--seeds`` physical structures drawn at random
  (:func:`okid_bench.physical_cases.physical_case`: shear buildings, coupled chains with close
  pairs, beams; forces at 1-3 points), scored by family; a mode the record does not show is
  neither found nor missed, nor spurious when listed;
* ``new-families`` (idem): structures of kinds no selection rule was tuned on
  (:func:`okid_bench.new_families.new_family_case`: plate grids, torsion frames with local dashpots,
  buildings under coloured forces), scored by family like ``physical``;
* ``families-2`` (idem): round two of such kinds (:func:`okid_bench.families_two.family_two_case`:
  buildings with local dampers and tuned mass dampers (complex true shapes), towers with bending pairs
  0.2-1 % apart under Kaimal-like gusts, long-span decks of 20-30 channels under traffic), scored by family;
* ``koma-frame`` (idem): the koma frame's own recipe with ``--seeds`` noise seeds
  (:func:`okid_bench.physical_cases.koma_frame_case`), scored against its discrete modes.

Every method gets the centred record; the peers get the Hankel block rows okid_ros chooses from
the data and orders 2..``--max-order`` (step 2): ``bench/output_only_peers.py``. A true mode is
*found* when an identified mode lies within 0.5 % of its frequency (one each: the most such pairs, those
of least frequency distance and 1 - MAC, so a close pair's crossed poles are paired by shape);
identified modes not paired one to one with a true mode within 2 % are *spurious* (a
mode listed twice counts once spurious). Columns: found / true modes
(summed over seeds), spurious (summed), RMS relative frequency and damping errors of the found
modes, the share of found modes with damping within 30 %, the smallest MAC, the 2-sigma
coverage of the standard deviations (okid_ros only), the median wall time of one call, and the
found modes whose MAC with the true shape is at least 0.9 (nan: a record without shapes).

Usage::

    python bench/output_only.py                          # everything, 5 seeds, ~10 min on one core
    python bench/output_only.py --seeds 20 --methods okid-ssi-cov,koma
    python bench/output_only.py --records koma,subframe --cases none
    python bench/output_only.py --records none --cases random --seeds 120 --methods okid-ssi-cov,koma
    python bench/output_only.py --records none --cases physical --seeds 36 --methods okid-ssi-cov,koma
    python bench/output_only.py --records koma --cases koma-frame --seeds 100 --methods okid-ssi-cva
    python bench/output_only.py --out /tmp/oo.md [--force]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import blas_threads  # noqa: F401  (sets the BLAS threads before numpy loads)
import numpy as np
from output_only_peers import METHODS, run_method

from okid_bench.families_two import FAMILIES_TWO_CASES, family_two_case
from okid_bench.new_families import NEW_FAMILY_CASES, new_family_case
from okid_bench.output_only_cases import OUTPUT_ONLY_CASES, output_only_case, random_case, score_modes
from okid_bench.physical_cases import KOMA_FRAME, koma_frame_case, physical_case
from okid_bench.report import add_output_options, refuse_existing, write_output
from okid_ros.core.output_covariance import choose_block_rows, reference_channels

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
KOMA = DATA / "oma" / "koma-shear-frame"
SUBFRAME = DATA / "real" / "daisy-steel-subframe"
#: A found mode whose shape has at least this MAC with the true one is found with its shape too: within
#: 0.5 % of one of a close pair, a pole with the other's shape is "found" by frequency alone.
SHAPE_MAC = 0.9
#: The case groups scored by family: each seed one structure.
FAMILY_BUILDERS = {"physical": physical_case, NEW_FAMILY_CASES: new_family_case, FAMILIES_TWO_CASES: family_two_case}


def _koma():
    record = np.load(KOMA / "shear_frame.npz")
    modes = json.loads((KOMA / "truth.json").read_text())["modes"]
    truth = [{"frequency_hz": m["discrete_frequency_hz"], "damping_ratio": m["discrete_damping_ratio"],
              "shape": np.asarray(m["shape"], float)} for m in modes]
    return record["y"], float(record["sample_time_s"]), truth, []


def _subframe():
    record = np.load(SUBFRAME / "steel_subframe.npz")
    reference = json.loads((SUBFRAME / "truth.json").read_text())["reference_estimates_not_published"]
    truth = [{"frequency_hz": m["f_Hz"], "damping_ratio": m["zeta_pct"] / 100, "shape": None}
             for m in reference["modes"]]
    uncertain = [m["f_Hz"] for m in reference["uncertain_near_band_edge_or_unstable"]]
    return record["y"], float(record["sample_time_s"]), truth, uncertain


def _runs(args):
    """(record name, seed, y, dt, truth, uncertain) for every record and seed asked for."""
    loaders = {"koma": _koma, "subframe": _subframe}
    for name in args.records:
        y, dt, truth, uncertain = loaders[name]()
        yield name, 0, y, dt, truth, uncertain
    for name in args.cases:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            if name in FAMILY_BUILDERS:  # scored by family; the modes it does not show not counted
                case = FAMILY_BUILDERS[name](seed)
                yield case.family, seed, case.simulate(seed), case.sample_time_s, case.truth(), case.hidden_hz()
                continue
            if name == KOMA_FRAME:  # koma's recipe, noise seeds of one structure
                case = koma_frame_case()
            else:
                case = random_case(seed) if name == "random" else output_only_case(name)
            yield name, seed, case.simulate(seed), case.sample_time_s, case.truth(), []


def _score(found: list[dict], truth: list[dict], uncertain: list[float]) -> dict:
    """Found within 0.5 %; spurious: not paired one to one within 2 % with a true (or uncertain) mode."""
    strict = score_modes(found, truth, match_tolerance=0.005)
    rows = [r for r in strict["modes"] if r["frequency_error"] == r["frequency_error"]]
    known = truth + [{"frequency_hz": f, "damping_ratio": np.nan, "shape": None} for f in uncertain]
    spurious = score_modes(found, known, match_tolerance=0.02)["spurious"]
    return {"rows": rows, "n_true": len(truth), "spurious": spurious}


def _summary(results: list[dict]) -> dict:
    rows = [r for res in results for r in res["rows"]]

    def rms(key):
        values = np.array([r[key] for r in rows], float)
        return float(100 * np.sqrt(np.mean(values ** 2))) if values.size else float("nan")

    def share(key, test=lambda v: v):
        values = np.array([r[key] for r in rows], float)
        values = values[np.isfinite(values)]
        return float(np.mean(test(values))) if values.size else float("nan")

    macs = [r["mac"] for r in rows if r["mac"] == r["mac"]]
    return {
        "shape_found": sum(mac >= SHAPE_MAC for mac in macs) if macs else float("nan"),
        "found": sum(len(res["rows"]) for res in results), "true": sum(res["n_true"] for res in results),
        "spurious": sum(res["spurious"] for res in results), "f_rms": rms("frequency_error"),
        "z_rms": rms("damping_error"), "z30": share("damping_error", lambda v: np.abs(v) <= 0.3),
        "mac": min(macs) if macs else float("nan"), "cov_f": share("frequency_covered"),
        "cov_z": share("damping_covered"), "time": float(np.median([res["time"] for res in results])),
        "failed": sum(res.get("failed", 0) for res in results),
    }


def _evaluate(args) -> dict:
    table: dict = {}
    for name, seed, y, dt, truth, uncertain in _runs(args):
        y = y - y.mean(axis=0)
        references = reference_channels(y, 12)
        block_rows, _ = choose_block_rows(y, dt, n_references=references.size, max_states=args.max_order)
        for method in args.methods:
            started = time.perf_counter()
            try:
                found = run_method(method, y, dt, block_rows, args.max_order)
                failed = 0
            except Exception as exc:  # a peer's crash is a result of the benchmark, not its end
                print(f"  {name} seed {seed} {method}: failed ({type(exc).__name__}: {exc})"[:200], file=sys.stderr)
                found, failed = [], 1
            elapsed = time.perf_counter() - started
            result = _score(found, truth, uncertain)
            result.update(time=elapsed, failed=failed)
            table.setdefault((name, method), []).append(result)
            print(f"  {name} seed {seed} {method}: {len(result['rows'])}/{result['n_true']} found, "
                  f"{result['spurious']} spurious, {elapsed:.2f} s", file=sys.stderr)
    return {key: _summary(results) for key, results in table.items()}


def _markdown(summary: dict, args) -> str:
    lines = [
        f"seeds per simulated case: {args.seeds}; peers at okid_ros's block rows, orders 2..{args.max_order}",
        "",
        "| record | method | found | spurious | f RMS % | zeta RMS % | zeta within 30 % | min MAC "
        f"| 2-sigma coverage f / zeta | time s (median) | failed | found with MAC >= {SHAPE_MAC} |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (name, method), s in summary.items():
        cover = "" if s["cov_f"] != s["cov_f"] else f"{100 * s['cov_f']:.0f} / {100 * s['cov_z']:.0f} %"
        lines.append(
            f"| {name} | {method} | {s['found']}/{s['true']} | {s['spurious']} | {s['f_rms']:.3f} | "
            f"{s['z_rms']:.1f} | {100 * s['z30']:.0f} % | {s['mac']:.3f} | {cover} | {s['time']:.2f} | "
            f"{s['failed']} | {s['shape_found']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--records", default="koma,subframe", help="koma,subframe or none")
    parser.add_argument("--cases", default=",".join(OUTPUT_ONLY_CASES),
                        help="simulated cases (or random, physical, new-families, families-2, koma-frame), or none")
    parser.add_argument("--methods", default=",".join(METHODS), help=f"subset of {','.join(METHODS)}")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0,
                        help="first noise seed (random, physical: first structure)")
    parser.add_argument("--max-order", type=int, default=100)
    add_output_options(parser)
    parser.add_argument("--threads", default="1", help="BLAS threads (read before numpy loads)")
    args = parser.parse_args(argv)
    for key in ("records", "cases", "methods"):
        setattr(args, key, [] if getattr(args, key) == "none" else getattr(args, key).split(","))
    refuse_existing(parser, args)
    text = _markdown(_evaluate(args), args)
    print(text)
    write_output(args.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
