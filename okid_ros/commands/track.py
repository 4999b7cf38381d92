"""`okid-ros track DATA --order Q --window W --every S [--states N|auto] --jsonl OUT.jsonl`.

Runs the recursive ARX window (:class:`okid_ros.core.recursive.SlidingWindowArx`) over a record
(.npz or .csv, as `identify`) and, once the window holds W regressor rows and then every S
samples, the identification pipeline of the core on the current window
(:func:`okid_ros.core.pipeline.identify_from_arx`). Each update writes one JSON object per line:

    {"sample_index": k, "window_first_index": ..., "time_s": ..., "n_states": ...,
     "modes": [{"frequency_rad_s", "frequency_hz", "damping_ratio", "mpc", "msv", "emac", ...}],
     "arx_penalty": ..., "condition_number": ..., "rows": W, "elapsed_s": ...}

``sample_index`` is the index in DATA of the newest sample used. The ARX fit of each update is
the batch fit of the window's normal equations (same as `identify` on those samples, with the
prior scaled by the window's data and the penalty by GCV unless ``--penalty`` fixes it); the
window keeps the normal equations up to date in O(d^2) per sample. An update whose pipeline
fails writes ``"modes": []`` and an ``"error"`` string instead of stopping the run.
"""

from __future__ import annotations

import argparse

from okid_ros.commands._args import penalty_or_gcv, positive_int, states_or_auto


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `track`."""
    parser = subparsers.add_parser(
        "track",
        help="track the modes of a record over a sliding window (one JSON line per update)",
        description="Slide a window of W regressor rows over the record, updating the ARX normal "
        "equations recursively, and every S samples (once the window is full) identify the model "
        "of the window and write its physical modes as one JSON line.",
    )
    parser.add_argument("data", help=".npz with u (N, m), y (N, p), sample_time_s; or .csv (see docs)")
    parser.add_argument("--order", type=positive_int, required=True, metavar="Q", help="ARX order q")
    parser.add_argument("--window", type=positive_int, default=4000, metavar="W",
                        help="regressor rows in the window (default: %(default)s)")
    parser.add_argument("--every", type=positive_int, default=250, metavar="S",
                        help="samples between updates once the window is full (default: %(default)s)")
    parser.add_argument("--states", type=states_or_auto, default="auto", metavar="N|auto",
                        help="model order n, or auto (lowest BIC; default)")
    parser.add_argument("--max-states", type=positive_int, default=40, metavar="N",
                        help="largest order tried by --states auto (default: %(default)s)")
    parser.add_argument("--regularization", choices=("ridge", "tc", "none"), default="ridge",
                        help="ARX regularization of each window (default: %(default)s)")
    parser.add_argument("--penalty", type=penalty_or_gcv, default="gcv", metavar="gcv|X",
                        help="regularization penalty: chosen by GCV per update (default) or fixed")
    parser.add_argument("--gain", choices=("refit", "whitening"), default="refit",
                        help="estimator gain: least-squares refit (default) or the paper's whitening")
    parser.add_argument("--jsonl", required=True, metavar="OUT.jsonl", help="where to write the updates")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    parser.set_defaults(func=run)
    return parser


def _progress(total: int, disable: bool):
    """A tqdm bar on stderr, or a stand-in with the same two methods if tqdm is missing."""
    import sys

    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a declared dependency
        class _Silent:
            def update(self, n: int) -> None:
                pass

            def close(self) -> None:
                pass

        return _Silent()
    return tqdm(total=total, unit="sample", file=sys.stderr, disable=disable, mininterval=0.5)


def run(args: argparse.Namespace) -> int:
    import json
    import time
    from pathlib import Path

    import numpy as np

    from okid_ros.core.pipeline import IdentificationError, identify_from_arx
    from okid_ros.core.recursive import SlidingWindowArx
    from okid_ros.core.regressors import regressor_length
    from okid_ros.errors import DataError, ParameterError
    from okid_ros.records import load_record

    record = load_record(args.data)
    u, y, dt = record.u, record.y, record.sample_time_s
    n_samples, m = u.shape
    p = y.shape[1]
    q, window = args.order, args.window
    d = regressor_length(q, p, m)
    if q < 2:
        raise ParameterError(f"--order must be >= 2 for the identification pipeline, got {q}")
    if args.regularization == "none" and window < d:
        raise ParameterError(
            f"--window {window} is smaller than the {d} ARX coefficients per output of order {q} "
            f"with {m} inputs and {p} outputs; unregularized least squares needs at least {d} rows"
        )
    if n_samples < window + q:
        raise DataError(
            f"too few samples for one window: {n_samples} given, at least {window + q} needed "
            f"(window {window} rows plus {q} lags)"
        )
    estimator = SlidingWindowArx(q, p, m, window=window)
    # Update points: the window is first full at sample window + q - 1, then every S samples.
    first = window + q - 1
    points = list(range(first, n_samples, args.every))
    out = Path(args.jsonl)
    try:
        handle = out.open("w")
    except OSError as exc:
        raise DataError(f"cannot write {out}: {exc}") from None
    bar = _progress(n_samples, disable=args.no_progress or n_samples < 20_000)
    started = time.perf_counter()
    failures = 0
    last_modes: list = []
    with handle:
        fed = 0
        for k in points:
            estimator.update(u[fed : k + 1], y[fed : k + 1])
            bar.update(k + 1 - fed)
            fed = k + 1
            t0 = time.perf_counter()
            entry = {
                "sample_index": int(k),
                "window_first_index": int(k - window - q + 1),
                "time_s": float(k * dt),
                "rows": int(estimator.status.rows_in_window),
            }
            try:
                fit = estimator.arx_fit(args.regularization, args.penalty)
                u_w, y_w, _ = estimator.window_samples()
                model = identify_from_arx(
                    fit, u_w, y_w, dt, n_states=args.states, max_states=args.max_states, gain=args.gain,
                )
                entry.update(
                    n_states=model.n_states,
                    arx_penalty=float(fit.penalty),
                    condition_number=float(fit.condition_number),
                    modes=[
                        {key: value for key, value in mode.as_dict().items() if not key.startswith("shape")}
                        for mode in model.modes
                    ],
                )
                last_modes = model.modes
            except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
                failures += 1
                entry.update(n_states=None, modes=[], error=str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            entry["elapsed_s"] = time.perf_counter() - t0
            handle.write(json.dumps(entry) + "\n")
        bar.update(n_samples - fed)
    bar.close()
    elapsed = time.perf_counter() - started
    print(
        f"tracked {n_samples} samples: {len(points)} updates ({failures} failed) of window {window}, "
        f"every {args.every} samples, in {elapsed:.1f} s -> {out}"
    )
    for mode in last_modes:
        print(
            f"  last update, mode {mode.id}: {mode.frequency_rad_s:10.4f} rad/s {mode.frequency_hz:9.4f} Hz "
            f"damping {100 * mode.damping_ratio:6.3f} %"
        )
    return 0
