"""The chain of both nodes over a record, scored against the true modes.

The services in step as ``okid-ros process`` and the live nodes run them
(:class:`okid_ros.service.windowed.WindowedPipeline`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from okid_bench.scoring import modes_of
from okid_ros.service.grid_samples import GridSample
from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams
from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, resolve_parameters
from okid_ros.service.windowed import WindowedPipeline

__all__ = ["ChainScore", "chain_modes", "run_pipeline"]


@dataclass
class ChainScore:
    """True modes found (within ``tol``) and modes listed beside them, summed over the model updates.

    ``level_steps``: sensor re-zeros node 2 took off the samples; ``output_error``: (p,) the median
    of ``|y - y_estimated|`` over the samples published (the measured outputs less the estimate).
    """

    found: int
    spurious: int
    updates: int
    changes: int
    arx_glitches: int
    level_steps: int = 0
    output_error: np.ndarray | None = None


def run_pipeline(u: np.ndarray, y: np.ndarray, sample_time_s: float, arx: dict) -> tuple[WindowedPipeline, list]:
    """Both services over ``u`` (N, m), ``y`` (N, p), each valid snapshot realized at once.

    ``arx``: node 1's parameters besides the record's sizes (``arx.order``, ``publish_rate_hz``, ...);
    node 2's are its defaults. Returns the pipeline and ``y - y_estimated`` of each sample published.
    """
    common = {"sample_time_s": sample_time_s, "n_inputs": u.shape[1], "n_outputs": y.shape[1]}
    pipeline = WindowedPipeline(
        ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, {**common, **arx})),
        ModalEstimationParams.from_parameters(resolve_parameters(ESTIMATOR_NODE, common)))
    errors = []
    for k in range(u.shape[0]):
        sample = GridSample(k, k * sample_time_s, u[k], y[k], restart=k == 0)
        result = pipeline.estimate(sample)
        if result is not None:
            errors.append(y[k] - result.y_estimated)
        snapshot = pipeline.identify(sample)
        if snapshot is not None and snapshot.valid:
            pipeline.realize_now(snapshot.fit, snapshot.stamp_s, snapshot.model_id, snapshot.window_rows)
    return pipeline, errors


def chain_modes(truth, u: np.ndarray, y: np.ndarray, *, order: int, window: int, every: int,
                tol: float = 0.005) -> ChainScore:
    """Run the chain over ``u`` (N, m), ``y`` (N, p) with a snapshot every ``every`` samples; score it.

    ``truth`` is the simulated model (``A``, ``sample_time_s``): its modes are the ones to find.
    """
    dt = truth.sample_time_s
    pipeline, errors = run_pipeline(u, y, dt, {"arx.order": order, "arx.window_length": window,
                                               "publish_rate_hz": 1.0 / (every * dt)})
    true_hz = np.array([mode.frequency_hz for mode in modes_of(truth.A, dt)])
    found = spurious = 0
    for line in pipeline.updates:
        hz = np.array([mode["frequency_hz"] for mode in line["modes"]])
        found += sum(bool(np.any(np.abs(hz - f) < tol * f)) for f in true_hz)
        spurious += sum(not np.any(np.abs(f - true_hz) < tol * true_hz) for f in hz)
    glitches = int(pipeline.arx.diagnostics().get("glitches", 0))  # not counted before the gate
    steps = int(pipeline.est.diagnostics().get("output_level_steps", 0))  # not counted before node 2 took them
    error = np.median(np.abs(errors), axis=0) if errors else None
    return ChainScore(found, spurious, len(pipeline.updates), len(pipeline.changes), glitches, steps, error)
