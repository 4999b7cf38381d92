"""The windowed pipeline of both nodes on one sample stream, written once.

Per sample, what each node does with an assembled
:class:`~okid_ros.service.grid_samples.GridSample` (:mod:`okid_ros.service.sample_steps`, which
the live nodes call too), and, in :class:`WindowedPipeline`, the two services in step without a
middleware, as ``okid-ros process`` runs them over a bag:

- node 1: the sample goes into the ARX window; a snapshot is due every ``publish_period_s``
  of *sample* time (the live node: its timer on the node clock);
- node 2: the sample steps the estimator; a valid snapshot handed back (:meth:`WindowedPipeline.realize_now`)
  is realized at once and takes over at the next sample (live: in a worker while samples go on);
- the end of the record (:meth:`WindowedPipeline.finish`): a model still delivered (a snapshot at or
  near the last sample), or realized now from a request whose window's last samples never reached
  node 2, takes over after the last sample (live: the idle timer,
  :meth:`~okid_ros.service.estimation.ModalEstimationService.apply_ready_if_idle`);
- a structural change declared by node 2 restarts node 1's window at the change point (live:
  through the ``StructuralChange`` message);
- a time jump resets a node when its ``reset_on_time_jump`` says so, as the live node does.

Each model update and each change is also kept as its JSON record (:mod:`okid_ros.service.records`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from okid_ros.core.arx import ArxFit
from okid_ros.core.validation import prediction_fits
from okid_ros.service.arx_solve import ArxSnapshot
from okid_ros.service.estimation import ModalEstimationService, ModalStatesResult
from okid_ros.service.grid_samples import GridSample
from okid_ros.service.identification import ArxIdentificationService
from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams
from okid_ros.service.records import change_record, update_record
from okid_ros.service.results import IdleSwitch, ModelUpdate, StructuralChangeEvent
from okid_ros.service.sample_steps import estimation_step, identification_step

__all__ = ["WindowedPipeline", "PipelineSettings"]


@dataclass(frozen=True)
class PipelineSettings:
    """What links the two nodes offline (the live nodes: their parameters and topics).

    Attributes
    ----------
    reset_arx_on_time_jump, reset_estimator_on_time_jump : each node's ``reset_on_time_jump``.
    restart_on_change : node 1 listens to node 2's structural changes (the topics match).
    validation_fits : record each update's one-step and simulation fit on its own window.
    """

    reset_arx_on_time_jump: bool = True
    reset_estimator_on_time_jump: bool = True
    restart_on_change: bool = True
    validation_fits: bool = True


class WindowedPipeline:
    """Both nodes' services on one sample stream, synchronously (see the module docstring).

    Parameters
    ----------
    arx_params, est_params : the services' options.
    settings : :class:`PipelineSettings`.

    Raises
    ------
    ValueError on options that do not fit together (from the services).
    """

    def __init__(self, arx_params: ArxIdentificationParams, est_params: ModalEstimationParams,
                 settings: PipelineSettings = PipelineSettings()) -> None:
        self.arx = ArxIdentificationService(arx_params)
        self.est = ModalEstimationService(est_params)
        self.settings = settings
        self.updates: list[dict] = []  # update_record of every accepted model, in order
        self.changes: list[dict] = []  # change_record of every change declared or re-identified
        self._change_since_update: dict | None = None
        self.unjudged_alarm = ""  # set by finish: an alarm the record ended before its verdict, in one sentence
        self._fits: dict[int, dict] = {}  # id(model) -> prediction fits on its window

    def estimate(self, sample: GridSample) -> ModalStatesResult | None:
        """Node 2 with one of its samples; the model update or change at it is recorded."""
        if sample.time_jump and self.settings.reset_estimator_on_time_jump:
            self.est.reset()
        result = estimation_step(self.est, sample)
        if result is not None:
            self._record(result.update, result.change, applied_at_stamp_s=sample.stamp_s)
        return result

    def finish(self) -> list[IdleSwitch]:
        """The end of the record: node 2 applies the models it still holds, after the last sample.

        What the live node's idle timer does once a replay has ended, without waiting
        (:meth:`~okid_ros.service.estimation.ModalEstimationService.apply_ready_at_end`): the
        outcome delivered since the last sample (a snapshot at or near it) is switched in; then a
        request still waiting (its window's last samples never reached node 2, or it came while
        the outcome was pending) is taken, realized and switched in the same way. Each accepted
        model and its change are recorded as at a sample, applied at the newest sample's stamp
        (``applied_after_last_sample`` true). An alarm of the change test still waiting for its
        modes' verdict is said in :attr:`unjudged_alarm` (neither declared nor dismissed).

        Returns
        -------
        The switches of the accepted models, in order (none if nothing was pending, or if a model
        was refused: its reason in ``est.diagnostics()``).
        """
        switches = [self.est.apply_ready_at_end()]  # the delivered outcome; from here on the stream has ended
        if self._realize_due_job() is not None:  # the waiting request: now taken even a few samples short
            switches.append(self.est.apply_ready_at_end())
        accepted = [switch for switch in switches if switch is not None]
        self.unjudged_alarm = self.est.unjudged_alarm()
        for switch in accepted:
            self._record(switch.update, switch.change, applied_at_stamp_s=switch.stamp_s, after_last_sample=True)
        return accepted

    def _record(self, update: ModelUpdate | None, change: StructuralChangeEvent | None, *,
                applied_at_stamp_s: float, after_last_sample: bool = False) -> None:
        """Keep the JSON records of a model update and a change (at a sample or after the last one).

        The update first: one that comes with a change's declaration was applied before it (a
        model of the old structure, not flagged); one that comes with its identification is the
        first model of the new structure (flagged by the declaration before).
        """
        if update is not None:
            line = update_record(update, applied_at_stamp_s, self._change_since_update,
                                 after_last_sample=after_last_sample)
            self._change_since_update = None
            fits = self._fits.pop(id(update.model), None)
            if fits is not None:  # on the model's own window, after the ARX order's samples
                line.update(fit_one_step_pct=fits["one_step_pct"], fit_simulation_pct=fits["simulation_pct"])
            self.updates.append(line)
        if change is not None:
            if self.settings.restart_on_change:
                self.arx.restart_at(change.change_stamp_s)  # what node 1 does with the message
            record = change_record(change)
            self.changes.append(record)
            if not change.modes_after:
                self._change_since_update = record

    def identify(self, sample: GridSample) -> ArxSnapshot | None:
        """Node 1 with one of its samples; the snapshot when one is due by sample time."""
        if sample.time_jump and self.settings.reset_arx_on_time_jump:
            self.arx.reset()
        identification_step(self.arx, sample)
        if not self.arx.due(sample.stamp_s):
            return None
        return self.arx.snapshot()

    def realize_now(self, fit: ArxFit, stamp_end_s: float, arx_model_id: int, window_rows: int) -> Any:
        """Node 2 with an ARX fit: realized at once, taken over at the next sample.

        Returns the outcome (None if no job was due: refused, or waiting for samples).
        """
        self.est.submit_arx(fit, stamp_end_s, arx_model_id, window_rows)
        return self._realize_due_job()

    def _realize_due_job(self) -> Any:
        """Take node 2's job if one is due, realize it and deliver it; its outcome, or None."""
        job = self.est.take_job()
        if job is None:
            return None
        outcome = self.est.run_job(job, follow=False)
        if outcome.model is not None and self.settings.validation_fits:
            self._fits[id(outcome.model)] = prediction_fits(outcome.model, outcome.job.u, outcome.job.y)  # as realized
        self.est.deliver(outcome)
        return outcome
