"""Innovation monitoring: divergence of the estimator and structural change of the system.

Both tests look at the identified model's innovations ``e_k = y_k - C xhat_k - D u_k``
(paper Eqs. 30-31), whitened by the model's innovation covariance ``Re = L L^T``::

    z_k = L^{-1} e_k,        nis_k = z_k^T z_k        (normalized innovation squared)

For a correct model ``z_k`` is white with unit covariance, so ``nis_k`` is chi-square with
``p`` degrees of freedom (mean ``p``).

Divergence (:class:`DivergenceMonitor`)
---------------------------------------
A sample is *diverged* when its innovation is not finite or the mean ``nis`` over the last
``window_samples`` samples exceeds ``nis_ratio * p`` (default 100 p: under a correct model the
window mean exceeds 100 p with probability far below 1e-100). ``sustained`` is true once
``window_samples`` samples in a row are diverged: the caller restarts the estimator.

Structural change (:class:`ChangeDetector`, :class:`StructuralChangeMonitor`)
---------------------------------------------------------------------------
An identified model is never exact, and its out-of-sample innovations are somewhat larger and
less white than ``Re`` says. The statistic is therefore calibrated on the model's own
innovations: after the detector is armed with a *reference model* (the first model after a
start or a change), its first ``reference_samples`` whitened innovations give a reference mean
``mu`` and covariance ``S = M^{-1} M^{-T}``, and from then on ``w_k = M (z_k - mu)`` is
monitored. The reference model stays fixed while the structure does not change (later models
of the same structure do not move the reference), so a slowly improving or a single poorer
model update cannot look like a change.

A structural change (frequency, damping, mode shape) makes the reference model's predictor
wrong, and its innovations grow. The test is Page's CUSUM for a covariance increase by a
factor ``gamma`` (``variance_ratio``): the log-likelihood ratio of ``N(0, gamma I)`` against
``N(0, I)`` for one sample is ``l_k = (1 - 1/gamma) |w_k|^2 / 2 - (p / 2) ln gamma``, and::

    g_k = max(0, g_{k-1} + l_k),        alarm when g_k > h.

Measured data are less tidy than the model class (the steel subframe's innovations, for one,
carry a slowly drifting mean and a power that is correlated over tens of samples), and the
chi-square CUSUM would raise false alarms on them. Two measures keep its false-alarm rate:

- the innovations' slowly varying mean is tracked (an exponential mean over
  ``mean_tracking_samples``, 200 by default) and removed before the test: offsets drifting
  in the sensors are not structural, whereas a changed mode makes oscillating, zero-mean
  innovations;
- the increments' serial correlation is measured on the calibration samples (batch means over
  ``batch_samples``, 25 by default: ``r = B var(batch means) / 2p``, the variance of the sum
  against that of independent chi-square increments) and the threshold is raised to ``r h``
  when ``r > 1``, as the run length of a CUSUM scales with ``h / variance`` of its increments.
  For white innovations ``r`` is 1 and nothing changes;
- the innovations of a model that misses or misplaces a mode are coloured: the missing mode
  rings on in them, their power fluctuates over hundreds of samples and 1000 calibration
  samples cannot measure the false-alarm rate of the test on them (of 30 models identified by
  node 1 from 1000-sample windows of the paper's structure, 5 raised an alarm within 20000
  stationary samples, where 2e-3 was expected). A vector AR of the calibration samples
  (:func:`okid_ros.core.stochastic_realization.fit_var`, order by BIC, at most
  ``whitening_max_order`` lags and ``WHITENING_MAX_COEFFICIENT_FRACTION`` of the calibration
  samples in coefficients per output) predicts what the reference model left predictable,
  and the test runs on its residuals ``z_k - sum_i Phi_i z_{k-i}`` (the 5 alarms: none). For
  a good model the order is 0 and nothing changes. A change still shows: the filter is fixed
  with the reference, and the new structure's innovations are not the ones it whitens.

A calibration of finitely many samples under-estimates the covariance about half of the time,
and the under-estimate inflates every later ``|w|^2``: with the threshold of an exact
calibration, 7 of 60 runs of white innovations (2 outputs, 200 calibration samples) raised an
alarm within 20000 samples where 0.1 was expected at ``false_alarm_samples`` 1e7 (1 of 60 with
1000 samples). The threshold allows
for the under-estimate that 90 % of calibrations stay below (:func:`calibration_scale`).

An alarm is declared only if no more mundane cause explains it: its judgement (a model error
in the residuals, else a jump of the state or a change of the noise model) is
:mod:`okid_ros.core.alarm_judgement`'s (:class:`~okid_ros.core.alarm_judgement.AlarmJudgement`,
the detector's ``judgement``).

The change point estimate is the sample after the last ``g = 0``
before the alarm. The threshold ``h`` follows from ONE parameter, ``false_alarm_samples``, the expected number of
samples between false alarms (the average run length under no change, ARL0): it is computed
for chi-square increments by the Markov-chain method of Brook & Evans (1972)
(:func:`cusum_threshold`). Covariance increases above ``gamma ln(gamma) / (gamma - 1)``
(1.22 for gamma = 1.5) make ``g`` drift upwards and are detected; the larger, the faster.

No rclpy; numpy and scipy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg

from okid_ros.core.alarm_judgement import AlarmJudgement, Judged
from okid_ros.core.cusum import (
    CALIBRATION_CONFIDENCE,
    DEFAULT_VARIANCE_RATIO,
    calibration_scale,
    cusum_average_run_length,
    cusum_threshold,
)
from okid_ros.core.divergence import DivergenceMonitor
from okid_ros.core.innovation_whitening import (
    DEFAULT_WHITENING_MAX_ORDER,
    WHITENING_MAX_COEFFICIENT_FRACTION,
    InnovationWhitening,
)
from okid_ros.core.options import DEFAULT_FALSE_ALARM_SAMPLES, DEFAULT_REFERENCE_SAMPLES

__all__ = [
    "DEFAULT_FALSE_ALARM_SAMPLES", "DEFAULT_VARIANCE_RATIO", "DEFAULT_REFERENCE_SAMPLES",
    "DEFAULT_MEAN_TRACKING_SAMPLES", "DEFAULT_BATCH_SAMPLES", "DEFAULT_WHITENING_MAX_ORDER", "ChangeAlarm",
    "ChangeDetector", "DivergenceMonitor", "calibration_scale", "cusum_average_run_length", "cusum_threshold",
    "predictor_spectral_radius", "whitening_matrix",
]

DEFAULT_MEAN_TRACKING_SAMPLES = 200  # time constant of the innovations' tracked mean
DEFAULT_BATCH_SAMPLES = 25  # batch length of the serial-correlation estimate


def whitening_matrix(covariance: np.ndarray) -> np.ndarray:
    """``L^{-1}`` with ``covariance = L L^T`` (Cholesky), so ``L^{-1} e`` has unit covariance.

    Parameters
    ----------
    covariance : (p, p) symmetric positive definite.

    Raises
    ------
    ValueError if the covariance is not finite and positive definite.
    """
    cov = np.asarray(covariance, dtype=float)
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
        raise ValueError(f"innovation covariance must be square, got shape {cov.shape}")
    if not np.all(np.isfinite(cov)):
        raise ValueError("innovation covariance holds NaN or Inf")
    try:
        lower = linalg.cholesky(0.5 * (cov + cov.T), lower=True)
    except linalg.LinAlgError:
        raise ValueError("innovation covariance is not positive definite") from None
    return linalg.solve_triangular(lower, np.eye(cov.shape[0]), lower=True)


def predictor_spectral_radius(model) -> float:
    """Spectral radius of the one-step predictor ``A - A K C`` of a model (0 for n = 0)."""
    return model.predictor_spectral_radius() if model.A.shape[0] else 0.0


@dataclass
class ChangeAlarm:
    """A declared change.

    Attributes
    ----------
    alarm_index : index of the sample at which the CUSUM crossed the threshold.
    change_index : estimated first sample of the new structure (after the last g = 0).
    statistic : CUSUM value g at the alarm [nats, log-likelihood ratio].
    threshold : h [nats].
    variance_ratio : mean of |w|^2 / p from change_index to alarm_index (1 under no change).
    """

    alarm_index: int
    change_index: int
    statistic: float
    threshold: float
    variance_ratio: float


class ChangeDetector:
    """Calibrated CUSUM on whitened innovations (see the module docstring).

    Parameters
    ----------
    n_outputs : p.
    false_alarm_samples : expected samples between false alarms under no change (ARL0).
    variance_ratio : gamma > 1, the covariance increase the test is tuned to.
    reference_samples : samples of calibration after each :meth:`restart`.
    mean_tracking_samples : time constant [samples] of the tracked innovation mean removed
        before the test; 0: no tracking (the calibration mean only).
    batch_samples : batch length of the serial-correlation estimate that raises the threshold;
        0: innovations taken as independent.
    calibration_confidence : fraction of calibrations for which ``false_alarm_samples`` holds
        (:func:`calibration_scale`); None: the threshold of an exact calibration.
    whitening_max_order : most lags of the AR that whitens the calibrated innovations (the
        order itself is chosen by BIC on the calibration samples); 0: no whitening.

    Attributes
    ----------
    threshold : the CUSUM threshold in use [nats]: ``correlation_factor`` times
        ``base_threshold`` once calibrated.
    base_threshold : h of independent chi-square increments for ``false_alarm_samples``, allowing
        for the calibration's under-estimate of the covariance (``scale``).
    correlation_factor : r >= 1 measured on the calibration samples (1 before).
    scale : :func:`calibration_scale` of ``reference_samples`` calibration samples.
    whitening_order : lags of the whitening AR chosen at the calibration (0: none).
    judgement : the :class:`~okid_ros.core.alarm_judgement.AlarmJudgement` of each alarm before
        it is declared (its ``check``, ``jump_test`` and ``noise_test`` the caller attaches, their
        verdicts and counts); the detector feeds the check the tested residuals.
    calibrated_at : the last calibration sample (-1 before the calibration).
    """

    def __init__(self, n_outputs: int, *, false_alarm_samples: float = DEFAULT_FALSE_ALARM_SAMPLES,
                 variance_ratio: float = DEFAULT_VARIANCE_RATIO,
                 reference_samples: int = DEFAULT_REFERENCE_SAMPLES,
                 mean_tracking_samples: int = DEFAULT_MEAN_TRACKING_SAMPLES,
                 batch_samples: int = DEFAULT_BATCH_SAMPLES,
                 calibration_confidence: float | None = CALIBRATION_CONFIDENCE,
                 whitening_max_order: int = DEFAULT_WHITENING_MAX_ORDER) -> None:
        if not variance_ratio > 1.0:
            raise ValueError(f"variance_ratio must be > 1, got {variance_ratio}")
        if int(reference_samples) < 10 * n_outputs:
            raise ValueError(f"reference_samples must be >= {10 * n_outputs}, got {reference_samples}")
        if int(mean_tracking_samples) < 0 or int(batch_samples) < 0 or int(whitening_max_order) < 0:
            raise ValueError("mean_tracking_samples, batch_samples and whitening_max_order must be >= 0")
        self.n_outputs = int(n_outputs)
        self.reference_samples = int(reference_samples)
        self.mean_tracking_samples = int(mean_tracking_samples)
        # At least 8 batches in the calibration, else the estimate of r is too rough to use.
        self.batch_samples = int(batch_samples) if int(batch_samples) * 8 <= self.reference_samples else 0
        self.correlation_factor = 1.0
        self.calibration_confidence = calibration_confidence
        self.whitening_max_order = min(int(whitening_max_order), int(
            WHITENING_MAX_COEFFICIENT_FRACTION * self.reference_samples / self.n_outputs))
        self.retune(false_alarm_samples=false_alarm_samples, variance_ratio=variance_ratio)
        self.judgement = AlarmJudgement()
        self.restart()

    def retune(self, *, false_alarm_samples: float, variance_ratio: float) -> None:
        """New false-alarm rate and tuned increase from the next sample on (calibration and statistic kept)."""
        if not variance_ratio > 1.0:
            raise ValueError(f"variance_ratio must be > 1, got {variance_ratio}")
        self.variance_ratio, self.false_alarm_samples = float(variance_ratio), float(false_alarm_samples)
        self.scale = 1.0
        if self.calibration_confidence is not None:
            # Capped at half the design margin: at the margin the statistic of a stationary
            # structure drifts upwards and no threshold keeps any false-alarm rate (a calibration
            # that short cannot keep the rate; more reference_samples can).
            margin = self.variance_ratio * math.log(self.variance_ratio) / (self.variance_ratio - 1.0) - 1.0
            self.scale = min(calibration_scale(self.reference_samples, self.n_outputs, self.calibration_confidence),
                             1.0 + 0.5 * margin)
        self.base_threshold = cusum_threshold(self.false_alarm_samples, self.n_outputs, self.variance_ratio,
                                              scale=self.scale)
        self.threshold = self.correlation_factor * self.base_threshold
        self._a = 0.5 * (1.0 - 1.0 / self.variance_ratio)
        self._b = 0.5 * self.n_outputs * math.log(self.variance_ratio)

    def restart(self) -> None:
        """Forget the calibration and the statistic: the next samples calibrate again."""
        self._ref: list[np.ndarray] = []
        self._ref_count = 0
        self.mean: np.ndarray | None = None
        self.rewhiten: np.ndarray | None = None
        self.statistic = 0.0
        self.correlation_factor = 1.0
        self.threshold = self.base_threshold
        self._last_zero = -1
        self._sum_nis = 0.0
        self._n_nis = 0
        self._tracked = np.zeros(self.n_outputs)  # the innovations' slowly varying mean
        self._tracked_count = 0
        self._tracked_quiet = self._tracked  # the tracked mean where the statistic was last 0
        self.whitening = InnovationWhitening(self.n_outputs)
        self.judgement.restart()
        self.calibrated_at = -1

    @property
    def whitening_order(self) -> int:
        """Lags of the whitening AR chosen at the calibration (0: none)."""
        return self.whitening.order

    def gap(self) -> None:
        """Samples are missing before the next one: the next ``whitening_order`` are not tested."""
        self.whitening.gap()

    def _remove_tracked_mean(self, z: np.ndarray) -> np.ndarray:
        """``z`` (N, p) less the tracked mean before each sample, which then takes the sample in.

        A running mean over the first ``mean_tracking_samples`` samples, an exponential one after.
        """
        if not self.mean_tracking_samples:
            return z
        out = np.empty_like(z)
        tracked, count, tau = self._tracked, self._tracked_count, self.mean_tracking_samples
        for k in range(z.shape[0]):
            out[k] = z[k] - tracked
            count += 1
            tracked = tracked + (z[k] - tracked) / min(count, tau)
        self._tracked, self._tracked_count = tracked, count
        return out

    def _calibrate(self, ref: np.ndarray, last_index: int) -> None:
        """Whitening AR, mean, re-whitening, correlation factor and the check's baseline.

        From the calibration samples ``ref``, the last of which is sample ``last_index``.
        """
        self.calibrated_at = int(last_index)
        self.whitening, ref = InnovationWhitening.calibrate(ref, max_order=self.whitening_max_order)
        self.mean = ref.mean(axis=0)
        # The AR's residuals on new samples: Akaike's final prediction error, the calibration's
        # residual covariance times (N + d) / (N - d) for d coefficients per output (1 for d = 0).
        n, dof = ref.shape[0], self.whitening.dof
        cov = np.atleast_2d(np.cov(ref, rowvar=False)) * (n + dof) / max(n - dof, 1.0)
        self.rewhiten = whitening_matrix(cov)
        w = (ref - self.mean) @ self.rewhiten.T
        if (check := self.judgement.check) is not None:
            check.push_residuals(last_index - n + 1, w)
            check.calibrate(last_index, n)
        if self.batch_samples:
            nis = np.einsum("ij,ij->i", w, w)
            n_batches = nis.shape[0] // self.batch_samples
            means = nis[: n_batches * self.batch_samples].reshape(n_batches, self.batch_samples).mean(axis=1)
            ratio = self.batch_samples * float(np.var(means, ddof=1)) / (2.0 * self.n_outputs)
            self.correlation_factor = max(1.0, ratio) if math.isfinite(ratio) else 1.0
        self.threshold = self.correlation_factor * self.base_threshold

    @property
    def calibrated(self) -> bool:
        return self.rewhiten is not None

    def process(self, z: np.ndarray, first_index: int) -> ChangeAlarm | None:
        """Feed whitened innovations ``z`` (N, p) of samples ``first_index ..``.

        Returns the first alarm in the block (the rest of the block is not processed), else None.
        """
        z = self._remove_tracked_mean(np.asarray(z, dtype=float).reshape(-1, self.n_outputs))
        start = 0
        if not self.calibrated:
            take = min(self.reference_samples - self._ref_count, z.shape[0])
            self._ref.append(z[:take])
            self._ref_count += take
            start = take
            if self._ref_count >= self.reference_samples:
                ref = np.concatenate(self._ref)
                self._ref = []
                self._last_zero = first_index + start - 1
                self._calibrate(ref, self._last_zero)
        if start >= z.shape[0] or not self.calibrated:
            return None
        residuals, skipped = self.whitening.residuals(z[start:])
        start += skipped
        w = (residuals - self.mean) @ self.rewhiten.T
        if self.judgement.check is not None:
            self.judgement.check.push_residuals(first_index + start, w)
        nis = np.einsum("ij,ij->i", w, w)
        for k in range(nis.shape[0]):
            alarm = self._add(float(nis[k]), first_index + start + k)
            if alarm is not None:
                return alarm
            if self.judgement.jump_at is not None:  # the rest of the block is the caller's to correct and feed again
                self._forget_jump()
                return None
            if self.judgement.noise_at is not None:  # the caller re-arms with the new noise model
                return None
        return None

    def push(self, z: np.ndarray, index: int) -> ChangeAlarm | None:
        """One whitened innovation ``z`` (p,) of sample ``index`` (the per-sample path)."""
        if not self.calibrated:
            return self.process(z[None, :], index)
        if self.mean_tracking_samples:
            tracked = self._tracked
            self._tracked_count += 1
            self._tracked = tracked + (z - tracked) / min(self._tracked_count, self.mean_tracking_samples)
            z = z - tracked
        z = self.whitening.step(z)
        if z is None:  # its lags reach across a gap
            return None
        w = self.rewhiten.dot(z - self.mean)  # (ndarray.dot: statespace.InnovationPredictor.step)
        if self.judgement.check is not None:
            self.judgement.check.push_sample(index, w=w)
        alarm = self._add(float(w.dot(w)), index)
        if self.judgement.jump_at is not None:
            self._forget_jump()
        return alarm

    def _add(self, nis: float, index: int) -> ChangeAlarm | None:
        """One CUSUM step with the calibrated ``|w|^2`` of sample ``index``; an alarm the judgement declares."""
        g = self.statistic + self._a * nis - self._b
        if g <= 0.0:
            self._end_excursion(index)
            return None
        self.statistic = g
        self._sum_nis += nis
        self._n_nis += 1
        if g <= self.threshold:
            return None
        judged = self.judgement.judge(self._last_zero + 1, index)
        if judged is Judged.EXPLAINED:
            self._end_excursion(index)
        if judged is not Judged.DECLARED:
            return None
        ratio = self._sum_nis / (self._n_nis * self.n_outputs)
        return ChangeAlarm(index, self._last_zero + 1, g, self.threshold, ratio)

    def excursion_ended(self, index: int) -> None:
        """The caller explained the excursion up to sample ``index`` (an output's step taken off): forget it.

        The tracked mean goes back to where the statistic last was 0 (per sample, :meth:`push`):
        over a few samples of a large step it took a bias the samples after it no longer have.
        """
        self._tracked = self._tracked_quiet
        self._end_excursion(index)
        self.whitening.gap()

    def offset_taken(self, offset: np.ndarray) -> None:
        """The caller takes ``offset`` (p,), whitened, off the innovations from now on: so does the tracked mean."""
        self._tracked = self._tracked - offset

    def _end_excursion(self, index: int) -> None:
        self._tracked_quiet = self._tracked
        self.statistic = 0.0
        self._last_zero = index
        self._sum_nis, self._n_nis = 0.0, 0
        self.judgement.excursion_ended()

    def _forget_jump(self) -> None:
        """The tracked mean from the jump's fit (offsets may step with it); the whitening's lags refill."""
        if self.mean_tracking_samples:
            self._tracked = self.judgement.last_jump.offset.copy()
        self.whitening.gap()
