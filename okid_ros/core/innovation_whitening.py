"""The AR that whitens a reference model's innovations for the change test.

A model that misses or misplaces a mode leaves that mode in its innovations: they are coloured,
and the change test's calibration cannot measure its false-alarm rate on them (see
:mod:`okid_ros.core.change_detection`). A vector AR fitted to the calibration samples predicts
what the reference left predictable; the test runs on its residuals
``z_k - sum_i Phi_i z_{k-i}``. The order comes from BIC (0 for a good model: nothing changes),
the fit is the core's :func:`okid_ros.core.stochastic_realization.fit_var` (ridge, GCV).

No rclpy; numpy only.
"""

from __future__ import annotations

import math

import numpy as np

from okid_ros.core.regressors import arx_regressors
from okid_ros.core.stochastic_realization import fit_var

__all__ = ["DEFAULT_WHITENING_MAX_ORDER", "WHITENING_MAX_COEFFICIENT_FRACTION", "InnovationWhitening",
           "whitening_order_by_bic"]

DEFAULT_WHITENING_MAX_ORDER = 10  # lags of the AR whitening of the calibrated innovations
# Coefficients per output of the whitening AR at most this fraction of the calibration samples:
# its residuals on new samples are larger than on the calibration samples by about that fraction.
WHITENING_MAX_COEFFICIENT_FRACTION = 0.05


def _lagged(z: np.ndarray, order: int) -> np.ndarray:
    """Regressor rows (N - q, q p) of ``z`` (N, p): lags 1 .. q of each sample from the q-th on."""
    return arx_regressors(np.zeros((z.shape[0], 0)), z, order)[0]


def whitening_order_by_bic(z: np.ndarray, max_order: int) -> int:
    """Lags of the whitening AR of ``z`` (N, p): BIC of least-squares fits over the same rows, 0 .. max.

    statsmodels' ``VAR.select_order`` does this, but statsmodels is not among our dependencies
    for a dozen lines.
    """
    if max_order < 1:
        return 0
    n, p = z.shape
    rows = n - max_order
    targets = z[max_order:]
    best, best_bic = 0, math.inf
    for q in range(max_order + 1):
        if q:
            phi = np.hstack([_lagged(z, q)[max_order - q:], np.ones((rows, 1))])
            coef, *_ = np.linalg.lstsq(phi, targets, rcond=None)
            residuals = targets - phi @ coef
        else:
            residuals = targets - targets.mean(axis=0)
        sign, logdet = np.linalg.slogdet(np.atleast_2d(residuals.T @ residuals) / rows)
        bic = rows * logdet + q * p * p * math.log(rows) if sign > 0 else math.inf
        if bic < best_bic:
            best, best_bic = q, bic
    return best


class InnovationWhitening:
    """The whitening AR of a calibration and its lags, stepped over later innovations.

    Parameters
    ----------
    n_outputs : p.
    order : q (0: the identity, residuals are the innovations).
    coefficients : (q p, p) AR coefficients, lag 1 first (``fit_var``'s ``theta``).
    lags : (q p,) the last q innovations, newest first.
    dof : coefficients per output the fit used (its effective parameters).

    Attributes
    ----------
    refill : samples still to come after a gap whose residuals reach across it (not to be tested).
    """

    def __init__(self, n_outputs: int, order: int = 0, coefficients: np.ndarray | None = None,
                 lags: np.ndarray | None = None, dof: float = 0.0) -> None:
        self.n_outputs, self.order, self.dof = int(n_outputs), int(order), float(dof)
        self.coefficients = np.zeros((0, n_outputs)) if coefficients is None else coefficients
        self.lags = np.zeros(self.order * self.n_outputs) if lags is None else lags
        self.refill = 0

    @classmethod
    def calibrate(cls, z: np.ndarray, *, max_order: int) -> tuple[InnovationWhitening, np.ndarray]:
        """The whitening of calibration samples ``z`` (N, p) and its residuals on them (N - q, p)."""
        q = whitening_order_by_bic(z, max_order)
        if not q:
            return cls(z.shape[1]), z
        var = fit_var(z, q)
        whitening = cls(z.shape[1], q, var.theta, z[-q:][::-1].ravel().copy(), var.effective_parameters)
        return whitening, z[q:] - _lagged(z, q) @ whitening.coefficients

    def gap(self) -> None:
        """Samples are missing before the next one: the lags are not those samples'."""
        self.lags = np.zeros_like(self.lags)
        self.refill = self.order

    def residuals(self, z: np.ndarray) -> tuple[np.ndarray, int]:
        """Residuals of innovations ``z`` (N, p), which then take the lags' place.

        Returns the residuals (N - s, p) of the samples to be tested and s, the leading samples
        left out because their lags reach across a gap (``refill``).
        """
        q = self.order
        if not q:
            return z, 0
        extended = np.vstack([self.lags.reshape(q, self.n_outputs)[::-1], z])  # oldest first
        self.lags = extended[-q:][::-1].ravel().copy()
        skip = min(self.refill, z.shape[0])
        self.refill -= skip
        return (z - _lagged(extended, q) @ self.coefficients)[skip:], skip

    def step(self, z: np.ndarray) -> np.ndarray | None:
        """The residual (p,) of one innovation ``z`` (p,), None while refilling: :meth:`residuals` per sample."""
        if not self.order:
            return z
        lags = self.lags
        self.lags = np.concatenate([z, lags[: -self.n_outputs]])
        if self.refill:
            self.refill -= 1
            return None
        return z - lags.dot(self.coefficients)  # (ndarray.dot: statespace.InnovationPredictor.step)
