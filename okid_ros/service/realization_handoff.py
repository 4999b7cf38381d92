"""Node 2's model updates between its sample path and the realization's thread: request, job, outcome.

:class:`RealizationHandoff` holds what the two share: the ARX request waiting for its window, the
job in flight and the outcome delivered, with the rules of each hand-over. Life of a model update::

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
    apply_ready_if_idle()          or, when no sample came for a while (the end of a bag, a
                                   sensor pause; :mod:`~okid_ros.service.idle`), a timer does,
                                   after the newest buffered sample; then the next request
                                   can be taken
    apply_ready_at_end()           or, when the caller knows the stream has ended (the end of
                                   a record offline), the same switch at once

(the methods of :class:`~okid_ros.service.estimation.ModalEstimationService`). The handoff is
not locked itself: the service holds its one lock around every call but :meth:`~RealizationHandoff.arrival`
(judged before the lock, as it came), and a model switches between two samples. The refusal rules
are :mod:`~okid_ros.service.arx_requests`'; a service's reset starts a new handoff, whose
``generation`` drops the outcomes of older jobs.
"""

from __future__ import annotations

from typing import NamedTuple

from okid_ros.core.arx import ArxFit
from okid_ros.core.realization_window import newest_run_start
from okid_ros.service.arx_requests import held_refusal, stamp_refusal, unbuffered_refusal, window_refusal
from okid_ros.service.idle import IdleWatch
from okid_ros.service.options import ModalEstimationParams
from okid_ros.service.results import (
    JOB_GENERATIONS,
    BufferedWindow,
    EstimationStats,
    RealizationJob,
    RealizationOutcome,
    RefusedArx,
)
from okid_ros.service.sample_buffer import SampleBuffer
from okid_ros.service.watch import InnovationWatch

__all__ = ["ArxRequest", "RealizationHandoff"]


class ArxRequest(NamedTuple):
    """An ARX fit offered for realization: its window ends at ``stamp_end_s`` and has ``rows`` regressor rows."""

    fit: ArxFit
    stamp_end_s: float
    arx_model_id: int
    rows: int


