"""The change test of a reference model, sample by sample.

:class:`StructuralChangeMonitor` runs the reference model's Kalman predictor over the samples,
whitens its innovations by the model's innovation covariance and hands them to a
:class:`~okid_ros.core.change_detection.ChangeDetector` (the calibrated CUSUM), whose alarms a
:class:`~okid_ros.core.model_error_check.ModelErrorCheck` of the same residuals and the inputs
confirms before they are declared. See :mod:`okid_ros.core.change_detection` for the test.

No rclpy; numpy and scipy only.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.change_detection import ChangeAlarm, ChangeDetector, whitening_matrix
from okid_ros.core.model_error_check import ModelErrorCheck
from okid_ros.core.statespace import InnovationPredictor

__all__ = ["StructuralChangeMonitor"]

_CHUNK_SAMPLES = 1024  # samples of a block handed to the detector at a time


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
    detector_options : those of :class:`ChangeDetector`.
    """

    def __init__(self, n_outputs: int, *, model_error_check: bool = True, **detector_options) -> None:
        self.detector = ChangeDetector(n_outputs, **detector_options)
        self.model_error_check = bool(model_error_check)
        self.disarm()

    def disarm(self) -> None:
        self.predictor: InnovationPredictor | None = None
        self.whiten: np.ndarray | None = None
        self.reference_rows = 0
        self._hold = 0
        self.detector.restart()
        self.detector.check = None

    @property
    def armed(self) -> bool:
        return self.predictor is not None

    @property
    def state(self) -> str:
        """'disarmed', 'calibrating' or 'monitoring'."""
        if not self.armed:
            return "disarmed"
        return "monitoring" if self.detector.calibrated else "calibrating"

    def arm(self, model, state: np.ndarray | None = None, *, reference_rows: int = 0) -> None:
        """Take ``model`` as the reference (its predicted state for the next sample: ``state``).

        Raises ValueError if the model's innovation covariance is not positive definite.
        """
        whiten = whitening_matrix(model.innovation_covariance)
        self.model = model
        self.predictor = InnovationPredictor(model, state)
        self.whiten = whiten
        self.reference_rows = int(reference_rows)
        self._hold = 0
        self.detector.restart()
        # The check holds the calibration and a chunk beyond.
        self.detector.check = ModelErrorCheck(
            model.C.shape[0], model.B.shape[1], capacity=self.detector.reference_samples + 2 * _CHUNK_SAMPLES,
        ) if self.model_error_check else None

    def gap(self, u_held: np.ndarray | None, skipped: int, max_gap: int) -> None:
        """Samples are missing before the next one (``skipped`` > 0) or time restarted (< 0).

        A short gap is bridged by prediction; otherwise the predictor restarts from zero and its
        innovations are not tested until its start-up transient has decayed.
        """
        if not self.armed:
            return
        if not self.predictor.bridge(u_held, skipped, max_gap):
            self._hold = self.predictor.memory_samples
        self.detector.gap()

    def set_state(self, state: np.ndarray) -> None:
        """Replace the reference predictor's state (e.g. after the estimator restarted)."""
        if self.armed:
            self.predictor.x = np.asarray(state, dtype=float).reshape(self.predictor.x.shape).copy()

    def process(self, u: np.ndarray, y: np.ndarray, first_index: int, *, test: bool = True) -> ChangeAlarm | None:
        """Samples ``first_index ..`` (u (N, m), y (N, p)); the first alarm, else None.

        ``test=False``: the predictor runs over the samples but they are not tested (samples
        the estimator flagged as diverged). After an alarm the monitor is disarmed.
        """
        if not self.armed or len(u) == 0:
            return None
        e = self.predictor.run(u, y)
        if not test:
            self.detector.gap()  # untested samples are a gap to the whitening's lags
            return None
        if self._hold:
            skip = min(self._hold, e.shape[0])
            self._hold -= skip
            e, u, first_index = e[skip:], u[skip:], first_index + skip
        z = e @ self.whiten.T
        if not np.all(np.isfinite(z)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(z), axis=1))[0])
            z = z[:bad]  # a non-finite innovation is the estimator's problem, not a change
        # In chunks, so the check holds a chunk's inputs before the detector judges its samples.
        for lo in range(0, z.shape[0], _CHUNK_SAMPLES):
            if self.detector.check is not None:
                self.detector.check.push_inputs(first_index + lo, u[lo:lo + _CHUNK_SAMPLES])
            alarm = self.detector.process(z[lo:lo + _CHUNK_SAMPLES], first_index + lo)
            if alarm is not None:
                self.disarm()
                return alarm
        return None

    def step(self, u: np.ndarray, y: np.ndarray, index: int, *, test: bool = True) -> ChangeAlarm | None:
        """One sample ``u`` (m,), ``y`` (p,): :meth:`process` without the block overhead."""
        if not self.armed:
            return None
        e = self.predictor.step(u, y)
        if self._hold:
            self._hold -= 1
            return None
        if not test:
            self.detector.gap()  # untested samples are a gap to the whitening's lags
            return None
        z = self.whiten @ e
        if not np.all(np.isfinite(z)):
            return None
        if self.detector.check is not None:
            self.detector.check.push_inputs(index, u[None, :])
        alarm = self.detector.push(z, index)
        if alarm is not None:
            self.disarm()
        return alarm

    @property
    def statistic(self) -> float:
        return self.detector.statistic

    @property
    def threshold(self) -> float:
        return self.detector.threshold

    @property
    def unconfirmed_alarms(self) -> int:
        """Alarms of the power test that the model-error check did not confirm (not declared)."""
        return self.detector.unconfirmed_alarms
