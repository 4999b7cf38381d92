"""MIMO ARX least squares with regularization (paper Eq. 23).

The fit minimizes, over the coefficient matrix ``Theta`` (d, p) of the observer-form regressor
of :mod:`okid_ros.core.regressors`,

    sum_k || y_k - Theta^T phi_k ||^2 + penalty * trace(Theta^T P^{-1} Theta),

i.e. ``(R + penalty P^{-1}) Theta = r`` with the normal equations ``R = Phi^T Phi`` (d, d) and
``r = Phi^T Y`` (d, p). The paper uses ``penalty = 0``; with inputs that leave part of the band
unexcited that solution is junk there and the rest of the chain amplifies it
(``docs/method.md``). ``P`` is a prior covariance of the coefficients:

- ``"ridge"``: diagonal, each regressor column scaled by its mean square (so outputs and inputs
  of different units are penalized alike);
- ``"tc"``: the tuned/correlated kernel ``P[(i, c), (j, c)] = alpha^max(i, j) / ms_c`` over lags
  ``i, j`` of the same channel ``c`` (Chen, Ohlsson & Ljung 2012), which encodes that the
  coefficients of a stable predictor decay with the lag.

The penalty (and ``alpha``) are chosen by generalized cross-validation, computed from the
normal equations alone so that the recursive window, which keeps only ``R``, ``r`` and
``Y^T Y``, can choose them the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from okid_ros.core.arx_gram import arx_normal_equations
from okid_ros.core.arx_order import ArxOrderChoice, longest_arx_order, select_arx_order

# The solver and the order choice live in their own modules; their names stay importable from here.
from okid_ros.core.channels import group_scales
from okid_ros.core.least_squares import (
    NormalEquations,
    center_normal_equations,
    channel_mean_square,
    normal_equations,
    prior_precision,
    residual_covariance,
    scaled_condition_number,
    solve_fixed_penalty,
    solve_normal_equations,
)
from okid_ros.core.regressors import check_io_arrays, regressor_length, valid_regressor_rows

__all__ = [
    "ArxFit",
    "NormalEquations",
    "fit_arx",
    "normal_equations",
    "prior_precision",
    "solve_normal_equations",
    "solve_fixed_penalty",
    "minimum_samples",
    "ArxOrderChoice",
    "center_normal_equations",
    "longest_arx_order",
    "select_arx_order",
    "check_regularization",
    "channel_mean_square",
    "residual_covariance",
    "scaled_condition_number",
]

REGULARIZATIONS = ("none", "ridge", "tc")
TC_DECAYS = (0.8, 0.9, 0.95, 0.97, 0.98, 0.99, 0.995)


def check_regularization(regularization: str) -> None:
    """ValueError unless ``regularization`` is one of :data:`REGULARIZATIONS`."""
    if not isinstance(regularization, str) or regularization not in REGULARIZATIONS:
        raise ValueError(f"regularization must be one of {REGULARIZATIONS}, got {regularization!r}")


@dataclass
class ArxFit:
    """An identified ARX model in the observer-form layout.

    Attributes
    ----------
    theta : (d, p) coefficients, ``y_k^T = phi_k^T theta``.
    order : ARX order q.
    n_inputs, n_outputs : m and p.
    residual_covariance : (p, p) one-step prediction-error covariance of the fit.
    condition_number : condition number of the column-scaled ``Phi^T Phi`` (before regularization).
    regularization : "none", "ridge" or "tc".
    penalty : the regularization weight used (0 for "none").
    decay : the TC kernel decay alpha (None unless "tc").
    effective_parameters : trace of the hat matrix (degrees of freedom used, per output).
    n_rows : number of regressor rows in the fit.
    """

    theta: np.ndarray
    order: int
    n_inputs: int
    n_outputs: int
    residual_covariance: np.ndarray
    condition_number: float
    regularization: str = "none"
    penalty: float = 0.0
    decay: float | None = None
    effective_parameters: float = 0.0
    n_rows: int = 0
    extras: dict = field(default_factory=dict)

    @property
    def D(self) -> np.ndarray:
        """(p, m) direct feedthrough ``B_0``."""
        return self.theta[: self.n_inputs].T.copy()

    @property
    def observer_markov(self) -> np.ndarray:
        """(q, p, p + m) the lag blocks ``[A_i, B_i]`` (ARX output and input coefficients)."""
        m, p, q = self.n_inputs, self.n_outputs, self.order
        return self.theta[m:].reshape(q, p + m, p).transpose(0, 2, 1).copy()

    @property
    def output_coefficients(self) -> np.ndarray:
        """(q, p, p) ``A_i`` of paper Eq. (23)."""
        return self.observer_markov[:, :, : self.n_outputs]

    @property
    def input_coefficients(self) -> np.ndarray:
        """(q, p, m) ``B_i`` of paper Eq. (23), i >= 1."""
        return self.observer_markov[:, :, self.n_outputs :]


def minimum_samples(order: int, n_outputs: int, n_inputs: int) -> int:
    """Fewest samples for a determined unregularized fit: ``q + d`` (d rows after q lags)."""
    return order + regressor_length(order, n_outputs, n_inputs)


def fit_arx(
    u: np.ndarray,
    y: np.ndarray,
    order: int,
    regularization: str = "ridge",
    penalty: float | str = "gcv",
    decay: float | str = "gcv",
    *,
    valid: np.ndarray | None = None,
    center: bool = False,
) -> ArxFit:
    """Fit a MIMO ARX model of order q by regularized least squares (paper Eq. 23).

    Parameters
    ----------
    u : (N, m) inputs; y : (N, p) outputs.
    order : q, the number of past samples of y and u in each regressor.
    regularization : "none" (the paper), "ridge" or "tc" (see module docstring).
    penalty : a fixed penalty, or "gcv" to choose it by generalized cross-validation.
    decay : TC kernel alpha, or "gcv" to choose it from ``TC_DECAYS`` with the penalty.
    valid : (N,) bool, optional mask of trustworthy samples (gaps break the regressors).
    center : fit an intercept too (signals with offsets; :func:`center_normal_equations`).

    Returns
    -------
    ArxFit

    Raises
    ------
    ValueError
        On bad shapes, non-finite data, or fewer samples than the order needs.
    """
    u, y = check_io_arrays(u, y)
    # Inputs and outputs divided by a power of two each: no overflow of the squares of values
    # near 1e+-150, and exactly the fit of the record itself, restored (channels.group_scales).
    scales = group_scales(u, y)
    u, y = scales.scale(u, y)
    check_regularization(regularization)
    if order < 1:
        raise ValueError(f"ARX order must be >= 1, got {order}")
    m, p = u.shape[1], y.shape[1]
    n_rows = valid_regressor_rows(u.shape[0], order, valid).size
    d = regressor_length(order, p, m)
    needed = minimum_samples(order, p, m)
    if regularization == "none" and n_rows < d:
        raise ValueError(
            f"too few samples for ARX order {order}: {u.shape[0]} given, at least {needed} needed "
            f"(d = {d} coefficients per output)"
        )
    if n_rows < max(order + 1, 2 * (p + m)):
        raise ValueError(
            f"too few samples for ARX order {order}: {u.shape[0]} given, at least {needed} recommended"
        )
    normal = arx_normal_equations(u, y, order, valid)
    return scales.restore_arx(fit_from_normal_equations(normal, order, p, m, regularization, penalty, decay=decay,
                                                        center=center))


def fit_from_normal_equations(
    normal: NormalEquations,
    order: int,
    n_outputs: int,
    n_inputs: int,
    regularization: str = "ridge",
    penalty: float | str = "gcv",
    *,
    decay: float | str = "gcv",
    center: bool = False,
) -> ArxFit:
    """The ARX solution of a window given only its normal equations (see :func:`fit_arx`).

    ``center=True`` fits an intercept (offsets of inputs and outputs) along with the
    coefficients (:func:`center_normal_equations`).
    """
    check_regularization(regularization)  # any other name was solved as "tc" in silence
    p, m = n_outputs, n_inputs
    if center:
        normal = center_normal_equations(normal)
    ms = channel_mean_square(normal, p, m, order)
    cond = scaled_condition_number(normal.R)
    chosen_decay: float | None = None
    if regularization == "none":
        theta, lam, dof, _ = solve_normal_equations(normal, prior_precision(order, p, m, ms, "ridge"), 0.0)
    elif regularization == "ridge":
        theta, lam, dof, _ = solve_normal_equations(normal, prior_precision(order, p, m, ms, "ridge"), penalty)
    else:
        decays = TC_DECAYS if decay == "gcv" else (float(decay),)
        best = None
        for alpha in decays:
            sol = solve_normal_equations(normal, prior_precision(order, p, m, ms, "tc", alpha), penalty)
            if best is None or sol[3] < best[0][3]:
                best = (sol, alpha)
        (theta, lam, dof, _), chosen_decay = best
    return ArxFit(
        theta=theta,
        order=order,
        n_inputs=m,
        n_outputs=p,
        residual_covariance=residual_covariance(normal, theta, dof),
        condition_number=cond,
        regularization=regularization,
        penalty=lam,
        decay=chosen_decay,
        effective_parameters=dof,
        n_rows=normal.n_rows,
    )


