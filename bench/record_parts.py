#!/usr/bin/env python3
"""Do a record's parts agree as their standard deviations say? A calibration check without truth.

A real record has no modal truth to score the standard deviations against; its parts do not need
one. The record is cut into ``--parts`` consecutive pieces of equal length, each identified apart
with the product's defaults (``identify``, or ``identify_output_only`` with ``--output-only`` or
a record without ``u``), and every listed mode of one piece is matched to the nearest of another
within ``--match`` (relative frequency). For calibrated standard deviations the difference of
the two estimates divided by their combined standard deviation, ``(a - b) / sqrt(s_a^2 +
s_b^2)``, has an RMS near 1 and lies within 2 for about 95 % of the modes (less for a
jackknife's few degrees of freedom; docs/benchmarks-uncertainty.md). An RMS well above 1 says
the intervals are too narrow for what the record does; well below, too wide.

The record is anything ``okid-ros identify`` reads (.npz, .csv, a bag with ``--params``); every
pair of pieces is compared. Modes without a standard deviation (NaN) are left out and counted.

Usage::

    python bench/record_parts.py ../shared/data/real/daisy-steel-subframe/steel_subframe.npz
    python bench/record_parts.py REC.npz --output-only --parts 3
    python bench/record_parts.py REC.npz --out /tmp/parts.md [--force]
"""

from __future__ import annotations

import argparse
import sys
import warnings
from itertools import combinations

import blas_threads  # noqa: F401  (sets the BLAS threads before numpy loads)
import checkout

checkout.add()

import numpy as np  # noqa: E402

from okid_bench.report import add_output_options, refuse_existing, write_output  # noqa: E402
from okid_ros.core.output_only import identify_output_only  # noqa: E402
from okid_ros.core.pipeline import identify  # noqa: E402
from okid_ros.tools.bag_record import load_any_record  # noqa: E402

#: Fewest samples a piece must hold.
MIN_PIECE = 500


def _modes(u: np.ndarray, y: np.ndarray, dt: float, output_only: bool) -> list[tuple[float, ...]]:
    """(frequency_hz, damping_ratio, frequency_hz_std, damping_ratio_std) of each listed mode."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_output_only(y, dt) if output_only else identify(u, y, dt)
    return [(m.frequency_hz, m.damping_ratio, m.frequency_hz_std, m.damping_ratio_std) for m in model.modes]


def _pairs(pieces: list[list[tuple[float, ...]]], match: float) -> list[dict]:
    """Each listed mode of a piece against the nearest of every later piece within ``match``."""
    rows = []
    for i, j in combinations(range(len(pieces)), 2):
        for f_a, z_a, sf_a, sz_a in pieces[i]:
            if not pieces[j]:
                continue
            f_b, z_b, sf_b, sz_b = min(pieces[j], key=lambda mode: abs(mode[0] - f_a))
            if abs(f_b - f_a) > match * f_a:
                continue
            rows.append({"pieces": (i, j), "f": (f_a, f_b), "zeta": (z_a, z_b),
                         "z_f": (f_a - f_b) / np.hypot(sf_a, sf_b), "z_zeta": (z_a - z_b) / np.hypot(sz_a, sz_b)})
    return rows


def _markdown(rows: list[dict], pieces: list, args) -> str:
    lines = [f"`{args.record}`: {len(pieces)} pieces, modes listed {', '.join(str(len(p)) for p in pieces)}, "
             f"{'output-only' if args.output_only else 'input-output'} identification with the defaults",
             "", "| pieces | f a / b [Hz] | zeta a / b [%] | (a - b) / std, f | (a - b) / std, zeta |",
             "|---|---|---|---|---|"]
    for row in rows:
        (f_a, f_b), (z_a, z_b) = row["f"], row["zeta"]
        lines.append(f"| {row['pieces'][0]}-{row['pieces'][1]} | {f_a:.3f} / {f_b:.3f} | {100 * z_a:.3f} / "
                     f"{100 * z_b:.3f} | {row['z_f']:.2f} | {row['z_zeta']:.2f} |")
    lines.append("")
    for key, name in (("z_f", "frequency"), ("z_zeta", "damping")):
        values = np.array([row[key] for row in rows], float)
        known = values[np.isfinite(values)]
        if known.size:
            lines.append(f"{name}: {known.size} pairs of modes ({values.size - known.size} without a standard "
                         f"deviation), RMS {np.sqrt(np.mean(known**2)):.2f}, within 2: "
                         f"{100 * np.mean(np.abs(known) <= 2):.0f} %")
        else:
            lines.append(f"{name}: no pair of modes with standard deviations")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("record", help="a record okid-ros identify reads (.npz, .csv, a bag with --params)")
    parser.add_argument("--params", action="append", default=[], help="parameter file for a bag's topics")
    parser.add_argument("--parts", type=int, default=2, help="consecutive pieces (default: %(default)s)")
    parser.add_argument("--output-only", action="store_true", help="identify from the outputs alone")
    parser.add_argument("--match", type=float, default=0.005, help="relative frequency to pair modes (0.5 %%)")
    add_output_options(parser)
    parser.add_argument("--threads", default="1", help="BLAS threads (read before numpy loads)")
    args = parser.parse_args(argv)
    refuse_existing(parser, args)
    record, _ = load_any_record(args.record, args.params)
    n = record.y.shape[0] // max(args.parts, 1)
    if args.parts < 2 or n < MIN_PIECE:
        parser.error(f"--parts {args.parts}: need at least 2 pieces of {MIN_PIECE} samples "
                     f"({record.y.shape[0]} samples)")
    args.output_only = args.output_only or record.u.shape[1] == 0
    pieces = [_modes(record.u[k * n : (k + 1) * n], record.y[k * n : (k + 1) * n], record.sample_time_s,
                     args.output_only) for k in range(args.parts)]
    table = _markdown(_pairs(pieces, args.match), pieces, args)
    write_output(args.out, table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
