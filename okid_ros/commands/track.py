"""`okid-ros track DATA --order Q --window W --every S [--states N|auto] --jsonl OUT.jsonl`.

Runs the recursive ARX window (:class:`okid_ros.core.recursive.SlidingWindowArx`) over a record
(.npz or .csv, as `identify`) and, once the window holds W regressor rows and then every S
samples, the identification pipeline of the core on the current window
(:func:`okid_ros.core.pipeline.identify_from_arx`, or, for a record without ``u`` or with
``--output-only``, the output-only identification of the window's outputs, as the nodes do:
:func:`okid_ros.service.realization.identify_window`; ``n_inputs`` 0 in every line). Each
update writes one JSON object per line:

    {"sample_index": k, "window_first_index": ..., "time_s": ..., "n_states": ...,
     "modes": [{"frequency_rad_s", "frequency_hz", "damping_ratio", "mpc", "msv", "emac", ...}],
     "arx_penalty": ..., "condition_number": ..., "rows": W, "elapsed_s": ...}

The lines go to a temporary file beside OUT, renamed to OUT when the run ends or is interrupted (Ctrl-C, SIGTERM: the
lines so far are kept); a run that fails leaves no OUT, or an old one as it was. ``--force`` replaces the name OUT (a
link there, never the file it points to), as `identify --json` does.

``sample_index`` is the index in DATA of the newest sample used. Every line also carries ``change_detected``: true on
the update where a structural change is declared, with ``change_sample_index`` (the estimated first sample of the new
structure), ``change_declared_index`` (the sample at which it was declared), ``change_statistic`` and
``change_threshold`` [nats].

Structural change (on unless ``--no-change-detection``): node 2's innovation watch runs over the
record (:class:`okid_ros.service.record_watch.RecordWatch`, on node 2's
:class:`~okid_ros.service.watch.InnovationWatch`): each update's model that passes node 2's checks
of a realized model steps its estimator over the following samples, whose divergence watchdog keeps diverged samples
out of the change test, corrects jumps of the state and restarts from the buffered samples, and
the innovations of a reference model (the first model, and after a change the first model of the
new structure) are tested sample by sample with the calibrated CUSUM of
:mod:`okid_ros.core.change_detection`, whose threshold follows from ``--false-alarm-samples``.
Every line then carries ``watch``, node 2's counts so far under its diagnostics' names
(``diverged_samples``, ``divergence_restarts``, ``state_jumps``, ``divergences_beyond_window``,
``change_glitches``, ``change_alarms_state_jump``, ..., ``models_accepted``, ``models_rejected``), and
``watch_refused`` when node 2 refuses the update's model (its checks, or its switch,
:class:`~okid_ros.service.model_switch.ModelSelection`: the model lost the modes in use; the model in use is
kept). A line whose model node 2 takes carries ``mode_ids``: node 2's persistent id of each of its ``modes``, in
order (each mode's ``id`` is its window's own numbering); the switch runs with ``--no-change-detection`` too.
When a change is declared, the window restarts at the
change point: the next models use post-change data only, from ``--restart-min-fill`` of the
window on (until then the lines have ``"modes": []`` and a ``"waiting"`` note), and the window
grows back to W rows. This is what the nodes do live and ``okid-ros process`` offline. The
samples after the last update are tested too: a change declared there is said in the summary on
stdout only (no update follows it to carry it in a line).

The ARX fit of each update is node 1's solve of the window's normal equations (kept up to date in
O(d^2) per sample; :func:`~okid_ros.service.arx_solve.solve_capture`: prior scaled by the window's data, penalty by
GCV unless ``--penalty`` fixes it, inputs silent over the window left out). An update whose window node 1 refuses (node
1's reason) or whose pipeline fails writes ``"modes": []`` and an ``"error"`` string instead of stopping the run. Every
line carries ``arx_identifier``, node 1's counts so far under its diagnostics' names: ``snapshots`` (windows its
solve judged; an update waiting for rows is none), ``valid_snapshots`` (those it took), ``silent_input_snapshots``,
``glitches``, ``input_glitches``; the summary on stdout says them.

Samples holding NaN/Inf (a dropped sensor reading) are missing samples, as on the nodes' topics:
the window leaves out the regressor rows that reach them, the realization fills gaps of up to
``estimator.max_gap_samples`` by prediction and starts after a longer one (node 2's rule,
:func:`okid_ros.core.realization_window.realization_window`; a spike at the window's last sample
judged by the next), and the change test bridges them. ``window_first_index`` counts them too.

Before the tracking, the record's sensor faults are named once on stderr, by identify's rules
(:mod:`okid_ros.service.tracked_record`): clipping, an output held alone, frozen outputs, level shifts,
spikes, a drift, harmonic lines the inputs lack. The windows take the samples as node 1 does (its glitch gates,
:mod:`okid_ros.service.window_gates`); a re-zero the change test finds is taken off where it lies, as node 2 does.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from okid_ros.commands._args import (
    NodeParameterDefault,
    add_bag_arguments,
    add_output_only_method_argument,
    ignored_for_output_only,
    node_parameter_range,
    output_only_method_ignored,
    path_text,
    penalty_or_gcv,
    positive_int,
    states_or_auto,
)
from okid_ros.core.options import GAINS, RealizationOptions
from okid_ros.errors import shown_path

if TYPE_CHECKING:
    from okid_ros.service.tracked_record import TrackedRecord
    from okid_ros.service.window_gates import ScreenedWindow


#: The options an output-only window passes over (its model comes from the outputs alone); --order,
#: --regularization and --penalty still make the vector autoregression that frames the window.
INPUT_OUTPUT_ONLY = ("--states", "--max-states", "--gain")
#: Samples between two updates unless --every says otherwise.
DEFAULT_EVERY = 250


def _fraction(text: str) -> float:
    """A number in (0, 1]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1], got {text!r}") from None
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1], got {value}")
    return value


