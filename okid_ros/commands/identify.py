"""`okid-ros identify DATA [--order Q|auto] [--states N|auto] [--ar-order R] --json OUT.json`.

Batch identification of one record (.npz or .csv, see :mod:`okid_ros.records`) with the core
pipeline; writes the model in normalized modal form and its physical modes as JSON.
``--output-only`` (automatic for a record without u) identifies from the outputs alone
(:mod:`okid_ros.core.output_only`): the same JSON with ``n_inputs`` 0 and B, D empty.
"""

from __future__ import annotations

import argparse

from okid_ros.commands._args import (
    add_bag_arguments,
    add_output_only_method_argument,
    ignored_for_output_only,
    output_only_method_ignored,
    path_text,
    positive_int,
    states_or_auto,
)
from okid_ros.core.options import GAINS, OFFSETS, RealizationOptions
from okid_ros.errors import shown_path

#: The most of a --reference file read. It is an `identify --json` output: 40-75 kB for a model of two
#: outputs (most of it the stabilization diagram), a few MB for hundreds of states of tens of outputs; 64 MiB
#: leaves room for far larger models and refuses a wrong file (a bag, a log) before it is read into memory.
MAX_REFERENCE_BYTES = 64 << 20
#: The options only the input-output chain takes: an output-only identification warns it ignores them.
INPUT_OUTPUT_ONLY = ("--order", "--states", "--ar-order", "--method", "--regularization", "--no-refine", "--gain",
                     "--max-states")


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `identify`."""
    parser = subparsers.add_parser(
        "identify",
        help="identify a modal state-space model and estimator gain from one record",
        description="Fit a regularized MIMO ARX model, realize it with ERA, refit the estimator "
        "gain and write A, B, C, D, K (paper convention: predictor gain A K) in normalized modal "
        "form, the innovation covariance, the Hankel singular values and the physical modes.",
    )
    parser.add_argument("data", type=path_text,
                        help=".npz with u (N, m), y (N, p), sample_time_s; .csv (see docs); or a bag "
                        "(samples assembled as by the nodes, see --params, --source)")
    parser.add_argument("--order", type=states_or_auto, default="auto", metavar="Q|auto",
                        help="ARX order q (paper: 100), or auto: chosen by generalized cross-validation (default)")
    parser.add_argument("--states", type=states_or_auto, default="auto", metavar="N|auto",
                        help="model order n, or auto (lowest BIC; default)")
    parser.add_argument("--ar-order", type=positive_int, default=None, metavar="R",
                        help="order of the AR whitening filter for --gain whitening (default: Q)")
    parser.add_argument("--method", choices=("okid", "paper"), default="okid",
                        help="okid: robust chain (default); paper: the published method as is")
    parser.add_argument("--regularization", choices=("ridge", "tc", "none"), default=None,
                        help="ARX regularization (default: ridge for okid, none for paper)")
    parser.add_argument("--gain", choices=GAINS, default=RealizationOptions.gain,
                        help="estimator gain: refit (least squares where the predictor is stable by "
                        "construction, else the Riccati gain; default), riccati (always the Kalman gain of "
                        "the Riccati equation on the residual covariances) or whitening (the paper's)")
    parser.add_argument("--offsets", choices=OFFSETS, default="remove",
                        help="remove: subtract the record's means and keep them with the model (default); "
                        "none: identify the raw signals")
    parser.add_argument("--no-refine", action="store_true",
                        help="skip the final prediction-error refinement (faster, less accurate)")
    parser.add_argument("--max-states", type=positive_int, default=RealizationOptions.max_states, metavar="N",
                        help="largest order tried first by --states auto; the search goes on while the "
                        "criterion is lowest there, up to %d (default: %%(default)s)"
                        % RealizationOptions.max_states_limit)
    parser.add_argument("--json", required=True, metavar="OUT.json", help="where to write the model")
    parser.add_argument("--plot-dir", default=None, metavar="DIR",
                        help="also write frf.png, mac.png (and stabilization.png when the model has the data) here")
    parser.add_argument("--reference", default=None, metavar="REF.json",
                        help="modes to compare the shapes with in mac.png (an `identify --json` output)")
    parser.add_argument("--frf-pairs", default=None, metavar="O:I,...",
                        help="output:input pairs drawn in frf.png, 1-based, e.g. 1:1,2:1 (default: all, at most 16)")
    parser.add_argument("--csv", default=None, metavar="MODES.csv",
                        help="also write the modal table (frequency, damping, standard deviations, indicators)")
    parser.add_argument("--uff", default=None, metavar="OUT.uff",
                        help="also write the mode shapes (UFF dataset 55) and the FRFs, model and measured H1 "
                        "(dataset 58), in Universal File Format")
    parser.add_argument("--output-only", action="store_true",
                        help="ignore the record's inputs and identify from its outputs alone (ambient vibration; "
                        "automatic for a record without u): the same JSON with n_inputs 0 and B, D empty")
    add_output_only_method_argument(parser)
    add_bag_arguments(parser)
    parser.add_argument("--force", action="store_true", help="replace existing outputs")
    parser.set_defaults(func=run)
    return parser


def _outputs(args: argparse.Namespace) -> list:
    """``(path, kind)`` of every file this run will write.

    Checked before the work: none over the record or another output, none replaced without --force.
    """
    from pathlib import Path

    from okid_ros.tools.validation_plots import VALIDATION_FIGURES

    paths: list = [(args.json, "JSON model")]  # as given: a trailing "/" is refused (prepare_file_outputs)
    if args.csv:
        paths.append((args.csv, "modes CSV"))
    if args.uff:
        paths.append((args.uff, "UFF file"))
    if args.plot_dir:
        paths += [(Path(args.plot_dir) / name, "figure") for name in VALIDATION_FIGURES]
    return paths


def _check_outputs(args: argparse.Namespace, outputs: list) -> None:
    """Refuse, before the record is read and making nothing, an output that cannot or may not be written.

    A bad ``--json``, ``--csv``, ``--uff`` or ``--plot-dir`` path was found only after reading the record (a big
    bag read in vain): the folders are made later, once every option is checked.
    """
    from okid_ros.tools.output_paths import check_file_outputs, check_folder_option, check_output_paths

    if args.plot_dir:
        check_folder_option("--plot-dir", args.plot_dir)
    check_output_paths(args.data, "record", outputs)
    check_file_outputs(outputs, force=args.force)


def _record_problem(record, output_only: bool) -> str:
    """Why the record cannot be identified before any work ("" if nothing is found yet).

    A channel without a value; outputs whose covariance float64 cannot hold in their units, refused
    as ``track`` refuses them before its work, a dead output among them said first, as ``track``
    says it (``identify`` refused them only after the work, where it got that far: outputs about
    1e308 failed first in the gap filling or the ARX order's search, with numpy's overflow
    warnings and another reason).
    """
    import numpy as np

    from okid_ros.core.excitation import output_problem
    from okid_ros.core.scaling import covariance_range_problem
    from okid_ros.records import channel_without_values, transposed_problem

    if problem := transposed_problem(record.y) or channel_without_values(record.u[:, :0] if output_only else record.u,
                                                                          record.y):
        return problem
    present = record.y[np.isfinite(record.y).all(axis=1)]
    if problem := covariance_range_problem(present):
        return output_problem(present) or problem  # a constant 1e308 is a dead output, not "spreads 1.48, inf"
    return ""


def _checked_record(record, output_only: bool):
    """``record`` with its input glitches replaced as node 1 and ``track`` replace them; DataError for a problem.

    The problem is :func:`_record_problem`'s (named with the record by ``run_command``). An input of
    1e149 between ordinary ones (a bit error in a force's exponent) was named clipping, its mean taken
    off as an offset of 1e147, and the fits fell by half: it is replaced by its neighbours' mean, as
    node 1's window takes it (:mod:`okid_ros.core.input_glitches`), and said in one warning.
    """
    import dataclasses
    import sys

    from okid_ros.core.input_glitches import input_glitch_warning, without_input_glitches
    from okid_ros.errors import DataError

    if problem := _record_problem(record, output_only):
        raise DataError(problem)
    if output_only:
        return record
    u, glitches = without_input_glitches(record.u)
    if not glitches.size:
        return record
    print(f"okid-ros identify: warning: {input_glitch_warning(glitches)}", file=sys.stderr)
    return dataclasses.replace(record, u=u)


def run(args: argparse.Namespace) -> int:
    import sys
    import time
    from pathlib import Path

    from okid_ros.core.validation import prediction_fits
    from okid_ros.errors import OutputError, ParameterError, writing
    from okid_ros.jsonio import write_json
    from okid_ros.records import bridged_run, longest_present_run
    from okid_ros.tools.bag_record import load_any_record
    from okid_ros.tools.output_paths import prepare_file_outputs

    out, outputs = Path(args.json), _outputs(args)
    _check_outputs(args, outputs)
    record, source = load_any_record(args.data, args.params, args.param, args.source, allow_nonfinite=True)
    output_only = bool(args.output_only) or record.u.shape[1] == 0
    record = _checked_record(record, output_only)
    ignored = ignored_for_output_only(args, INPUT_OUTPUT_ONLY) if output_only else _input_output_ignored(args)
    if ignored:
        print(f"okid-ros identify: warning: {ignored}", file=sys.stderr)
    valid = None
    if args.method == "paper" and not output_only:  # the paper's method needs contiguous samples
        record, gaps = longest_present_run(record)
    else:  # missing samples in short gaps are filled, as on node 2
        record, valid, gaps = bridged_run(record, use_inputs=not output_only)
    measured = record
    if valid is not None:  # the fits and figures need contiguous samples
        measured = longest_present_run(record, use_inputs=not output_only)[0]
        gaps += f"; the fits and figures on its longest run without them ({measured.u.shape[0]} samples)"
    if gaps:
        print(f"okid-ros identify: warning: {gaps}", file=sys.stderr)
        source = f"{source}; {gaps}"
    reference = _load_reference(args.reference, record.y.shape[1]) if args.reference else None
    pairs = None
    if args.frf_pairs:
        from okid_ros.tools.validation_plots import parse_pairs

        try:
            pairs = parse_pairs(args.frf_pairs, record.y.shape[1], record.u.shape[1])
        except ValueError as exc:
            raise ParameterError(f"--frf-pairs: {exc}") from None
        if not args.plot_dir:
            print("okid-ros identify: warning: --frf-pairs chooses the panels of frf.png, which only --plot-dir "
                  "draws: nothing to choose for", file=sys.stderr)
    if output_only and (args.uff or args.plot_dir or args.frf_pairs):
        raise ParameterError("--uff, --plot-dir and --frf-pairs draw frequency responses from the measured input: "
                             "not available for an output-only identification")
    # After every option is checked (an option's error leaves no folder made), before the work; removes
    # nothing, --force or not: each file replaces its old one when it is written.
    prepare_file_outputs(outputs, force=args.force)
    started = time.perf_counter()
    model = _identify(record, args, output_only, valid)
    uncertainty = model.uncertainty
    elapsed = time.perf_counter() - started
    u_used = measured.u[:, :0] if output_only else measured.u
    fits = prediction_fits(model, u_used, measured.y)
    document = model.to_json_dict()
    document["uncertainty"] = {"computed": uncertainty.computed, "reason": uncertainty.reason or None,
                               "method": _uncertainty_method(model)}
    document["fit_one_step_pct"] = fits["one_step_pct"]
    document["fit_simulation_pct"] = fits["simulation_pct"]
    document["fit_burn_in_samples"] = fits["burn_in_samples"]
    document["source"] = source
    document["elapsed_s"] = elapsed
    with writing(out, "JSON model"):
        write_json(out, document)
    shown_source = shown_path(args.data) + source[len(args.data):]  # the JSON keeps the name as it is
    _print_report(model, source=shown_source, output_only=output_only, elapsed_s=elapsed, out=out)
    if not uncertainty.computed:
        print(f"  mode standard deviations {uncertainty.reason}")
    print(_fit_line(fits, output_only=output_only))
    try:
        _write_exports(args, model, measured, reference=reference, pairs=pairs)
    except OutputError as exc:  # a full disk, a device that refuses: say what is written already
        raise OutputError(f"{exc}; the JSON model is written ({shown_path(out)})") from None
    return 0


def _input_output_ignored(args: argparse.Namespace) -> str:
    """The warning for options given that an input-output run passes over ("" if none)."""
    output_only_method = output_only_method_ignored(args)
    return "; ".join(filter(None, (output_only_method, _gain_options_ignored(args))))


def _gain_options_ignored(args: argparse.Namespace) -> str:
    """The warning for options given that the input-output chain passes over ("" if none).

    ``--method paper`` identifies as published: the gain by whitening, the order by the largest
    gap of the Hankel singular values, no refinement; ``--ar-order`` is only the whitening's AR
    order (all were passed over in silence).
    """
    if args.method == "paper":
        given = {f"--gain {args.gain}": args.gain not in (RealizationOptions.gain, "whitening"),
                 "--no-refine": args.no_refine, "--max-states": args.max_states != RealizationOptions.max_states}
        if names := ", ".join(option for option, passed_over in given.items() if passed_over):
            return ("--method paper identifies as published (the estimator gain by whitening, the order by the "
                    f"largest gap of the Hankel singular values, no refinement): {names} ignored")
    elif args.ar_order is not None and args.gain != "whitening":
        return (f"--ar-order is the order of the AR whitening filter of --gain whitening (and --method paper): "
                f"ignored with --gain {args.gain}")
    return ""


def _print_report(model, *, source: str, output_only: bool, elapsed_s: float, out) -> None:
    """The warnings on stderr; the model, its modes with standard deviations, on stdout."""
    import sys

    for warning in model.warnings:
        print(f"okid-ros identify: warning: {warning}", file=sys.stderr)
    print(f"record: {source}")
    front = (f"output-only ({model.method}, {model.gain_method} gain)" if output_only
             else f"ARX order {model.arx.order}")
    print(
        f"identified {front}, n={model.n_states} states, {len(model.modes)} physical modes "
        f"in {elapsed_s:.2f} s (spectral radius of A {model.spectral_radius():.4f}, of the predictor "
        f"{model.predictor_spectral_radius():.4f}) -> {shown_path(out)}"
    )
    for mode in model.modes:
        print(
            f"  mode {mode.id}: {mode.frequency_rad_s:10.4f} rad/s "
            f"{mode.frequency_hz:9.4f} Hz{_pm(mode.frequency_hz_std)} "
            f"damping {100 * mode.damping_ratio:6.3f} %{_pm(100 * mode.damping_ratio_std)}  "
            f"MPC {mode.mpc:.3f}  MSV {mode.msv:.3f}"
        )


def _write_exports(args: argparse.Namespace, model, record, *, reference, pairs) -> None:
    """``--csv``, ``--uff`` and ``--plot-dir``."""
    from okid_ros.errors import writing

    if args.csv:
        from okid_ros.tools.exports import write_modal_csv

        with writing(args.csv, "modes CSV"):
            write_modal_csv(args.csv, model.modes)
        print(f"modal table -> {shown_path(args.csv)}")
    if args.uff:
        from okid_ros.core.validation import h1_frf, model_frf
        from okid_ros.tools.exports import write_uff

        freq, measured = h1_frf(record.u, record.y, record.sample_time_s)
        modelled = model_frf(model.A, model.B, model.C, model.D, freq, record.sample_time_s)
        with writing(args.uff, "UFF file"):
            count = write_uff(args.uff, model.modes, frequency_hz=freq,
                              frfs={"model": modelled, "measured H1": measured})
        print(f"UFF (datasets 55 and 58, {count} in all) -> {shown_path(args.uff)}")
    if args.plot_dir:
        from okid_ros.tools.validation_plots import ModelView, write_validation_figures

        written = write_validation_figures(ModelView.of(model), record.u, record.y, args.plot_dir, force=args.force,
                                           reference=reference, pairs=pairs)
        print(f"figures -> {shown_path(args.plot_dir)}: {', '.join(shown_path(p.name) for p in written)}")


_JACKKNIFE = "delete-one jackknife over consecutive segments of the record"
_UNCERTAINTY_METHODS = {
    "okid": "first-order propagation of the prediction-error covariance",
    "paper": "first-order propagation of the prediction-error covariance",
    "ssi-cov": _JACKKNIFE,
    "ssi-cva": _JACKKNIFE,
    "var": "spread of the mode's poles across model orders",
}


def _uncertainty_method(model) -> str:
    """How the modes' standard deviations were computed (the JSON's ``uncertainty.method``)."""
    if model.uncertainty.method == "jackknife":  # an okid model with too many outputs for the covariance
        return _JACKKNIFE
    return _UNCERTAINTY_METHODS.get(model.method, _UNCERTAINTY_METHODS["okid"])


def _identify(record, args: argparse.Namespace, output_only: bool, valid=None):
    """The model of the record: the chain of the core, or its outputs alone (:func:`_identify_output_only`).

    ``valid``: False at the record's missing samples, which the core fills (None: none missing).
    """
    from okid_ros.core.arx_order import states_problem
    from okid_ros.core.options import ArxOrderOptions
    from okid_ros.core.pipeline import IdentificationError, identify
    from okid_ros.errors import DataError, ParameterError

    if not output_only and args.order == "auto" and args.states != "auto":
        # The bound is the states' (was said as the ARX order's cost, an option not given).
        n_present = record.u.shape[0] if valid is None else int(valid.sum())
        if problem := states_problem(args.states, n_present, record.y.shape[1], record.u.shape[1],
                                     arx_orders=ArxOrderOptions()):
            raise ParameterError(f"--states {args.states}: {problem}")
    try:
        if output_only:
            return _identify_output_only(record, args, valid)
        return identify(
            record.u,
            record.y,
            record.sample_time_s,
            order=args.order,
            n_states=args.states,
            method=args.method,
            regularization=args.regularization,
            gain=args.gain,
            ar_order=args.ar_order,
            max_states=args.max_states,
            max_states_limit=max(args.max_states, RealizationOptions.max_states_limit),
            refine=not args.no_refine,
            offsets=args.offsets,
            valid=valid,
        )
    except IdentificationError as exc:
        raise DataError(str(exc)) from None


def _identify_output_only(record, args: argparse.Namespace, valid=None):
    """The output-only identification of ``record.y`` (its ``u``, if any, ignored).

    By ``--output-only-method`` (canonical-variate SSI by default: the measured winner of
    ``docs/benchmarks-output-only.md``). ``valid``: False at
    missing samples, filled first by a VAR's prediction as node 2 fills its window, and left out
    of the output correlations. Its decompositions run in a thread per usable core (up to four;
    the same model as one thread gives).
    """
    from okid_ros.core.gap_fill import fill_missing_outputs
    from okid_ros.core.record_checks import high_modes_note
    from okid_ros.errors import DataError
    from okid_ros.service.realization import output_only_model
    from okid_ros.tools.cores import identify_workers

    try:
        y = record.y if valid is None else fill_missing_outputs(record.y, valid)
    except ValueError as exc:
        raise DataError(f"the missing samples cannot be filled: {exc}") from None
    model = output_only_model(y, record.sample_time_s, method=args.output_only_method, offsets=args.offsets,
                              valid=valid, workers=identify_workers())
    if note := high_modes_note([mode.frequency_hz for mode in model.modes], record.sample_time_s):
        model.warnings.append(note)
    return model


def _fit_line(fits: dict, *, output_only: bool) -> str:
    """One line with the fits per output (identification record, after the burn-in)."""
    pred = ", ".join(f"{v:.1f}" for v in fits["one_step_pct"])
    sim = ", ".join(f"{v:.1f}" for v in fits["simulation_pct"])
    # Without an input the free run is zero: only the one-step prediction says something.
    free_run = " (output-only)" if output_only else f", free-run simulation [{sim}] %"
    return (f"fit on the record (after {fits['burn_in_samples']} samples), per output: one-step prediction "
            f"[{pred}] %{free_run}")


def _load_reference(path: str, n_outputs: int) -> list:
    """The ``modes`` of an `identify --json` document (for MAC against a reference), checked against the record.

    Raises
    ------
    ParameterError
        one line (about the option's file, not the record): the file is unreadable, not such a
        document, or a mode's shape is missing, not finite, all zero, or not one entry per output
        (see ``validation_plots.reference_modes``).
    """
    import json
    import os

    from okid_ros.errors import ParameterError, os_reason, special_file_kind
    from okid_ros.jsonio import NOT_JSON
    from okid_ros.tools.validation_plots import reference_modes

    if kind := special_file_kind(path, pipe=True):  # a FIFO would be waited on for ever; <(cmd) is read
        raise ParameterError(f"--reference {shown_path(path)}: not a regular file ({kind})")
    too_large = (f"--reference {shown_path(path)}: more than the {MAX_REFERENCE_BYTES >> 20} MiB read for a reference "
                 "model (an `okid-ros identify --json` output is a few kB to a few MB): another file?")
    try:
        if os.stat(path).st_size > MAX_REFERENCE_BYTES:
            raise ParameterError(too_large)
        with open(path, "rb") as stream:  # bounded too: a file that grows meanwhile is not read whole
            text = stream.read(MAX_REFERENCE_BYTES + 1)
        if len(text) > MAX_REFERENCE_BYTES:
            raise ParameterError(too_large)
        if not text.strip():  # json said "Expecting value: line 1 column 1 (char 0)"
            raise ParameterError(f"--reference {shown_path(path)}: not an `okid-ros identify --json` output (the "
                                 f"file is empty)")
        document = json.loads(text)
    except (OSError, *NOT_JSON) as exc:
        raise ParameterError(f"--reference {shown_path(path)}: not an `okid-ros identify --json` output "
                             f"({os_reason(exc)})") from None
    if not isinstance(document, dict) or "modes" not in document:
        raise ParameterError(f"--reference {shown_path(path)}: not an `okid-ros identify --json` output (no 'modes')")
    return reference_modes(document["modes"], f"--reference {shown_path(path)}", n_outputs)


def _pm(std: float) -> str:
    """`` +- std`` (2 significant digits), or nothing when it is not known."""
    return "" if std != std else f" +- {std:.2g}"
