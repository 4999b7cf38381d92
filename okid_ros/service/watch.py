"""Divergence and structural-change watch of the model in use (node 2, on the sample path).

Divergence watchdog: each innovation the estimator took is whitened by the model's innovation
covariance (:class:`okid_ros.core.change_detection.DivergenceMonitor`; a glitch candidate's is
0: the estimator did not take its far outputs); a diverged sample (non-finite, or the moving mean
of the normalized innovation squared far above p) is not published. Sustained
divergence is first judged as a jump of the state (:mod:`okid_ros.core.state_jump`: an impact,
a bag replayed in a loop); a jump that explains it corrects the estimator's state, and nothing
else happens. Otherwise the estimator restarts from the buffered samples (warm start with the
model's predictor, diverged samples predicted over: a spike).

Structural change: every sample also goes to a
:class:`okid_ros.core.change_detection.StructuralChangeMonitor` armed with a reference model
(the first model of a structure, then models of windows twice as long; not while an output-only
reference's alarm waits for its modes' verdict). An alarm, or a
divergence that comes back right after a restart or a jump's correction, declares a
:class:`~okid_ros.service.results.StructuralChangeEvent`, which waits (:attr:`InnovationWatch.change`)
until a model of post-change data is accepted. A divergence that comes back after the model in use was
driven by an input far beyond its window's (an impact hammer's blow on an input its window held at a quiet
force only) is not declared: the model's error there grows with the input, so its divergence says nothing of
the structure (:meth:`InnovationWatch.beyond_window_inputs`; counted, ``divergences_beyond_window``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from okid_ros.core.change_detection import DivergenceMonitor
from okid_ros.core.change_monitor import StructuralChangeMonitor
from okid_ros.core.output_step import output_step, step_response
from okid_ros.core.pipeline import IdentifiedModel
from okid_ros.core.sample_ring import SampleRing
from okid_ros.core.state_jump import StateJump, StateJumpTest
from okid_ros.core.statespace import InnovationPredictor
from okid_ros.service.options import ModalEstimationParams
from okid_ros.service.realization import bridge_state
from okid_ros.service.results import ActiveModel, EstimationStats, StructuralChangeEvent
from okid_ros.service.sample_buffer import SampleBuffer

__all__ = ["InnovationWatch", "is_new_reference"]

_JUMP_RING_SAMPLES = 512  # the estimator's last whitened innovations, for the state-jump fit
_ONSET_ROOM = 16  # samples before the first diverged one the state-jump fit may start from (a glitch
# candidate, zero to the watchdog, and the moving mean's rise lie between an output's step and it)
# Fewest samples of a divergence's state-jump fit (raised to 4 n / p by the test): judged when
# the divergence is sustained (25 samples by default, with the room before them). Shorter than
# the change test's: a divergence is 100 times the innovations' power, and what a changed
# structure leaves after such a fit is far above the test's limit of twice the baseline.
_DIVERGENCE_JUMP_SAMPLES = 16


def is_new_reference(monitor: StructuralChangeMonitor, rows: int) -> bool:
    """Whether a model from a window of ``rows`` regressor rows becomes the change test's reference.

    The first model (of a structure: the monitor is disarmed after a change), then models of
    windows at least twice as long as the reference's, except while an alarm waits for its modes'
    verdict (an output-only reference's, :mod:`okid_ros.core.mode_confirmation`): that alarm is judged
    against the reference it was raised by, and a model of a window reaching past its change point
    must not make a structural change vanish. (Node 2, and ``okid-ros track``.)
    """
    return not monitor.armed or (rows >= 2 * monitor.reference_rows and not monitor.holding)


class InnovationWatch:
    """The divergence watchdog and the change test, with the change waiting for its model.

    Parameters
    ----------
    params : the service's options (read at each call: :meth:`configure` takes new ones).
    buffer : the service's sample buffer (stamps of change points, restarts from it).
    stats : the service's counters (divergence and change counts are kept there).
    confirm_executor : runs the change test's confirmations of an output-only reference's alarms by their
        modes (:mod:`okid_ros.core.mode_confirmation`; ``submit(fn) -> Future``): node 2's worker thread,
        so its sample path only polls; None: inline, at the sample that completes them (``track``, ``process``).
    """

    def __init__(self, params: ModalEstimationParams, buffer: SampleBuffer, stats: EstimationStats, *,
                 confirm_executor=None) -> None:
        p = params.n_outputs
        self.params = params
        self._buffer = buffer
        self._stats = stats
        self.divergence = DivergenceMonitor(p, window_samples=params.divergence_window_samples,
                                            nis_ratio=params.divergence_nis_ratio)
        self.monitor = StructuralChangeMonitor(
            p, false_alarm_samples=params.change_false_alarm_samples,
            variance_ratio=params.change_variance_ratio, reference_samples=params.change_reference_samples,
            noise_change_test=params.change_noise_test, mode_confirmation=params.change_mode_confirmation,
            confirm_executor=confirm_executor,
        )
        self.change: StructuralChangeEvent | None = None  # declared, waiting for its new model
        self.changes = 0
        self.diverged: list[int] = []  # buffer indices of diverged samples since the last restart or new model
        self.restart_failed = False  # no good sample since the last divergence restart or jump
        self._innovations = SampleRing(p, _JUMP_RING_SAMPLES)
        self._jump_test: tuple[int, StateJumpTest] | None = None  # (model id, its test)
        self._settle: list[tuple] = []  # the last two models' (model, predictor, settle_samples)
        self.level = np.zeros(p)  # the outputs' level steps found, taken off each sample (level_corrected)
        self.level_steps: list[int] = []  # buffer indices where a step taken off lies, still buffered
        self.level_steps_taken = 0
        # The model in use's window inputs: their median and largest distance from it, per input (None: none
        # held); whether an input beyond them (beyond_window_inputs) has come since the model was accepted.
        self._input_range: tuple[np.ndarray, np.ndarray] | None = None
        self._input_limit: tuple[float, np.ndarray | None] = (math.nan, None)
        self.driven_beyond_window = False

    def configure(self, params: ModalEstimationParams) -> None:
        """Take run-time options at once: the divergence ratio and the change test's tuning.

        Switching the change test off or on disarms it: while off its reference predictor
        saw no samples, so the next accepted model arms it afresh.
        """
        if bool(params.change_detection) != bool(self.params.change_detection):
            self.monitor.disarm()
        self.params = params
        self.divergence.nis_ratio = float(params.divergence_nis_ratio)
        self.monitor.detector.retune(false_alarm_samples=params.change_false_alarm_samples,
                                     variance_ratio=params.change_variance_ratio)

    # ------------------------------------------------------------------ per sample
    def gap(self, u_prev: np.ndarray | None, skipped: int) -> None:
        """Samples missing before the next one (or time restarted): the change test's predictor bridges them."""
        self._innovations.clear()  # the estimator's error is not a free response across a gap
        if self.params.change_detection:
            self.monitor.gap(u_prev, int(skipped), self.params.max_gap_samples)

    def step(self, active: ActiveModel, stamp_s: float, index: int, u: np.ndarray, y: np.ndarray, *, skipped: int,
             u_prev: np.ndarray | None) -> tuple:
        """One sample through the model in use's estimator, then :meth:`observe` (node 2's sample path, ``track``'s).

        ``skipped``: missing slots before it (< 0: a restart), bridged from ``u_prev``, the last input stepped.
        Returns ``(x_post, y_estimated, innovation, diverged, change, u_prev)``: the estimator's step, what
        :meth:`observe` says of it, and the input to bridge the next gap from.
        """
        est, max_gap = active.estimator, self.params.max_gap_samples
        if skipped:
            self.gap(u_prev, skipped)
            bridged = bridge_state(active.model, est.state, u_prev, skipped, max_gap)
            if 0 < skipped <= max_gap:
                self._stats.gaps_bridged += 1
            else:
                self._stats.estimator_restarts += 1
            est.set_state(bridged)
        x_post, y_est, innov = est.step(u, y)
        diverged, change, u_restart = self.observe(active, stamp_s, index, u, y, innov)
        return x_post, y_est, innov, diverged, change, u if u_restart is None else u_restart

    def observe(self, active: ActiveModel, stamp_s: float, index: int, u: np.ndarray, y: np.ndarray,
                innovation: np.ndarray) -> tuple[bool, StructuralChangeEvent | None, np.ndarray | None]:
        """One sample's innovation under the model in use.

        Returns whether the sample diverged (not to be published), the change declared at it
        (or None) and, after a restart from the buffer, the last buffered input (else None).
        """
        prm = self.params
        if active.estimator.last_glitch is not None:  # the last sample, a glitch: warm starts follow the
            self._buffer.predicted_glitch(index - 1, *active.estimator.last_glitch)  # estimator's prediction
            active.estimator.last_glitch = None
        if self._input_range is not None and not self.driven_beyond_window:
            self.driven_beyond_window = self.beyond_window_inputs(u)
        z = active.whiten.dot(innovation)  # (ndarray.dot: @ without the ufunc's dispatch)
        # The estimator's divergence: a glitch candidate, whose far outputs it did not take
        # (core/estimator.py), is no part of it (0; else one glitch of 30 output spreads withheld the
        # watchdog's 25 samples and had the state corrected). The state-jump fit keeps the sample's own.
        diverged = self.divergence.check(np.zeros_like(z) if active.estimator.holding else z)
        self._innovations.push_one(index, z)  # a non-finite one makes the jump fit refuse
        change = None
        if prm.change_detection:
            alarm = self.monitor.step(u, y, index, test=not diverged)
            if self.monitor.steps:  # a re-zero its state-jump fit found; it took it off its own
                F, _, G_y = active.model.predictor()
                for first, step in self.monitor.steps:
                    active.estimator.set_state(active.estimator.state - step_response(F, G_y, step, index + 1 - first))
                    self._take_level_step(step, first, index, monitor=False)
                self.monitor.steps.clear()
            if alarm is not None:
                change = self.declare(active, stamp_s, index, alarm.change_index, statistic=alarm.statistic,
                                      threshold=alarm.threshold, variance_ratio=alarm.variance_ratio)
        if not diverged:
            self.restart_failed = False
            return False, change, None
        self._stats.diverged_samples += 1
        self.diverged.append(index)
        if len(self.diverged) > self._buffer.cap:
            del self.diverged[0]
        u_prev = None
        if self.divergence.sustained:
            wait, jump = self._state_jump(active, index)
            if wait:  # too few samples of the excursion to judge yet
                return True, change, None
            if jump is not None and jump.explained:
                F, _, G_y = active.model.predictor()  # the jump test's F
                state = active.estimator.state + jump.correction(F, index + 1)
                step = output_step(jump, F, G_y, active.model.C, active.whiten)
                if step is not None:  # a sensor re-zeroed: its step taken off this sample's and the next ones
                    state = state - step_response(F, G_y, step)
                    self._take_level_step(step, jump.loud_index if jump.loud_index >= 0 else jump.onset_index, index)
                active.estimator.set_state(state)
                self.diverged.clear()
                self.divergence.restart()
                self._stats.state_jumps += 1
                self.restart_failed = True  # diverging again at once: not a jump after all
                return True, change, None
            if self.restart_failed and prm.change_detection and self.change is None and self.driven_beyond_window:
                self._stats.divergences_beyond_window += 1  # its error grows with an input it never saw
            elif self.restart_failed and prm.change_detection and self.change is None:
                # Diverged again right after a restart: the model no longer fits at all.
                ratio = self.divergence.nis_ratio_now
                change = self.declare(active, stamp_s, index, self.diverged[0], statistic=self.monitor.statistic,
                                      threshold=self.monitor.threshold,
                                      variance_ratio=ratio if math.isfinite(ratio) else 0.0) or change
            u_prev = self._restart_from_buffer(active, index)
            self.restart_failed = True
        return True, change, u_prev

    def _state_jump(self, active: ActiveModel, index: int) -> tuple[bool, StateJump | None]:
        """The diverged samples' innovations fitted by a jump of the estimator's state.

        Returns ``(wait, jump)``: wait while there are too few of them; no jump when a restart or
        a correction has just failed (the divergence came back) or the innovations are not held.
        """
        if self._jump_test is None or self._jump_test[0] != active.model_id:
            F = active.model.predictor()[0]
            self._jump_test = (active.model_id, StateJumpTest(F, active.whiten @ active.model.C,
                                                              min_samples=_DIVERGENCE_JUMP_SAMPLES))
        test = self._jump_test[1]
        if self.restart_failed:
            return False, None
        run = self.divergence.consecutive  # the diverged samples in a row up to this one
        z, first = self._innovations.since(index - run + 1 - _ONSET_ROOM, index)
        if z.shape[0] < test.needed_samples and run < test.needed_samples:
            return True, None
        return False, test.judge(z, first)

    def level_corrected(self, y: np.ndarray) -> np.ndarray:
        """A sample's outputs (p,) less the level steps found so far (what the buffer and the estimator take)."""
        return y - self.level if self.level_steps_taken else y

    def level_step_within(self, lo: int, hi: int) -> bool:
        """Whether a level step taken off lies inside buffer samples ``lo .. hi - 1`` (node 1's fit holds it)."""
        return any(lo < i < hi for i in self.level_steps)

    def _take_level_step(self, step: np.ndarray, first: int, index: int, *, monitor: bool = True) -> None:
        """Take an output step off samples ``first .. index`` (buffered) and the next ones.

        ``monitor``: the change test's predictor ran over them as they came: its state loses what
        it took of the step, and the excursion it saw ends (its innovations are those of the level
        before). False: the change test found the step and took it off its own.
        """
        self.level = self.level + step
        self._buffer.add_to_outputs(first, index + 1, -step)
        self.level_steps = [i for i in self.level_steps if i >= self._buffer.first] + [first]
        self.level_steps_taken += 1
        if monitor and self.monitor.armed:
            self.monitor.take_output_step(step, index + 1 - first, index)

    def declare(self, active: ActiveModel, stamp_s: float, index: int, change_index: int, *, statistic: float,
                threshold: float, variance_ratio: float) -> StructuralChangeEvent:
        """A structural change at buffer index ``change_index``, declared at sample ``index``."""
        self.monitor.disarm()
        self.changes += 1
        change_stamp = self._buffer.stamp_at(change_index)
        event = StructuralChangeEvent(
            change_id=self.changes, stamp_s=float(stamp_s),
            change_stamp_s=change_stamp if math.isfinite(change_stamp) else float(stamp_s),
            statistic=float(statistic), threshold=float(threshold),
            variance_ratio=float(variance_ratio), modes_before=[replace(m) for m in active.modes],
            detection_delay_samples=int(index - change_index),
            change_index=int(change_index),
        )
        self.change = event
        st = self._stats
        st.changes_detected += 1
        st.last_change_stamp_s = event.change_stamp_s
        st.last_change_statistic = event.statistic
        st.last_change_delay_samples = event.detection_delay_samples
        return event

    # ------------------------------------------------------------------ models
    def new_model(self, model: IdentifiedModel, state: np.ndarray, rows: int, *,
                  window_inputs: np.ndarray | None = None) -> None:
        """A model was accepted (``state``: its state for the next sample; ``rows``: its window's rows).

        It becomes the change test's reference by :func:`is_new_reference`. ``window_inputs``
        (N, m): the inputs of its window (None or m = 0: no input is judged beyond them).
        """
        self._input_range = None
        self._input_limit = (math.nan, None)  # (divergence_nis_ratio, the distance beyond_window_inputs allows)
        self.driven_beyond_window = False
        if window_inputs is not None and window_inputs.shape[1] and window_inputs.shape[0]:
            center = np.median(window_inputs, axis=0)
            self._input_range = (center, np.max(np.abs(window_inputs - center), axis=0))
        self.divergence.restart()
        self._innovations.clear()
        # The samples the last model diverged on: the new one was warm-started over them, and a restart of it
        # predicting over them (warm_state) would lose them and run from further back on the sample path.
        self.diverged.clear()
        if self.params.change_detection and is_new_reference(self.monitor, rows):
            self.monitor.arm(model, state, reference_rows=rows)

    def beyond_window_inputs(self, u: np.ndarray) -> bool:
        """Whether an input of ``u`` (m,) lies beyond its distance from the median in the model's window.

        Beyond ``sqrt(estimator.divergence_nis_ratio)`` times the largest distance there: the part of
        the model's error that grows with an input grows in power with its square, so such an input
        alone can take the window's largest error to the divergence's ratio.
        """
        center, reach = self._input_range
        ratio = self.params.divergence_nis_ratio
        if self._input_limit[0] != ratio:  # (the ratio may change at run time)
            self._input_limit = (ratio, math.sqrt(ratio) * reach)
        return bool((np.abs(u - center) > self._input_limit[1]).any())

    def warm_state(self, model: IdentifiedModel, index: int) -> tuple[np.ndarray, np.ndarray | None]:
        """A model's predicted state after the buffered samples up to ``index``, from zero.

        Diverged samples may hold what made it diverge (a spike): predicted over (open loop),
        not used. From the samples the state depends on, not the whole buffer: on the sample
        path, a restart over 8192 samples stalled it for tens of milliseconds, and the samples
        missed meanwhile made the estimator diverge again. The predictor forgets its start after
        :attr:`InnovationPredictor.settle_samples` (a few hundred at 28 outputs); the open-loop
        steps do not (the model's own poles), so those samples are counted before the first
        diverged one.
        """
        buffer, max_gap = self._buffer, self.params.max_gap_samples
        predictor, settle = self._predictor(model)
        open_loop_from = min([index + 1, *(i for i in self.diverged if i >= buffer.first)])
        first = max(buffer.first, open_loop_from - settle)
        _, u, y, skipped = buffer.get(first, index + 1, predicted_glitches=True)
        # realization.advance_state and bridge_state, on the model's one predictor (its chunk powers made once).
        predictor.x, u_prev = np.zeros(model.n_states), None
        lo = 0
        for k in sorted(i - first for i in self.diverged if first <= i <= index) + [u.shape[0]]:
            if k > lo:
                u_prev = predictor.run_with_gaps(u[lo:k], y[lo:k], skipped[lo:k], u_prev, max_gap, chunked=True)
            if k < u.shape[0]:
                if skipped[k]:
                    predictor.bridge(u_prev, int(skipped[k]), max_gap)
                predictor.bridge(u[k], 1, 1)  # the diverged sample predicted over, open loop
                u_prev = u[k]
            lo = k + 1
        x = predictor.x
        if not np.all(np.isfinite(x)):
            x = np.zeros(model.n_states)
        return x, u_prev

    def _predictor(self, model: IdentifiedModel) -> tuple[InnovationPredictor, int]:
        """The predictor of the model in use or the change test's and its ``settle_samples`` (kept)."""
        for known, predictor, samples in self._settle:
            if known is model:
                return predictor, samples
        predictor = InnovationPredictor(model)
        samples = predictor.settle_samples
        self._settle = [(model, predictor, samples), *self._settle[:1]]
        return predictor, samples

    def _restart_from_buffer(self, active: ActiveModel, index: int) -> np.ndarray | None:
        """Restart the estimator after sustained divergence, warm-started over the buffer up to ``index``."""
        x, u_prev = self.warm_state(active.model, index)
        if self.monitor.armed:  # the change test's predictor saw the same samples
            self.monitor.set_state(self.warm_state(self.monitor.model, index)[0])
        self.diverged.clear()
        active.estimator.set_state(x)
        self.divergence.restart()
        self._stats.divergence_restarts += 1
        return u_prev

    def unjudged_alarm(self) -> str:
        """An alarm still waiting for its modes' verdict where the samples end, in one sentence ('' if none).

        Neither declared nor dismissed: at the end of a record (``process``, ``track``) nothing
        else would say it. Its verdict is taken inline, once its samples are in, so a record that
        ends first leaves it unjudged; judged on fewer samples, a mode's estimate may scatter
        enough to hide a move (:meth:`~okid_ros.core.mode_confirmation.ModeConfirmation.take`).
        """
        held = self.monitor.held_alarm if self.params.change_detection else None
        if held is None:
            return ""
        alarm, need = held
        have = self._buffer.count - alarm.change_index
        why = (f"the samples end {have} after its change point, and its modes' identification needs {need}"
               if have < need else "its modes' identification had not ended")
        return (f"the change test's alarm at {self._buffer.stamp_at(alarm.alarm_index):.3f} s (change point "
                f"{self._buffer.stamp_at(alarm.change_index):.3f} s, statistic {alarm.statistic:.1f} > "
                f"{alarm.threshold:.1f}) was never judged: {why}; neither declared a structural change nor "
                "dismissed as a change of the excitation")

    def diagnostics(self) -> dict:
        """The change test's part of the service's diagnostics."""
        return {
            "change_monitor": self.monitor.state if self.params.change_detection else "off",
            "change_statistic": float(self.monitor.statistic),
            "change_threshold": float(self.monitor.threshold),
            "change_alarms_unconfirmed": int(self.monitor.unconfirmed_alarms),
            "change_alarms_state_jump": int(self.monitor.state_jumps),
            "change_alarms_noise": int(self.monitor.noise_changes),  # excitation changed (core/noise_change.py)
            # An output-only reference's alarm its modes called a change of the excitation (core/mode_confirmation.py).
            "change_alarms_excitation": int(self.monitor.excitation_changes),
            "change_glitches": int(self.monitor.glitches),  # samples the test took for glitches
            "change_waiting_for_model": self.change is not None,
            "output_level_steps": self.level_steps_taken,  # sensor re-zeros taken off the samples (core/output_step.py)
        }
