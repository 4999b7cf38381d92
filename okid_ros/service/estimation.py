"""Node 2 without ROS: realization of ARX models, mode tracking and the modal state estimator.

:class:`ModalEstimationService` receives every assembled sample (:meth:`step`) and, now and
then, an ARX fit of node 1 (:meth:`submit_arx`). For every sample it runs the identified state
estimator (:class:`okid_ros.core.estimator.ModalStateEstimator`, filterpy) and returns the
modal states; for an ARX fit it realizes a model (:func:`okid_ros.core.pipeline.identify_from_arx`:
weighted ERA, least-squares refit of B, D and the gain, normalized modal form) from the fit
and the samples of its window, which this service buffers itself.

A model update goes from :meth:`~ModalEstimationService.submit_arx` through
:meth:`~ModalEstimationService.take_job`, ``realize``, :meth:`~ModalEstimationService.follow`
and :meth:`~ModalEstimationService.deliver` to the switch at a sample (:meth:`~ModalEstimationService.step`)
or without one (``apply_ready_if_idle``, ``apply_ready_at_end``); its life, and the request,
job and outcome it is on the way, are :mod:`~okid_ros.service.realization_handoff`'s.

``process_pending()`` runs take_job, realize and deliver synchronously. Offline
(:class:`~okid_ros.service.windowed.WindowedPipeline`) each model is realized at once, and one
delivered after the last sample is applied and published as live (``apply_ready_at_end``).

The parts, each in a module of its own: the results (:mod:`~okid_ros.service.results`), the ARX fits
refused (:mod:`~okid_ros.service.arx_requests`), the request, job and outcome handed between the sample
path and the realization's thread (:mod:`~okid_ros.service.realization_handoff`), the realization and
its checks (:mod:`~okid_ros.service.realization`), model switching with mode ids
(:mod:`~okid_ros.service.model_switch`), the divergence and change watch
(:mod:`~okid_ros.service.watch`), the diagnostics dict
(:mod:`~okid_ros.service.estimation_diagnostics`); this module is the service that holds them, with all
its locking: one lock, around what the realization's thread and the sample path share (the waiting
request, the job in flight, the delivered outcome and a change of options), held by
:meth:`~ModalEstimationService.step` and the switches without a sample (``apply_ready_if_idle``,
``apply_ready_at_end``) throughout, so that a delivered outcome is applied once, by one of them, between
two samples.

Checks before a model is accepted (otherwise the current one is kept, with the reason in
:meth:`diagnostics`, naming the check):

- the realization succeeded, ``A`` is stable (spectral radius < 1), so is its one-step predictor
  ``A - A K C``, the innovation covariance is positive definite, and it has a physical mode;
- modes are not lost (:mod:`~okid_ros.service.model_switch`): ``min_matched_fraction`` of the current
  model's modes found again; after ``max_consecutive_rejections`` such rejections the next stable one is taken.

Mode ids are persistent: a mode matched to one seen in the last ``mode_memory`` accepted
models keeps its id (and ``mac_previous`` is its MAC to it); other modes get fresh ids.

No jump at a model switch: the new estimator starts from the state its own predictor reaches over the
buffered samples (not from zero), and the normalized modal form of :mod:`okid_ros.core.modal` fixes each
mode's coordinates up to the identification error, so matched modes continue smoothly. The size of the
step at each switch relative to the modes' RMS amplitude is measured and reported (``last_switch_jump``).

Divergence watchdog and structural change (:mod:`okid_ros.service.watch`): a diverged sample is not published (its
model update or change event goes out with the next good sample); sustained divergence restarts the estimator from
the buffer; a change declared waits for a model identified from post-change data only (windows that span it are
refused), which is matched against the modes before the change (:mod:`okid_ros.service.model_switch`).

Gaps: ``skipped <= max_gap_samples`` missing slots are bridged by open-loop predictions with the last input
held; after a longer gap or a time jump the estimator restarts from zero. A realization's window starts
after the last longer gap; short gaps, large spikes filled (:mod:`okid_ros.core.realization_window`,
``window_samples_filled``). A sensor re-zero found in the innovations is taken off the samples from where it
lies (:mod:`~okid_ros.service.watch`).
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.change_detection import whitening_matrix
from okid_ros.core.estimator import ModalStateEstimator
from okid_ros.core.input_glitches import InputGlitchGate
from okid_ros.core.modal import Mode
from okid_ros.core.pipeline import IdentifiedModel
from okid_ros.core.window_samples import in_bound
from okid_ros.service import realization
from okid_ros.service.estimation_diagnostics import estimation_diagnostics
from okid_ros.service.idle import IdleWatch
from okid_ros.service.model_switch import ModelSelection, SwitchJump
from okid_ros.service.options import ModalEstimationParams, check_runtime_change
from okid_ros.service.realization import realize
from okid_ros.service.realization_handoff import RealizationHandoff
from okid_ros.service.results import (
    ActiveModel,
    EstimationStats,
    IdleSwitch,
    ModalStatesResult,
    ModelUpdate,
    RealizationJob,
    RealizationOutcome,
    StructuralChangeEvent,
)
from okid_ros.service.sample_buffer import SampleBuffer
from okid_ros.service.watch import InnovationWatch

__all__ = ["realize", "IdleSwitch", "ModalEstimationParams", "ModalEstimationService", "ModalStatesResult",
           "ModelUpdate", "RealizationJob", "RealizationOutcome", "StructuralChangeEvent"]


class ModalEstimationService:
    """Realization, persistent mode ids and per-sample modal state estimation.

    Parameters
    ----------
    params : :class:`ModalEstimationParams`.
    confirm_executor : runs the change test's confirmations by the modes (:class:`InnovationWatch`; None: inline).
    """

    def __init__(self, params: ModalEstimationParams, *, confirm_executor=None) -> None:
        self._params = params
        self._confirm_executor = confirm_executor
        params.realization_options()  # raises ValueError with the reason on a bad option
        # The one lock: the waiting request, the job in flight, the delivered outcome and the
        # options, which the realization's thread and the sample path share; held by step() and
        # the switches without a sample (apply_ready_*) throughout: a model switches between two samples.
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
            self._active: ActiveModel | None = None
            self._model_id = 0
            self._stats = EstimationStats()
            self._u_prev: np.ndarray | None = None
            self._refused = 0  # samples refused since the last one stepped: a gap before the next
            self._inputs = InputGlitchGate(self.params.n_inputs)
            self._selection = ModelSelection(self.params, self._stats)
            self._watch = InnovationWatch(self.params, self._buffer, self._stats,
                                          confirm_executor=self._confirm_executor)
            self._jump = SwitchJump(self._stats)
            self._held_update: ModelUpdate | None = None  # outputs of withheld samples, passed on
            self._held_change: StructuralChangeEvent | None = None
            self._accepted_change: StructuralChangeEvent | None = None  # set by _apply, reported by step
            self._idle = IdleWatch()
            # The waiting request, the job in flight, the delivered outcome; a new generation of jobs.
            self._handoff = RealizationHandoff(self._buffer, self._stats, self._watch, self._idle)

    def set_params(self, params: ModalEstimationParams) -> list[str]:
        """Take new options at once; returns the changed fields.

        The next realization uses them (jobs carry their options), the mode registry, the
        divergence watchdog and the change test take theirs now. Raises ValueError if an
        option that is not ``runtime`` in the parameter table changes (it sizes the buffer), or
        if the options do not fit together (:meth:`ModalEstimationParams.realization_options`).
        """
        params.realization_options()
        with self._lock:
            changed = check_runtime_change(self._params, params)
            self._params = params
            self._selection.configure(params)
            self._watch.configure(params)
        return changed

    @property
    def params(self) -> ModalEstimationParams:
        """The options in use; assigning new ones is :meth:`set_params`."""
        return self._params

    @params.setter
    def params(self, params: ModalEstimationParams) -> None:
        self.set_params(params)

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
        return self._handoff.request is not None

    @property
    def busy(self) -> bool:
        """A job was taken and its outcome not yet applied."""
        return self._handoff.busy

    # ------------------------------------------------------------------ ARX fits
    def submit_arx(
        self, fit: ArxFit, stamp_end_s: float, arx_model_id: int = 0, window_rows: int | None = None
    ) -> bool:
        """Offer an ARX fit of the window ending at ``stamp_end_s``; False if refused at once.

        The newest request waits until :meth:`take_job`; a request still waiting is replaced. What is
        refused: :meth:`~okid_ros.service.realization_handoff.RealizationHandoff.arrival`.
        """
        self._stats.arx_received += 1
        if not self.enabled:
            return False
        request = self._handoff.arrival(fit, stamp_end_s, arx_model_id, window_rows, self.params)
        if request is None:
            return False
        with self._lock:
            self._handoff.wait(request)
        return True

    def take_job(self) -> RealizationJob | None:
        """A realization job for the waiting ARX fit, once the buffer covers its window; None disabled.

        When taken, when dropped: :meth:`~okid_ros.service.realization_handoff.RealizationHandoff.take_job`.
        """
        with self._lock:
            if not self.enabled:
                return None
            hint = None if self._active is None else self._active.model.n_states  # warm start
            return self._handoff.take_job(self.params, order_hint=hint)

    def run_job(self, job: RealizationJob, follow: bool = True) -> RealizationOutcome:
        """:func:`realize` a job, then (``follow``) :meth:`follow` the samples that arrived since."""
        outcome = realize(job)
        return self.follow(outcome) if follow else outcome

    def follow(self, outcome: RealizationOutcome) -> RealizationOutcome:
        """Continue a realized outcome's warm start over the samples buffered since its window.

        On any thread, before :meth:`deliver` (:func:`okid_ros.service.realization.follow`):
        the switch then has at most ``handover_samples`` left to catch up. An outcome of a job
        taken before a reset, or by another service, is returned as it is (:meth:`deliver` drops it).
        """
        if outcome.job.generation != self._handoff.generation:
            return outcome  # followed over this buffer, of other samples, it was work for nothing
        return realization.follow(outcome, self._buffer)

    def deliver(self, outcome: RealizationOutcome) -> None:
        """Hand a job's outcome back; applied at the next :meth:`step` (or ``apply_ready_if_idle``, ``_at_end``)."""
        with self._lock:
            self._handoff.deliver(outcome)  # dropped if taken before a reset

    def process_pending(self) -> bool:
        """Synchronously: take a job if one is due, run it, deliver it. True if one ran."""
        job = self.take_job()
        if job is None:
            return False
        self.deliver(self.run_job(job, follow=False))
        return True

    # ------------------------------------------------------------------ samples
    def step(self, stamp_s: float, u, y, skipped: int = 0) -> ModalStatesResult | None:
        """Process one sample; return its modal states (None before the first model, or the sample refused).

        Parameters
        ----------
        stamp_s : the sample's stamp [s].
        u : (m,) inputs; y : (p,) outputs.
        skipped : missing slots just before this sample (0: contiguous); -1 (``grid_samples.RESTART_SKIP``)
            after a time jump or restart (see :class:`okid_ros.service.grid_samples.GridSample`).
        """
        prm, st = self.params, self._stats
        u, y = np.asarray(u, dtype=float).reshape(-1), np.asarray(y, dtype=float).reshape(-1)
        # Node 1's rule: wrong size, NaN/Inf or beyond 1e150 refused, counted, a missing slot before the next
        # (a finite 1e200 would overflow the estimator's, the watchdog's and the change test's squares).
        absurd = u.size != prm.n_inputs or y.size != prm.n_outputs or not in_bound(u, y)
        if absurd or self._inputs.refused(u):  # so is an input glitch, by node 1's bound (core/input_glitches.py)
            st.rejected_samples += 1
            st.input_glitches += int(not absurd)
            self._refused += 1
            return None
        if self._refused:
            skipped, self._refused = (skipped + self._refused if skipped >= 0 else skipped), 0
        st.samples += 1
        with self._lock:  # the sample appended and stepped with no idle switch in between
            return self._step(float(stamp_s), u, y, int(skipped))

    def _step(self, stamp_s: float, u: np.ndarray, y: np.ndarray, skipped: int) -> ModalStatesResult | None:
        prm = self.params
        y = self._watch.level_corrected(y)  # a sensor re-zero found is taken off (service/watch.py)
        index = self._buffer.append(stamp_s, u, y, skipped)
        update = None
        if (outcome := self._handoff.take_ready()) is not None:
            update = self._apply(outcome, index, u, y, skipped)
        active = self._active
        if active is None:
            self._u_prev = u
            return None
        # A switch made while the stream was idle has its jump measured at this sample.
        switched = update is not None or self._jump.measure_deferred(u, y, skipped, self._u_prev,
                                                                     prm.max_gap_samples)
        x_post, y_est, innov, diverged, change, self._u_prev = self._watch.step(
            active, stamp_s, index, u, y, skipped=skipped, u_prev=self._u_prev)
        change, self._accepted_change = change or self._accepted_change, None
        if diverged:
            # Never published: outputs of this sample wait for the next good one.
            self._held_update = update or self._held_update
            self._held_change = change or self._held_change
            return None
        n = active.n_modes
        coords = x_post[: 2 * n].reshape(n, 2)
        self._jump.after_sample(active, coords, switched)
        update, self._held_update = update or self._held_update, None
        change, self._held_change = change or self._held_change, None
        y_est = y_est + self._watch.level  # in the sensors' units, as they came
        return ModalStatesResult(stamp_s, active.model_id, active.modes, coords, y_est, innov, update, change)

    def apply_ready_if_idle(self, *, now_s: float | None = None) -> IdleSwitch | None:
        """Apply a delivered outcome when no sample came for a while (:mod:`okid_ros.service.idle`).

        Call it now and then (the node: from a timer). At the end of a replayed bag or in a
        sensor pause no next sample comes to apply the outcome in :meth:`step`: this makes the
        switch :meth:`step` would make before the sample after the newest buffered one (the same
        checks and mode ids; the new estimator caught up through the newest sample, which the
        next sample steps once and measures the jump at). Then the next request can be taken.

        Parameters
        ----------
        now_s : the time on a monotonic clock [s] (default: ``time.monotonic()``).

        Returns
        -------
        The :class:`IdleSwitch` to publish if a model was accepted; else None (not idle, nothing
        delivered, or the model refused: the reason in :meth:`diagnostics`).
        """
        now_s = time.monotonic() if now_s is None else float(now_s)
        with self._lock:
            if not self._idle.idle(self._buffer.count, now_s, self.params.sample_time_s):
                return None
            return self._switch_after_newest()

    def apply_ready_at_end(self) -> IdleSwitch | None:
        """The stream has ended (a record processed offline): apply a delivered outcome now.

        The switch of :meth:`apply_ready_if_idle` without waiting for the quiet time: the stream
        is idle from here on (:meth:`IdleWatch.end <okid_ros.service.idle.IdleWatch.end>`), so
        :meth:`take_job` also takes a request whose window's last samples never came. Returns as
        :meth:`apply_ready_if_idle`.
        """
        with self._lock:
            self._idle.end(self._buffer.count)
            return self._switch_after_newest()

    def _switch_after_newest(self) -> IdleSwitch | None:
        """The delivered outcome switched in after the newest buffered sample (the stream idle; lock held)."""
        if (outcome := self._handoff.take_ready()) is None:
            return None
        update = self._apply(outcome, self._buffer.count, None, None, 0)
        if update is None:
            return None
        self._stats.models_applied_idle += 1
        self._held_update = None  # superseded: one withheld at a diverged sample is older
        change, self._accepted_change = self._accepted_change, None
        return IdleSwitch(update, change, self._buffer.newest_stamp())

    # ------------------------------------------------------------------ model switch
    def _apply(self, outcome: RealizationOutcome, index: int, u: np.ndarray | None, y: np.ndarray | None,
               skipped: int) -> ModelUpdate | None:
        """Check an outcome and switch to its model before sample ``index`` (``u``, ``y``, ``skipped``).

        ``u`` None: sample ``index`` has not arrived (the stream is idle); the jump is measured when it does.
        """
        st = self._stats
        self._handoff.busy = False
        self._jump.cancel()
        job = outcome.job
        st.realizations += 1
        st.last_realization_time_s = outcome.realization_time_s
        st.last_window_samples = int(job.u.shape[0])
        st.last_accepted = False
        if outcome.model is None:
            st.models_rejected += 1
            st.last_reason = outcome.reason
            return None
        model = outcome.model
        change = self._watch.change
        modes = self._selection.select(model, job.first_index, self._active, change)
        if modes is None:
            return None
        if change is not None:
            self._watch.change = None
            self._accepted_change = change
        x, u_prev = realization.catch_up(outcome, self._buffer, index, max_gap=self.params.max_gap_samples)
        estimator = outcome.estimator or ModalStateEstimator.from_model(model)
        estimator.set_state(x)
        whiten = outcome.whiten if outcome.whiten is not None else whitening_matrix(model.innovation_covariance)
        self._model_id += 1
        st.estimator_glitches += 0 if self._active is None else self._active.estimator.glitches  # (its life ends)
        if self._active is not None and u is None:
            self._jump.defer(self._active)
        elif self._active is not None:
            self._jump.before_switch(self._active, u, y, skipped, self._u_prev, self.params.max_gap_samples)
        rows = int(job.u.shape[0])
        self._active = ActiveModel(model, estimator, self._model_id, modes, len(modes), whiten, rows)
        self._watch.new_model(model, x, rows - job.fit.order, window_inputs=job.u)  # regressor rows of its window
        self._u_prev = u_prev if u_prev is not None else self._u_prev
        return ModelUpdate(
            model=model, model_id=self._model_id, arx_model_id=job.arx_model_id, stamp_s=job.stamp_end_s,
            modes=modes, realization_time_s=outcome.realization_time_s, window_samples=rows,
        )

    # ------------------------------------------------------------------ inspection
    @property
    def current_model(self) -> IdentifiedModel | None:
        return None if self._active is None else self._active.model

    @property
    def current_modes(self) -> list[Mode]:
        return [] if self._active is None else list(self._active.modes)

    def unjudged_alarm(self) -> str:
        """An alarm of the change test still waiting for its modes' verdict (:meth:`InnovationWatch.unjudged_alarm`)."""
        with self._lock:
            return self._watch.unjudged_alarm()

    def diagnostics(self) -> dict[str, Any]:
        """Counters and health as a flat dict (:mod:`okid_ros.service.estimation_diagnostics`)."""
        return estimation_diagnostics(self._stats, self._buffer, self._watch.diagnostics(), self._active,
                                      model_id=self._model_id, busy=self._handoff.busy,
                                      request_waiting=self._handoff.request is not None, enabled=self.enabled)
