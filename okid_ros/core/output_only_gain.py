"""The innovation gain of an output-only model: the covariance model's Riccati gain or a VAR's, the better predictor.

At the model order ``(A, C)`` are fixed; two gains are at hand. The stochastic Riccati equation
of the covariance model ``(A, C, G, R_0)``, ``G`` fitted to the record's correlations, gives the
Kalman predictor of that model, but only when the model is positive real, and its ``G`` is an
estimate: a truncated or noisy ``G`` gives a predictor worse than the alternative. A VAR of the
record gives stochastic Markov parameters ``C A^(k-1) L`` to which ``L`` is fitted with ``A``
and ``C`` fixed (:func:`.output_only_var.gain_from_var`). Where both exist, the one whose
one-step predictions of the record itself have the smaller innovation covariance (its
determinant, the Gaussian likelihood's term: no channel's units weigh) is kept, so the model
handed to the estimator is never the worse predictor of its own record
(docs/benchmarks-output-only.md, forty-fourth session: the in-sample choice agreed with the
predictors' exact variances on fresh data; a two-fold cross-validation did not). The ``Re``
handed with either gain is that predictor's error covariance on the record: the VAR's residual
covariance is smaller (the VAR, of many more coefficients, predicts the record better than the
model) and the covariance model's Riccati ``Re`` is that model's, not the predictor's, so either
scaled the model's normalized innovations wrongly (same docs, "The innovation covariance handed
with the gain").
"""

from __future__ import annotations

import numpy as np
from scipy import linalg

from okid_ros.core.output_only_var import (
    BURN_IN_FRACTION,
    MAX_GAIN_VAR_COEFFICIENTS,
    gain_from_var,
    prediction_error_covariance,
    var_markov,
)
from okid_ros.core.stochastic_realization import forward_innovation

__all__ = ["BURN_IN_FRACTION", "covariance_innovation", "prediction_log_det"]


def _log_det(covariance: np.ndarray | None) -> float:
    """Log determinant of a prediction-error covariance; ``inf`` for an unstable predictor (None) or a singular one."""
    if covariance is None:
        return float(np.inf)
    sign, log_det = np.linalg.slogdet(np.atleast_2d(covariance))
    return float(log_det) if sign > 0 else float(np.inf)


def prediction_log_det(A: np.ndarray, C: np.ndarray, L: np.ndarray, y: np.ndarray) -> float:
    """Log determinant of the covariance of ``y``'s one-step prediction errors by ``x+ = A x + L (y - C x)``.

    The first :data:`BURN_IN_FRACTION` of the record is left out; an unstable predictor scores ``inf``.
    """
    return _log_det(prediction_error_covariance(A, C, L, y))


def covariance_innovation(A, C, gamma, correlations, block_rows, y):
    """``L``, ``Re`` of the forward innovation model at this order, and how they were obtained.

    ``gamma``: the observability matrix of ``(A, C)`` over ``block_rows``; ``correlations``
    ``R_0 .. R_i`` (at least), of the record ``y`` (N, p). The Riccati gain of the covariance
    model when it is positive real and predicts ``y`` at least as well as the VAR's gain; otherwise
    the VAR's (:func:`.output_only_var.gain_from_var`: fitted to its stochastic Markov parameters,
    or the Kalman gain of the noise covariances of a state sequence where that predictor is unstable).
    ``Re`` is the chosen predictor's error covariance on ``y`` (:func:`.output_only_var.prediction_error_covariance`).
    """
    p = C.shape[0]
    stacked = correlations[1 : block_rows + 1].reshape(block_rows * p, p)  # [R_1; ..; R_i], all columns
    G = linalg.lstsq(gamma, stacked)[0]
    solved = forward_innovation(A, C, G, correlations[0])
    var = gain_from_var(A, C, y, *var_markov(y, block_rows, MAX_GAIN_VAR_COEFFICIENTS))
    if solved is None:
        return var
    # Each candidate's Re is its predictor's error covariance on this record (the VAR gain's computed with it):
    # the covariance model's Riccati Re is that of a model fitted to the correlations, not of this predictor.
    riccati = (solved[0], prediction_error_covariance(A, C, solved[0], y), "riccati")
    if _log_det(riccati[1]) <= _log_det(var[1]):
        return riccati
    return var
