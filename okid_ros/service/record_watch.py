"""Node 2's innovation watch over a record tracked offline (``okid-ros track``).

``track`` has no node 2: its models come from its own window. What node 2 does with them on the
sample path is run here by node 2's own objects, not a copy: the model in use (each model that
passes node 2's checks, :func:`~okid_ros.service.realization.model_problem`, and node 2's switch,
:class:`~okid_ros.service.model_switch.ModelSelection`: lost modes refused, persistent mode ids;
warm-started as node 2 warm-starts one, :func:`~okid_ros.service.realization.warm_start`) steps a
:class:`~okid_ros.core.estimator.ModalStateEstimator` over every sample, and
:meth:`InnovationWatch.step <okid_ros.service.watch.InnovationWatch.step>` runs its divergence
watchdog (diverged samples kept out of the change test, state jumps corrected, restarts from the
buffered samples) and the change test of the reference model. The counts are node 2's diagnostics'
(:meth:`RecordWatch.counts`).

What differs from node 2, because ``track`` is not a live stream: its samples carry their record
index as their stamp's multiple of the sample time; a model takes over at the sample after its
update's; a sensor re-zero the watch finds is taken off the record from where it lies (its
windows are fitted on the record).
"""

from __future__ import annotations

import warnings

import numpy as np

from okid_ros.core.change_detection import ChangeAlarm
from okid_ros.core.estimator import ModalStateEstimator
from okid_ros.core.pipeline import IdentifiedModel
from okid_ros.errors import OkidWarning
from okid_ros.service.model_switch import ModelSelection
from okid_ros.service.options import ModalEstimationParams
from okid_ros.service.realization import model_problem, warm_start
from okid_ros.service.results import ActiveModel, EstimationStats
from okid_ros.service.sample_buffer import SampleBuffer
from okid_ros.service.watch import InnovationWatch

__all__ = ["RecordWatch"]

#: Node 2's counts (its diagnostics' names) that ``track`` writes in each line.
_STATS_COUNTS = ("diverged_samples", "divergence_restarts", "state_jumps", "divergences_beyond_window",
                 "estimator_restarts", "gaps_bridged")
#: Node 2's counts of its model switch (service/model_switch.py), in the same place.
_SWITCH_COUNTS = ("models_accepted", "models_rejected", "forced_accepts", "windows_refused_for_change", "modes_retired")
_WATCH_COUNTS = ("change_glitches", "change_alarms_state_jump", "change_alarms_noise", "change_alarms_excitation",
                 "change_alarms_unconfirmed", "output_level_steps")


