"""`okid-ros plot OUT [--out-dir DIR]`: figures like the paper's Figs 2-5 from an output bag."""

from __future__ import annotations

import argparse
import contextlib
import warnings
from pathlib import Path
from typing import Any

from okid_ros.commands._args import int_between, namespace, path_text
from okid_ros.errors import shown_path

#: Bound of --terms, equal to okid_ros.tools.plots.MAX_TERMS (not imported: every parser is built at start-up).
MAX_TERMS = 10_000
#: Defaults of --window [s] and --terms (a campaign folder names them when given otherwise).
DEFAULT_WINDOW_S = 5.0
DEFAULT_TERMS = 100


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `plot`."""
    parser = subparsers.add_parser(
        "plot",
        help="PNG figures like the paper's Figs 2-5 and the modes over time, from an output bag",
        description="Read a bag with /okid/arx_model, /okid/state_space_model and /okid/modal_states "
        "(the output of `okid-ros process`, or a live recording) and write PNG files: system Markov "
        "parameters (1,1), stochastic Markov parameters C A^i K (1,1), modal states, measured against "
        "estimated output 1, and frequency and damping of each mode over time; for the last model, mac.png, "
        "frf.png (measured H1 against the model, from the input bag's record) and stabilization.png (when "
        "`process` recorded the model's stabilization data). The measured output and the truth of a simulated "
        "experiment come from the input bag: --input, or for `process` output the source bag recorded in its "
        "metadata.",
    )
    parser.add_argument("bag", type=path_text,
                        metavar="OUT", help="output bag of `okid-ros process` (or a live recording), or a "
                        "campaign directory of `okid-ros batch` (then: campaign_modes.png, frequency and damping "
                        "of every mode id over the campaign, in DIR/figures by default)")
    parser.add_argument("--out-dir", default=None, metavar="DIR",
                        help="folder for the PNG files (default: OUT_figures next to the bag)")
    parser.add_argument("--input", default=None, metavar="BAG",
                        help="the input bag: measured outputs and truth (default: the source recorded by process)")
    parser.add_argument("--params", action="append", default=[], metavar="FILE",
                        help="the nodes' parameter file(s), for the input topics of --input (default: those "
                        "recorded by process, else the built-in defaults)")
    parser.add_argument("--window", type=float, default=DEFAULT_WINDOW_S, metavar="S",
                        help="seconds of modal states and outputs shown, at the end of the bag (default: %(default)s)")
    parser.add_argument("--terms", type=int_between(1, MAX_TERMS), default=DEFAULT_TERMS, metavar="N",
                        help=f"stochastic Markov parameters drawn, 1 to {MAX_TERMS}: the figure is about 800 "
                        "pixels wide and the terms decay, more would not show (default: %(default)s)")
    parser.add_argument("--frf-pairs", default=None, metavar="O:I,...",
                        help="output:input pairs drawn in frf.png, 1-based, e.g. 1:1,2:1 (default: all, at most 16)")
    parser.add_argument("--namespace", type=namespace, default=None, metavar="NS",
                        help="the rig namespace of the bag's topics (a bag of `okid-ros record --namespace NS` or "
                        "`okid-ros process --namespace NS`; default: /okid/...)")
    parser.add_argument("--force", action="store_true", help="replace existing PNG files")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from okid_ros.tools.errors import ToolParameterError
    from okid_ros.tools.output_paths import bag_folder, check_folder_option, check_output_paths
    from okid_ros.tools.plots import read_plot_data, write_figures

    if args.out_dir:
        check_folder_option("--out-dir", args.out_dir)
    if _is_campaign(args.bag):
        return _plot_campaign(args)
    if not args.window > 0:
        raise ToolParameterError(f"--window must be positive, got {args.window}")
    bag_path = Path(args.bag)
    folder = bag_folder(bag_path).resolve()  # the figures go beside the bag, never inside it
    if not args.out_dir and not folder.name:
        raise ToolParameterError(f"{shown_path(args.bag)}: no folder to put the figures beside; give --out-dir")
    out_dir = _figure_folder(args, folder.with_name(folder.name + "_figures"))
    check_output_paths(bag_path, "bag", [(out_dir, "figure folder")])
    data = read_plot_data(bag_path, window_s=args.window, namespace=args.namespace)
    info = data.process_info or {}
    with _about_the_input_option(args.input):
        input_bag, est_values, note = _read_input_bag(args, data, out_dir)
    if info.get("interrupted"):
        note += "; the run that wrote the bag was interrupted: its models and modal states end early"
    from okid_ros.tools.plots import FIGURES, refuse_existing
    from okid_ros.tools.validation_plots import VALIDATION_FIGURES, ModelView, parse_pairs, write_validation_figures

    refuse_existing(out_dir, (*FIGURES, *VALIDATION_FIGURES), args.force)  # every figure named in one refusal
    view = None if data.state_space is None else ModelView.of(data.state_space)
    try:  # before any figure is written: a wrong pair left five figures that refused the rerun
        pairs = parse_pairs(args.frf_pairs, view.C.shape[0], view.B.shape[1]) if args.frf_pairs and view else None
    except ValueError as exc:
        raise ToolParameterError(f"--frf-pairs: {exc}") from None
    made_here = not out_dir.exists()  # removed again if nothing is drawn into it
    written = write_figures(data, out_dir, force=args.force, n_stochastic=args.terms)
    if view is not None:
        view.stabilization = data.stabilization
        u = y = None
        if input_bag is not None:
            from okid_ros.tools.bag_record import record_from_bag

            with _about_the_input_option(args.input):
                from_bag = record_from_bag(input_bag, est_values)
            u, y = from_bag.record.u, from_bag.record.y
            if u.shape[1]:  # output-only: no inputs, no FRF drawn
                note += f"; FRF from {from_bag.summary()}"
        reference, why_not = _truth_reference(data.truth, view.C.shape[0])
        note += why_not
        written += write_validation_figures(view, u, y, out_dir, force=args.force, pairs=pairs,
                                            reference=reference, reference_label="truth")
    if not written:  # e.g. `process` refused every model: say so instead of "wrote 0 figures"
        from okid_ros.errors import DataError

        held = ", ".join(f"{count} on {shown_path(topic)}" for topic, count in data.counts.items())
        if made_here:
            with contextlib.suppress(OSError):  # not empty, or gone: leave it
                out_dir.rmdir()
        raise DataError(f"{shown_path(args.bag)}: nothing to draw: no valid model and no modal states "
                        f"({held} messages); the diagnostics of the run that wrote it say why")
    print(f"wrote {len(written)} figures to {shown_path(out_dir)}" + ("" if data.truth else " (no truth)") + note)
    for path in written:
        print(f"  {shown_path(path)}")
    return 0


@contextlib.contextmanager
def _about_the_input_option(given: str | None):
    """A bag given as ``--input`` that cannot be read: refused as that option, not prefixed with the plotted bag.

    The CLI names the file a command reads (OUT) in a data error that does not: ``OUT: INPUT: not a
    readable rosbag2 ...`` read as if OUT were at fault.
    """
    from okid_ros.errors import DataError
    from okid_ros.tools.errors import ToolParameterError

    try:
        yield
    except DataError as exc:
        if given is None:  # the source `process` recorded: about OUT's run, named with it
            raise
        text = str(exc)
        raise ToolParameterError(text if text.startswith("--input ") else f"--input {text}") from None


def _read_input_bag(args: argparse.Namespace, data: Any, out_dir: Path) -> tuple[str | None, dict | None, str]:
    """The measured outputs (and the truth) from the input bag into ``data``: the bag, its parameters, a note.

    The bag is ``--input``, else the source `process` recorded. A source that changed since
    `process` read it is drawn with a warning; one whose samples lie apart from the run's is left
    out with a warning, and ``--input`` such a bag is refused (it is another recording).
    """
    from okid_ros.errors import DataError, OkidWarning
    from okid_ros.tools.bagio import TRUTH_KEY, open_bag
    from okid_ros.tools.output_paths import check_output_paths
    from okid_ros.tools.plot_metadata import usable_truth
    from okid_ros.tools.plots import add_measured_outputs
    from okid_ros.tools.process import load_node_parameters
    from okid_ros.tools.source_check import changed_since, stamps_apart

    info = data.process_info or {}
    input_bag = args.input
    if input_bag is None and info.get("source") and Path(info["source"]).exists():
        input_bag = info["source"]
    without = "; no input bag: measured output drawn as the one-step prediction + innovation"
    if input_bag is None:  # a source recorded and gone: a bag moved (batch reuses its outputs: docs/batch.md)
        source = info.get("source")
        gone = f"; {shown_path(source)}, the bag `process` read, is not there (moved? give --input)" if source else ""
        return None, None, gone + without
    if args.params or "parameters" not in info:
        est_values = load_node_parameters(args.params, namespace=args.namespace)[1]
    else:
        est_values = info["parameters"]["okid_modal_estimator"]
    check_output_paths(Path(input_bag), "input bag", [(out_dir, "figure folder")])
    if changed := changed_since(input_bag, info.get("source_files")):
        warnings.warn(f"{shown_path(input_bag)}: not the bag `process` read ({changed}): the measured outputs, the "
                      "truth and the FRF may be of another recording", OkidWarning, stacklevel=2)
    note, truth, start_ns, run_span_ns = "", data.truth, data.experiment_start_ns, _run_span_ns(data)
    if data.truth is None:
        with open_bag(input_bag) as bag:
            data.truth, why = usable_truth(bag.custom_json(TRUTH_KEY))
        if why:
            note += f"; the truth in {shown_path(input_bag)}'s metadata left out ({why})"
    matched = add_measured_outputs(data, input_bag, est_values, namespace=args.namespace)
    # Samples apart from the run in time, or within its span but on none of its stamps (another grid).
    unmatched = not matched and (stamps_apart(data.measured_span_ns, run_span_ns) or (
        data.modal_stamp_ns and "none of its samples has the stamp of a ModalStates of the run"))
    if unmatched:
        if args.input is not None:
            raise DataError(f"--input {shown_path(input_bag)}: {unmatched}: another recording?")
        warnings.warn(f"{shown_path(input_bag)}: {unmatched}: not drawn from", OkidWarning, stacklevel=2)
        data.measured, data.truth, data.experiment_start_ns = None, truth, start_ns
        return None, None, without
    return input_bag, est_values, note + f"; measured outputs from {shown_path(input_bag)} ({matched} samples)"


def _run_span_ns(data: Any) -> tuple:
    """The first sample's and the last ModalStates' stamps [ns] of the run that wrote the bag, or ()."""
    if not data.modal_stamp_ns:
        return ()
    first = data.experiment_start_ns if data.experiment_start_ns is not None else data.first_stamp_log_ns[0]
    return first, data.modal_stamp_ns[-1]


def _figure_folder(args: argparse.Namespace, default: Path) -> Path:
    """``--out-dir`` (checked first by :func:`run`), else ``default``, refused as ``--out-dir`` is when no folder."""
    from okid_ros.tools.output_paths import check_folder_option

    if args.out_dir:
        return Path(args.out_dir)
    check_folder_option("--out-dir (by default)", default)  # was "exists and is not a folder", another wording
    return default


def _is_campaign(path: str) -> bool:
    from okid_ros.tools.campaign.runner import is_campaign_dir

    return is_campaign_dir(path)


def _plot_campaign(args: argparse.Namespace) -> int:
    """A campaign directory of `okid-ros batch`: every mode id over the campaign."""
    import sys

    from okid_ros.tools.campaign.plot import write_campaign_figures

    # Options of a bag's figures, given for a campaign (were passed over in silence).
    given = {"--input": args.input, "--params": args.params, "--window": args.window != DEFAULT_WINDOW_S,
             "--terms": args.terms != DEFAULT_TERMS, "--frf-pairs": args.frf_pairs, "--namespace": args.namespace}
    ignored = [option for option, value in given.items() if value]
    if ignored:
        print(f"okid-ros plot: warning: {', '.join(ignored)}: options of an output bag's figures; ignored for the "
              f"campaign folder {shown_path(args.bag)} (campaign_modes.png)", file=sys.stderr)
    out_dir = _figure_folder(args, Path(args.bag) / "figures")
    written = write_campaign_figures(Path(args.bag), out_dir, force=args.force)
    print(f"wrote {len(written)} figure(s) of the campaign {shown_path(args.bag)} to {shown_path(out_dir)}")
    for path in written:
        print(f"  {shown_path(path)}")
    return 0


def _truth_reference(truth: dict | None, n_outputs: int) -> tuple[list | None, str]:
    """The true modes to compare in mac.png, or None and a note why not (a model of other outputs)."""
    modes = _truth_modes(truth)
    sizes = sorted({mode.shape.size for mode in modes or []})
    if sizes and sizes != [n_outputs]:
        return None, (f"; truth not in mac.png (its mode shapes have {', '.join(map(str, sizes))} entries, the "
                      f"model {n_outputs} outputs)")
    return modes, ""


def _truth_modes(truth: dict | None) -> list | None:
    """The true modes with their shapes, from the truth's A, B, C (a simulated experiment), or None."""
    if not truth or not all(k in truth for k in ("A", "B", "C", "sample_time_s")):
        return None
    import numpy as np

    from okid_ros.core.modal import identify_modes

    modes, _ = identify_modes(np.asarray(truth["A"], float), np.asarray(truth["B"], float),
                              np.asarray(truth["C"], float), float(truth["sample_time_s"]))
    return [m for m in modes if m.stable]
