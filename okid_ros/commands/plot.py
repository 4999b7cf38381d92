"""`okid-ros plot OUT [--out-dir DIR]`: figures like the paper's Figs 2-5 from an output bag."""

from __future__ import annotations

import argparse


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `plot`."""
    parser = subparsers.add_parser(
        "plot",
        help="PNG figures like the paper's Figs 2-5 and the modes over time, from an output bag",
        description="Read a bag with /okid/arx_model, /okid/state_space_model and /okid/modal_states "
        "(the output of `okid-ros process`, or a live recording) and write PNG files: system Markov "
        "parameters (1,1), stochastic Markov parameters C A^i K (1,1), modal states, measured against "
        "estimated output 1, and frequency and damping of each mode over time. The truth of a "
        "simulated experiment is drawn when the bag metadata (or --truth-from) carries it.",
    )
    parser.add_argument("bag", metavar="OUT", help="output bag of `okid-ros process` (or a live recording)")
    parser.add_argument("--out-dir", default=None, metavar="DIR",
                        help="folder for the PNG files (default: OUT_figures next to the bag)")
    parser.add_argument("--window", type=float, default=5.0, metavar="S",
                        help="seconds of modal states and outputs shown, at the end of the bag (default: %(default)s)")
    parser.add_argument("--terms", type=int, default=100, metavar="N",
                        help="stochastic Markov parameters drawn (default: %(default)s)")
    parser.add_argument("--truth-from", default=None, metavar="BAG",
                        help="take the truth from this bag's metadata (e.g. the input of process)")
    parser.add_argument("--force", action="store_true", help="replace existing PNG files")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from okid_ros.tools.bagio import TRUTH_KEY, open_bag
    from okid_ros.tools.errors import ToolParameterError
    from okid_ros.tools.plots import read_plot_data, write_figures

    if not args.window > 0:
        raise ToolParameterError(f"--window must be positive, got {args.window}")
    truth = None
    if args.truth_from:
        with open_bag(args.truth_from) as bag:
            truth = bag.custom_json(TRUTH_KEY)
    bag_path = Path(args.bag)
    out_dir = Path(args.out_dir) if args.out_dir else bag_path.with_name(bag_path.name + "_figures")
    data = read_plot_data(bag_path, window_s=args.window, truth=truth)
    written = write_figures(data, out_dir, force=args.force, n_stochastic=args.terms)
    print(f"wrote {len(written)} figures to {out_dir}" + ("" if data.truth else " (no truth in the metadata)"))
    for path in written:
        print(f"  {path}")
    return 0