class RecordWatch:
    """The model in use's estimator and node 2's :class:`InnovationWatch` over a record's samples.

    Parameters
    ----------
    record : the :class:`~okid_ros.service.tracked_record.TrackedRecord` (``u``, ``y``, ``present``;
        its ``y`` loses the sensor re-zeros found, ``steps`` lists where).
    params : node 2's options (``change.*``, ``estimator.*``; sizes and sample time of the record).
    capacity : samples buffered for the restarts (at least the window's).
    """

    def __init__(self, record, params: ModalEstimationParams, *, capacity: int) -> None:
        self.record, self.params = record, params
        self.stats = EstimationStats()
        self.buffer = SampleBuffer(capacity, params.n_inputs, params.n_outputs)
        self.watch = InnovationWatch(params, self.buffer, self.stats)
        self.selection = ModelSelection(params, self.stats)
        self.active: ActiveModel | None = None
        self._u_prev: np.ndarray | None = None
        self._missing = 0  # samples missing since the last one buffered
        self._levels = 0  # the watch's level steps already taken off the record, and their sum
        self._level = np.zeros(params.n_outputs)

    @property
    def monitor(self):
        """The change test (:class:`~okid_ros.core.change_monitor.StructuralChangeMonitor`)."""
        return self.watch.monitor

    def run(self, lo: int, hi: int) -> ChangeAlarm | None:
        """Samples ``lo .. hi - 1`` through the watch (missing ones bridged); the first change declared.

        The change's indices are the record's (``alarm_index``: the sample it was declared at).
        """
        # The record's units may be scaled by powers of two (a record near 1e+-150: core/channels.record_units),
        # and a model of such windows may square a far sample's whitened innovation beyond the floats in its
        # glitch gates: inf, which the gates judge as they should.
        with np.errstate(over="ignore"):
            return self._run(lo, hi)

    def _run(self, lo: int, hi: int) -> ChangeAlarm | None:
        """:meth:`run` (overflow not warned of)."""
        rec, dt, first = self.record, self.params.sample_time_s, None
        for k in range(lo, hi):
            if not rec.present[k]:
                self._missing += 1
                continue
            u, y = rec.u[k], rec.y[k]  # y less the re-zeros found so far (node 2: level_corrected)
            skipped, self._missing = self._missing, 0
            index = self.buffer.append(k * dt, u, y, skipped)
            if self.active is None:
                self._u_prev = u
                continue
            *_, change, self._u_prev = self.watch.step(self.active, k * dt, index, u, y, skipped=skipped,
                                                       u_prev=self._u_prev)
            self._take_level_steps()
            if change is not None and first is None:
                first = ChangeAlarm(alarm_index=k, change_index=int(round(change.change_stamp_s / dt)),
                                    statistic=change.statistic, threshold=change.threshold,
                                    variance_ratio=change.variance_ratio)
        return first

    def _take_level_steps(self) -> None:
        """A sensor re-zero the watch found taken off the record from where it lies (the buffer has it off)."""
        if self.watch.level_steps_taken == self._levels:
            return
        self._levels = self.watch.level_steps_taken
        first = int(round(self.buffer.stamp_at(self.watch.level_steps[-1]) / self.params.sample_time_s))
        self.record.y[first:] -= self.watch.level - self._level
        self._level = self.watch.level.copy()
        self.record.steps.append(first)

    def new_model(self, model: IdentifiedModel, u: np.ndarray, y: np.ndarray, rows: int, *, first: int) -> str:
        """The model of a window (``u`` (N, m), ``y`` (N, p); ``rows`` regressor rows) in use from the next sample.

        ``first``: the record index of the window's first sample. As node 2 switches to a model: its
        checks (:func:`~okid_ros.service.realization.model_problem`), then its switch
        (:meth:`ModelSelection.select <okid_ros.service.model_switch.ModelSelection.select>`: a model
        that lost the modes in use refused, the modes' persistent ids given, a change waiting for its model
        taken); its estimator warm-started over the window, the change test's reference by
        :func:`~okid_ros.service.watch.is_new_reference`. Returns why node 2 refuses it ("" if it does not;
        a refused model is counted, the model in use kept).
        """
        st = self.stats
        reason, whiten = model_problem(model)
        if reason:  # counted as node 2 counts a realization its checks refuse
            st.models_rejected += 1
            st.last_reason = reason
            return reason
        dt = self.params.sample_time_s
        window_first = self.buffer.first_at_or_after((first - 0.5) * dt)
        modes = self.selection.select(model, window_first, self.active, self.watch.change)
        if modes is None:
            return st.last_reason
        x, _, _ = warm_start(model, u, y, max_gap=self.params.max_gap_samples)
        estimator = ModalStateEstimator.from_model(model)
        estimator.set_state(x)
        model_id = 1 if self.active is None else self.active.model_id + 1
        self.active = ActiveModel(model, estimator, model_id, modes, len(modes), whiten, u.shape[0])
        self.watch.change = None
        self.watch.new_model(model, x, rows, window_inputs=u)
        return ""

    @property
    def mode_ids(self) -> list[int]:
        """The persistent ids of the model in use's modes (node 2's, :mod:`~okid_ros.service.mode_registry`)."""
        return [] if self.active is None else [int(mode.id) for mode in self.active.modes]

    def finish(self) -> None:
        """The record ends: a glitch candidate the change test holds at its last sample is one.

        An alarm still waiting for its modes' verdict is said (an OkidWarning: `okid-ros track` prints it).
        """
        self.monitor.finish()
        if note := self.watch.unjudged_alarm():
            warnings.warn(note, OkidWarning, stacklevel=2)

    def counts(self) -> dict:
        """Node 2's counts of the watch and the model switch so far (its diagnostics' names)."""
        diagnostics = self.watch.diagnostics()
        return {**{name: int(getattr(self.stats, name)) for name in _STATS_COUNTS},
                **{name: int(diagnostics[name]) for name in _WATCH_COUNTS}, **self.switch_counts()}

    def switch_counts(self) -> dict:
        """Node 2's counts of the model switch so far: models taken and refused, modes retired."""
        return {name: int(getattr(self.stats, name)) for name in _SWITCH_COUNTS}
