"""Known-truth system types and the modal structures the benchmarks are built from.

Two kinds of true system are used to score identified models:

:class:`okid_ros.core.statespace.InnovationModel` -- the paper's innovation form (Chen, Huang &
Juang 1991, Eqs. 30-31), the core's one model type::

    x_{k+1} = A x_k + B u_k + A K e_k,      y_k = C x_k + D u_k + e_k,
    e_k ~ N(0, Re) white  (Re = ``innovation_covariance``)

so ``K`` is the paper's gain and the one-step predictor gain is ``L = A K``.

:class:`NoisyStateSpace` -- separate process and measurement noise::

    x_{k+1} = A x_k + B u_k + w_k,          y_k = C x_k + D u_k + v_k,
    E[w w^T] = Q,  E[v v^T] = R,  E[w v^T] = S   (all at the same k, white in k)

whose innovation form is its steady-state Kalman predictor
(:meth:`NoisyStateSpace.to_innovation_form`).

:func:`modal_structure` builds a continuous-time modal structure discretized by zero-order
hold. Arrays follow the project convention: time along axis 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence, Union

import numpy as np
import scipy.linalg

from okid_ros.core.kalman_gain import riccati_predictor_gain
from okid_ros.core.statespace import InnovationModel, StateSpaceDimensions, as_matrix

__all__ = ["InnovationModel", "NoisyStateSpace", "TrueSystem", "as_noisy_state_space", "modal_structure"]


def as_noisy_state_space(model: InnovationModel) -> "NoisyStateSpace":
    """The process of an innovation model written with correlated process / measurement noise.

    ``w_k = A K e_k``, ``v_k = e_k``, hence ``Q = L Re L^T``, ``R = Re``, ``S = L Re``
    with ``L = A K``. The oracle applied to the result returns ``K`` and ``Re`` again.
    """
    L = model.predictor_gain
    Re = model.innovation_covariance
    return NoisyStateSpace(
        A=model.A, B=model.B, C=model.C, D=model.D,
        process_noise_covariance=L @ Re @ L.T,
        measurement_noise_covariance=Re,
        sample_time_s=model.sample_time_s,
        cross_covariance=L @ Re,
    )


@dataclass
class NoisyStateSpace(StateSpaceDimensions):
    """State space with process noise ``w`` and measurement noise ``v``.

    Equations::

        x_{k+1} = A x_k + B u_k + w_k
        y_k     = C x_k + D u_k + v_k
        E[w_k w_k^T] = Q,  E[v_k v_k^T] = R,  E[w_k v_k^T] = S  (zero if ``None``)

    Attributes
    ----------
    A, B, C, D : system matrices, shapes (n, n), (n, m), (p, n), (p, m).
    process_noise_covariance : (n, n) ``Q``, positive semi-definite.
    measurement_noise_covariance : (p, p) ``R``, positive definite.
    sample_time_s : sample period in seconds.
    cross_covariance : (n, p) ``S`` or ``None`` (uncorrelated). Acceleration outputs of a
        structure driven by disturbance forces have ``S != 0`` (the force reaches the output
        through the feed-through as well as the state).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    process_noise_covariance: np.ndarray
    measurement_noise_covariance: np.ndarray
    sample_time_s: float
    cross_covariance: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        self.A = as_matrix(self.A, "A")
        self.B = as_matrix(self.B, "B")
        self.C = as_matrix(self.C, "C")
        self.D = as_matrix(self.D, "D")
        self.process_noise_covariance = as_matrix(self.process_noise_covariance, "Q")
        self.measurement_noise_covariance = as_matrix(self.measurement_noise_covariance, "R")
        n, m, p = self.n_states, self.n_inputs, self.n_outputs
        if self.cross_covariance is None:
            self.cross_covariance = np.zeros((n, p))
        self.cross_covariance = as_matrix(self.cross_covariance, "S")
        self._check_shapes((
            ("A", self.A, (n, n)),
            ("B", self.B, (n, m)),
            ("C", self.C, (p, n)),
            ("D", self.D, (p, m)),
            ("Q", self.process_noise_covariance, (n, n)),
            ("R", self.measurement_noise_covariance, (p, p)),
            ("S", self.cross_covariance, (n, p)),
        ))
        self.sample_time_s = float(self.sample_time_s)

    def joint_noise_covariance(self) -> np.ndarray:
        """``[[Q, S], [S^T, R]]``, shape (n + p, n + p): covariance of ``[w_k; v_k]``."""
        Q, R, S = self.process_noise_covariance, self.measurement_noise_covariance, self.cross_covariance
        return np.block([[Q, S], [S.T, R]])

    def to_innovation_form(self) -> InnovationModel:
        """Steady-state Kalman predictor of this system as an :class:`InnovationModel`.

        The predictor gain ``L`` and ``innovation_covariance = C P C^T + R`` come from the
        filtering Riccati equation (:func:`okid_ros.core.kalman_gain.riccati_predictor_gain`).
        ``K`` is in the paper's convention (predictor gain ``A K``): the Kalman filter gain
        ``P C^T Re^{-1}`` when ``S = 0``, otherwise ``A^{-1} L`` (A is invertible for any
        ZOH-discretized system).
        """
        A, C, S = self.A, self.C, self.cross_covariance
        L, Re, P = riccati_predictor_gain(A, C, self.process_noise_covariance, self.measurement_noise_covariance, S)
        if np.allclose(S, 0.0):
            K = np.linalg.solve(Re, (P @ C.T).T).T
        else:
            K = np.linalg.solve(A, L)
        return InnovationModel(A, self.B, C, self.D, K, Re, self.sample_time_s)


