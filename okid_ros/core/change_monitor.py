"""The change test of a reference model, sample by sample.

:class:`StructuralChangeMonitor` runs the reference model's Kalman predictor over the samples,
whitens its innovations by the model's innovation covariance and hands them to a
:class:`~okid_ros.core.change_detection.ChangeDetector` (the calibrated CUSUM), whose alarms a
:class:`~okid_ros.core.model_error_check.ModelErrorCheck` of the same residuals and the inputs
confirms; a confirmed alarm's excursion is then judged as a jump of the state
(:mod:`okid_ros.core.state_jump`), and one that a jump explains is not declared: the monitor
corrects its predictor's state by the fitted jump and goes on. One that no jump explains is
judged as a change of the noise model (:mod:`okid_ros.core.noise_change`: the excitation changed
relative to the sensor noise), and one that such a change explains is not declared either: the
monitor re-arms with the reference's noise model refitted (and calibrates again). A glitch
(:mod:`okid_ros.core.glitches`) is not tested: the predictor goes on from its prediction. The
test: :mod:`okid_ros.core.change_detection`; the judgement of its alarms: :mod:`okid_ros.core.alarm_judgement`.
An output-only reference's alarm none of them explains waits for its modes (:mod:`okid_ros.core.mode_confirmation`).

No rclpy; numpy and scipy only.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from okid_ros.core.change_detection import ChangeAlarm, ChangeDetector, whitening_matrix
from okid_ros.core.glitches import GLITCH_STD, glitch_candidates, held_last, settled, without_glitches
from okid_ros.core.mode_confirmation import ModeConfirmation
from okid_ros.core.model_error_check import ModelErrorCheck
from okid_ros.core.noise_change import NoiseChangeTest, NoiseVerdict, with_noise
from okid_ros.core.output_step import output_step, step_response
from okid_ros.core.sample_ring import SampleRing
from okid_ros.core.state_jump import StateJump, StateJumpTest
from okid_ros.core.statespace import InnovationPredictor

__all__ = ["StructuralChangeMonitor"]

_CHUNK_SAMPLES = 1024  # samples of a block handed to the detector at a time
_ONSET_ROOM = 8  # samples before the CUSUM's change point the state-jump fit may start from


class StructuralChangeMonitor:
    """A reference model's predictor, whitening and :class:`ChangeDetector`, sample by sample.

    Life: :meth:`arm` with a model (and its predicted state for the next sample), then
    :meth:`process` the samples; on an alarm the monitor disarms itself and waits for the next
    :meth:`arm` (the first model of the new structure).

    Parameters
    ----------
    n_outputs : p.
    model_error_check : judge each alarm by a :class:`ModelErrorCheck` of the reference
        model's inputs and residuals before declaring it (an alarm of more noise alone is not a
        change); False: every alarm of the power test is declared.
    state_jump_test : judge each confirmed alarm by a :class:`StateJumpTest` of the reference
        predictor before declaring it (a jump of the state is not a change); False: no such
        judgement.
    noise_change_test : (with the model-error check) judge each confirmed alarm that no state jump
        explains by a :class:`~okid_ros.core.noise_change.NoiseChangeTest` before declaring it;
        False: no such judgement.
    mode_confirmation : a reference without inputs declares an alarm once the modes after it moved
        (:mod:`~okid_ros.core.mode_confirmation`; else re-armed with theirs, ``excitation_changes``).
    confirm_executor : runs the confirmations' identifications (``submit(fn) -> Future``; None: inline).
    detector_options : those of :class:`ChangeDetector`.
    """

    def __init__(self, n_outputs: int, *, model_error_check: bool = True, state_jump_test: bool = True,
                 noise_change_test: bool = True, mode_confirmation: bool = True, confirm_executor=None,
                 **detector_options) -> None:
        self.mode_confirmation, self.confirm_executor = bool(mode_confirmation), confirm_executor
        self.excitation_changes, self._confirm = 0, None  # alarms the modes explained (monitor's life); the modes' test
        self.detector = ChangeDetector(n_outputs, **detector_options)
        self._judgement = self.detector.judgement  # the detector's for its life: the tests attached to it here
        self.model_error_check = bool(model_error_check)
        self.state_jump_test = bool(state_jump_test)
        self.noise_change_test = bool(noise_change_test) and self.model_error_check
        self._ring = SampleRing(n_outputs, self.detector.reference_samples + 2 * _CHUNK_SAMPLES)
        self.glitches = 0  # samples taken out as glitches (GLITCH_STD), over the monitor's life
        # Output steps (a sensor re-zeroed: :mod:`okid_ros.core.output_step`) found in explained
        # excursions, (first sample, step (p,)): the caller takes each off the outputs from there on.
        self.steps: list[tuple[int, np.ndarray]] = []
        self.disarm()

    def disarm(self) -> None:
        # A glitch held for the next sample's verdict: (innovation, u, index, the state after it as it came).
        self._pending: tuple | None = None
        self.predictor: InnovationPredictor | None = None
        self.whiten: np.ndarray | None = None
        self.reference_rows = 0
        self._hold = 0
        self.detector.restart()
        self._judgement.check = None
        self._judgement.jump_test = None
        self._judgement.noise_test = None
        self._jumps: StateJumpTest | None = None
        self._noise: NoiseChangeTest | None = None
        self._noise_model = None  # the reference with the noise model the last noise verdict fitted
        self._noise_excursion = -1  # the change point of the excursion the noise test judges
        self._ring.clear()
        self._calibration_power = [0.0, 0]  # sum of |z|^2 / p and samples while calibrating
        self._offset_taken: np.ndarray | None = None  # the whitened constant of the last step taken

    @property
    def armed(self) -> bool:
        return self.predictor is not None

    @property
    def state(self) -> str:
        """'disarmed', 'calibrating', 'monitoring' or 'confirming' (an alarm waits for its modes' verdict)."""
        if not self.armed:
            return "disarmed"
        return "confirming" if self.holding else "monitoring" if self.detector.calibrated else "calibrating"

    def arm(self, model, state: np.ndarray | None = None, *, reference_rows: int = 0) -> None:
        """Take ``model`` as the reference (its predicted state for the next sample: ``state``).

        Raises ValueError if the model's innovation covariance is not positive definite.
        """
        whiten = whitening_matrix(model.innovation_covariance)
        self.model = model
        self.predictor = InnovationPredictor(model, state)
        self._pending = None
        self.whiten = whiten
        self.reference_rows = int(reference_rows)
        self._hold = 0
        self.detector.restart()
        # The check holds the calibration and a chunk beyond.
        self._judgement.check = ModelErrorCheck(
            model.C.shape[0], model.B.shape[1], capacity=self.detector.reference_samples + 2 * _CHUNK_SAMPLES,
        ) if self.model_error_check else None
        self._ring.clear()
        self._calibration_power = [0.0, 0]
        self._jumps = StateJumpTest(self.predictor.F, whiten @ self.predictor.C) if self.state_jump_test else None
        self._judgement.jump_test = self._judge_jump if self.state_jump_test else None
        self._noise = self._noise_test(whiten) if self.noise_change_test else None
        self._judgement.noise_test = self._judge_noise if self.noise_change_test else None
        self._noise_excursion = -1
        self._innovation_std = np.sqrt(np.diag(model.innovation_covariance))
        self._confirm = ModeConfirmation(model, executor=self.confirm_executor) if (
            self.mode_confirmation and model.B.shape[1] == 0 and getattr(model, "modes", None)) else None

    @property
    def holding(self) -> bool:
        """Whether an alarm waits for its modes' verdict (:mod:`~okid_ros.core.mode_confirmation`)."""
        return self._confirm is not None and self._confirm.alarm is not None

    @property
    def held_alarm(self) -> tuple[ChangeAlarm, int] | None:
        """The alarm waiting for its modes' verdict and the samples from its change point that verdict needs."""
        return (self._confirm.alarm, self._confirm.samples_needed) if self.holding else None

    def _alarmed(self, alarm: ChangeAlarm, u: np.ndarray, y: np.ndarray, first_index: int) -> ChangeAlarm | None:
        """An alarm to declare: held for its modes' verdict (the block's samples after it go to it), else declared."""
        if self._confirm is None or not self._confirm.usable:
            self.disarm()
            return alarm
        self._confirm.start(alarm, y, first_index)
        k = alarm.alarm_index + 1 - first_index
        return self._confirming(u[k:], y[k:], alarm.alarm_index + 1) if k < u.shape[0] else None

    def _confirming(self, u: np.ndarray, y: np.ndarray, first_index: int) -> ChangeAlarm | None:
        """Samples while an alarm waits for its modes' verdict: declared, or re-armed with the new modes' model."""
        found = self._confirm.take(y, first_index)
        if found is None:
            return None
        verdict, at = found
        alarm = dataclasses.replace(self._confirm.alarm, alarm_index=at)
        if verdict.structural:
            self.disarm()
            return alarm
        self.excitation_changes += 1
        self.arm(*self._confirm.new_reference(at), reference_rows=verdict.samples)
        k = at + 1 - first_index
        return self.process(u[k:], y[k:], at + 1) if k < u.shape[0] else None

    def _noise_test(self, whiten: np.ndarray) -> NoiseChangeTest:
        """The noise-change test, with the check's inputs and the ring holding the samples its verdict needs.

        Its samples grow with the check's regressors (many inputs): beyond the calibration's
        capacity a verdict would never come, and the ring was read on every sample meanwhile.
        """
        check = self._judgement.check
        test = NoiseChangeTest(self.predictor.F, whiten @ self.predictor.C, check)
        needed = test.max_samples + check.lags + _CHUNK_SAMPLES
        if check.capacity < needed:
            check = self._judgement.check = ModelErrorCheck(check.n_outputs, check.n_inputs, capacity=needed)
            test = NoiseChangeTest(self.predictor.F, whiten @ self.predictor.C, check)
        if self._ring.capacity < needed:
            self._ring = SampleRing(check.n_outputs, needed)
        return test

    def _step_pending(self, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """The held sample's verdict, given the next one (u, y): its (whitened innovation, inputs, index) to test.

        A glitch (the next innovation :func:`~okid_ros.core.glitches.settled` from the predicted
        state): innovation 0; else the sample's own innovation, and the predictor's state that of
        the sample as it came.
        """
        e_held, u_held, index, as_came = self._pending
        self._pending = None
        predicted = self.predictor.x  # step() binds a new state: no copy
        quiet = settled(self.predictor.step(u, y), self._innovation_std)
        self.predictor.x = predicted
        if quiet:
            self.glitches += 1
            return np.zeros(e_held.shape[0]), u_held, index
        self.predictor.x = as_came  # the state of the sample as it came
        return self.whiten @ e_held, u_held, index

    def _judge_jump(self, change_index: int, alarm_index: int, index: int) -> StateJump | None:
        """The detector's ``jump_test``: the excursion's innovations fitted by a jump of the state."""
        z, first = self._ring.since(change_index - _ONSET_ROOM, index)
        total, count = self._calibration_power
        return self._jumps.judge(z, first, baseline_power=total / max(count, 1), loud_until=alarm_index)

    def _judge_noise(self, change_index: int, index: int) -> NoiseVerdict | None:
        """The detector's ``noise_test``: the excursion from ``change_index`` judged as a change of the noise model."""
        if change_index != self._noise_excursion:  # a new excursion
            self._noise_excursion = change_index
            self._noise.restart()
        if index - change_index + 1 < min(self._noise.next_samples, self._noise.max_samples):
            return None  # (not read from the ring on every sample)
        verdict = self._noise.judge(self._ring.since(change_index, index)[0], index)
        if verdict is not None and verdict.explained:
            self._noise_model = with_noise(self.model, self.whiten, verdict.change)
            if self._noise_model is None:  # no model of the new noise to monitor with: declared
                return dataclasses.replace(verdict, explained=False)
        return verdict

    def _calibrate_noise(self) -> None:
        """The noise test's baseline, once the detector's calibration is done."""
        if self._noise is None or self._noise.baseline is not None or self.detector.calibrated_at < 0:
            return
        last = self.detector.calibrated_at
        self._noise.calibrate(self._ring.since(last - self.detector.reference_samples + 1, last)[0], last)

    def _rest_after_noise(self, x0: np.ndarray, u: np.ndarray, y: np.ndarray, first_index: int, *,
                          test: bool) -> ChangeAlarm | None:
        """A block's samples after a noise verdict, processed with the re-armed reference.

        ``u``, ``y`` the block from ``first_index`` (its glitches' predictions in place), ``x0``
        the state it started from: the old predictor's state after the verdict's sample is the
        new reference's start.
        """
        k = self._judgement.noise_at + 1 - first_index
        self.predictor.x = x0.copy()
        self.predictor.advance(u[:k], y[:k])
        self._take_noise()
        return self.process(u[k:], y[k:], first_index + k, test=test) if k < u.shape[0] else None

    def _take_noise(self) -> None:
        """After an explained noise change: re-arm with the refitted noise model from the predictor's state."""
        if self._judgement.noise_at is not None:
            self.arm(self._noise_model, self.predictor.x, reference_rows=self.reference_rows)

    def _record(self, first_index: int, z: np.ndarray) -> None:
        """Keep the innovations for the state-jump and noise tests (and their power while calibrating)."""
        if self._jumps is None and self._noise is None:
            return
        self._ring.push(first_index, z)
        total, count = self._calibration_power
        if count < self.detector.reference_samples:  # the calibration's samples
            z = z[:self.detector.reference_samples - count]
            self._calibration_power = [total + float(np.einsum("ij,ij->", z, z)) / z.shape[1], count + z.shape[0]]

    def _record_one(self, index: int, z: np.ndarray) -> None:
        """:meth:`_record` of one sample's ``z`` (p,) (the per-sample path)."""
        if self._jumps is None and self._noise is None:
            return
        if self._calibration_power[1] < self.detector.reference_samples:
            self._record(index, z[None, :])
        else:
            self._ring.push_one(index, z)

    def _take_jump(self, next_index: int) -> int | None:
        """After an explained jump: correct the predictor's state for sample ``next_index``.

        Returns the sample of the jump's alarm (None if there was none).
        """
        at = self._judgement.jump_at
        if at is None:
            return None
        self._judgement.jump_at = None
        jump, F, G_y = self._judgement.last_jump, self.predictor.F, self.predictor.Gy
        correction = jump.correction(F, next_index)
        total, count = self._calibration_power
        step = output_step(jump, F, G_y, self.predictor.C, self.whiten, baseline_power=total / max(count, 1))
        self._offset_taken = None
        if step is not None:  # an output re-zeroed, which the caller takes off the samples from next_index on
            steady = step_response(F, G_y, step)
            correction = correction - steady
            self._offset_taken = self.whiten @ (step - self.predictor.C @ steady)  # the constant it leaves
            self.detector.offset_taken(self._offset_taken)
            self.steps.append((jump.loud_index, step))
        self.predictor.x = self.predictor.x + correction
        if self._pending is not None:  # a block's held last sample: its state as it came is of the same sample
            self._pending = (*self._pending[:3], self._pending[3] + correction)
        return at

    @property
    def state_jumps(self) -> int:
        """Alarms whose excursion was explained as a jump of the state (not declared)."""
        return self._judgement.state_jumps

    @property
    def noise_changes(self) -> int:
        """Alarms whose excursion was explained as a change of the noise model (not declared; re-armed)."""
        return self._judgement.noise_changes

    def gap(self, u_held: np.ndarray | None, skipped: int, max_gap: int) -> None:
        """Samples are missing before the next one (``skipped`` > 0) or time restarted (< 0).

        A short gap is bridged by prediction; otherwise the predictor restarts from zero and its
        innovations are not tested until its start-up transient has decayed.
        """
        if not self.armed:
            return
        self._drop_pending()
        if not self.predictor.bridge(u_held, skipped, max_gap):
            self._hold = self.predictor.memory_samples
        self.detector.gap()

    def finish(self, u_next: np.ndarray | None = None, y_next: np.ndarray | None = None) -> None:
        """The samples tested end: a held glitch candidate's verdict, untested (no later sample is).

        With the record's next sample ``u_next`` (m,), ``y_next`` (p,): a glitch when that
        sample's innovation :func:`~okid_ros.core.glitches.settled`, else run as it came. Without
        one (the candidate is the record's last sample): a glitch, as the candidate's rule has it
        (some outputs far off, not every one).
        """
        if self._pending is None:
            return
        if u_next is None:
            self._pending = None
            self.glitches += 1
            return
        self._step_pending(u_next, y_next)

    def set_state(self, state: np.ndarray) -> None:
        """Replace the reference predictor's state (e.g. after the estimator restarted)."""
        if self.armed:
            self._pending = None
            self.predictor.x = np.asarray(state, dtype=float).reshape(self.predictor.x.shape).copy()

    def take_output_step(self, step: np.ndarray, samples: int, index: int) -> None:
        """An output step ``step`` (p,) in the last ``samples`` samples up to ``index``, taken off the next ones.

        The predictor's state loses what it took of the step (:mod:`okid_ros.core.output_step`);
        the excursion it caused ends.
        """
        if not self.armed:
            return
        self._drop_pending()
        self.predictor.x = self.predictor.x - step_response(self.predictor.F, self.predictor.Gy, step, samples)
        self.detector.excursion_ended(index)
        self._ring.clear()  # its innovations held the step: no later state-jump fit of the excursion reads them

    def _drop_pending(self) -> None:
        """A held sample run as it came, untested (no next sample judges it: a gap follows)."""
        if self._pending is not None:
            self.predictor.x = self._pending[3]
            self._pending = None
            self.detector.gap()

    def process(self, u: np.ndarray, y: np.ndarray, first_index: int, *, test: bool = True) -> ChangeAlarm | None:
        """Samples ``first_index ..`` (u (N, m), y (N, p)); the first alarm, else None.

        ``test=False``: the predictor runs over the samples but they are not tested (samples
        the estimator flagged as diverged). After an alarm the monitor is disarmed. A glitch
        candidate at the block's last sample is held, as :meth:`step` holds one: the next
        block's first sample judges it (a gap runs it as it came; :meth:`finish` ends the record).
        """
        if not self.armed or len(u) == 0:
            return None
        if self._confirm is not None:
            if self.holding:
                return self._confirming(u, y, first_index)
            self._confirm.push(first_index, y)
        whole = (u, y, first_index)
        if self._pending is not None:  # the last block's last sample, judged by this one's first
            alarm = self._test_one(*self._step_pending(u[0], y[0]), test=True)
            if alarm is not None or self.holding:
                return alarm or self._confirming(u, y, first_index)
        x0 = self.predictor.x.copy()
        e, y_taken, taken = without_glitches(self.predictor, self._innovation_std, u, y, self.predictor.run(u, y), x0)
        self.glitches += taken
        block = (u, y_taken, first_index)  # as it came (u and first_index move below)
        end = first_index + e.shape[0]  # the predictor's state is that of sample `end`
        if test and self._hold < e.shape[0] and glitch_candidates(e[-1:], self._innovation_std)[0]:
            self._pending = held_last(self.predictor, u, y_taken, e, x0, first_index)
            e, u = e[:-1], u[:-1]
        if not test:
            self._record(first_index, self._finite(e @ self.whiten.T))
            self.detector.gap()  # untested samples are a gap to the whitening's lags
            return None
        if self._hold:
            skip = min(self._hold, e.shape[0])
            self._hold -= skip
            e, u, first_index = e[skip:], u[skip:], first_index + skip
        z = self._finite(e @ self.whiten.T)
        # In chunks, so the check holds a chunk's inputs before the detector judges its samples.
        lo = 0
        while lo < z.shape[0]:
            hi = min(lo + _CHUNK_SAMPLES, z.shape[0])
            self._record(first_index + lo, z[lo:hi])
            if self._judgement.check is not None:
                self._judgement.check.push_inputs(first_index + lo, u[lo:hi])
            alarm = self.detector.process(z[lo:hi], first_index + lo)
            if alarm is not None:
                return self._alarmed(alarm, *whole)
            self._calibrate_noise()
            if self._judgement.noise_at is not None:
                if block is None:  # a jump corrected the state in this block: re-armed from its end
                    self._take_noise()
                    return None
                return self._rest_after_noise(x0, *block, test=test)
            at = self._take_jump(end)
            if at is None:
                lo = hi
                continue
            block = None  # its states before `end` are no longer those the jump corrected
            # The samples after the jump's alarm again, less the jump's response.
            lo = at + 1 - first_index
            if lo < z.shape[0]:
                z[lo:] -= self._jumps.response(self._judgement.last_jump, at + 1, z.shape[0] - lo)
                if self._offset_taken is not None:  # an output step the caller takes off these samples
                    z[lo:] -= self._offset_taken
        return None

    @staticmethod
    def _finite(z: np.ndarray) -> np.ndarray:
        """``z`` up to its first non-finite row (the estimator's problem, not a change)."""
        if np.all(np.isfinite(z)):
            return z
        return z[:int(np.flatnonzero(~np.all(np.isfinite(z), axis=1))[0])]

    def step(self, u: np.ndarray, y: np.ndarray, index: int, *, test: bool = True) -> ChangeAlarm | None:
        """One sample ``u`` (m,), ``y`` (p,): :meth:`process` without the block overhead.

        A sample that may be a glitch (:data:`GLITCH_STD`) is held for the next one's verdict: an
        alarm it raises comes with the next sample.
        """
        if not self.armed:
            return None
        if self._confirm is not None:
            if self.holding:
                return self._confirming(u[None, :], y[None, :], index)
            self._confirm.push_one(index, y)
        if self._pending is not None:
            alarm = self._test_one(*self._step_pending(u, y), test=True)
            if alarm is not None or self.holding:
                return alarm or self._confirming(u[None, :], y[None, :], index)
        before = self.predictor.x  # step() binds a new state: no copy
        e = self.predictor.step(u, y)
        if self._hold:
            self._hold -= 1
            return None
        z = self.whiten.dot(e)  # (ndarray.dot: @ without the ufunc's dispatch, statespace.InnovationPredictor.step)
        # |z|^2 = e^T Re^-1 e bounds every (e_i / sigma_i)^2: below GLITCH_STD^2 no output is past it.
        if test and float(z.dot(z)) > GLITCH_STD ** 2 and glitch_candidates(e[None, :], self._innovation_std)[0]:
            after = self.predictor.x
            self.predictor.x = before
            prediction = self.predictor.predicted_output(u)
            self.predictor.step(u, prediction)  # its prediction in its place
            self._pending = (e, u, index, after)
            return None
        return self._test_one(z, u, index, test=test)

    def _test_one(self, z: np.ndarray, u: np.ndarray, index: int, *, test: bool) -> ChangeAlarm | None:
        """The test of one sample's whitened innovation ``z`` (p,), the predictor's state already past it."""
        finite = bool(np.isfinite(z).all())
        if finite:
            self._record_one(index, z)
        if not test:
            self.detector.gap()  # untested samples are a gap to the whitening's lags
            return None
        if not finite:
            return None
        if self._judgement.check is not None:
            self._judgement.check.push_sample(index, u=u)
        alarm = self.detector.push(z, index)
        if alarm is not None:
            return self._alarmed(alarm, u[:0, None], u[:0, None], index)
        self._calibrate_noise()
        self._take_jump(index + 1)
        self._take_noise()
        return None

    @property
    def statistic(self) -> float:
        return self.detector.statistic

    @property
    def threshold(self) -> float:
        return self.detector.threshold

    @property
    def unconfirmed_alarms(self) -> int:
        """Alarms of the power test that the model-error check did not confirm (not declared)."""
        return self._judgement.unconfirmed_alarms
