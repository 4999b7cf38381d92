"""`okid-ros batch BAG_OR_DIR... --params FILE --out DIR`: a campaign of bags into one table.

Every bag is processed as `okid-ros process` does (same parameters and options); the logic
lives in :mod:`okid_ros.tools.campaign`.
"""

from __future__ import annotations

import argparse

from okid_ros.commands._args import add_progress_arguments, namespace, path_text, positive_finite_float, positive_int
from okid_ros.tools.campaign import SCHEDULER_TIMEOUT_S
from okid_ros.tools.cores import usable_cores

#: Storage plugin of the output bags unless --storage is given.
DEFAULT_STORAGE = "mcap"


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `batch`."""
    parser = subparsers.add_parser(
        "batch",
        help="process many bags (a monitoring campaign) in parallel into one table of modes",
        description="Process every bag given (directories are searched for rosbag2 directories, .mcap, .db3 "
        "and ROS 1 .bag files) as `okid-ros process` does, locally in parallel (--workers) or on a running Dask "
        "cluster (--scheduler). Writes DIR/modes.parquet (one row per mode per model update, mode ids kept "
        "across the bags in stamp order), DIR/summary.csv (one row per bag), and per bag the output bag and "
        "JSON lines of `process` under DIR/bags/. A rerun processes only new or changed bags; the tables keep "
        "every bag of the campaign, given this time or not (docs/batch.md). Exit status: 0 when every bag given "
        "is ok, 1 when one failed or was not run, 2 for a usage error.",
    )
    parser.add_argument("paths", nargs="*", type=path_text,
                        metavar="BAG_OR_DIR", help="bags, or directories to search for bags")
    parser.add_argument("--params", action="append", default=[], metavar="FILE",
                        help="the nodes' parameter YAML (repeatable, later files override; default: the "
                        "built-in defaults, equal to config/okid.yaml)")
    parser.add_argument("--out", metavar="DIR", help="campaign directory (created; a rerun continues it)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="override a parameter, as for `okid-ros process` (repeatable)")
    parser.add_argument("--source", action="append", default=[], metavar="SPEC",
                        help="replace inputs.sources, as for `okid-ros process` (repeatable)")
    parser.add_argument("--namespace", type=namespace, default=None, metavar="NS",
                        help="the rig's namespace, as for `okid-ros process`")
    parser.add_argument("--strict-params", action="store_true",
                        help="refuse a parameter file that sets a name no node declares (default: a warning)")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default=DEFAULT_STORAGE,
                        help="storage plugin of the output bags (default: %(default)s)")
    engine = parser.add_mutually_exclusive_group()
    engine.add_argument("--workers", type=positive_int, default=None, metavar="N",
                        help="local worker processes, at most one per core and per bag (default: the number of "
                        "cores; 1: in this process)")
    engine.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="address of a running Dask distributed scheduler, e.g. tcp://10.0.0.1:8786 "
                        "(needs the extra okid_ros[dask]); each bag is one task")
    parser.add_argument("--scheduler-timeout", type=positive_finite_float, default=SCHEDULER_TIMEOUT_S,
                        metavar="SECONDS", help="how long to try to reach --scheduler before giving up "
                        "(default: %(default)s)")
    parser.add_argument("--max-failures", type=positive_int, default=None, metavar="K",
                        help="stop after K bags failed (bags not started are reported skipped)")
    parser.add_argument("--force", action="store_true", help="process every bag given again, even when unchanged; "
                        "with --forget: remove the forgotten bags' outputs too")
    parser.add_argument("--forget", nargs="+", type=path_text, default=None, metavar="BAG",
                        help="take these bags (by path, name or output folder) out of the campaign --out: their "
                        "journal lines removed and the tables rebuilt, no bag processed; their outputs under "
                        "DIR/bags are kept unless --force is given")
    parser.add_argument("--retry-failed", action="store_true",
                        help="process again the unchanged bags that failed before (default: keep their failure)")
    parser.add_argument("--csv", action="store_true", help="also write DIR/modes.csv")
    parser.add_argument("--plan", action="store_true",
                        help="only list the bags, their durations, topics and message counts (from metadata)")
    add_progress_arguments(parser)
    parser.set_defaults(func=run)
    return parser


def local_workers(requested: int | None) -> int:
    """The local worker processes for ``--workers requested``: one per core at most (None: one per core).

    Processing a bag is CPU-bound (one core each; BLAS is kept to one thread): a process more than
    the cores adds its memory, not speed. A request above them is said, as a warning line.
    """
    import warnings

    from okid_ros.errors import OkidWarning

    cores = usable_cores()
    if requested is None:
        return cores
    if requested > cores:
        warnings.warn(f"--workers {requested} is more than the {cores} cores this process may use: {cores} used "
                      "(processing a bag is CPU-bound: more processes add memory, not speed)", OkidWarning,
                      stacklevel=2)
        return cores
    return requested


def _check_bags_given(args: argparse.Namespace) -> None:
    """Refuse a run without bags to process, or with bags and --forget (which processes none)."""
    from okid_ros.errors import OkidError

    if args.forget is None:
        if not args.paths:
            raise OkidError("give the bags to process (BAG_OR_DIR...), or --forget BAG... --out DIR to take bags "
                            "out of a campaign")
    elif args.paths or args.plan:
        extra = " ".join((["--plan"] if args.plan else []) + args.paths)
        raise OkidError(f"--forget BAG... processes and plans no bag: {extra} cannot go with it (the bags to forget "
                        "follow --forget)")


def _ignored_without_processing(args: argparse.Namespace) -> list[str]:
    """The options of processing bags given with --forget or --plan, which process none (passed over in silence).

    ``--force`` and ``--csv`` mean something to --forget (remove the outputs, rebuild modes.csv), not to --plan.
    """
    given = {"--workers": args.workers is not None, "--scheduler": args.scheduler is not None,
             "--scheduler-timeout": args.scheduler_timeout != SCHEDULER_TIMEOUT_S,
             "--max-failures": args.max_failures is not None, "--retry-failed": args.retry_failed,
             "--progress": args.progress is True}
    if args.plan:
        given |= {"--force": args.force, "--csv": args.csv, "--storage": args.storage != DEFAULT_STORAGE}
    return [option for option, value in given.items() if value]


def run(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    from okid_ros.errors import OkidError, shown_path
    from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams
    from okid_ros.tools.campaign.runner import CampaignOptions, input_topics, run_campaign
    from okid_ros.tools.campaign.summary import print_summary
    from okid_ros.tools.output_paths import check_folder_option
    from okid_ros.tools.process import load_node_parameters

    namespace = args.namespace  # validated by its argparse type
    arx_values, est_values = load_node_parameters(args.params, args.param, args.source, namespace=namespace,
                                                  strict=args.strict_params)
    _check_bags_given(args)
    if args.forget is None:  # what every bag's processing would refuse, refused once at the start
        ArxIdentificationParams.from_parameters(arx_values)
    if ignored := ModalEstimationParams.from_parameters(est_values).output_only_ignored():
        print(f"okid-ros batch: warning: {ignored}", file=sys.stderr)
    if (args.forget is not None or args.plan) and (ignored := _ignored_without_processing(args)):
        print(f"okid-ros batch: warning: {', '.join(ignored)}: options of processing bags; ignored with "
              f"{'--plan (it lists the bags and processes none)' if args.plan else '--forget (it processes no bag)'}",
              file=sys.stderr)
    if args.plan:
        from okid_ros.tools.campaign.discovery import find_bags
        from okid_ros.tools.campaign.plan import format_plan, plan_campaign

        bags = find_bags(args.paths, exclude=Path(args.out) if args.out else None)
        if not bags:
            raise OkidError(f"no bags found in {', '.join(map(shown_path, args.paths))}")
        plans, elapsed_s = plan_campaign(bags)
        format_plan(plans, input_topics(arx_values, est_values, namespace), elapsed_s)
        return 0
    if not args.out:
        raise OkidError("--out DIR is required (except with --plan)")
    check_folder_option("--out", args.out)
    options = CampaignOptions(
        paths=args.paths, out_dir=Path(args.out), arx_values=arx_values, est_values=est_values,
        namespace=namespace, storage=args.storage,
        workers=1 if args.forget is not None else local_workers(args.workers),
        scheduler=args.scheduler, scheduler_timeout_s=args.scheduler_timeout, force=args.force,
        retry_failed=args.retry_failed, max_failures=args.max_failures, csv=args.csv, progress=args.progress,
        provenance={"params_files": args.params, "param_overrides": args.param, "namespace": namespace or "/"},
        forget=args.forget or [])
    report = run_campaign(options)
    print_summary(report, options)
    return report.exit_status