class RealizationHandoff:
    """The waiting ARX request, the job in flight and the delivered outcome of one service (see the module docstring).

    Parameters
    ----------
    buffer, stats, watch, idle : the service's sample buffer, counters, innovation watch (the
        change a window must not start before; an output's re-zero within it) and idle watch.

    Attributes
    ----------
    request : the ARX request waiting for :meth:`take_job`, if any.
    last_request_end : the window end of the last request taken [s].
    busy : a job was taken and its outcome not yet applied (the service sets it back).
    ready : the outcome delivered and not yet applied.
    generation : the jobs' generation of this handoff; an outcome of another is dropped.
    """

    def __init__(self, buffer: SampleBuffer, stats: EstimationStats, watch: InnovationWatch, idle: IdleWatch) -> None:
        self._buffer, self._stats, self._watch, self._idle = buffer, stats, watch, idle
        self.request: ArxRequest | None = None
        self.last_request_end: float | None = None
        self.busy = False
        self.ready: RealizationOutcome | None = None
        self.generation = next(JOB_GENERATIONS)  # outcomes of older jobs (any service's) are dropped

    def arrival(self, fit: ArxFit, stamp_end_s: float, arx_model_id: int, window_rows: int | None,
                params: ModalEstimationParams) -> ArxRequest | None:
        """The request an offered fit becomes, or None if refused at once (counted with its reason).

        Refused: other dimensions, a stamp refused (:mod:`~okid_ros.service.arx_requests`), a
        window that ends where the last taken or the waiting one ends (node 1 republishing an
        unchanged window, e.g. while the inputs are silent), or a window refused for its size or
        never to be buffered.
        """
        st, prm, buffer = self._stats, params, self._buffer
        if fit.n_inputs != prm.n_inputs or fit.n_outputs != prm.n_outputs:
            st.refuse_arx(RefusedArx.DIMENSIONS, f"ARX model has m={fit.n_inputs}, p={fit.n_outputs}; this estimator "
                          f"has n_inputs={prm.n_inputs}, n_outputs={prm.n_outputs}")
            return None
        if refused := stamp_refusal(stamp_end_s, buffer):
            st.refuse_arx(*refused)
            return None
        pending = self.request
        for end in (self.last_request_end, None if pending is None else pending.stamp_end_s):
            if end is not None and abs(stamp_end_s - end) <= 0.5 * prm.sample_time_s:
                st.arx_unchanged += 1  # same window as one taken or waiting (no new samples)
                return None
        rows = int(window_rows) if window_rows else int(fit.n_rows)
        if refused := window_refusal(fit, rows, prm, buffer) or unbuffered_refusal(
                stamp_end_s, buffer, prm.sample_time_s):
            st.refuse_arx(*refused)
            return None
        return ArxRequest(fit, float(stamp_end_s), int(arx_model_id), rows)

    def wait(self, request: ArxRequest) -> None:
        """``request`` waits for :meth:`take_job`, replacing (and counting) one still waiting."""
        if self.request is not None:
            self._stats.arx_replaced += 1
        self.request = request

    def take_job(self, params: ModalEstimationParams, *, order_hint: int | None) -> RealizationJob | None:
        """A realization job for the waiting request, once the buffer covers its window.

        None when there is nothing to do, a job runs, nothing is buffered yet (node 2 started after node 1,
        or lags it) or the window's last sample has not come (an idle stream's newest sample ends it if at
        most ``max_gap_samples`` short). A request whose window is not buffered (too few samples after a
        long gap, too many missing) is dropped; so is one offered with nothing buffered whose window ends
        beyond ``MAX_ARX_LEAD_S`` of the first samples, or before them (the rules of :meth:`arrival`).
        ``order_hint``: the states of the model in use (the realization's warm start), None without one.
        """
        if self.busy or self.request is None or self._buffer.count == 0:
            return None
        fit, stamp_end, arx_id, rows = self.request
        dt, prm, st = params.sample_time_s, params, self._stats
        # Offered with none buffered, or a time jump since: judged now.
        if refused := stamp_refusal(stamp_end, self._buffer) or unbuffered_refusal(stamp_end, self._buffer, dt):
            self.request = None
            return st.refuse_arx(*refused)
        short = (stamp_end - self._buffer.newest_stamp()) / dt
        if short > 0.5 and not (self._idle.still_idle(self._buffer.count) and short <= prm.max_gap_samples + 0.5):
            return None  # the window's last sample has not arrived here yet
        self.request = None
        self.last_request_end = stamp_end
        end, end_stamp = self._buffer.find_end(stamp_end, 0.5 * dt)  # found: its timeline starts before
        need = rows + fit.order
        change = self._watch.change
        if change is not None and end + 1 - need < change.change_index:
            st.windows_refused_for_change += 1
            return st.refuse_arx(RefusedArx.CHANGE, f"ARX window starts before the structural change at "
                                 f"{change.change_stamp_s:.3f} s; waiting for a model of post-change data")
        _, u, y, skipped = self._buffer.get(end + 1 - need, end + 1)
        if refused := held_refusal(skipped, need=need, order=fit.order, max_gap=prm.max_gap_samples):
            return st.refuse_arx(*refused)
        try:  # the cheap part of realization_window here; its filling is the worker's (realize)
            first = newest_run_start(skipped, max_gap=prm.max_gap_samples, order=fit.order, need=need)
        except ValueError as exc:
            return st.refuse_arx(RefusedArx.GAP, str(exc))
        self.busy = True
        buffered = BufferedWindow(skipped[first:], need, self._watch.level_step_within(end + 1 - need, end + 1))
        return RealizationJob(fit, arx_id, end_stamp, u[first:], y[first:], end, params, self.generation,
                              order_hint=order_hint, buffered=buffered)

    def deliver(self, outcome: RealizationOutcome) -> None:
        """A job's outcome becomes the one to apply (dropped if its job was taken before a reset)."""
        if outcome.job.generation != self.generation:
            return
        self._stats.window_samples_filled += outcome.window_filled
        self.ready = outcome

    def take_ready(self) -> RealizationOutcome | None:
        """The delivered outcome, to apply now (None if none was delivered)."""
        outcome, self.ready = self.ready, None
        return outcome
