"""The VAR route of output-only identification (the paper's): its Markov parameters, replicates and gain.

A vector AR of the record, fitted by least squares, gives the stochastic Markov parameters
``C A^(k-1) A K`` by the OKID recursion (:func:`.stochastic_realization.stochastic_markov_from_var`),
realized by ERA. So that its candidate modes are screened by the same rules as the SSI routes'
(:func:`.output_only._drop_noise_modes`: jackknife scatter and spectral share), this module also
gives the route's jackknife replicates (the VAR refitted with each segment of the record left out,
from the segments' normal equations) and a covariance model of each order for the spectral share.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import linalg

from okid_ros.core.arx import fit_from_normal_equations
from okid_ros.core.arx_gram import arx_normal_equations, arx_regressor_product
from okid_ros.core.era import HankelDecomposition
from okid_ros.core.identified_model import IdentificationError
from okid_ros.core.kalman_gain import kalman_gain_from_residuals
from okid_ros.core.refit import innovation_covariance
from okid_ros.core.statespace import driven_states
from okid_ros.core.stochastic_realization import (
    CovarianceDecomposition,
    OrderRealizer,
    covariance_decomposition,
    fit_var,
    gain_from_markov,
    stochastic_markov_from_var,
)

__all__ = ["BURN_IN_FRACTION", "MAX_GAIN_VAR_COEFFICIENTS", "VAR_ROUTE_WARNING", "VarCovarianceModel",
           "gain_from_var", "prediction_error_covariance", "var_markov", "var_replicates"]

#: The VAR of the route keeps at most this many coefficients per output (and N / 10).
MAX_VAR_COEFFICIENTS = 1500
#: The VAR that only supplies a gain (no modes) is kept smaller: its cost is N (q p)^2 and the
#: predictor's Markov parameters decay at the predictor's rate (4 outputs, 60000 samples: 15 s at
#: q = 250, 1 s at q = 50).
MAX_GAIN_VAR_COEFFICIENTS = 200
#: The first part of the record a predictor's errors leave out (its start from a zero state).
BURN_IN_FRACTION = 0.1

#: Every model of the route says what it lacks: screened as the SSI routes' modes are, its poles
#: scatter more across the jackknife's replicates, so more true modes are dropped (docs/benchmarks-output-only.md,
#: forty-third session), and the modes far below the sampling rate are not re-estimated.
VAR_ROUTE_WARNING = ("method 'var' (the paper's VAR route): its pole estimates scatter more than the SSI routes', so "
                     "the noise screening drops more true modes (on simulated records it finds fewer and damps them "
                     "worse), and the slowest modes are not re-estimated from the decimated record; prefer 'ssi-cva'")


def _var_order(y: np.ndarray, block_rows: int, max_coefficients: int) -> int:
    """The VAR order over the lag window: ``max_coefficients`` per output, N / 10 at most."""
    budget = min(max_coefficients, y.shape[0] // 10)
    return int(max(2, min(2 * block_rows, budget // y.shape[1])))


def var_markov(y: np.ndarray, block_rows: int, max_coefficients: int = MAX_VAR_COEFFICIENTS):
    """A VAR over the lag window (:func:`_var_order`), its stochastic Markov parameters ``(2 i + 1, p, p)``."""
    var = fit_var(y, _var_order(y, block_rows, max_coefficients))
    return var, stochastic_markov_from_var(var, 2 * block_rows + 1)


def var_replicates(y: np.ndarray, block_rows: int, n_segments: int, max_states: int,
                   max_coefficients: int = MAX_VAR_COEFFICIENTS):
    """``decompose(j)``: the route's Hankel decomposition (``max_states`` triplets) without segment ``j``.

    ``n_segments`` segments as :func:`.output_covariance.output_correlations` cuts them. The VAR's normal
    equations without a segment are the record's less the rows wholly inside it (a row straddling
    its edge stays: q of N / S rows); the fit as the record's, the Hankel's leading triplets from its
    Gram (:func:`.stochastic_realization.covariance_decomposition`: the full SVD of each replicate's was
    nine tenths of the route's time).
    """
    order, p = _var_order(y, block_rows, max_coefficients), y.shape[1]
    u = np.zeros((y.shape[0], 0))
    whole = arx_normal_equations(u, y, order)
    bounds = np.linspace(0, y.shape[0], n_segments + 1).astype(int)

    def decompose(j: int) -> CovarianceDecomposition | HankelDecomposition:
        part = arx_normal_equations(u[bounds[j]:bounds[j + 1]], y[bounds[j]:bounds[j + 1]], order)
        rest = replace(whole, R=whole.R - part.R, r=whole.r - part.r, yy=whole.yy - part.yy,
                       n_rows=whole.n_rows - part.n_rows, phi_sum=whole.phi_sum - part.phi_sum,
                       y_sum=whole.y_sum - part.y_sum)
        var = fit_from_normal_equations(rest, order, p, 0, "ridge", center=True)
        markov = stochastic_markov_from_var(var, 2 * block_rows)
        # The Hankel of h_1 .. h_2i is that of correlations R_1 .. R_2i: its leading triplets from the Gram.
        return covariance_decomposition(np.concatenate([np.zeros((1, p, p)), markov]), np.arange(p), block_rows,
                                        max_states)

    return decompose


class VarCovarianceModel:
    """The covariance model ``(A, C, G)`` of each order of the route, for the spectral share.

    ``A`` and ``C`` are the route's; ``G`` (n, r) is fitted to the record's correlations
    ``R_k = C A^(k-1) G``, k = 1 .. i (reference columns), as the SSI routes' innovation model
    is (:func:`.output_only_gain.covariance_innovation`), so that
    :func:`.output_only_support.spectral_dominance` reads the share of the record's spectrum.
    """

    def __init__(self, realizer: OrderRealizer, correlations: np.ndarray, references: np.ndarray,
                 block_rows: int) -> None:
        self._realizer = realizer
        p = correlations.shape[1]
        self._stacked = correlations[1 : block_rows + 1][:, :, references].reshape(block_rows * p, references.size)
        self.eigen = realizer.eigen

    def realize(self, n_states: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``A``, ``C`` of order n and the ``G`` of the record's correlations."""
        A, C, _ = self._realizer.realize(n_states)
        return A, C, linalg.lstsq(self._realizer.observability(n_states), self._stacked)[0]


def prediction_error_covariance(A, C, L, y) -> np.ndarray | None:
    """Covariance of ``y``'s one-step prediction errors by ``x+ = A x + L (y - C x)``; None if it is unstable.

    The first :data:`BURN_IN_FRACTION` of the record is left out.
    """
    predictor = A - L @ C
    if np.max(np.abs(linalg.eigvals(predictor)), initial=0.0) >= 1.0:
        return None
    errors = y - driven_states(predictor, y @ L.T) @ C.T
    return innovation_covariance(errors[int(BURN_IN_FRACTION * y.shape[0]):])


def gain_from_var(A, C, y, var, markov):
    """``L``, ``Re`` from a VAR of the record.

    ``L`` fitted to its stochastic Markov parameters, or if that predictor is unstable, the Kalman
    gain of the noise covariances of a state sequence. ``Re`` is the covariance of that predictor's
    errors on the record (:func:`prediction_error_covariance`), not the VAR's residual covariance:
    the VAR, of many more coefficients, predicts its own record better than the model does, and an
    ``Re`` that small makes the model's normalized innovations too large (docs/benchmarks-output-only.md,
    forty-fourth session).
    """
    L = gain_from_markov(A, C, markov)
    Re = prediction_error_covariance(A, C, L, y)
    if Re is not None:
        return L, Re, "var-markov"
    # States driven by the VAR's innovations through the stable A (x+ = A x + L e), the noise
    # covariances of their residuals and the Kalman gain of the filtering Riccati equation,
    # stable by construction (as :mod:`.state_completion`).
    targets = y[var.order :]
    drive = (targets - arx_regressor_product(np.zeros((y.shape[0], 0)), y, var.order, var.theta)) @ L.T
    states = driven_states(A, drive)  # x_0 = 0
    try:
        L, _ = kalman_gain_from_residuals(A, C, states[1:] - states[:-1] @ A.T, targets[:-1] - states[:-1] @ C.T)
    except ValueError as exc:
        raise IdentificationError(f"no stable innovation model: {exc}") from None
    Re = prediction_error_covariance(A, C, L, y)
    if Re is None:
        raise IdentificationError("no stable innovation model: the Kalman gain's predictor is unstable")
    return L, Re, "riccati-residuals"
