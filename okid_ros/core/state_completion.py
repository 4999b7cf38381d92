"""Completion from a state sequence: a stable ``A`` and the Riccati gain (many outputs).

Given state estimates ``xhat_k`` (N, n) of consecutive samples (from the weighted ERA through
the ARX predictor, ``xhat_k = S^-1/2 U^T H(0) z_k``, or from a model's own Kalman predictor),
the innovation model follows from regressions, as in subspace methods:

1. ``y_k = C xhat_k + D u_k + v_k`` by least squares gives ``C``, ``D`` and residuals ``v_k``;
2. ``xhat_{k+1} = A xhat_k + B u_k + L v_k + w'_k`` gives ``A`` and ``B`` (``v`` in the
   regression removes the bias that the innovation term would put on ``A``);
3. eigenvalues of ``A`` on or outside the unit circle are moved inside (modulus
   ``min(1 / |lambda|, max_radius)``, angle kept, so the frequency stays) and ``B`` refitted:
   on measured data a realization of high order carries such poles, which are not structural
   modes and would make the model useless for simulation and the estimator;
4. ``Q``, ``R``, ``S`` are the covariances of ``w_k = xhat_{k+1} - A xhat_k - B u_k`` and
   ``v_k``, and the gain is the Kalman predictor gain of the discrete Riccati equation
   (:mod:`okid_ros.core.kalman_gain`): the predictor ``A - A K C`` is stable by construction.
   (The gain ``L`` of step 2 is not: on the steel subframe record its predictor had spectral
   radius 1.03 and the one-step prediction diverged.)

Then :func:`complete_from_states` re-estimates the state sequence with the completed model's
own Kalman predictor and repeats the regressions, keeping a pass only when it lowers the
one-step prediction error. On the steel subframe (28 outputs, n = 80) one pass took the
held-out one-step prediction error from 1.1e-3 to 2.8e-4 of the output variance
(``docs/method.md``).
"""

from __future__ import annotations

import numpy as np
from scipy import linalg

from okid_ros.core.kalman_gain import kalman_gain_from_covariances
from okid_ros.core.refit import PredictorFit, gain_from_predictor, innovation_covariance
from okid_ros.core.stable_matrix import stabilize_state_matrix, stabilize_with_eigen
from okid_ros.core.state_gram import StateGram, fewest_state_samples
from okid_ros.core.statespace import InnovationModel, free_parameters, predictor_states

__all__ = [
    "stabilize_state_matrix",
    "stabilize_with_eigen",
    "regress_state_equations",
    "fit_from_states",
    "complete_from_states",
    "screen_from_states",
]


