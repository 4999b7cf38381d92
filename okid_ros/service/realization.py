"""The realization of a model update and its checks (node 2, off the sample path).

:func:`realize` turns a :class:`~okid_ros.service.results.RealizationJob` (an ARX fit and a
copy of its window's samples) into a :class:`~okid_ros.service.results.RealizationOutcome`:
the core's realization (:func:`identify_window`: :func:`okid_ros.core.pipeline.identify_from_arx`,
weighted ERA, refit, order selection, refinement; with no input, m = 0, the output-only front
end :func:`okid_ros.core.output_only.identify_output_only` on the window's outputs), the
checks every model handed out passes (stable ``A`` and stable predictor,
:meth:`okid_ros.core.statespace.InnovationModel.stability_problem`; a positive definite
innovation covariance; a physical mode) and the warm start of the new model's predictor over
the window (its last samples the state depends on, :attr:`InnovationPredictor.settle_samples`).
Pure: runs on any thread or in a worker process.

:func:`advance_state` and :func:`bridge_state` move a model's predicted state over samples
and gaps, as the estimator would (same state to rounding): the warm start, the catch-up of a
new model over the samples that arrived during its realization (:func:`follow` off the sample
path, :func:`catch_up` at the switch), the restart after divergence.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.change_detection import whitening_matrix
from okid_ros.core.estimator import ModalStateEstimator
from okid_ros.core.gap_fill import MAX_GAP_SAMPLES
from okid_ros.core.options import RealizationOptions
from okid_ros.core.output_only import OUTPUT_ONLY_METHODS, identify_output_only
from okid_ros.core.pipeline import IdentificationError, IdentifiedModel, identify_from_arx
from okid_ros.core.realization_window import realization_window
from okid_ros.core.record_checks import narrowband_note
from okid_ros.core.statespace import InnovationPredictor
from okid_ros.service.results import RealizationJob, RealizationOutcome
from okid_ros.service.sample_buffer import SampleBuffer

__all__ = ["advance_state", "bridge_state", "catch_up", "follow", "identify_window", "model_problem",
           "output_only_model", "prepare_window", "realize", "warm_start"]


def advance_state(model: IdentifiedModel, x: np.ndarray, u: np.ndarray, y: np.ndarray, skipped: np.ndarray,
                  u_prev: np.ndarray | None, *, max_gap: int,
                  chunked: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """The predicted state after samples ``u`` (N, m), ``y`` (N, p), gaps ``skipped`` (N,) bridged.

    ``chunked``: a chunk of samples per matrix product (the same state to rounding), for the
    catch-up next to the sample path, where a Python step per sample made the samples wait
    for the interpreter. Returns the state (n,) and the last input (m,) (``u_prev`` if none).
    """
    predictor = InnovationPredictor(model, x)
    u_prev = predictor.run_with_gaps(u, y, skipped, u_prev, max_gap, chunked=chunked)
    return predictor.x, u_prev


def follow(outcome: RealizationOutcome, buffer: SampleBuffer) -> RealizationOutcome:
    """Continue a realized outcome's warm start over the samples buffered since its window.

    Runs (on any thread) until at most ``handover_samples`` are left for the switch, and makes
    the new model's estimator there, so that the switch on the sample path has less to do.
    """
    if outcome.model is None:
        return outcome
    prm = outcome.job.params
    x, u_prev, last, count = outcome.state, outcome.last_input, outcome.last_index, outcome.warm_start_samples
    for _ in range(50):
        # Never the newest buffered sample: step() may be applying this outcome to it.
        available = buffer.count - 1
        if available - 1 - last <= prm.handover_samples:
            break
        _, u, y, skipped = buffer.get(last + 1, available, predicted_glitches=True)
        if u.shape[0] == 0:
            break
        x, u_prev = advance_state(outcome.model, x, u, y, skipped, u_prev, max_gap=prm.max_gap_samples, chunked=True)
        last += u.shape[0]
        count += u.shape[0]
    estimator = outcome.estimator or ModalStateEstimator.from_model(outcome.model)
    return replace(outcome, state=x, last_input=u_prev, last_index=last, warm_start_samples=count,
                   estimator=estimator)


def catch_up(outcome: RealizationOutcome, buffer: SampleBuffer, index: int, *,
             max_gap: int) -> tuple[np.ndarray, np.ndarray | None]:
    """A realized model's state for sample ``index``: its warm start run over the buffered samples since.

    Returns the predicted state (n,) and the last input (m,) (the outcome's if no sample is left).
    """
    x, u_prev = outcome.state, outcome.last_input
    if outcome.last_index < index - 1:
        _, u, y, skipped = buffer.get(outcome.last_index + 1, index, predicted_glitches=True)
        x, u_prev = advance_state(outcome.model, x, u, y, skipped, u_prev, max_gap=max_gap)
    return x, u_prev


def bridge_state(model: IdentifiedModel, x: np.ndarray, u_prev: np.ndarray | None, skipped: int,
                 max_gap: int) -> np.ndarray:
    """State over ``skipped`` missing samples: open-loop prediction, or zero after a long gap."""
    predictor = InnovationPredictor(model, x)
    predictor.bridge(u_prev, skipped, max_gap)
    return predictor.x


def output_only_model(y: np.ndarray, sample_time_s: float, **options) -> IdentifiedModel:
    """The output-only model of ``y`` (N, p), or an error that names the outputs' harmonic lines.

    ``options`` are :func:`~okid_ros.core.output_only.identify_output_only`'s. Its method assumes
    broadband excitation: when it finds no model of outputs that hold harmonic lines, the error says
    so (:func:`~okid_ros.core.record_checks.narrowband_note`).
    """
    try:
        return identify_output_only(y, sample_time_s, **options)
    except IdentificationError as exc:
        if note := narrowband_note(y, sample_time_s, options.get("valid")):
            raise IdentificationError(f"{exc}; {note}") from None
        raise


def identify_window(fit: ArxFit, u: np.ndarray, y: np.ndarray, sample_time_s: float, *,
                    options: RealizationOptions, offsets: str = "remove",
                    output_only_method: str = OUTPUT_ONLY_METHODS[0],
                    valid: np.ndarray | None = None, order_hint: int | None = None,
                  max_gap: int = MAX_GAP_SAMPLES) -> IdentifiedModel:
    """The core's model of one window: from its ARX fit, or (m = 0) from its outputs alone.

    The one place where the nodes (:func:`realize`), ``okid-ros process`` and ``okid-ros
    track`` choose the front end. With no input channel (``u`` (N, 0)) the ARX fit is a vector
    autoregression that defines the window; the model comes from the window's outputs by the
    core's output-only identification (:func:`okid_ros.core.output_only.identify_output_only`,
    route ``output_only_method``: "ssi-cov", "var" or "ssi-cva"); ``options`` (the input-output
    realization's) do not apply to it.

    Parameters
    ----------
    fit : the window's ARX fit; u : (N, m) inputs; y : (N, p) outputs of the window.
    sample_time_s : dt [s]; options : the realization's options; offsets : "remove" or "none".
    valid : (N,) bool, False at samples filled in short gaps (:mod:`okid_ros.core.gap_fill`):
        left out of the Gram of past data (input-output route) or of the output correlations
        (output-only route).
    order_hint : the order of the model in use, which warm-starts the order search.
    max_gap : the longest gap the window's filled samples may come from (node 2's
        ``estimator.max_gap_samples``); the output-only route holds ``valid`` to it.

    Raises
    ------
    IdentificationError, ValueError or numpy.linalg.LinAlgError with the reason.
    """
    if u.shape[1] == 0:
        return output_only_model(y, sample_time_s, method=output_only_method, offsets=offsets, valid=valid,
                                 max_gap=max_gap)
    return identify_from_arx(fit, u, y, sample_time_s, options=options, offsets=offsets, valid=valid,
                             order_hint=order_hint)


def realize(job: RealizationJob) -> RealizationOutcome:
    """Realize the model of a job, check it, warm-start its predictor over the job's window.

    Pure (reads only the job) and picklable: runs on any thread or in another process. The
    expensive part of a model update: weighted ERA, refit, order selection, refinement.
    """
    prm = job.params
    t0, filled = time.perf_counter(), 0

    def refused(reason: str) -> RealizationOutcome:
        return RealizationOutcome(job, None, reason, realization_time_s=time.perf_counter() - t0, window_filled=filled)

    try:
        job, filled = prepare_window(job)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return refused(str(exc))
    try:
        model = identify_window(job.fit, job.u, job.y, prm.sample_time_s, options=prm.realization_options(),
                                offsets=prm.offsets, output_only_method=prm.output_only_method,
                                valid=job.valid, order_hint=job.order_hint, max_gap=prm.max_gap_samples)
    except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
        return refused(f"realization failed: {exc}")
    elapsed = time.perf_counter() - t0
    reason, whiten = model_problem(model)
    if reason:
        return refused(reason)
    x, u_prev, settled = warm_start(model, job.u, job.y, max_gap=prm.max_gap_samples)
    return RealizationOutcome(job, model, "", x, job.end_index, u_prev, elapsed, settled, whiten,
                              window_filled=filled)


def model_problem(model: IdentifiedModel) -> tuple[str, np.ndarray | None]:
    """Why a realized model is not used (node 2 refuses it; ``track`` runs no watch on it), or "".

    Returns the reason and, for a model that passes, the whitening matrix of its innovation covariance.
    """
    problem = model.stability_problem()
    if problem:
        return f"check failed: {problem}", None
    try:
        whiten = whitening_matrix(model.innovation_covariance)
    except ValueError as exc:
        return f"check: innovation covariance: {exc}", None
    if not model.modes:
        return "model has no physical mode", None
    return "", whiten


def warm_start(model: IdentifiedModel, u: np.ndarray, y: np.ndarray, *,
               max_gap: int) -> tuple[np.ndarray, np.ndarray | None, int]:
    """A model's predicted state after its window ``u`` (N, m), ``y`` (N, p), from zero.

    Run over the window's last samples the state depends on (:attr:`InnovationPredictor.settle_samples`).
    Returns the state (n,), the last input (m,) and how many samples it ran over.
    """
    first = max(0, u.shape[0] - InnovationPredictor(model).settle_samples)
    x, u_prev = advance_state(model, np.zeros(model.n_states), u[first:], y[first:],
                              np.zeros(u.shape[0] - first, dtype=np.int64), None, max_gap=max_gap)
    return x, u_prev, u.shape[0] - first


def prepare_window(job: RealizationJob) -> tuple[RealizationJob, int]:
    """The job with its window's samples as the realization reads them, and the slots filled.

    A job taken with its window as buffered (:attr:`RealizationJob.buffered`): its newest run
    without a long gap, short gaps and spikes filled (:func:`okid_ros.core.realization_window.realization_window`,
    node 2's rule). Raises ValueError with the reason when too much is missing.
    """
    raw = job.buffered
    if raw is None:
        return job, 0
    prm = job.params
    window = realization_window(job.u, job.y, raw.skipped, job.fit, max_gap=prm.max_gap_samples, need=raw.need,
                                center=prm.offsets == "remove", refit=raw.refit)
    return replace(job, fit=window.fit, u=window.u, y=window.y, valid=window.valid, buffered=None), window.filled
