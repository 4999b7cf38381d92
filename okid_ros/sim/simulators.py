"""Simulators of the known-truth systems, and the fast state recursion they share.

Arrays follow the project convention: time along axis 0, ``u`` is ``(N, m)``, ``y`` is
``(N, p)``, states are ``(N, n)``.
"""

from __future__ import annotations

from typing import Optional, Union

import numpy as np
import scipy.linalg
import scipy.signal

from okid_ros.core.statespace import InnovationModel
from okid_ros.sim.models import NoisyStateSpace, TrueSystem

__all__ = ["propagate_states", "simulate_innovation", "simulate_noisy", "simulate"]


def _propagate_loop(F: np.ndarray, W: np.ndarray, x0: np.ndarray) -> np.ndarray:
    N, n = W.shape
    X = np.empty((N, n))
    x = np.array(x0, dtype=float)
    Ft = F.T.copy()
    for k in range(N):
        X[k] = x
        x = x @ Ft + W[k]
    return X


def propagate_states(F: np.ndarray, W: np.ndarray, x0: Optional[np.ndarray] = None,
                     max_condition: float = 1e6) -> np.ndarray:
    """States of ``x_{k+1} = F x_k + W_k`` for ``k = 0 .. N-1``.

    Parameters
    ----------
    F : (n, n) transition matrix.
    W : (N, n) forcing, row ``k`` is ``W_k``.
    x0 : (n,) initial state (zeros if ``None``).
    max_condition : if ``F`` is diagonalizable with an eigenvector matrix of condition number
        below this, the recursion runs per eigen-coordinate with ``scipy.signal.lfilter``
        (compiled, about 50x faster than a Python loop); otherwise a plain loop is used.

    Returns
    -------
    X : (N, n) with ``X[0] = x0`` and ``X[k+1] = F X[k] + W[k]``.
    """
    F = np.asarray(F, dtype=float)
    W = np.asarray(W, dtype=float)
    N, n = W.shape
    x0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).reshape(n)
    if N == 0:
        return np.zeros((0, n))
    if n == 0:
        return np.zeros((N, 0))
    lam, V = np.linalg.eig(F)
    if not np.all(np.isfinite(lam)) or np.linalg.cond(V) > max_condition:
        return _propagate_loop(F, W, x0)
    Vinv = np.linalg.inv(V)
    G = W[:-1] @ Vinv.T                     # (N-1, n) modal forcing
    z0 = Vinv @ x0
    Z = np.empty((N, n), dtype=complex)
    Z[0] = z0
    done = np.zeros(n, dtype=bool)
    with np.errstate(over="ignore", invalid="ignore"):
        for i in range(n):
            if done[i]:
                continue
            if N > 1:
                zi = np.array([lam[i] * z0[i]])
                Z[1:, i], _ = scipy.signal.lfilter([1.0], [1.0, -lam[i]], G[:, i], zi=zi)
            done[i] = True
            # LAPACK returns a complex pair of a real matrix as adjacent conjugate eigenvalues
            # with conjugate eigenvectors; with real forcing the coordinates are conjugate too.
            if (lam[i].imag != 0 and i + 1 < n and lam[i + 1] == np.conj(lam[i])
                    and np.array_equal(V[:, i + 1], np.conj(V[:, i]))):
                Z[:, i + 1] = np.conj(Z[:, i])
                done[i + 1] = True
        X = (Z @ V.T).real
    return X


def sqrt_psd(M: np.ndarray) -> np.ndarray:
    """Square root ``T`` with ``T T^T = M`` for a symmetric positive semi-definite ``M``."""
    M = 0.5 * (M + M.T)
    w, V = np.linalg.eigh(M)
    w = np.clip(w, 0.0, None)
    return V * np.sqrt(w)


def _stationary_state_covariance(A: np.ndarray, Qd: np.ndarray) -> Optional[np.ndarray]:
    """Solution ``P`` of ``P = A P A^T + Qd`` or ``None`` if ``A`` is not stable."""
    if A.size == 0 or np.max(np.abs(np.linalg.eigvals(A))) >= 1.0:
        return None
    P = scipy.linalg.solve_discrete_lyapunov(A, Qd)
    return 0.5 * (P + P.T)


