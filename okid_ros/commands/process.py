"""`okid-ros process BAG --params config/okid.yaml --out OUT [--jsonl MODELS.jsonl]`.

The two nodes' logic run offline over a recorded bag, faster than real time, with the same
parameter file; writes the ARX models, state-space models and modal states to a new bag.
"""

from __future__ import annotations

import argparse
import sys

from okid_ros.commands._args import add_progress_arguments, namespace, path_text
from okid_ros.errors import shown_path


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `process`."""
    parser = subparsers.add_parser(
        "process",
        help="run both nodes' logic offline over a bag; write models and modal states to a new bag",
        description="Read the nodes' input topics (inputs.sources of the parameter file) from a rosbag2 "
        "(sqlite3 or MCAP, any writer) or ROS 1 bag, run the identification and estimation services as "
        "the nodes do (ArxModel every 1/publish_rate_hz seconds of sample time, each valid one realized "
        "at once) and write /okid/arx_model, /okid/state_space_model, /okid/modal_states and "
        "/okid/structural_change (topic names "
        "from the parameters) to a new bag. Existing outputs are never replaced without --force.",
    )
    parser.add_argument("bag", type=path_text, help="input bag directory, .mcap or .db3 file")
    parser.add_argument("--params", action="append", default=[], metavar="FILE",
                        help="the nodes' parameter YAML (repeatable, later files override; default: the "
                        "built-in defaults, equal to config/okid.yaml)")
    parser.add_argument("--out", required=True, metavar="OUT", help="output bag directory to create")
    parser.add_argument("--jsonl", default=None, metavar="MODELS.jsonl",
                        help="also write one JSON object per model update (stamp_s, modes, ...)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="override a parameter of the node(s) that have it, e.g. publish_rate_hz=0.5 "
                        "(repeatable; VALUE is YAML)")
    parser.add_argument("--source", action="append", default=[], metavar="SPEC",
                        help="replace inputs.sources, one 'KIND TOPIC [FIELD=CHANNEL ...]' per option, e.g. "
                        "--source 'imu /accel/tip1/imu linear_acceleration.x=y0'")
    parser.add_argument("--namespace", type=namespace, default=None, metavar="NS",
                        help="the rig's namespace, as `okid-ros up --namespace NS`: relative topic names are read "
                        "and written under NS (NS/io_sample -> NS/modal_states) and the parameter file's sections "
                        "apply as to nodes in NS (default: the root namespace, topics under /okid)")
    parser.add_argument("--strict-params", action="store_true",
                        help="refuse a parameter file that sets a name no node declares (default: a warning)")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                        help="storage plugin of the output bag (default: %(default)s)")
    parser.add_argument("--force", action="store_true", help="replace existing outputs")
    add_progress_arguments(parser)
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from okid_ros.service.options import ModalEstimationParams
    from okid_ros.tools.process import load_node_parameters, process_bag

    arx_values, est_values = load_node_parameters(args.params, args.param, args.source, namespace=args.namespace,
                                                  strict=args.strict_params)
    if ignored := ModalEstimationParams.from_parameters(est_values).output_only_ignored():
        print(f"okid-ros process: warning: {ignored}", file=sys.stderr)
    summary = process_bag(args.bag, args.out, arx_values, est_values, jsonl_path=args.jsonl, force=args.force,
                          storage=args.storage, progress=args.progress,
                          provenance={"params_files": args.params, "param_overrides": args.param,
                                      "namespace": args.namespace or "/"},
                          namespace=args.namespace)
    duration = summary.data_duration_s
    speed = duration / summary.elapsed_s if summary.elapsed_s > 0 else float("inf")
    print(f"processed {shown_path(args.bag)}: {summary.input_messages} messages, {summary.samples} samples "
          f"({summary.data_text()}) in {summary.elapsed_s:.1f} s ({speed:.1f}x real time)")
    print(f"wrote {shown_path(args.out)}: {summary.arx_models} ArxModel ({summary.valid_arx_models} valid), "
          f"{summary.models} StateSpaceModel, {summary.modal_states} ModalStates"
          + (f"; {shown_path(args.jsonl)}: {len(summary.updates)} lines" if args.jsonl else ""))
    for change in summary.changes:
        if not change["modes_after"]:
            print(f"structural change {change['change_id']} at {change['change_stamp_s']:.3f} s, declared at "
                  f"{change['detection_stamp_s']:.3f} s "
                  f"(statistic {change['statistic']:.1f} > {change['threshold']:.1f})")
    if summary.updates:
        print(f"modes of the last model ({summary.updates[-1]['model_id']}):")
        for mode in summary.final_modes:
            print(f"  id {mode['id']:3d}: {mode['frequency_rad_s']:10.4f} rad/s {mode['frequency_hz']:9.4f} Hz"
                  f"{_pm(mode.get('frequency_hz_std'))}  damping {100 * mode['damping_ratio']:6.3f} %"
                  f"{_pm(mode.get('damping_ratio_std'), 100.0)}")
        last = summary.updates[-1]
        if "fit_one_step_pct" in last:
            pred = ", ".join(f"{v:.1f}" for v in last["fit_one_step_pct"])
            sim = ", ".join(f"{v:.1f}" for v in last["fit_simulation_pct"])
            # Without an input the free run is zero: only the one-step prediction says something.
            free_run = f", free-run simulation [{sim}] %" if last.get("n_inputs", 1) else " (output-only)"
            print(f"  fit on its window, per output: one-step prediction [{pred}] %{free_run}")
    else:
        reason = summary.estimator_diagnostics.get("last_reason") or summary.arx_diagnostics.get("last_reason")
        period = 1.0 / float(arx_values["publish_rate_hz"])
        span = summary.sample_span_s  # ArxModel are due by sample time, gaps included
        if not reason and not summary.arx_models and span < period:  # no ArxModel was ever due
            reason = (f"no ArxModel was due: one every {period:g} s of sample time (publish_rate_hz), the bag's data "
                      f"span {span:.3g} s")
        print("no model was identified" + (f": {reason}" if reason else ""))
    note = summary.rejection_note()
    # The likely cause, models of a wrong grid, or a share of the bag lost (a topic that stopped half-way)
    if note and (not summary.updates or summary.grid_hints() or summary.losses_worth_saying() or summary.no_data_note):
        print(f"okid-ros process: warning: {note}", file=sys.stderr)
    if summary.unjudged_alarm:
        print(f"okid-ros process: warning: {summary.unjudged_alarm}", file=sys.stderr)
    if refused := summary.arx_refused_note():
        print(f"okid-ros process: warning: {refused}", file=sys.stderr)
    return 0


def _pm(std: float | None, scale: float = 1.0) -> str:
    """`` +- std`` (2 significant digits), or nothing when it is unknown."""
    return "" if std is None else f" +- {scale * std:.2g}"
