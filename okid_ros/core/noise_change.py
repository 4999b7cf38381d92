"""The noise-change test: an excursion of the innovations explained by a change of the noise model alone.

The change test (:mod:`okid_ros.core.change_detection`) watches the reference predictor's
whitened innovations ``z``; the model-error check confirms an alarm when they have become
predictable from their past. A changed structure does that, but so does a change of the
unmeasured excitation relative to the sensor noise (wind or traffic picking up, a shaker's
level turned): the optimal predictor gain depends on that ratio, and the old gain's innovations
are coloured. On the change bench's structure (``bench/change_detection.py``'s systems, disturbance
forces doubled, the true models) 48-62 % of the old predictor's whitened innovation energy
became predictable from its past: every such change was declared as structural.

With ``A, B, C, D`` unchanged and the predictor gain ``L = A K`` of the new noise ``L + dL``,
the reference predictor's error ``eps = x - xhat`` runs, input-free, as::

    eps_(k+1) = F eps_k + dL e_k,        z_k = Cw eps_k + W e_k,        F = A - L C,  Cw = W C

(``e`` the new innovations, ``W`` the reference's whitening). So ``z`` is the output of an
innovation model whose ``F`` and ``Cw`` are known and whose gain ``dL W^-1`` is not: a vector
AR of ``z`` gives that model's stochastic Markov parameters ``Cw F^(k-1) dL W^-1`` (the OKID
recursion, as the output-only route's gain), the gain follows by least squares with ``F`` and
``Cw`` fixed (:func:`~okid_ros.core.stochastic_realization.gain_from_markov`), and ``z`` run
through that model's inverse is re-whitened. :class:`NoiseChangeTest` then asks the model-error
check's question again of the re-whitened innovations, against the same statistic of the
calibration re-whitened alike: a changed structure leaves a model error (its innovations ring
at poles ``F`` does not have), a changed noise does not.

Measured on the change bench's systems (3 seeds; the excess predictable fraction, old
innovations -> re-whitened, over the first 512 samples after the change): the disturbance
forces x1.5 to x3 0.33-0.77 -> 0.00-0.03; structural changes keep 0.06-0.34 (frequency -2 %
and -6 %, damping x2, storey stiffness -20 %) and 0.03-0.05 (stiffness -10 %). Fewer samples
tell them apart less well, so a verdict of noise waits for :attr:`NoiseChangeTest.max_samples`
while a model error found earlier is declared at once (docs/benchmarks-change.md).

No library tests a change of noise model with the dynamics fixed (the state-space tests in
the field's packages re-identify the whole model); numpy and scipy only.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from okid_ros.core.model_error_check import ModelErrorCheck
from okid_ros.core.statespace import InnovationModel, simulate, spectral_radius
from okid_ros.core.stochastic_realization import fit_var, gain_from_markov, stochastic_markov_from_var

__all__ = ["MIN_JUDGED_SAMPLES", "VERDICT_FACTOR", "NoiseChange", "NoiseChangeTest", "NoiseVerdict", "refit_noise",
           "with_noise"]

#: Samples per coefficient of the vector AR fitted to the innovations (its order is lowered to keep them).
_ROWS_PER_COEFFICIENT = 4
#: Most condition number of ``A`` for which the paper's gain ``K = A^-1 L`` of the new noise is formed.
_MAX_CONDITION = 1e10
#: Fewest samples of an excursion judged (and at least the check's ``min_samples``): on fewer, the
#: fitted gain's error alone left a predictable part beyond the check's limit (0.11 of the energy
#: at 128 samples of the output-only service test's structure, its excitation doubled).
MIN_JUDGED_SAMPLES = 256
#: A verdict of noise needs this many times the fewest samples judged.
VERDICT_FACTOR = 4


@dataclass(frozen=True)
class NoiseChange:
    """The reference predictor's innovations explained by a change of its noise model (whitened coordinates).

    Attributes
    ----------
    gain_change : (n, p) ``dL W^-1``, the predictor gain's change acting on whitened innovations.
    residuals : (N, p) the innovations re-whitened (those of the predictor with the new gain).
    covariance : (p, p) the covariance of ``residuals``.
    """

    gain_change: np.ndarray
    residuals: np.ndarray
    covariance: np.ndarray


@dataclass(frozen=True)
class NoiseVerdict:
    """The judgement of one excursion.

    Attributes
    ----------
    explained : a change of the noise model explains it (no model error remains).
    excess : predictable fraction of the re-whitened innovations beyond the calibration's (NaN: no fit).
    limit : what ``excess`` had to exceed for a model error.
    samples : innovations judged.
    change : the fitted noise change (None when there was none to fit).
    """

    explained: bool
    excess: float
    limit: float
    samples: int
    change: NoiseChange | None = None


def refit_noise(z: np.ndarray, F: np.ndarray, C_whitened: np.ndarray, *, var_order: int) -> NoiseChange | None:
    """The gain change that re-whitens ``z`` (N, p), the predictor's ``F`` (n, n) and ``Cw`` (p, n) fixed.

    None when the fitted gain leaves the new predictor unstable or anything is not finite.
    """
    n, p = F.shape[0], C_whitened.shape[0]
    order = max(1, min(int(var_order), z.shape[0] // (_ROWS_PER_COEFFICIENT * p)))
    if not np.all(np.isfinite(z)) or z.shape[0] <= 2 * order * p:
        return None
    var = fit_var(z, order)
    markov = stochastic_markov_from_var(var, math.ceil(2 * n / p) + order)
    gain = gain_from_markov(F, C_whitened, markov)
    F_new = F - gain @ C_whitened
    if not np.all(np.isfinite(gain)) or not spectral_radius(F_new) < 1.0:
        return None
    residuals = _without_free_response(simulate(F_new, gain, -C_whitened, np.eye(p), z), F_new, C_whitened)
    return NoiseChange(gain, residuals, np.atleast_2d(np.cov(residuals, rowvar=False)))


def _without_free_response(residuals: np.ndarray, F: np.ndarray, C: np.ndarray) -> np.ndarray:
    """``residuals`` (N, p) less their least-squares fit by a free response ``C F^k x0``.

    The two predictors' states differ at the first sample: that difference's free response, left
    in, is predictable from its own past. By the normal equations: their matrix by doubling
    (:func:`_response_gram`) and the right side by one backward pass, where the stacked
    responses (N p x n) and ``lstsq`` took 0.19 s at 28 outputs, 122 states, 1024 samples.
    """
    n, samples = F.shape[0], residuals.shape[0]
    # sum_k (C F^k)^T r_k: the adjoint system run backwards over the residuals, its last state.
    backward = simulate(F.T, C.T, np.eye(n), np.zeros((n, C.shape[0])), residuals[::-1])
    right = F.T @ backward[-1] + C.T @ residuals[0]
    x0 = np.linalg.lstsq(_response_gram(F, C, samples), right, rcond=None)[0]
    return residuals - simulate(F, np.zeros((n, 1)), C, np.zeros((C.shape[0], 1)), np.zeros((samples, 1)), x0=x0)


def _response_gram(F: np.ndarray, C: np.ndarray, samples: int) -> np.ndarray:
    """``sum_(k < samples) (C F^k)^T (C F^k)`` (n, n), by doubling: a few n x n products per bit of ``samples``."""
    n = F.shape[0]
    total, power = np.zeros((n, n)), np.eye(n)  # over the terms so far, and F to their count
    block, block_power = C.T @ C, F.copy()  # over 2^i terms, and F^(2^i)
    remaining = int(samples)
    while remaining:
        if remaining & 1:
            total = total + power.T @ block @ power
            power = power @ block_power
        remaining >>= 1
        if remaining:
            block = block + block_power.T @ block @ block_power
            block_power = block_power @ block_power
    return total


def with_noise(model: InnovationModel, whiten: np.ndarray, change: NoiseChange) -> InnovationModel | None:
    """``model`` with the noise model of ``change`` (``whiten``: the model's whitening ``W``).

    Predictor gain ``L + dL``, innovation covariance ``W^-1 S W^-T`` (``S`` the re-whitened
    innovations' covariance); the paper's gain ``K = A^-1 (L + dL)``. None when ``A`` is too
    ill-conditioned to give ``K`` or the model fails its checks.
    """
    if np.linalg.cond(model.A) > _MAX_CONDITION:
        return None
    unwhiten = np.linalg.inv(whiten)
    gain = model.predictor_gain + change.gain_change @ whiten
    covariance = unwhiten @ change.covariance @ unwhiten.T
    noisy = dataclasses.replace(model, K=np.linalg.solve(model.A, gain),
                                innovation_covariance=0.5 * (covariance + covariance.T))
    return None if noisy.stability_problem() else noisy


class NoiseChangeTest:
    """Judge confirmed excursions of one predictor's whitened innovations as a change of its noise model.

    Parameters
    ----------
    F : (n, n) the predictor's state matrix; C_whitened : (p, n) ``W C``.
    check : the model-error check whose statistic judges (its inputs, lags and spread).

    Attributes
    ----------
    baseline : the check's predictable fraction of the calibration re-whitened alike (NaN
        without a fit), and its rows; None until :meth:`calibrate`.
    first_samples : the fewest samples judged (:data:`MIN_JUDGED_SAMPLES`, at least the check's
        ``min_samples``); max_samples : those a verdict of noise needs (:data:`VERDICT_FACTOR` times).
    next_samples : the excursion's samples at which it is judged next (doubling from
        ``first_samples`` up to ``max_samples``).
    """

    def __init__(self, F: np.ndarray, C_whitened: np.ndarray, check: ModelErrorCheck) -> None:
        self.F, self.C_whitened, self.check = np.asarray(F, float), np.asarray(C_whitened, float), check
        self.first_samples = max(MIN_JUDGED_SAMPLES, check.min_samples)
        self.max_samples = VERDICT_FACTOR * self.first_samples
        self.baseline: tuple[float, int] | None = None
        self.restart()

    def restart(self) -> None:
        """A new excursion: its first judgement at ``first_samples``."""
        self.next_samples = self.first_samples

    def _fraction(self, z: np.ndarray, last_index: int) -> tuple[float, int, NoiseChange | None]:
        change = refit_noise(z, self.F, self.C_whitened, var_order=self.check.lags)
        found = None if change is None else self.check.predictable(change.residuals, last_index)
        return (math.nan, 0, None) if found is None else (found[0], found[1], change)

    def calibrate(self, z: np.ndarray, last_index: int) -> None:
        """The baseline from the calibration's whitened innovations ``z`` ending at sample ``last_index``."""
        fraction, rows, _ = self._fraction(z, last_index)
        self.baseline = (fraction, rows)  # NaN without a fit: no excursion is then explained

    def judge(self, z: np.ndarray, last_index: int) -> NoiseVerdict | None:
        """The excursion's whitened innovations ``z`` (N, p) up to sample ``last_index``; None: judge it later.

        Judged once ``N`` reaches :attr:`next_samples`: a model error found (the excess beyond
        ``z`` spreads of the check's statistic and ``n / N``, the fitted gain's error) is a
        verdict at once; none found waits for twice the samples, up to ``max_samples``, where
        it is the verdict of a noise change.
        Without a baseline or a fit the excursion is not explained (declared as before).
        """
        if z.shape[0] < min(self.next_samples, self.max_samples):
            return None
        if self.baseline is None or not math.isfinite(self.baseline[0]):
            return NoiseVerdict(False, math.nan, math.nan, z.shape[0])
        fraction, rows, change = self._fraction(z[-self.max_samples:], last_index)
        if change is None:
            return NoiseVerdict(False, math.nan, math.nan, z.shape[0])
        # The chance spread of the check's statistic, and what the gain's estimate leaves
        # predictable: about n / rows of the energy (n the states) on the simulations measured.
        spread = math.hypot(self.check.spread(rows), self.check.spread(self.baseline[1]))
        limit, excess = self.check.z * spread + self.F.shape[0] / rows, fraction - self.baseline[0]
        if excess > limit or z.shape[0] >= self.max_samples:
            return NoiseVerdict(bool(excess <= limit), float(excess), float(limit), rows, change)
        self.next_samples = 2 * z.shape[0]
        return None