def _lstsq(regressor: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Least-squares coefficients (columns of ``regressor`` -> ``target``), transposed.

    By the column-scaled normal equations (a Cholesky solve, several times faster than QR for
    these tall, well-conditioned regressions), with a whisper of ridge for dependent columns;
    QR when the factorization fails.
    """
    scale = np.sqrt(np.maximum(np.einsum("ij,ij->j", regressor, regressor), np.finfo(float).tiny))
    scaled = regressor / scale
    gram = scaled.T @ scaled
    gram[np.diag_indices_from(gram)] += 1e-10
    try:
        coef = linalg.cho_solve(linalg.cho_factor(gram, check_finite=False), scaled.T @ target, check_finite=False)
    except linalg.LinAlgError:
        coef = linalg.lstsq(scaled, target, lapack_driver="gelsy")[0]
    return (coef / scale[:, None]).T


def regress_state_equations(
    states: np.ndarray, u: np.ndarray, y: np.ndarray, *, max_radius: float = 0.9999
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Steps 1-3 of the module docstring: ``(A, B, C, D)`` with ``A`` stable, and residuals.

    Returns
    -------
    A (n, n), B (n, m), C (p, n), D (p, m); w : (N - 1, n) state-equation residuals;
    v : (N, p) output-equation residuals.
    """
    n_samples, n = states.shape
    m, p = u.shape[1], y.shape[1]
    if n_samples < fewest_state_samples(n, m, p):
        raise ValueError(f"{n_samples} samples are too few to fit a {n}-state model")
    if not np.all(np.isfinite(states)):
        raise ValueError("the state sequence is not finite")
    xu = np.hstack([states, u])
    cd = _lstsq(xu, y)
    C, D = cd[:, :n], cd[:, n:]
    v = y - xu @ cd.T
    x_next, x_now, u_now, v_now = states[1:], states[:-1], u[:-1], v[:-1]
    abl = _lstsq(np.hstack([x_now, u_now, v_now]), x_next)
    A, B = abl[:, :n], abl[:, n : n + m]
    A, n_moved = stabilize_state_matrix(A, max_radius=max_radius)
    if n_moved:
        bl = _lstsq(np.hstack([u_now, v_now]), x_next - x_now @ A.T)
        B = bl[:, :m]
    w = x_next - x_now @ A.T - u_now @ B.T
    return A, B, C, D, w, v


def fit_from_states(
    states: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    *,
    max_radius: float = 0.9999,
) -> InnovationModel:
    """Innovation model with a stable ``A`` and the Riccati gain from a state sequence.

    Parameters
    ----------
    states : (N, n) state estimates of the consecutive samples ``u`` (N, m), ``y`` (N, p).
    max_radius : largest modulus of a moved eigenvalue (:func:`stabilize_state_matrix`).

    Returns
    -------
    InnovationModel (no sample time); its ``innovation_covariance`` is the Riccati one.

    Raises
    ------
    ValueError
        Too few samples, non-finite states, or no stabilizing Riccati solution.
    """
    # The regressions and residual covariances from one Gram of [u, x, y, x_next] (a third of the
    # flops of regressing the data twice, same models to rounding: test_core_state_completion).
    regression = StateGram.of_states(states, u, y).regress(states.shape[1], max_radius=max_radius, covariances=True)
    A, C = regression.A, regression.C
    L, Re = kalman_gain_from_covariances(A, C, *regression.noise_covariances())
    return InnovationModel(A, regression.B, C, regression.D, gain_from_predictor(A, L), Re)


def _evaluate(model: InnovationModel, u: np.ndarray, y: np.ndarray, burn_in: int
              ) -> tuple[PredictorFit | None, np.ndarray]:
    """The model's one-step prediction errors on the record (after ``burn_in``) as a fit.

    Also returns its predicted states (N, n), which the next re-estimation pass starts from.
    """
    states, innovations = predictor_states(model, u, y)
    used = innovations[burn_in:]
    if not np.all(np.isfinite(used)):
        return None, states
    model.innovation_covariance = innovation_covariance(used)
    n, p, m = model.n_states, model.n_outputs, model.n_inputs
    return PredictorFit(model, np.zeros(n), used, free_parameters(n, p, m)), states


def complete_from_states(
    states: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    *,
    passes: int = 2,
    burn_in: int = 0,
    max_radius: float = 0.9999,
    first: InnovationModel | None = None,
) -> PredictorFit:
    """:func:`fit_from_states`, then re-estimate the states with the model's own predictor.

    Parameters
    ----------
    states : (N, n) initial state estimates of the consecutive samples ``u`` (N, m), ``y`` (N, p).
    passes : at most this many re-estimations; a pass is kept only if it lowers
        ``log det`` of the one-step prediction-error covariance on the record.
    burn_in : samples at the start left out of the comparison and of the regressions of a
        re-estimation (the predictor starts from zero there).
    max_radius : see :func:`fit_from_states`.
    first : the model of :func:`fit_from_states` on ``states`` when already known (from the
        window's Gram, :mod:`.state_gram`); ``states`` are then not regressed again.

    Returns
    -------
    PredictorFit with the innovation covariance of the model's own one-step predictions on
    the record (after ``burn_in``) and ``x0 = 0`` (the predictor starts from zero).

    Raises
    ------
    ValueError
        As :func:`fit_from_states`, or if the first model's predictions are not finite.
    """
    burn_in = int(min(max(burn_in, 0), u.shape[0] // 4))
    first = fit_from_states(states, u, y, max_radius=max_radius) if first is None else first
    best, own_states = _evaluate(first, u, y, burn_in)
    if best is None:
        raise ValueError("the completed predictor does not give finite predictions")
    best_cost = np.linalg.slogdet(best.model.innovation_covariance)[1]
    for _ in range(passes):
        try:
            candidate = fit_from_states(
                own_states[burn_in:], u[burn_in:], y[burn_in:], max_radius=max_radius
            )
        except (ValueError, np.linalg.LinAlgError):
            break
        fit, candidate_states = _evaluate(candidate, u, y, burn_in)
        if fit is None:
            break
        cost = np.linalg.slogdet(fit.model.innovation_covariance)[1]
        if not cost < best_cost - 1e-9 * abs(best_cost):
            break
        best, best_cost, own_states = fit, cost, candidate_states
    return best


def screen_from_states(
    states: np.ndarray, u: np.ndarray, y: np.ndarray, *, max_radius: float = 0.9999
) -> PredictorFit:
    """A cheap fit for comparing model orders: the regressions only, no gain.

    The output-equation residuals stand for the innovations (what the old state completion
    used for BIC), so no Riccati equation and no predictor run is needed per order; the
    model's ``K`` is zero and its poles (``A``) are those of :func:`fit_from_states`.
    """
    A, B, C, D, _, v = regress_state_equations(states, u, y, max_radius=max_radius)
    n, p, m = A.shape[0], C.shape[0], B.shape[1]
    model = InnovationModel(A, B, C, D, np.zeros((n, p)), innovation_covariance(v))
    return PredictorFit(model, states[0].copy(), v, free_parameters(n, p, m))