TrueSystem = Union[InnovationModel, NoisyStateSpace]


def zero_order_hold(Ac: np.ndarray, Bc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of ``dx/dt = Ac x + Bc u`` sampled every ``dt`` seconds with the input held constant."""
    n, m = Bc.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = Ac
    M[:n, n:] = Bc
    E = scipy.linalg.expm(M * dt)
    return E[:n, :n], E[:n, n:]


def modal_structure(frequencies_hz: Sequence[float], damping_ratios: Sequence[float] | float,
                    n_inputs: int, n_outputs: int, sample_time_s: float, *, seed: int = 0,
                    output: str = "acceleration", disturbance_std: float = 0.3,
                    n_disturbances: Optional[int] = None,
                    measurement_noise_ratio: float = 0.05) -> NoisyStateSpace:
    """Continuous-time modal structure, zero-order-hold discretized, with noise.

    Mode ``i`` (natural frequency ``w_i = 2 pi f_i`` rad/s, damping ratio ``z_i``, modal mass 1)::

        q_i'' + 2 z_i w_i q_i' + w_i^2 q_i = phi_in_i^T u(t) + phi_w_i^T d(t)

    State ``x = [q_1, q_1', q_2, q_2', ...]`` (n = 2 * n_modes).  Outputs at ``n_outputs``
    sensors with mode-shape matrix ``Phi_out`` (p, n_modes)::

        displacement:  y = Phi_out q                                   (D = 0)
        acceleration:  y = Phi_out q'' = Phi_out (-W^2 q - 2 Z W q' + Phi_in u + Phi_w d)
                       (D = Phi_out Phi_in != 0, as for accelerometers)

    ``Phi_in`` (n_modes, m), ``Phi_out`` (p, n_modes), ``Phi_w`` (n_modes, n_disturbances)
    are standard normal, drawn from ``default_rng(seed)`` (seeded, reproducible).  Inputs
    ``u`` and disturbance forces ``d`` are held constant over a sample (zero-order hold), so
    ``A = expm(Ac dt)`` and ``[B, Bw] = int_0^dt expm(Ac s) ds [Bc, Bw_c]``; the discrete
    poles are exactly ``exp(s_i dt)`` with ``s_i = -z_i w_i +- j w_i sqrt(1 - z_i^2)``.

    Noise:

    * process noise ``w_k = Bw d_k``, ``d_k ~ N(0, disturbance_std^2 I)`` (in units of the
      input, whose reference standard deviation is 1): ``Q = Bw Bw^T disturbance_std^2``;
      for acceleration outputs the disturbance also reaches ``y`` through ``Dw = Phi_out Phi_w``,
      giving correlated noise ``S = Bw Dw^T disturbance_std^2``;
    * measurement noise ``N(0, diag(r_j^2))`` with ``r_j = measurement_noise_ratio`` times the
      standard deviation of output ``j`` of the noise-free system driven by unit white input
      (from a Lyapunov equation).

    Parameters
    ----------
    frequencies_hz : natural frequencies in Hz (keep them well below ``0.5 / sample_time_s``).
    damping_ratios : damping ratios as fractions (scalar or one per mode).
    n_inputs, n_outputs : m and p.
    sample_time_s : sample period in seconds.
    seed : seed of the mode shapes.
    output : ``"acceleration"`` or ``"displacement"``.
    disturbance_std : standard deviation of the disturbance forces.
    n_disturbances : number of independent disturbance forces (default: number of modes).
    measurement_noise_ratio : see above.

    Returns
    -------
    NoisyStateSpace with n = 2 * len(frequencies_hz).
    """
    f = np.asarray(frequencies_hz, dtype=float).ravel()
    nm = f.size
    z = np.broadcast_to(np.asarray(damping_ratios, dtype=float), (nm,)).copy()
    nyq = 0.5 / sample_time_s
    if np.any(f <= 0) or np.any(f >= nyq):
        raise ValueError(f"frequencies must lie in (0, {nyq}) Hz")
    if np.any(z <= 0) or np.any(z >= 1):
        raise ValueError("damping ratios must be fractions in (0, 1)")
    if output not in ("acceleration", "displacement"):
        raise ValueError("output must be 'acceleration' or 'displacement'")
    rng = np.random.default_rng(seed)
    nd = nm if n_disturbances is None else int(n_disturbances)
    phi_in = rng.standard_normal((nm, n_inputs))
    phi_out = rng.standard_normal((n_outputs, nm))
    phi_w = rng.standard_normal((nm, nd))
    Ac, Bc, Bwc, Cq, D, Dw = _continuous_modal_matrices(2 * np.pi * f, z, phi_in, phi_out, phi_w, output)
    A, BB = zero_order_hold(Ac, np.hstack([Bc, Bwc]), sample_time_s)
    B, Bw = BB[:, :n_inputs], BB[:, n_inputs:]
    s2 = float(disturbance_std) ** 2
    Q = s2 * Bw @ Bw.T
    S = s2 * Bw @ Dw.T
    Rw = s2 * Dw @ Dw.T
    P = scipy.linalg.solve_discrete_lyapunov(A, B @ B.T)
    out_var = np.diag(Cq @ P @ Cq.T + D @ D.T)
    R = Rw + np.diag((measurement_noise_ratio ** 2) * out_var)
    return NoisyStateSpace(A, B, Cq, D, Q, R, sample_time_s, cross_covariance=S)


def _continuous_modal_matrices(w: np.ndarray, z: np.ndarray, phi_in: np.ndarray, phi_out: np.ndarray,
                               phi_w: np.ndarray, output: str) -> tuple[np.ndarray, ...]:
    """``Ac, Bc, Bw_c, C, D, Dw`` of the modal structure of :func:`modal_structure` (continuous time)."""
    nm, n_inputs = phi_in.shape
    n_outputs, nd = phi_out.shape[0], phi_w.shape[1]
    n = 2 * nm
    Ac = np.zeros((n, n))
    Bc = np.zeros((n, n_inputs))
    Bwc = np.zeros((n, nd))
    Cq = np.zeros((n_outputs, n))
    for i in range(nm):
        Ac[2 * i:2 * i + 2, 2 * i:2 * i + 2] = [[0.0, 1.0], [-w[i] ** 2, -2 * z[i] * w[i]]]
        Bc[2 * i + 1] = phi_in[i]
        Bwc[2 * i + 1] = phi_w[i]
    if output == "displacement":
        for i in range(nm):
            Cq[:, 2 * i] = phi_out[:, i]
        return Ac, Bc, Bwc, Cq, np.zeros((n_outputs, n_inputs)), np.zeros((n_outputs, nd))
    for i in range(nm):
        Cq[:, 2 * i] = -phi_out[:, i] * w[i] ** 2
        Cq[:, 2 * i + 1] = -phi_out[:, i] * 2 * z[i] * w[i]
    return Ac, Bc, Bwc, Cq, phi_out @ phi_in, phi_out @ phi_w