def _samples(text: str) -> float:
    """A number of samples (may be written 1e7) in the range of the nodes' change.false_alarm_samples."""
    low, high = node_parameter_range("change.false_alarm_samples")
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of samples, got {text!r}") from None
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"expected a number of samples from {low:g} to {high:g}, got {value}")
    return value


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `track`."""
    parser = subparsers.add_parser(
        "track",
        help="track the modes of a record over a sliding window (one JSON line per update)",
        description="Slide a window of W regressor rows over the record, updating the ARX normal "
        "equations recursively, and every S samples (once the window is full) identify the model "
        "of the window and write its physical modes as one JSON line. Exit status: 0 when an update gave a model, "
        "2 for a usage or data error, none of the updates giving a model among them (OUT.jsonl left as it was), "
        "130 when interrupted (Ctrl-C, SIGTERM: the lines so far written to OUT.jsonl), 70 for an internal error.",
    )
    parser.add_argument("data", type=path_text,
                        help=".npz with u (N, m), y (N, p), sample_time_s; .csv (see docs); or a bag "
                        "(samples assembled as by the nodes, see --params, --source)")
    parser.add_argument("--order", type=states_or_auto, default="auto", metavar="Q|auto",
                        help="ARX order q, or auto: chosen by generalized cross-validation on the first "
                        "window (default)")
    parser.add_argument("--window", type=positive_int, default=4000, metavar="W",
                        help="regressor rows in the window (default: %(default)s)")
    parser.add_argument("--every", type=positive_int, default=DEFAULT_EVERY, metavar="S",
                        help="samples between updates once the window is full (default: %(default)s)")
    parser.add_argument("--states", type=states_or_auto, default="auto", metavar="N|auto",
                        help="model order n, or auto (lowest BIC; default)")
    parser.add_argument("--max-states", type=positive_int, default=RealizationOptions.max_states, metavar="N",
                        help="largest order tried first by --states auto; the search goes on while the "
                        "criterion is lowest there (default: %(default)s)")
    parser.add_argument("--regularization", choices=("ridge", "tc", "none"), default="ridge",
                        help="ARX regularization of each window (default: %(default)s)")
    parser.add_argument("--penalty", type=penalty_or_gcv, default="gcv", metavar="gcv|X",
                        help="regularization penalty: chosen by GCV per update (default) or fixed (a TC prior's "
                        "decay then fixed too: node 1's arx.tc_decay)")
    parser.add_argument("--gain", choices=GAINS, default=RealizationOptions.gain,
                        help="estimator gain: refit (default), riccati or whitening (see identify --help)")
    parser.add_argument("--no-change-detection", dest="change_detection", action="store_false",
                        help="do not test for structural changes (the window only slides; node 2's watch does "
                        "not run: no 'watch' counts)")
    parser.add_argument("--no-noise-test", dest="noise_test", action="store_false",
                        help="declare an alarm without judging it as a change of the noise model (louder or quieter "
                        "excitation against the sensor noise): ~250 samples sooner, and such changes declared too "
                        "(node parameter change.noise_test)")
    parser.add_argument("--no-mode-confirmation", dest="mode_confirmation", action="store_false",
                        help="output-only: declare an alarm without waiting for the modes of the samples after it "
                        "(40-100 periods of the slowest mode): sooner, and louder or recoloured ambient excitation "
                        "declared too (node parameter change.mode_confirmation)")
    parser.add_argument("--false-alarm-samples", type=_samples, metavar="N",
                        default=NodeParameterDefault("change.false_alarm_samples"),
                        help="expected samples between false alarms of the change test on a stationary "
                        "structure (default: %(default)g)")
    parser.add_argument("--restart-min-fill", type=_fraction, default=NodeParameterDefault("arx.restart_min_fill"),
                        metavar="F", help="after a change the window restarts at the change point; models "
                        "come from this fraction of W rows on (default: %(default)g)")
    parser.add_argument("--output-only", action="store_true",
                        help="identify from the outputs alone, ignoring the record's u (automatic for a record "
                        "without u): each window's model by output-only identification, n_inputs 0 in every line")
    add_output_only_method_argument(parser)
    parser.add_argument("--jsonl", required=True, metavar="OUT.jsonl", help="where to write the updates")
    add_bag_arguments(parser)
    parser.add_argument("--force", action="store_true", help="replace an existing OUT.jsonl (when the run ends)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    parser.set_defaults(func=run)
    return parser


def _progress(total: int, disable: bool):
    """A tqdm bar on stderr (a declared dependency, as for ``process`` and ``batch``)."""
    import sys

    from tqdm import tqdm

    return tqdm(total=total, unit="sample", file=sys.stderr, disable=disable, mininterval=0.5)


def run(args: argparse.Namespace) -> int:
    import time

    import numpy as np

    from okid_ros.core.pipeline import IdentificationError
    from okid_ros.core.recursive import SlidingWindowArx
    from okid_ros.errors import DataError
    from okid_ros.jsonio import JsonLines
    from okid_ros.service.tracked_record import TrackedRecord, node_1_params
    from okid_ros.service.window_gates import ScreenedWindow

    out, (u, y, dt) = _output_and_record(args)
    (n_samples, m), p, window = u.shape, y.shape[1], args.window
    options = RealizationOptions(n_states=args.states, max_states=args.max_states, gain=args.gain,
                                 max_states_limit=max(args.max_states, RealizationOptions.max_states_limit))
    q = _arx_order(args, u, y, options)
    node_1 = node_1_params(dt, q, p, m, window=window, regularization=args.regularization, penalty=args.penalty,
                           restart_min_fill=float(args.restart_min_fill))
    record = TrackedRecord(u, y, q, params=node_1)
    estimator = SlidingWindowArx(q, p, m, window=window)  # fed and solved as node 1's (ScreenedWindow)
    fed_window = ScreenedWindow(estimator, (u, y), record.present, params=node_1)
    watch = _record_watch(args, record, dt)
    points = _update_points(args, n_samples, q)
    changes: list = []
    handle = JsonLines(out, replace=True)  # a failed run leaves an old OUT as it was; Ctrl-C keeps the lines
    bar = _progress(n_samples, disable=args.no_progress or n_samples < 20_000)
    started = time.perf_counter()
    failures, waits, first_reason = 0, 0, ""  # updates without a model: refused, or waiting for rows
    last_modes: list = []
    with handle, bar:  # the bar closed on a failure too: its line ends before the error's
        fed = 0
        for k in points:
            alarm = watch.run(fed, k + 1) if args.change_detection else None
            if alarm is None:
                fed_window.feed(k + 1)
            else:  # restart the window at the change point before this update's solve, as node 1 does
                fed_window.restart(alarm.change_index, k + 1)
                record.origin = alarm.change_index
                changes.append(alarm)
            bar.update(k + 1 - fed)
            fed = k + 1
            t0 = time.perf_counter()
            rows = int(estimator.status.rows_in_window)
            entry = _line_head(k, record.window_start(k, rows), rows, dt, alarm)
            if args.change_detection:
                entry["watch"] = watch.counts()
            if why := record.waiting(k, rows, estimator.status, changes):
                entry.update(n_states=None, modes=[], waiting=why)
                first_reason, waits = first_reason or entry["waiting"], waits + 1
            else:
                try:
                    fields, model, u_w, y_w = _window_model(fed_window, record, k, dt, args, options)
                    entry.update(fields)
                    last_modes = model.modes
                    _switch(watch, entry, model, (u_w, y_w), rows)
                except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
                    reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                    first_reason, failures = first_reason or reason, failures + 1
                    entry.update(n_states=None, modes=[], error=reason)
            entry.update(arx_identifier=fed_window.counts(), elapsed_s=time.perf_counter() - t0)  # node 1's so far
            handle.write(entry)
        if failures + waits == len(points):  # a failure: the lines go with it, an old OUT stays (JsonLines)
            raise DataError(f"none of the {len(points)} updates gave a model ({failures} failed, {waits} waiting "
                            f"for rows); the first: {first_reason}")
        if args.change_detection:  # a change after the last update: said in the summary
            late = watch.run(fed, n_samples)
            watch.finish()
            changes += [late] if late is not None else []
        bar.update(n_samples - fed)
    elapsed = time.perf_counter() - started
    _print_summary(changes, dt, last_modes, points[-1], watch.counts() if args.change_detection else
                   watch.switch_counts(), fed_window)  # (_arx_order: an update)
    missing = f" ({record.n_missing} missing: NaN/Inf or beyond 1e150)" if record.n_missing else ""
    print(f"tracked {n_samples} samples{missing}: {len(points)} updates ({failures} failed, {waits} waiting for rows) "
          f"of window {window}, every {args.every} samples, in {elapsed:.1f} s -> {shown_path(out)}")
    return 0


def _update_points(args: argparse.Namespace, n_samples: int, q: int) -> list[int]:
    """The samples of the updates: the window first full at sample W + q - 1, then every S samples.

    ``--every 1`` (a model at every sample, as `process` warns of a publish rate at the sampling
    rate) is said with what it costs: 3000 samples took 265 s in silence.
    """
    import sys

    points = list(range(args.window + q - 1, n_samples, args.every))
    if args.every == 1 and len(points) > 1:
        print(f"okid-ros track: warning: --every 1 identifies a model at every sample: {len(points)} identifications, "
              f"{DEFAULT_EVERY} times as many as at the default --every {DEFAULT_EVERY}; this may take long",
              file=sys.stderr)
    return points


def _output_and_record(args: argparse.Namespace) -> tuple:
    """The JSON lines path (refused if it exists, unless --force) and the record: u (N, m), y (N, p), dt."""
    import sys
    from pathlib import Path

    import numpy as np

    from okid_ros.core.channels import record_units
    from okid_ros.core.excitation import output_problem
    from okid_ros.core.input_glitches import input_glitch_warning, without_input_glitches
    from okid_ros.core.scaling import covariance_range_problem
    from okid_ros.core.window_samples import WindowStatus, accepted_samples
    from okid_ros.errors import DataError
    from okid_ros.records import channel_without_values, transposed_problem
    from okid_ros.service.tracked_record import tracked_record_warnings
    from okid_ros.tools.bag_record import load_any_record
    from okid_ros.tools.output_paths import check_output_paths, prepare_file_outputs

    out = Path(args.jsonl)
    check_output_paths(args.data, "record", [(out, "JSON lines file")])
    # --force removes nothing: the lines replace the old file when the run ends (JsonLines(replace=True)).
    prepare_file_outputs([(args.jsonl, "JSON lines file")], force=args.force)
    # NaN/Inf samples are missing samples, as on the nodes' topics (TrackedRecord).
    record, _ = load_any_record(args.data, args.params, args.param, args.source, allow_nonfinite=True)
    # A record without u, or --output-only: the window of outputs alone (m = 0, a VAR window).
    u = record.u[:, :0] if args.output_only else record.u
    if problem := transposed_problem(record.y) or channel_without_values(u, record.y):
        raise DataError(problem)
    # Inputs and outputs each divided by a power of two (exact: the same fits) where a channel's typical size lies
    # beyond 2^+-64, so that values near 1e+-150 neither overflow nor underflow the window's sums (core/channels.py);
    # a group of ordinary size keeps its units, and a sample beyond 1e150 in them is refused, as the nodes refuse it.
    units = record_units(u, record.y)
    scaled_u, scaled_y = units.scale(u, record.y)
    # Input glitches judged as node 1's gate judges them, on the samples its window accepts (a refused one a gap).
    scaled_u, glitches = without_input_glitches(scaled_u, accepted=accepted_samples(scaled_u, scaled_y, WindowStatus()))
    u = scaled_u * units.input  # the record's units (powers of two: exact), in which its faults are said
    if glitches.size:
        print(f"okid-ros track: warning: {input_glitch_warning(glitches)}", file=sys.stderr)
    if u.shape[1] == 0 and (ignored := ignored_for_output_only(args, INPUT_OUTPUT_ONLY)):
        print(f"okid-ros track: warning: {ignored}", file=sys.stderr)
    elif u.shape[1] and (ignored := output_only_method_ignored(args)):
        print(f"okid-ros track: warning: {ignored}", file=sys.stderr)
    if ignored := _turned_off(args):
        print(f"okid-ros track: warning: {ignored}", file=sys.stderr)
    # A dead channel or one the others make up is the record's problem, as identify says (in the
    # record's units; every window would fail on it, the first in the ARX order's search).
    present = record.y[np.isfinite(record.y).all(axis=1)]
    problem = output_problem(present) or covariance_range_problem(present)  # identify's refusal, before the work
    if problem:
        raise DataError(problem)
    # The record's faults said once, in its units, judged on the samples the windows accept; a record shorter than
    # one window is refused next (_arx_order): its faults (a "drift" of 5 samples) are noise.
    faults = tracked_record_warnings(u, record.y, record.sample_time_s, scaled=(scaled_u, scaled_y)) \
        if record.y.shape[0] > args.window else []
    for warning in faults:
        print(f"okid-ros track: warning: {warning}", file=sys.stderr)
    return out, (scaled_u, scaled_y, record.sample_time_s)


def _turned_off(args: argparse.Namespace) -> str:
    """The warning for options given that others turn off ("" if none; they were passed over in silence)."""
    notes = []
    if args.regularization == "none" and args.penalty != "gcv":
        notes.append(f"--penalty {args.penalty:g} weighs a regularization: ignored with --regularization none")
    given = {"--no-noise-test": not args.noise_test, "--no-mode-confirmation": not args.mode_confirmation,
             "--false-alarm-samples": not isinstance(args.false_alarm_samples, NodeParameterDefault),
             "--restart-min-fill": not isinstance(args.restart_min_fill, NodeParameterDefault)}
    if not args.change_detection and any(given.values()):
        notes.append(f"{', '.join(o for o, g in given.items() if g)}: options of the change test, which "
                     "--no-change-detection turns off; ignored")
    return "; ".join(notes)


def _arx_order(args: argparse.Namespace, u, y, options) -> int:
    """The ARX order of every update (chosen on the first window with ``--order auto``), checked."""
    import numpy as np

    from okid_ros.core.arx_order import choose_arx_order, states_problem
    from okid_ros.core.options import ArxOrderOptions
    from okid_ros.core.regressors import regressor_length
    from okid_ros.core.window_minimum import window_minimum
    from okid_ros.errors import DataError, ParameterError
    from okid_ros.records import first_present_run

    window, (n_samples, m), p = args.window, u.shape, y.shape[1]
    if args.order == "auto" and m == 0:
        from okid_ros.core.gap_fill import OUTPUT_ONLY_VAR_ORDER

        q = OUTPUT_ONLY_VAR_ORDER  # the VAR only frames the window; its model comes from the outputs
    elif args.order == "auto":
        # Chosen once, on the first window, so every update uses the same regressors.
        lo = first_present_run(np.isfinite(u).all(axis=1) & np.isfinite(y).all(axis=1), window + 200)
        if lo is None:
            raise DataError(f"--order auto chooses the ARX order on {window + 200} samples without NaN/Inf and the "
                            f"record has no such run; give --order Q")
        if args.states != "auto" and (problem := states_problem(args.states, window + 200, p, m,
                                                                 arx_orders=ArxOrderOptions())):
            raise ParameterError(f"--states {args.states}: {problem} (the ARX order is chosen on the first "
                                 f"--window + 200 samples)")
        try:
            q, _ = choose_arx_order(u[lo : lo + window + 200], y[lo : lo + window + 200], options=options)
        except ValueError as exc:
            raise DataError(str(exc)) from None
    else:
        q = args.order
    d = regressor_length(q, p, m)
    if q < 2:
        raise ParameterError(f"--order must be >= 2 for the identification pipeline, got {q}")
    if args.regularization == "none" and window < d:
        raise ParameterError(
            f"--window {window} is smaller than the {d} ARX coefficients per output of order {q} "
            f"with {m} inputs and {p} outputs; unregularized least squares needs at least {d} rows"
        )
    minimum = window_minimum(q, window + q, m)
    if window + q < minimum:  # then every update would be refused
        raise ParameterError(f"--window {window} rows with {q} lags are {window + q} samples; the realization needs "
                             f"at least {minimum} (a window of at least {minimum - q} rows)")
    if n_samples < window + q:
        raise DataError(f"too few samples for one window: {n_samples} given, at least {window + q} needed "
                        f"(window {window} rows plus {q} lags)")
    return q


def _line_head(k: int, first: int, rows: int, dt: float, alarm) -> dict:
    """The first fields of the JSON line of the update at sample ``k`` (and of a change declared there)."""
    entry = {
        "sample_index": int(k),
        "window_first_index": int(first),
        "time_s": float(k * dt),
        "rows": rows,
        "change_detected": alarm is not None,
    }
    if alarm is not None:
        entry.update(
            change_sample_index=int(alarm.change_index), change_declared_index=int(alarm.alarm_index),
            change_statistic=float(alarm.statistic), change_threshold=float(alarm.threshold),
        )
    return entry


def _record_watch(args: argparse.Namespace, record: "TrackedRecord", dt: float):
    """Node 2's model switch and innovation watch over the record with track's change options.

    ``--no-change-detection``: the switch only (no sample is stepped: no watch, no test).
    """
    from dataclasses import replace

    from okid_ros.service.options import ModalEstimationParams
    from okid_ros.service.params import ESTIMATOR_NODE, resolve_parameters
    from okid_ros.service.record_watch import RecordWatch

    defaults = ModalEstimationParams.from_parameters(resolve_parameters(ESTIMATOR_NODE))
    params = replace(defaults, sample_time_s=float(dt), n_inputs=record.u.shape[1], n_outputs=record.y.shape[1],
                     change_false_alarm_samples=float(args.false_alarm_samples), change_noise_test=args.noise_test,
                     change_mode_confirmation=args.mode_confirmation, change_detection=bool(args.change_detection))
    return RecordWatch(record, params, capacity=max(8192, 2 * (args.window + record.order)))


def _switch(watch, entry: dict, model, window: tuple, rows: int) -> None:
    """Node 2's switch to an update's model: its reason in the line if refused, else its modes' persistent ids."""
    u_w, y_w = window
    if refused := watch.new_model(model, u_w, y_w, rows, first=entry["window_first_index"]):
        entry["watch_refused"] = refused  # node 2's reason: the model in use is kept
    else:  # node 2's persistent ids of the modes ("modes" keeps each window's own ids)
        entry["mode_ids"] = watch.mode_ids


