"""`okid-ros export BAG --npz OUT.npz [--params FILE] [--source SPEC]`: a bag's samples as a record.

The samples are assembled from the bag's input topics exactly as the nodes and `process` do
(:mod:`okid_ros.tools.bag_record`), and the longest contiguous run is written as the ``.npz``
record that `identify` and `track` read (``u``, ``y``, ``sample_time_s``, plus ``stamp_s``), so
batch and live analyses use the same data.
"""

from __future__ import annotations

import argparse

from okid_ros.commands._args import add_bag_arguments, path_text
from okid_ros.errors import shown_path


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `export`."""
    parser = subparsers.add_parser(
        "export",
        help="write a bag's input/output samples as an .npz record (for identify and track)",
        description="Assemble the samples of a bag's input topics (inputs.sources of the parameter file, "
        "or --source) on the sample grid as the nodes do, and write the longest contiguous run as an .npz "
        "record: u (N, m), y (N, p), sample_time_s and the stamps stamp_s (N,).",
    )
    parser.add_argument("bag", type=path_text, help="input bag directory, .mcap, .db3 or ROS 1 .bag")
    parser.add_argument("--npz", required=True, metavar="OUT.npz", help="the record to write")
    add_bag_arguments(parser)
    parser.add_argument("--force", action="store_true", help="replace an existing OUT.npz")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    from okid_ros.errors import DataError, ParameterError
    from okid_ros.records import save_record
    from okid_ros.tools.bag_record import record_from_bag
    from okid_ros.tools.output_paths import check_output_paths, prepare_file_outputs
    from okid_ros.tools.process import load_node_parameters

    out = Path(args.npz)
    if out.suffix.lower() != ".npz":
        raise ParameterError(f"--npz {shown_path(out)}: the record file must end in .npz")  # an option, not the bag
    check_output_paths(args.bag, "input bag", [(out, "record")])
    prepare_file_outputs([(args.npz, "record")], force=args.force)  # replaced when written: a failed read keeps it
    est_values = load_node_parameters(args.params, args.param, args.source)[1]
    from_bag = record_from_bag(args.bag, est_values)
    record = from_bag.record
    note = _kept_note(from_bag)  # DataError where the run is too short for any command
    try:
        save_record(out, record.u, record.y, record.sample_time_s, stamp_s=from_bag.stamp_s)
    except OSError as exc:
        raise DataError(f"cannot write {shown_path(out)}: {exc}") from None
    if note:
        print(f"okid-ros export: warning: {shown_path(args.bag)}: {note}", file=sys.stderr)
    print(f"exported {from_bag.summary()} ({record.u.shape[1]} inputs, {record.y.shape[1]} outputs) "
          f"from {shown_path(args.bag)} -> {shown_path(out)}")
    return 0


def _kept_note(from_bag) -> str:
    """The warning on what the record leaves out of the bag ("" if nothing to say), or DataError.

    The record is the longest contiguous run: one shorter than any command identifies from
    (:func:`~okid_ros.tools.bag_record.fewest_usable_samples`) is refused with the cause; one that
    leaves out a share worth saying (:func:`~okid_ros.tools.grid_hints.loss_worth_saying`) says the
    share kept (a bag with many gaps wrote 13 of its 1393 samples, the warning naming only the gaps).
    """
    from okid_ros.errors import DataError
    from okid_ros.tools.bag_record import fewest_usable_samples
    from okid_ros.tools.grid_hints import loss_worth_saying

    record, total, note = from_bag.record, from_bag.samples_total, from_bag.rejection_note()
    (n, m), p = record.u.shape, record.y.shape[1]
    run = (f"the longest of its {from_bag.runs} contiguous runs, {n} of the {total} samples ({100 * n / total:.2g} %)"
           if from_bag.runs > 1 else f"its {n} samples")
    if n < (fewest := fewest_usable_samples(p, m)):
        raise DataError(f"{run}, is shorter than any command identifies from ({fewest} samples with {m} inputs and "
                        f"{p} outputs)" + (f": {note}" if note else ""))
    if loss_worth_saying(from_bag.samples_left_out, total):
        return f"the record written is {run}" + (f"; {note}" if note else "")
    return note