def initial_state(A, Qd, x0, rng) -> np.ndarray:
    """The first state: zero, a draw from the stationary distribution of ``x+ = A x + w`` (``Qd``), or ``x0``."""
    n = A.shape[0]
    if x0 is None or (isinstance(x0, str) and x0 == "zero"):
        return np.zeros(n)
    if isinstance(x0, str):
        if x0 != "stationary":
            raise ValueError("x0 must be None, 'zero', 'stationary' or an array")
        P = _stationary_state_covariance(A, Qd)
        if P is None:
            return np.zeros(n)
        return sqrt_psd(P) @ rng.standard_normal(n)
    return np.asarray(x0, dtype=float).reshape(n)


def simulate_innovation(model: InnovationModel, u: np.ndarray, seed: Optional[int] = None,
                        x0: Union[str, np.ndarray, None] = "stationary"
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Simulate an innovation-form model.

    ``x_{k+1} = A x_k + B u_k + A K e_k``, ``y_k = C x_k + D u_k + e_k`` with
    ``e_k ~ N(0, Re)`` drawn from ``numpy.random.default_rng(seed)``.

    Parameters
    ----------
    model : the true model.
    u : (N, m) input.
    seed : noise seed.
    x0 : ``"stationary"`` (default) draws ``x_0 ~ N(0, P)`` with ``P = A P A^T + L Re L^T``,
        i.e. the noise-driven part starts in steady state (the structure was already moving
        before the recording); ``None``/``"zero"`` starts at rest; or an (n,) array.

    Returns
    -------
    y : (N, p) outputs.
    e : (N, p) the innovations actually drawn (the oracle's one-step prediction errors).
    """
    u = np.asarray(u, dtype=float).reshape(len(u), -1)
    if u.shape[1] != model.n_inputs:
        raise ValueError(f"u has {u.shape[1]} columns, model has {model.n_inputs} inputs")
    rng = np.random.default_rng(seed)
    N, p = u.shape[0], model.n_outputs
    Re = model.innovation_covariance
    e = rng.standard_normal((N, p)) @ sqrt_psd(Re).T
    L = model.predictor_gain
    xi = initial_state(model.A, L @ Re @ L.T, x0, rng)
    X = propagate_states(model.A, u @ model.B.T + e @ L.T, xi)
    y = X @ model.C.T + u @ model.D.T + e
    return y, e


def simulate_noisy(system: NoisyStateSpace, u: np.ndarray, seed: Optional[int] = None,
                   x0: Union[str, np.ndarray, None] = "stationary",
                   return_noise_free: bool = False):
    """Simulate a system with process and measurement noise.

    ``x_{k+1} = A x_k + B u_k + w_k``, ``y_k = C x_k + D u_k + v_k``, with ``[w_k; v_k]``
    Gaussian, white, covariance ``[[Q, S], [S^T, R]]``.

    Parameters
    ----------
    system : the true system.
    u : (N, m) input.
    seed : noise seed.
    x0 : ``"stationary"`` (default; ``x_0 ~ N(0, P)``, ``P = A P A^T + Q``), ``None`` or an array.
    return_noise_free : also return the noise-free response ``C x^u_k + D u_k`` from rest.

    Returns
    -------
    y : (N, p) noisy outputs; and ``y_noise_free`` (N, p) if requested.
    """
    u = np.asarray(u, dtype=float).reshape(len(u), -1)
    if u.shape[1] != system.n_inputs:
        raise ValueError(f"u has {u.shape[1]} columns, system has {system.n_inputs} inputs")
    rng = np.random.default_rng(seed)
    N, n, p = u.shape[0], system.n_states, system.n_outputs
    wv = rng.standard_normal((N, n + p)) @ sqrt_psd(system.joint_noise_covariance()).T
    w, v = wv[:, :n], wv[:, n:]
    xi = initial_state(system.A, system.process_noise_covariance, x0, rng)
    X = propagate_states(system.A, u @ system.B.T + w, xi)
    y = X @ system.C.T + u @ system.D.T + v
    if return_noise_free:
        X0 = propagate_states(system.A, u @ system.B.T, None)
        return y, X0 @ system.C.T + u @ system.D.T
    return y


def simulate(system: TrueSystem, u: np.ndarray, seed: Optional[int] = None) -> np.ndarray:
    """Outputs ``y`` (N, p) of either kind of true system (stationary start)."""
    if isinstance(system, InnovationModel):
        return simulate_innovation(system, u, seed)[0]
    return simulate_noisy(system, u, seed)
