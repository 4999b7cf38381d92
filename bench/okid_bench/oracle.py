"""Oracle steady-state Kalman predictor of a known system, and the one-step predictor.

For ``x_{k+1} = A x_k + B u_k + w_k``, ``y_k = C x_k + D u_k + v_k`` with
``cov([w; v]) = [[Q, S], [S^T, R]]``, the steady-state a-priori error covariance ``P`` solves
the filtering Riccati equation::

    P = A P A^T + Q - (A P C^T + S) (C P C^T + R)^{-1} (A P C^T + S)^T

(``scipy.linalg.solve_discrete_are(A^T, C^T, Q, R, s=S)``).  The optimal one-step predictor is::

    x_{k+1|k} = A x_{k|k-1} + B u_k + L e_k,    e_k = y_k - C x_{k|k-1} - D u_k
    L  = (A P C^T + S) Re^{-1},                 Re = C P C^T + R

The paper writes the predictor gain as ``A K`` (Eqs. 30-31).  With ``S = 0``,
``K = P C^T Re^{-1}`` is the Kalman *filter* gain.  With ``S != 0`` there is no filter-gain
reading and ``K = A^{-1} L`` is used (A is invertible for any ZOH-discretized system).
"""

from __future__ import annotations

from typing import Optional, Union

import numpy as np

from okid_ros.core.kalman_gain import riccati_covariance, riccati_predictor_gain
from okid_ros.core.statespace import InnovationModel
from okid_ros.sim.models import NoisyStateSpace
from okid_ros.sim.simulators import propagate_states

__all__ = [
    "kalman_predictor",
    "predictor_gain",
    "riccati_covariance",
    "one_step_predictions",
]


def predictor_gain(A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray,
                   S: Optional[np.ndarray] = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steady-state predictor gain ``(L, Re, P)`` (:func:`okid_ros.core.kalman_gain.riccati_predictor_gain`)."""
    return riccati_predictor_gain(A, C, Q, R, S)


def kalman_predictor(system: Union[InnovationModel, NoisyStateSpace]
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The oracle gain in the paper's convention and the innovation covariance.

    Parameters
    ----------
    system : a known system.  For an :class:`InnovationModel` the truth is given and is
        returned as is.

    Returns
    -------
    K : (n, p) the paper's gain, predictor gain ``A K``.  ``K = P C^T Re^{-1}`` (the filter
        gain) when ``S = 0``; ``K = A^{-1} L`` in general.
    Re : (p, p) innovation covariance ``C P C^T + R``.
    """
    model = system if isinstance(system, InnovationModel) else system.to_innovation_form()
    return model.K.copy(), model.innovation_covariance.copy()


def one_step_predictions(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray,
                         K: Optional[np.ndarray], u: np.ndarray, y: np.ndarray,
                         x0: Optional[np.ndarray] = None,
                         predictor_gain: Optional[np.ndarray] = None
                         ) -> tuple[np.ndarray, np.ndarray]:
    """One-step-ahead predictions of an innovation-form model on data.

    Runs the predictor (paper Eqs. 30-31, steady-state gain)::

        x_{k+1} = (A - L C) x_k + (B - L D) u_k + L y_k,    L = A K
        y_hat_k = C x_k + D u_k,                            e_k = y_k - y_hat_k

    from ``x_0 = x0`` (zeros by default; discard a burn-in when scoring).

    Parameters
    ----------
    A (n, n), B (n, m), C (p, n), D (p, m) : the model.
    K : (n, p) the paper's gain, or ``None`` when ``predictor_gain`` is given.  ``K = None``
        and no ``predictor_gain`` gives the pure simulation predictor (``L = 0``).
    u : (N, m) inputs; y : (N, p) outputs.
    x0 : (n,) initial predictor state.
    predictor_gain : (n, p) ``L`` directly (use it for models identified in predictor form,
        e.g. SIPPY's or nfoursid's ``K``, to avoid forming ``A^{-1} L``).

    Returns
    -------
    y_hat : (N, p) predictions; e : (N, p) prediction errors ``y - y_hat``.
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    C = np.asarray(C, dtype=float).reshape(-1, A.shape[0])
    D = np.asarray(D, dtype=float).reshape(C.shape[0], B.shape[1])
    u = np.asarray(u, dtype=float).reshape(len(u), -1)
    y = np.asarray(y, dtype=float).reshape(len(y), -1)
    if predictor_gain is not None:
        L = np.asarray(predictor_gain, dtype=float)
    elif K is not None:
        L = A @ np.asarray(K, dtype=float)
    else:
        L = np.zeros((A.shape[0], C.shape[0]))
    F = A - L @ C
    W = u @ (B - L @ D).T + y @ L.T
    with np.errstate(over="ignore", invalid="ignore"):
        X = propagate_states(F, W, x0)
        y_hat = X @ C.T + u @ D.T
    return y_hat, y - y_hat
