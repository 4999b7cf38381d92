"""The model-error check: does an alarm of the change test come with a model error, or only with more noise.

The CUSUM of :mod:`okid_ros.core.change_detection` watches the power of the reference model's
innovations. That power also rises when the unmeasured disturbances or the sensor noise grow
while the structure stays as it was: the steel subframe's record, a stationary structure, has
stretches of 0.1-0.5 s with 15-45 % more innovation power, and with 28 outputs a CUSUM tuned
to a 50 % increase crosses its threshold within ~100 samples of any lasting rise above 22 %.

What a changed structure does and more noise does not: the reference predictor is then wrong,
so its innovations carry a part that the past explains, the response to the inputs of the last
``lags`` samples (a changed input-output path) and each output's own last ``lags`` residuals (a
mode that rings at another frequency or decays at another rate). More noise leaves the
residuals as unpredictable as before. :class:`ModelErrorCheck` measures the fraction of the
tested residuals' energy that those regressors explain, by least squares per output:

- at the calibration, over the calibration samples: ``R0^2``. A real model is not exact and
  leaves some of its residuals predictable (the subframe's models: about 6 % of their energy);
- at an alarm, over the last samples of the CUSUM's excursion (at least ``min_samples``): ``R^2``.

With ``k`` regressors per output over ``n`` rows, chance alone explains ``c = k / (n - 1)`` of
white residuals, so the predictable fraction is estimated by ``(R^2 - c) / (1 - c)``. The alarm
is confirmed when the excess over the calibration's::

    excess = (R^2 - c) / (1 - c) - (R0^2 - c0) / (1 - c0)  >  max(min_excess, z * sd)

``sd`` is the spread of that difference for white residuals (each output's ``R^2`` is
Beta(k/2, (n-k-1)/2), pooled over ``p`` outputs) and ``z`` its one-sided quantile for
``false_confirmation``; ``min_excess`` (8 % of the energy) is an effect size below which no
alarm is confirmed. It is set between what was measured (``bench/change_detection.py --part
delay``; docs/benchmarks-change.md): the real subframe's false alarms, judged against reference
models of 1500-6000 samples, reach excesses of 0.01-0.07 (the shorter the reference's window,
the more of its error a change of the excitation exposes); simulated changes of 2-30 % were
confirmed at 0.08-0.29. The statistic is invariant to the residuals' scale: a rise of power
alone does not move it.

An alarm that is not confirmed is not declared; the CUSUM goes on and its excursion is judged
again ``judge_period`` samples later (a change that happens during a noisy stretch is declared
once its samples dominate the judged ones), until the statistic returns to zero.

No rclpy; numpy and scipy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from okid_ros.core.sample_ring import SampleRing

__all__ = [
    "DEFAULT_CHECK_LAGS",
    "DEFAULT_MIN_EXCESS",
    "ModelErrorCheck",
    "ModelErrorVerdict",
    "explained_fraction",
]

DEFAULT_CHECK_LAGS = 10  # lags of the inputs and of each output's residuals
DEFAULT_MIN_EXCESS = 0.08  # fraction of the residuals' energy a model error must make predictable
DEFAULT_FALSE_CONFIRMATION = 1e-3  # chance that a judgement of white, input-free residuals confirms
_CAPACITY_ROWS = 4096  # samples kept; a longer excursion is judged on its last ones


@dataclass
class ModelErrorVerdict:
    """The judgement of one alarm.

    Attributes
    ----------
    confirmed : the residuals of the judged samples carry a model error.
    excess : predictable fraction of their energy beyond the calibration's (module docstring).
    limit : what ``excess`` had to exceed.
    samples : rows judged (after the lags).
    """

    confirmed: bool
    excess: float
    limit: float
    samples: int


def explained_fraction(w: np.ndarray, u: np.ndarray, lags: int) -> tuple[float, int]:
    """Fraction of ``w``'s energy explained per output by the lagged inputs and its own lags.

    Parameters
    ----------
    w : (N, p) residuals of consecutive samples.
    u : (N, m) inputs of the same samples (m may be 0).
    lags : regressors of row t: ``u[t - j]`` for j = 0 .. lags and ``w[t - j, i]`` for
        j = 1 .. lags (output i).

    Returns
    -------
    (R^2 pooled over the outputs: explained energy over total energy, rows n = N - lags).
    """
    # One least-squares fit per output, all outputs at once: the inputs' lags are common to
    # every output, so they are projected out of all outputs' own lags and targets in one
    # matrix product (an orthonormal basis of their span from one SVD, its rank as lstsq
    # decides it), and each output's own lags then need only the triangle of a small QR of
    # [own lags, target] (numpy's stacked QR, mode "r"): the explained energy is the target's
    # projection on the inputs plus the last column of that triangle. The same fits as numpy's
    # lstsq per output (to rounding), which took 9-34 ms per judgement at 28 outputs on the
    # sample path. An output whose own lags are rank deficient once the inputs are projected
    # out (a residual that does not move) is fitted by lstsq. Means are removed: a drifting
    # offset is not structural (the CUSUM tracks it out too).
    n, p = w.shape[0] - lags, w.shape[1]
    w = w - w.mean(axis=0)
    shared = [u[lags - j: lags - j + n] for j in range(lags + 1)] if u.shape[1] else []
    shared = np.hstack([s - s.mean(axis=0) for s in shared]) if shared else np.zeros((n, 0))
    own = np.empty((n, p, lags + 1))  # per output: its lags 1 .. lags, then its target
    for j in range(1, lags + 1):
        own[:, :, j - 1] = w[lags - j: lags - j + n]
    own[:, :, lags] = w[lags:]
    total = float(np.sum(own[:, :, lags] ** 2))
    if total <= 0:
        return 0.0, n
    basis = _column_basis(shared, n_columns=shared.shape[1] + lags)
    flat = own.reshape(n, p * (lags + 1))
    along = basis.T @ flat  # (r, p (lags + 1))
    explained = np.sum(along.reshape(-1, p, lags + 1)[:, :, lags] ** 2, axis=0)  # (p,) by the inputs
    rest = (flat - basis @ along).reshape(n, p, lags + 1).transpose(1, 0, 2)  # (p, n, lags + 1)
    r = np.linalg.qr(rest, mode="r")
    explained += np.sum(r[:, :lags, lags] ** 2, axis=1)
    diagonal = np.abs(np.diagonal(r[:, :lags, :lags], axis1=1, axis2=2))
    tolerance = np.finfo(float).eps * max(n, shared.shape[1] + lags) * np.max(diagonal, axis=1, initial=0.0)
    for i in np.flatnonzero(~np.all(diagonal > tolerance[:, None], axis=1)):
        regressors = np.hstack([shared, own[:, i, :lags]])
        coef, *_ = np.linalg.lstsq(regressors, own[:, i, lags], rcond=None)
        fitted = regressors @ coef
        explained[i] = fitted @ fitted
    return float(np.sum(explained)) / total, n


def _column_basis(columns: np.ndarray, *, n_columns: int) -> np.ndarray:
    """Orthonormal basis (n, r) of the span of ``columns`` (n, k), rank as numpy's lstsq decides it.

    ``n_columns``: the columns of the whole regression the rank threshold counts (lstsq's
    ``rcond=None``: machine precision times the larger dimension).
    """
    if columns.shape[1] == 0:
        return np.zeros((columns.shape[0], 0))
    left, singular, _ = np.linalg.svd(columns, full_matrices=False)
    keep = singular > np.finfo(float).eps * max(columns.shape[0], n_columns) * singular[0]
    return left[:, keep]


class ModelErrorCheck:
    """Tested residuals and inputs of the last samples, and the model-error judgement of an alarm.

    Parameters
    ----------
    n_outputs, n_inputs : p, m (m may be 0: the residuals' own lags only).
    lags : lags of the inputs (0 .. lags) and of each output's residuals (1 .. lags).
    min_excess : effect size the excess must exceed to confirm (module docstring).
    false_confirmation : chance that a judgement of white residuals uncorrelated with the inputs
        confirms; sets ``z``.
    capacity : samples kept at least (the calibration's must be among them when it ends).

    Attributes
    ----------
    regressors : k, per output.
    min_samples : fewest rows judged (8 k, at least 128).
    judge_period : samples between two judgements of one excursion (``min_samples / 8``, at least 16).
    baseline : ``(R0^2 - c0) / (1 - c0)`` of the calibration; None before :meth:`calibrate`.
    """

    def __init__(self, n_outputs: int, n_inputs: int, *, lags: int = DEFAULT_CHECK_LAGS,
                 min_excess: float = DEFAULT_MIN_EXCESS,
                 false_confirmation: float = DEFAULT_FALSE_CONFIRMATION, capacity: int = 0) -> None:
        self.n_outputs, self.n_inputs, self.lags = int(n_outputs), int(n_inputs), int(lags)
        self.regressors = self.n_inputs * (self.lags + 1) + self.lags
        self.min_samples = max(8 * self.regressors, 128)
        self.judge_period = max(self.min_samples // 8, 16)
        self.min_excess = float(min_excess)
        self.z = float(stats.norm.isf(false_confirmation))
        self.capacity = max(_CAPACITY_ROWS, 2 * (self.min_samples + self.lags), int(capacity))
        self._w = SampleRing(self.n_outputs, self.capacity)
        self._u = SampleRing(self.n_inputs, self.capacity)
        self.baseline: float | None = None
        self._baseline_rows = 0

    def push_inputs(self, first_index: int, u: np.ndarray) -> None:
        """Inputs ``u`` (N, m) of samples ``first_index ..``."""
        self._u.push(first_index, u)

    def push_sample(self, index: int, u: np.ndarray | None = None, w: np.ndarray | None = None) -> None:
        """One sample's input ``u`` (m,) or tested residual ``w`` (p,) (the per-sample path)."""
        if u is not None:
            self._u.push_one(index, u)
        if w is not None:
            self._w.push_one(index, w)

    def push_residuals(self, first_index: int, w: np.ndarray) -> None:
        """Tested residuals ``w`` (N, p) of samples ``first_index ..``."""
        self._w.push(first_index, w)

    def _run_until(self, last: int, samples: int) -> tuple[np.ndarray, np.ndarray]:
        """Up to ``samples`` consecutive samples ending at ``last`` that hold a residual and an input."""
        w, w_first = self._w.since(int(last) - int(samples) + 1, last)
        u, u_first = self._u.since(int(last) - int(samples) + 1, last)
        first = max(w_first, u_first)
        return w[first - w_first:], u[first - u_first:]

    def _predictable(self, last: int, samples: int) -> tuple[float, int] | None:
        """``((R^2 - c) / (1 - c), n)`` over the samples ending at ``last``; None if too few."""
        w, u = self._run_until(last, samples + self.lags)
        return self._fraction(w, u)

    def _fraction(self, w: np.ndarray, u: np.ndarray) -> tuple[float, int] | None:
        if w.shape[0] - self.lags < 2 * self.regressors:
            return None
        r2, n = explained_fraction(w, u, self.lags)
        chance = self.regressors / (n - 1)
        return (r2 - chance) / (1.0 - chance), n

    def predictable(self, w: np.ndarray, last: int) -> tuple[float, int] | None:
        """The statistic of other residuals ``w`` (N, p) of the samples ending at ``last``, with their inputs.

        ``((R^2 - c) / (1 - c), n)`` as :meth:`judge` computes it (e.g. for the innovations of
        another predictor, :mod:`okid_ros.core.noise_change`); only the samples whose inputs are
        held count; None if too few.
        """
        u, _ = self._u.since(int(last) - w.shape[0] + 1, last)
        return self._fraction(w[w.shape[0] - u.shape[0]:], u)

    def spread(self, n: int) -> float:
        """Standard deviation of the pooled ``(R^2 - c) / (1 - c)`` of white residuals over ``n`` rows."""
        k, p = self.regressors, self.n_outputs
        a, b = 0.5 * k, 0.5 * max(n - k - 1, 1)
        beta_var = a * b / ((a + b) ** 2 * (a + b + 1.0))
        return math.sqrt(beta_var / p) / (1.0 - k / (n - 1))

    def calibrate(self, last_index: int, samples: int) -> None:
        """The baseline from the ``samples`` calibration samples ending at ``last_index``."""
        found = self._predictable(last_index, samples)
        self.baseline, self._baseline_rows = (found[0], found[1]) if found is not None else (None, 0)

    def judge(self, change_index: int, alarm_index: int) -> ModelErrorVerdict:
        """Whether the samples ``change_index .. alarm_index`` carry a model error.

        At least ``min_samples`` are judged (the last ones before the alarm). Without a
        baseline or with too few consecutive samples the alarm stands (the power test alone).
        """
        samples = max(int(alarm_index) - int(change_index) + 1, self.min_samples)
        found = self._predictable(alarm_index, samples)
        if found is None or self.baseline is None:
            return ModelErrorVerdict(True, float("nan"), float("nan"), 0 if found is None else found[1])
        fraction, n = found
        spread = math.hypot(self.spread(n), self.spread(self._baseline_rows))
        limit = max(self.min_excess, self.z * spread)
        excess = fraction - self.baseline
        return ModelErrorVerdict(bool(excess > limit), float(excess), float(limit), int(n))
