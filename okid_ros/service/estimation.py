"""Node 2 without ROS: realization of ARX models, mode tracking and the modal state estimator.

:class:`ModalEstimationService` receives every assembled sample (:meth:`step`) and, now and
then, an ARX fit of node 1 (:meth:`submit_arx`). For every sample it runs the identified state
estimator (:class:`okid_ros.core.estimator.ModalStateEstimator`, filterpy) and returns the
modal states; for an ARX fit it realizes a model (:func:`okid_ros.core.pipeline.identify_from_arx`:
weighted ERA, least-squares refit of B, D and the gain, normalized modal form) from the fit
and the samples of its window, which this service buffers itself.

Life of a model update::

    submit_arx(fit, stamp_end_s)   newest request kept; older waiting ones are replaced
    take_job()                     when the buffer holds the window's end sample: a job with a
                                   copy of the window (u, y), or None
    realize(job)                   the expensive part (ERA + refit + refinement, ~1 s at
                                   q = 100; then the modes' standard deviations, a few ms),
                                   then a warm start: the new model's predictor runs
                                   over the window; pure, any thread or process
    follow(outcome)                the warm start goes on over the samples that arrived
                                   meanwhile, so the state is converged when it takes over
    deliver(outcome)               hands the result back
    step(...)                      the next sample switches models at a sample boundary

``process_pending()`` runs the last three synchronously (offline processing).

Checks before a model is accepted (otherwise the current one is kept, with the reason in
:meth:`diagnostics`, naming the check):

- the realization succeeded, ``A`` is stable (spectral radius < 1), so is its one-step
  predictor ``A - A K C``, the innovation covariance is positive definite, and it has a
  physical mode;
- modes are not lost: at least ``min_matched_fraction`` of the current model's modes are found
  again (frequency within ``max_frequency_change``, MAC >= ``min_mac``, by
  :func:`okid_ros.core.modal.match_modes`). After ``max_consecutive_rejections`` models
  rejected in a row for lost modes, the next stable one is accepted (the structure changed).

Mode ids are persistent: a mode matched to one seen in the last ``mode_memory`` accepted
models keeps its id (and ``mac_previous`` is its MAC to it); other modes get fresh ids.

No jump at a model switch: the new estimator starts from the state its own predictor reaches
over the buffered samples (not from zero), and the normalized modal form of
:mod:`okid_ros.core.modal` fixes each mode's coordinates up to the identification error, so
matched modes continue smoothly. The size of the step at each switch relative to the modes'
RMS amplitude is measured and reported (``last_switch_jump``).

Divergence watchdog: each innovation is whitened by the model's innovation covariance
(:class:`okid_ros.core.change_detection.DivergenceMonitor`); a diverged sample (non-finite, or
the moving mean of the normalized innovation squared far above p) is not published (its model
update or change event goes out with the next good sample), and sustained divergence restarts
the estimator from the buffered samples (warm start with the model's predictor, diverged
samples predicted over).

Structural change: every sample also goes to a
:class:`okid_ros.core.change_detection.StructuralChangeMonitor` armed with a reference model
(the first model of a structure, then models of windows twice as long). On an alarm
:class:`StructuralChangeEvent` is reported with the sample (``ModalStatesResult.change``);
until a model identified from post-change data only is accepted, ARX windows that start before
the change point are refused; that model is matched against the modes before the change only
(modes not matched are retired, :class:`okid_ros.service.mode_registry.ModeRegistry`) and the
event is reported again with the modes after. A divergence that comes back right after a
restart is declared a change too.

Gaps: a sample that follows ``skipped`` missing slots is preceded by ``skipped`` open-loop
predictions with the last input held, if ``skipped <= max_gap_samples``; after a longer gap or a
time jump the estimator restarts from zero.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import linalg

from okid_ros.core.arx import ArxFit
from okid_ros.core.change_detection import (
    DivergenceMonitor,
    StructuralChangeMonitor,
    predictor_spectral_radius,
    whitening_matrix,
)
from okid_ros.core.estimator import ModalStateEstimator
from okid_ros.core.modal import Mode
from okid_ros.core.pipeline import IdentificationError, IdentifiedModel, identify_from_arx
from okid_ros.core.statespace import InnovationPredictor
from okid_ros.service.mode_registry import ModeRegistry
from okid_ros.service.options import ModalEstimationParams, check_runtime_change
from okid_ros.service.sample_buffer import SampleBuffer

__all__ = [
    "realize",
    "ModalEstimationParams",
    "ModalEstimationService",
    "ModalStatesResult",
    "ModelUpdate",
    "RealizationJob",
    "RealizationOutcome",
    "StructuralChangeEvent",
]



@dataclass
class ModelUpdate:
    """An accepted model, as ``StateSpaceModel`` carries it."""

    model: IdentifiedModel
    model_id: int
    arx_model_id: int
    stamp_s: float  # newest sample of the window it was identified from
    modes: list[Mode]  # physical modes with persistent ids, in state order
    realization_time_s: float
    window_samples: int


@dataclass
class StructuralChangeEvent:
    """A structural change declared by the innovation monitor, as ``StructuralChange`` carries it.

    Reported twice: when it is declared (``modes_after`` empty) and when the first model
    identified from post-change data only is accepted (``modes_after`` set).

    Attributes
    ----------
    change_id : 1 for the first change since start or reset, then 2, ...
    stamp_s : stamp of the sample at which the change was declared [s].
    change_stamp_s : estimated stamp of the first sample of the new structure [s].
    statistic, threshold : the CUSUM statistic at the declaration and its threshold [nats].
    variance_ratio : mean normalized innovation power since the change point (1: no change).
    modes_before : the modes of the model in use when the change was declared.
    modes_after : the modes of the first model of the new structure (empty until accepted).
    retired_ids : ids of the modes before that no mode after matched (retired).
    detection_delay_samples : samples from the change point to the declaration.
    """

    change_id: int
    stamp_s: float
    change_stamp_s: float
    statistic: float
    threshold: float
    variance_ratio: float
    modes_before: list[Mode]
    modes_after: list[Mode] = field(default_factory=list)
    retired_ids: list[int] = field(default_factory=list)
    detection_delay_samples: int = 0
    change_index: int = -1  # buffer index of the change point (internal)


@dataclass
class ModalStatesResult:
    """The estimate for one sample, as ``ModalStates`` carries it.

    Attributes
    ----------
    stamp_s : the sample's stamp [s].
    model_id : id of the model that produced it.
    modes : the model's physical modes (persistent ids), in the order of ``coordinates``.
    coordinates : (n_modes, 2) normalized modal states.
    y_estimated : (p,) ``C x + D u`` (filtered).
    innovation : (p,) ``y - C xhat - D u`` (one-step prediction error).
    update : the model accepted at this sample, if any (publish it before the states).
    change : a structural change declared or re-identified at this sample, if any.
    """

    stamp_s: float
    model_id: int
    modes: list[Mode]
    coordinates: np.ndarray
    y_estimated: np.ndarray
    innovation: np.ndarray
    update: ModelUpdate | None = None
    change: StructuralChangeEvent | None = None


@dataclass
class RealizationJob:
    """Everything :meth:`ModalEstimationService.run_job` needs (a copy; thread-safe)."""

    fit: ArxFit
    arx_model_id: int
    stamp_end_s: float
    u: np.ndarray
    y: np.ndarray
    end_index: int  # absolute buffer index of the window's last sample
    params: ModalEstimationParams
    generation: int = 0  # outcomes of jobs taken before a reset are dropped


@dataclass
class RealizationOutcome:
    """Result of :meth:`ModalEstimationService.run_job`.

    ``model`` is None when the realization failed its checks (``reason``); otherwise
    ``state`` is the new model's predicted state for the sample after ``last_index``.
    ``whiten`` (from the realization's check) and ``estimator`` (made by :meth:`follow`) are
    the parts of the switch that need only the model, prepared off the sample path.
    """

    job: RealizationJob
    model: IdentifiedModel | None
    reason: str = ""
    state: np.ndarray | None = None
    last_index: int = -1
    last_input: np.ndarray | None = None
    realization_time_s: float = 0.0
    warm_start_samples: int = 0
    whiten: np.ndarray | None = None
    estimator: ModalStateEstimator | None = None


def _run_predictor(model: IdentifiedModel, x: np.ndarray, u: np.ndarray, y: np.ndarray,
                   skipped: np.ndarray, u_prev: np.ndarray | None,
                   max_gap: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Advance the predicted state over samples, gaps bridged (same result as ModalStateEstimator.step)."""
    predictor = InnovationPredictor(model, x)
    u_prev = predictor.run_with_gaps(u, y, skipped, u_prev, max_gap)
    return predictor.x, u_prev


def _fast_forward(model: IdentifiedModel, x: np.ndarray, u: np.ndarray, y: np.ndarray,
                  skipped: np.ndarray, u_prev: np.ndarray | None,
                  max_gap: int) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`_run_predictor` a chunk of samples per matrix product (the same state to rounding).

    For the catch-up of a new model over the samples that arrived during its realization
    (:meth:`ModalEstimationService.follow`, in the node's interpreter next to the sample path)
    and the restart after a divergence (on the sample path), where a Python step per sample
    made the samples wait for the interpreter.
    """
    predictor = InnovationPredictor(model, x)
    u_prev = predictor.run_with_gaps(u, y, skipped, u_prev, max_gap, chunked=True)
    return predictor.x, u_prev


def _bridge(model: IdentifiedModel, x: np.ndarray, u_prev: np.ndarray | None, skipped: int, max_gap: int) -> np.ndarray:
    """State over ``skipped`` missing samples: open-loop prediction, or zero after a long gap."""
    predictor = InnovationPredictor(model, x)
    predictor.bridge(u_prev, skipped, max_gap)
    return predictor.x


def realize(job: RealizationJob) -> RealizationOutcome:
    """Realize the model of a job, check it, warm-start its predictor over the job's window.

    Pure (reads only the job) and picklable: runs on any thread or in another process. The
    expensive part of a model update: weighted ERA, refit, order selection, refinement.
    """
    prm = job.params
    t0 = time.perf_counter()
    try:
        model = identify_from_arx(
            job.fit, job.u, job.y, prm.sample_time_s,
            options=prm.realization_options(), offsets=prm.offsets,
        )
    except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
        return RealizationOutcome(job, None, f"realization failed: {exc}", realization_time_s=time.perf_counter() - t0)
    elapsed = time.perf_counter() - t0
    radius = float(np.max(np.abs(linalg.eigvals(model.A)))) if model.n_states else 0.0
    if not radius < 1.0:
        return RealizationOutcome(
            job, None, f"unstable model (check: A stable): spectral radius of A {radius:.6f} >= 1",
            realization_time_s=elapsed)
    radius = predictor_spectral_radius(model)
    if not radius < 1.0:
        return RealizationOutcome(
            job, None, f"unstable predictor (check: A - A K C stable): spectral radius {radius:.6f} >= 1",
            realization_time_s=elapsed)
    try:
        whiten = whitening_matrix(model.innovation_covariance)
    except ValueError as exc:
        return RealizationOutcome(job, None, f"check: innovation covariance: {exc}", realization_time_s=elapsed)
    if not model.modes:
        return RealizationOutcome(job, None, "model has no physical mode", realization_time_s=elapsed)
    x, u_prev = _run_predictor(model, np.zeros(model.n_states), job.u, job.y,
                               np.zeros(job.u.shape[0], dtype=np.int64), None, prm.max_gap_samples)
    return RealizationOutcome(job, model, "", x, job.end_index, u_prev, elapsed, job.u.shape[0], whiten)


@dataclass
class _Active:
    model: IdentifiedModel
    estimator: ModalStateEstimator
    model_id: int
    modes: list[Mode]
    n_modes: int
    whiten: np.ndarray  # (p, p) inverse Cholesky factor of the innovation covariance
    window_samples: int


@dataclass
class _Stats:
    samples: int = 0
    rejected_samples: int = 0
    arx_received: int = 0
    arx_replaced: int = 0
    arx_refused: int = 0
    arx_unchanged: int = 0
    realizations: int = 0
    models_accepted: int = 0
    models_rejected: int = 0
    consecutive_rejections: int = 0
    forced_accepts: int = 0
    estimator_restarts: int = 0
    gaps_bridged: int = 0
    last_reason: str = ""
    last_accepted: bool = False
    last_realization_time_s: float = math.nan
    last_window_samples: int = 0
    last_switch_jump: float = math.nan
    max_switch_jump: float = 0.0
    switches_measured: int = 0
    diverged_samples: int = 0
    divergence_restarts: int = 0
    changes_detected: int = 0
    windows_refused_for_change: int = 0
    last_change_stamp_s: float = math.nan
    last_change_statistic: float = math.nan
    last_change_delay_samples: int = 0
    modes_retired: int = 0


class ModalEstimationService:
    """Realization, persistent mode ids and per-sample modal state estimation.

    Parameters
    ----------
    params : :class:`ModalEstimationParams`.
    """

    def __init__(self, params: ModalEstimationParams) -> None:
        self.params = params
        params.realization_options()  # raises ValueError with the reason on a bad option
        self._lock = threading.Lock()
        cap = params.buffer_length if params.buffer_length > 0 else 8192
        self._buffer = SampleBuffer(cap, params.n_inputs, params.n_outputs)
        self.enabled = True
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the model, the mode ids, the buffer and the counters."""
        with self._lock:
            self._buffer.clear()
            self._active: _Active | None = None
            prm = self.params
            self._registry = ModeRegistry(max_frequency_change=prm.max_frequency_change, min_mac=prm.min_mac,
                                          mode_memory=prm.mode_memory)
            self._model_id = 0
            self._request: tuple[ArxFit, float, int, int] | None = None
            self._last_request_end: float | None = None
            self._busy = False
            self._ready: RealizationOutcome | None = None
            self._generation = getattr(self, "_generation", -1) + 1  # outcomes of older jobs are dropped
            self._stats = _Stats()
            self._u_prev: np.ndarray | None = None
            self._power: dict[int, float] = {}
            self._divergence = DivergenceMonitor(prm.n_outputs, window_samples=prm.divergence_window_samples,
                                                 nis_ratio=prm.divergence_nis_ratio)
            self._monitor = StructuralChangeMonitor(
                prm.n_outputs, false_alarm_samples=prm.change_false_alarm_samples,
                variance_ratio=prm.change_variance_ratio, reference_samples=prm.change_reference_samples,
            )
            self._change: StructuralChangeEvent | None = None  # declared, waiting for its new model
            self._changes = 0
            self._held_update: ModelUpdate | None = None  # outputs of withheld samples, passed on
            self._held_change: StructuralChangeEvent | None = None
            self._accepted_change: StructuralChangeEvent | None = None
            self._diverged: list[int] = []  # buffer indices of diverged samples since the last restart
            self._restart_failed = False  # no good sample since the last divergence restart

    def set_params(self, params: ModalEstimationParams) -> list[str]:
        """Take new options at once; returns the changed fields.

        The next realization uses them (jobs carry their options), the mode registry, the
        divergence watchdog and the change test take theirs now. Raises ValueError if an
        option that is not ``runtime`` in the parameter table changes (it sizes the buffer).
        """
        with self._lock:
            changed = check_runtime_change(self.params, params)
            self.params = params
            self._configure_parts()
        return changed

    def _configure_parts(self) -> None:
        """Hand the options to the parts that hold their own copy."""
        prm = self.params
        self._registry.configure(max_frequency_change=prm.max_frequency_change, min_mac=prm.min_mac,
                                 mode_memory=prm.mode_memory)
        self._divergence.nis_ratio = float(prm.divergence_nis_ratio)
        self._monitor.detector.retune(false_alarm_samples=prm.change_false_alarm_samples,
                                      variance_ratio=prm.change_variance_ratio)

    def set_enabled(self, on: bool) -> None:
        """When disabled, ARX fits are ignored and the current model is kept (states still run)."""
        self.enabled = bool(on)

    @property
    def model_id(self) -> int:
        return self._model_id

    @property
    def has_model(self) -> bool:
        return self._active is not None

    @property
    def has_request(self) -> bool:
        """An ARX fit is waiting for :meth:`take_job`."""
        return self._request is not None

    @property
    def busy(self) -> bool:
        """A job was taken and its outcome not yet applied."""
        return self._busy

    # ------------------------------------------------------------------ ARX fits
    def submit_arx(
        self, fit: ArxFit, stamp_end_s: float, arx_model_id: int = 0, window_rows: int | None = None
    ) -> bool:
        """Offer an ARX fit of the window ending at ``stamp_end_s``; False if refused at once.

        The newest request waits until :meth:`take_job`; a request still waiting is replaced.
        A fit whose window ends where the last taken or the waiting one ends (node 1
        republishing an unchanged window, e.g. while the inputs are silent) is ignored.
        """
        st = self._stats
        st.arx_received += 1
        prm = self.params
        if not self.enabled:
            return False
        if fit.n_inputs != prm.n_inputs or fit.n_outputs != prm.n_outputs:
            st.arx_refused += 1
            st.last_reason = (
                f"ARX model has m={fit.n_inputs}, p={fit.n_outputs}; this estimator has "
                f"n_inputs={prm.n_inputs}, n_outputs={prm.n_outputs}"
            )
            return False
        if not math.isfinite(stamp_end_s):
            st.arx_refused += 1
            st.last_reason = "ARX model without a stamp"
            return False
        pending = self._request
        for end in (self._last_request_end, None if pending is None else pending[1]):
            if end is not None and abs(stamp_end_s - end) <= 0.5 * prm.sample_time_s:
                st.arx_unchanged += 1  # same window as one taken or waiting (no new samples)
                return False
        rows = int(window_rows) if window_rows else int(fit.n_rows)
        need = rows + fit.order
        if prm.buffer_length <= 0 and self._buffer.cap < need * 1.1 + 64:
            self._buffer.resize(int(need * 1.1) + 64)
        with self._lock:
            if self._request is not None:
                st.arx_replaced += 1
            self._request = (fit, float(stamp_end_s), int(arx_model_id), rows)
        return True

    def take_job(self) -> RealizationJob | None:
        """A realization job for the waiting ARX fit, once the buffer covers its window.

        Returns None when there is nothing to do, a job is running, or the buffer has not yet
        received the window's last sample. A request whose window is not in the buffer (too
        few contiguous samples) is dropped with a reason.
        """
        with self._lock:
            if self._busy or self._request is None or not self.enabled:
                return None
            fit, stamp_end, arx_id, rows = self._request
            dt = self.params.sample_time_s
            if self._buffer.count > 0 and self._buffer.newest_stamp() < stamp_end - 0.5 * dt:
                return None  # the window's last sample has not arrived here yet
            self._request = None
            self._last_request_end = stamp_end
            end, end_stamp = self._buffer.find_end(stamp_end, 0.5 * dt)
            need = rows + fit.order
            if end < 0:
                return self._refuse("no buffered sample at or before the ARX window's end")
            change = self._change
            if change is not None and end + 1 - need < change.change_index:
                self._stats.windows_refused_for_change += 1
                return self._refuse(
                    f"ARX window starts before the structural change at {change.change_stamp_s:.3f} s; "
                    f"waiting for a model of post-change data"
                )
            stamps, u, y, skipped = self._buffer.get(end + 1 - need, end + 1)
            # Keep the newest contiguous run (the window's rows never span a gap either).
            breaks = np.flatnonzero(skipped[1:] != 0) + 1
            start = int(breaks[-1]) if breaks.size else 0
            u, y = u[start:], y[start:]
            minimum = max(4 * fit.order, need // 2)
            if u.shape[0] < minimum:
                return self._refuse(
                    f"buffer holds {u.shape[0]} contiguous samples of the ARX window of {need}; need at least {minimum}"
                )
            self._busy = True
            return RealizationJob(fit, arx_id, end_stamp, u, y, end, self.params, self._generation)

    def _refuse(self, reason: str) -> None:
        self._stats.arx_refused += 1
        self._stats.last_reason = reason
        return None

    def run_job(self, job: RealizationJob, follow: bool = True) -> RealizationOutcome:
        """:func:`realize` a job, then (``follow``) :meth:`follow` the samples that arrived since."""
        outcome = realize(job)
        return self.follow(outcome) if follow else outcome

    def follow(self, outcome: RealizationOutcome) -> RealizationOutcome:
        """Continue a realized outcome's warm start over the samples buffered since its window.

        Runs (on any thread) until at most ``handover_samples`` are left for :meth:`step`, and
        makes the new model's estimator there, so that the switch in :meth:`step` has less to do.
        """
        if outcome.model is None:
            return outcome
        prm = outcome.job.params
        x, u_prev, last, count = outcome.state, outcome.last_input, outcome.last_index, outcome.warm_start_samples
        for _ in range(50):
            # Never the newest buffered sample: step() may be applying this outcome to it.
            available = self._buffer.count - 1
            if available - 1 - last <= prm.handover_samples:
                break
            _, u, y, skipped = self._buffer.get(last + 1, available)
            if u.shape[0] == 0:
                break
            x, u_prev = _fast_forward(outcome.model, x, u, y, skipped, u_prev, prm.max_gap_samples)
            last += u.shape[0]
            count += u.shape[0]
        estimator = outcome.estimator or ModalStateEstimator.from_model(outcome.model)
        return replace(outcome, state=x, last_input=u_prev, last_index=last, warm_start_samples=count,
                       estimator=estimator)

    def deliver(self, outcome: RealizationOutcome) -> None:
        """Hand a job's outcome back; it is applied at the next :meth:`step`."""
        with self._lock:
            if outcome.job.generation != self._generation:
                return  # taken before a reset
            self._ready = outcome

    def process_pending(self) -> bool:
        """Synchronously: take a job if one is due, run it, deliver it. True if one ran."""
        job = self.take_job()
        if job is None:
            return False
        self.deliver(self.run_job(job, follow=False))
        return True

    # ------------------------------------------------------------------ samples
    def step(self, stamp_s: float, u, y, skipped: int = 0) -> ModalStatesResult | None:
        """Process one sample; return its modal states (None before the first model).

        Parameters
        ----------
        stamp_s : the sample's stamp [s].
        u : (m,) inputs; y : (p,) outputs.
        skipped : missing slots just before this sample (0: contiguous); -1
            (``sample_grid.RESTART_SKIP``) after a time jump or restart (see
            :class:`okid_ros.service.sample_grid.GridSample`).
        """
        prm = self.params
        u = np.asarray(u, dtype=float).reshape(-1)
        y = np.asarray(y, dtype=float).reshape(-1)
        st = self._stats
        # One sum catches NaN/Inf (look closer only if it is not finite: it may just overflow).
        if u.size != prm.n_inputs or y.size != prm.n_outputs or (
                not math.isfinite(u.sum() + y.sum()) and not (np.isfinite(u).all() and np.isfinite(y).all())):
            st.rejected_samples += 1
            return None
        st.samples += 1
        index = self._buffer.append(float(stamp_s), u, y, int(skipped))
        update = None
        if self._ready is not None:
            with self._lock:
                outcome, self._ready = self._ready, None
            update = self._apply(outcome, index)
        active = self._active
        if active is None:
            self._u_prev = u
            return None
        est = active.estimator
        if skipped and prm.change_detection:
            self._monitor.gap(self._u_prev, int(skipped), prm.max_gap_samples)
        if skipped:
            x = est.state
            bridged = _bridge(active.model, x, self._u_prev, int(skipped), prm.max_gap_samples)
            if skipped > 0 and skipped <= prm.max_gap_samples:
                st.gaps_bridged += 1
            else:
                st.estimator_restarts += 1
            est.set_state(bridged)
        x_post, y_est, innov = est.step(u, y)
        self._u_prev = u
        change, self._accepted_change = self._accepted_change, None
        diverged = self._divergence.check(active.whiten @ innov)
        if prm.change_detection:
            change = self._watch_structure(active, float(stamp_s), index, u, y, test=not diverged) or change
        if diverged:
            # Never published: outputs of this sample wait for the next good one.
            st.diverged_samples += 1
            self._diverged.append(index)
            if len(self._diverged) > self._buffer.cap:
                del self._diverged[0]
            if self._divergence.sustained:
                if self._restart_failed and prm.change_detection and self._change is None:
                    # Diverged again right after a restart: the model no longer fits at all.
                    ratio = self._divergence.nis_ratio_now
                    change = self._declare_change(active, float(stamp_s), index, self._diverged[0],
                                                  self._monitor.statistic, self._monitor.threshold,
                                                  ratio if math.isfinite(ratio) else 0.0) or change
                self._restart_from_buffer(active, index)
                self._restart_failed = True
            self._held_update = update or self._held_update
            self._held_change = change or self._held_change
            return None
        self._restart_failed = False
        n = active.n_modes
        coords = x_post[: 2 * n].reshape(n, 2)
        if update is not None and self._switch_reference is not None:
            self._measure_jump(active, coords)
        self._track_power(active, coords)
        update, self._held_update = update or self._held_update, None
        change, self._held_change = change or self._held_change, None
        return ModalStatesResult(float(stamp_s), active.model_id, active.modes, coords, y_est, innov, update, change)

    _accepted_change: StructuralChangeEvent | None = None  # set by _apply, reported by step

    def _watch_structure(self, active: _Active, stamp_s: float, index: int, u: np.ndarray,
                         y: np.ndarray, *, test: bool) -> StructuralChangeEvent | None:
        """Feed the change monitor one sample (tested unless the estimator diverged on it)."""
        alarm = self._monitor.step(u, y, index, test=test)
        if alarm is None:
            return None
        return self._declare_change(active, stamp_s, index, alarm.change_index, alarm.statistic,
                                    alarm.threshold, alarm.variance_ratio)

    def _declare_change(self, active: _Active, stamp_s: float, index: int, change_index: int,
                        statistic: float, threshold: float, variance_ratio: float) -> StructuralChangeEvent:
        """A structural change at ``change_index``, declared at sample ``index``."""
        self._monitor.disarm()
        self._changes += 1
        change_stamp = self._buffer.stamp_at(change_index)
        event = StructuralChangeEvent(
            change_id=self._changes, stamp_s=stamp_s,
            change_stamp_s=change_stamp if math.isfinite(change_stamp) else stamp_s,
            statistic=float(statistic), threshold=float(threshold),
            variance_ratio=float(variance_ratio), modes_before=[replace(m) for m in active.modes],
            detection_delay_samples=int(index - change_index),
            change_index=int(change_index),
        )
        self._change = event
        st = self._stats
        st.changes_detected += 1
        st.last_change_stamp_s = event.change_stamp_s
        st.last_change_statistic = event.statistic
        st.last_change_delay_samples = event.detection_delay_samples
        return event

    def _warm_state(self, model: IdentifiedModel, index: int) -> tuple[np.ndarray, np.ndarray | None]:
        """A model's predicted state after the buffered samples up to ``index``, from zero.

        Diverged samples may hold what made it diverge (a spike): predicted over, not used.
        """
        first = self._buffer.first
        _, u, y, skipped = self._buffer.get(first, index + 1)
        x, u_prev = np.zeros(model.n_states), None
        lo = 0
        for k in sorted(i - first for i in self._diverged if first <= i <= index) + [u.shape[0]]:
            if k > lo:
                x, u_prev = _fast_forward(model, x, u[lo:k], y[lo:k], skipped[lo:k], u_prev,
                                          self.params.max_gap_samples)
            if k < u.shape[0]:
                if skipped[k]:
                    x = _bridge(model, x, u_prev, int(skipped[k]), self.params.max_gap_samples)
                x = _bridge(model, x, u[k], 1, 1)  # the diverged sample predicted over, open loop
                u_prev = u[k]
            lo = k + 1
        if not np.all(np.isfinite(x)):
            x = np.zeros(model.n_states)
        return x, u_prev

    def _restart_from_buffer(self, active: _Active, index: int) -> None:
        """Restart the estimator after sustained divergence.

        From zero, warm-started with the model's
        predictor over the buffered samples up to ``index``.
        """
        x, u_prev = self._warm_state(active.model, index)
        if self._monitor.armed:  # the change test's predictor saw the same samples
            self._monitor.set_state(self._warm_state(self._monitor.model, index)[0])
        self._diverged.clear()
        active.estimator.set_state(x)
        self._u_prev = u_prev if u_prev is not None else self._u_prev
        self._divergence.restart()
        self._stats.divergence_restarts += 1

    # ------------------------------------------------------------------ model switch
    def _apply(self, outcome: RealizationOutcome, index: int) -> ModelUpdate | None:
        """Check an outcome and switch to its model before sample ``index``."""
        st = self._stats
        prm = self.params
        self._busy = False
        self._switch_reference = None
        st.realizations += 1
        st.last_realization_time_s = outcome.realization_time_s
        st.last_window_samples = int(outcome.job.u.shape[0])
        st.last_accepted = False
        if outcome.model is None:
            st.models_rejected += 1
            st.last_reason = outcome.reason
            return None
        model = outcome.model
        change = self._change
        job = outcome.job
        window_first = job.end_index - job.u.shape[0] + 1
        if change is not None and window_first < change.change_index:
            st.models_rejected += 1
            st.windows_refused_for_change += 1
            st.last_reason = "model identified from a window that spans the structural change"
            return None
        # After a change: match against the modes before it only (no memory, no lost-mode check).
        matches = self._registry.match(model.modes, None if change is None else change.modes_before)
        ids = [None if found is None else found[0] for found in matches]
        active = self._active
        if change is None and active is not None and active.modes:
            current_ids = {mode.id for mode in active.modes}
            found = len(current_ids & {i for i in ids if i is not None})
            fraction = found / len(current_ids)
            if fraction < prm.min_matched_fraction:
                forced = 0 < prm.max_consecutive_rejections <= st.consecutive_rejections
                if not forced:
                    st.models_rejected += 1
                    st.consecutive_rejections += 1
                    st.last_reason = (
                        f"modes lost: {found} of the current model's {len(current_ids)} modes found in the new "
                        f"model (tracking.min_matched_fraction {prm.min_matched_fraction:g})"
                    )
                    return None
                st.forced_accepts += 1
        st.consecutive_rejections = 0
        st.last_accepted = True
        st.last_reason = ""
        modes = self._registry.assign(model.modes, matches)
        st.models_accepted += 1
        if change is not None:
            kept = {mode.id for mode in modes}
            self._registry.retire_except(kept)
            change.retired_ids = [mode.id for mode in change.modes_before if mode.id not in kept]
            change.modes_after = [replace(mode) for mode in modes]
            st.modes_retired += len(change.retired_ids)
            self._change = None
            self._accepted_change = change
        # Catch up the samples between the warm start and this one.
        x = outcome.state
        u_prev = outcome.last_input
        if outcome.last_index < index - 1:
            _, u, y, skipped = self._buffer.get(outcome.last_index + 1, index)
            x, u_prev = _run_predictor(model, x, u, y, skipped, u_prev, prm.max_gap_samples)
        estimator = outcome.estimator or ModalStateEstimator.from_model(model)
        estimator.set_state(x)
        whiten = outcome.whiten if outcome.whiten is not None else whitening_matrix(model.innovation_covariance)
        self._model_id += 1
        if active is not None:
            self._switch_reference = (active, self._previous_coordinates(active, index))
        self._active = _Active(model, estimator, self._model_id, modes, len(modes), whiten, int(job.u.shape[0]))
        self._divergence.restart()
        monitor = self._monitor
        rows = int(job.u.shape[0]) - job.fit.order  # regressor rows of the model's window
        if prm.change_detection and (not monitor.armed or rows >= 2 * monitor.reference_rows):
            # The reference of the change test: the first model (of a structure), then models
            # of windows at least twice as long as the reference's.
            monitor.arm(model, x, reference_rows=rows)
        self._u_prev = u_prev if u_prev is not None else self._u_prev
        return ModelUpdate(
            model=model, model_id=self._model_id, arx_model_id=outcome.job.arx_model_id,
            stamp_s=outcome.job.stamp_end_s, modes=modes,
            realization_time_s=outcome.realization_time_s, window_samples=int(outcome.job.u.shape[0]),
        )

    def _previous_coordinates(self, old: _Active, index: int) -> dict[int, np.ndarray]:
        """The old model's modal states for sample ``index`` (run on a copy of its estimator)."""
        _, u, y, skipped = self._buffer.get(index, index + 1)
        if u.shape[0] != 1:
            return {}
        x = old.estimator.state
        if skipped[0]:
            x = _bridge(old.model, x, self._u_prev, int(skipped[0]), self.params.max_gap_samples)
        innovation = InnovationPredictor(old.model, x).run(u, y)[0]  # on the offset-free signals
        x_post = x + old.estimator.K_steady @ innovation
        coords = x_post[: 2 * old.n_modes].reshape(old.n_modes, 2)
        return {mode.id: coords[i] for i, mode in enumerate(old.modes)}

    def _measure_jump(self, active: _Active, coords: np.ndarray) -> None:
        """Step of the matched modes' coordinates at a switch, relative to their RMS amplitude."""
        _, previous = self._switch_reference
        self._switch_reference = None
        jumps = []
        for i, mode in enumerate(active.modes):
            old = previous.get(mode.id)
            power = self._power.get(mode.id)
            if old is None or not power:
                continue
            jumps.append(float(np.linalg.norm(coords[i] - old)) / math.sqrt(power))
        if jumps:
            st = self._stats
            st.last_switch_jump = max(jumps)
            st.max_switch_jump = max(st.max_switch_jump, st.last_switch_jump)
            st.switches_measured += 1

    def _track_power(self, active: _Active, coords: np.ndarray) -> None:
        """Exponential average (about 1000 samples) of each mode's squared coordinate norm."""
        sq = np.einsum("ij,ij->i", coords, coords)
        for i, mode in enumerate(active.modes):
            old = self._power.get(mode.id)
            self._power[mode.id] = float(sq[i]) if old is None else old + 1e-3 * (float(sq[i]) - old)

    _switch_reference = None

    # ------------------------------------------------------------------ inspection
    @property
    def current_model(self) -> IdentifiedModel | None:
        return None if self._active is None else self._active.model

    @property
    def current_modes(self) -> list[Mode]:
        return [] if self._active is None else list(self._active.modes)

    def diagnostics(self) -> dict[str, Any]:
        """Counters and health as a flat dict."""
        st = self._stats
        buf = self._buffer
        prm = self.params
        model = self.current_model
        extra = {
            "order_limit_reached": bool(model is not None and model.max_states_reached),
            "model_warnings": "" if model is None else "; ".join(model.warnings),
        }
        return {
            "samples": st.samples,
            "rejected_samples": st.rejected_samples,
            "buffer_samples": min(buf.count, buf.cap),
            "buffer_capacity": buf.cap,
            "arx_models_received": st.arx_received,
            "arx_models_replaced": st.arx_replaced,
            "arx_models_refused": st.arx_refused,
            "arx_models_unchanged": st.arx_unchanged,
            "realizations": st.realizations,
            "models_accepted": st.models_accepted,
            "models_rejected": st.models_rejected,
            "consecutive_rejections": st.consecutive_rejections,
            "last_model_accepted": st.last_accepted,
            "forced_accepts": st.forced_accepts,
            "last_reason": st.last_reason,
            "last_realization_time_s": st.last_realization_time_s,
            "last_window_samples": st.last_window_samples,
            "last_switch_jump": st.last_switch_jump,
            "max_switch_jump": st.max_switch_jump,
            "switches_measured": st.switches_measured,
            "gaps_bridged": st.gaps_bridged,
            "estimator_restarts": st.estimator_restarts,
            "diverged_samples": st.diverged_samples,
            "divergence_restarts": st.divergence_restarts,
            "change_monitor": self._monitor.state if prm.change_detection else "off",
            "change_statistic": float(self._monitor.statistic),
            "change_threshold": float(self._monitor.threshold),
            "changes_detected": st.changes_detected,
            "change_waiting_for_model": self._change is not None,
            "last_change_stamp_s": st.last_change_stamp_s,
            "last_change_statistic": st.last_change_statistic,
            "last_change_delay_samples": st.last_change_delay_samples,
            "windows_refused_for_change": st.windows_refused_for_change,
            "modes_retired": st.modes_retired,
            "model_id": self._model_id,
            "n_modes": 0 if self._active is None else self._active.n_modes,
            "n_states": 0 if self._active is None else self._active.model.n_states,
            "busy": self._busy,
            "arx_request_waiting": self._request is not None,
            "enabled": self.enabled,
            **extra,
        }