def _window_model(fed_window, record: "TrackedRecord", k: int, dt: float, args: argparse.Namespace,
                  options) -> tuple:
    """Node 1's fit of the window, realized: (its fields of the JSON line, model, u, y); refused: node 1's reason."""
    from okid_ros.core.pipeline import IdentificationError
    from okid_ros.service.realization import identify_window
    from okid_ros.service.records import mode_record

    q = record.order
    solved = fed_window.solve()  # its fit judges the next samples' outputs in node 1's gate, as node 1's does
    if solved.fit is None:
        raise IdentificationError(solved.reason)
    samples = record.window_samples(solved.fit, k, int(fed_window.window.status.rows_in_window))
    u_w, y_w, fit = samples.u, samples.y, samples.fit
    model = identify_window(fit, u_w, y_w, dt, options=options, valid=samples.valid,  # output-only when m = 0
                            output_only_method=args.output_only_method, max_gap=record.max_gap)
    fields = dict(
        warnings=list(model.warnings),  # dead input channels, large offsets, the order limit
        n_states=model.n_states,
        n_inputs=model.n_inputs,  # 0: output-only
        method=model.method,  # the route: "okid" or "paper" (input-output), --output-only-method's (output-only)
        arx_order=int(q),
        max_states_reached=bool(model.max_states_reached),
        arx_penalty=float(fit.penalty),
        condition_number=float(fit.condition_number),
        modes=[mode_record(mode) for mode in model.modes],
    )
    return fields, model, u_w, y_w


