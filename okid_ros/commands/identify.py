"""`okid-ros identify DATA --order Q [--states N|auto] [--ar-order R] --json OUT.json`.

Batch identification of one record (.npz or .csv, see :mod:`okid_ros.records`) with the core
pipeline; writes the model in normalized modal form and its physical modes as JSON.
"""

from __future__ import annotations

import argparse

from okid_ros.commands._args import positive_int, states_or_auto


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `identify`."""
    parser = subparsers.add_parser(
        "identify",
        help="identify a modal state-space model and estimator gain from one record",
        description="Fit a regularized MIMO ARX model, realize it with ERA, refit the estimator "
        "gain and write A, B, C, D, K (paper convention: predictor gain A K) in normalized modal "
        "form, the innovation covariance, the Hankel singular values and the physical modes.",
    )
    parser.add_argument("data", help=".npz with u (N, m), y (N, p), sample_time_s; or .csv (see docs)")
    parser.add_argument("--order", type=positive_int, required=True, metavar="Q", help="ARX order q (paper: 100)")
    parser.add_argument("--states", type=states_or_auto, default="auto", metavar="N|auto",
                        help="model order n, or auto (lowest BIC; default)")
    parser.add_argument("--ar-order", type=positive_int, default=None, metavar="R",
                        help="order of the AR whitening filter for --gain whitening (default: Q)")
    parser.add_argument("--method", choices=("okid", "paper"), default="okid",
                        help="okid: robust chain (default); paper: the published method as is")
    parser.add_argument("--regularization", choices=("ridge", "tc", "none"), default=None,
                        help="ARX regularization (default: ridge for okid, none for paper)")
    parser.add_argument("--gain", choices=("refit", "whitening"), default="refit",
                        help="estimator gain: least-squares refit (default) or the paper's whitening")
    parser.add_argument("--no-refine", action="store_true",
                        help="skip the final prediction-error refinement (faster, less accurate)")
    parser.add_argument("--max-states", type=positive_int, default=40, metavar="N",
                        help="largest order tried by --states auto (default: %(default)s)")
    parser.add_argument("--json", required=True, metavar="OUT.json", help="where to write the model")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    import json
    import time
    from pathlib import Path

    from okid_ros.core.pipeline import IdentificationError, identify
    from okid_ros.errors import DataError
    from okid_ros.records import load_record

    record = load_record(args.data)
    started = time.perf_counter()
    try:
        model = identify(
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
            refine=not args.no_refine,
        )
    except IdentificationError as exc:
        raise DataError(str(exc)) from None
    elapsed = time.perf_counter() - started
    document = model.to_json_dict()
    document["source"] = str(args.data)
    document["elapsed_s"] = elapsed
    out = Path(args.json)
    try:
        out.write_text(json.dumps(document, indent=1) + "\n")
    except OSError as exc:
        raise DataError(f"cannot write {out}: {exc}") from None
    print(f"identified n={model.n_states} states, {len(model.modes)} physical modes in {elapsed:.2f} s -> {out}")
    for mode in model.modes:
        print(
            f"  mode {mode.id}: {mode.frequency_rad_s:10.4f} rad/s {mode.frequency_hz:9.4f} Hz "
            f"damping {100 * mode.damping_ratio:6.3f} %  MPC {mode.mpc:.3f}  MSV {mode.msv:.3f}"
        )
    return 0