def _print_summary(changes: list, dt: float, last_modes: list, last_update: int, counts: dict,
                   window: ScreenedWindow) -> None:
    """The changes, node 2's watch's and switch's counts, node 1's gates' not 0 and solves (``window``'s), on stdout."""
    for alarm in changes:
        after = "the window restarted there" if alarm.alarm_index <= last_update else (
            f"after the last update (sample {last_update}): no window of the new structure")
        print(f"structural change at sample {alarm.change_index} ({alarm.change_index * dt:.2f} s), declared at "
              f"sample {alarm.alarm_index} (statistic {alarm.statistic:.1f} > {alarm.threshold:.1f}); {after}")
    if counted := [f"{name} {n}" for name, n in counts.items() if n]:  # (--no-change-detection: the switch's only)
        print(f"node 2's {'watch' if 'diverged_samples' in counts else 'model switch'}: " + ", ".join(counted))
    if counted := [f"{name} {n}" for name, n in window.gate_counts().items() if n]:
        print("node 1's glitch gates: " + ", ".join(counted))
    if window.solves.snapshots:  # the windows node 1's solve judged (not those waiting for rows), how many it took
        print("node 1's solve: " + ", ".join(f"{name} {n}" for name, n in window.solves.counts().items()))
    for mode in last_modes:
        print(f"  last update, mode {mode.id}: {mode.frequency_rad_s:10.4f} rad/s {mode.frequency_hz:9.4f} Hz "
              f"damping {100 * mode.damping_ratio:6.3f} %")
