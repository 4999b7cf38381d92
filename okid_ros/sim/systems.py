"""Known-truth linear systems, input generators and simulators.

Two kinds of true system are used to score identified models:

``InnovationModel`` -- the paper's innovation form (Chen, Huang & Juang 1991, Eqs. 30-31)::

    x_{k+1} = A x_k + B u_k + A K e_k,      y_k = C x_k + D u_k + e_k,
    e_k ~ N(0, Re) white  (Re = ``innovation_covariance``)

so ``K`` is the paper's gain and the one-step predictor gain is ``L = A K``.

``NoisyStateSpace`` -- separate process and measurement noise::

    x_{k+1} = A x_k + B u_k + w_k,          y_k = C x_k + D u_k + v_k,
    E[w w^T] = Q,  E[v v^T] = R,  E[w v^T] = S   (all at the same k, white in k)

Its innovation form is computed by the oracle steady-state Kalman predictor
(:func:`okid_ros.sim.oracle.kalman_predictor`).

Arrays follow the project convention: time along axis 0, ``u`` is ``(N, m)``,
``y`` is ``(N, p)``, states are ``(N, n)``.

Also here: a builder for continuous-time modal structures discretized by zero-order hold
(:func:`modal_structure`), white and Butterworth low-pass input generators, simulators, and
the named benchmark cases (:func:`benchmark_cases`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence, Union

import numpy as np
import scipy.linalg
import scipy.signal

__all__ = [
    "InnovationModel",
    "NoisyStateSpace",
    "BenchmarkCase",
    "modal_structure",
    "white_input",
    "lowpass_input",
    "simulate_innovation",
    "simulate_noisy",
    "simulate",
    "propagate_states",
    "suggested_arx_order",
    "benchmark_cases",
    "benchmark_case",
]


# ---------------------------------------------------------------------------
# System containers
# ---------------------------------------------------------------------------


def _as2d(x, name: str) -> np.ndarray:
    a = np.atleast_2d(np.asarray(x, dtype=float))
    if a.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array, got shape {a.shape}")
    return a


class _Dimensions:
    """Dimensions of a model with ``A`` (n, n), ``B`` (n, m), ``C`` (p, n), and a shape check."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray

    @property
    def n_states(self) -> int:
        return self.A.shape[0]

    @property
    def n_inputs(self) -> int:
        return self.B.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.C.shape[0]

    def _check_shapes(self, arrays: tuple[tuple[str, np.ndarray, tuple[int, int]], ...]) -> None:
        for name, arr, shape in arrays:
            if arr.shape != shape:
                raise ValueError(f"{name} has shape {arr.shape}, expected {shape}")


@dataclass
class InnovationModel(_Dimensions):
    """Innovation-form model in the paper's convention (predictor gain ``A @ K``).

    Equations::

        x_{k+1} = A x_k + B u_k + A K e_k
        y_k     = C x_k + D u_k + e_k,        e_k ~ N(0, innovation_covariance)

    Attributes
    ----------
    A : (n, n) state matrix.
    B : (n, m) input matrix.
    C : (p, n) output matrix.
    D : (p, m) direct feed-through.
    K : (n, p) the paper's Kalman filter gain (predictor gain is ``A @ K``).
    innovation_covariance : (p, p) covariance ``Re`` of ``e_k``.
    sample_time_s : sample period in seconds.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray
    innovation_covariance: np.ndarray
    sample_time_s: float

    def __post_init__(self) -> None:
        self.A = _as2d(self.A, "A")
        self.B = _as2d(self.B, "B")
        self.C = _as2d(self.C, "C")
        self.D = _as2d(self.D, "D")
        self.K = _as2d(self.K, "K")
        self.innovation_covariance = _as2d(self.innovation_covariance, "innovation_covariance")
        n, m, p = self.n_states, self.n_inputs, self.n_outputs
        self._check_shapes((
            ("A", self.A, (n, n)),
            ("B", self.B, (n, m)),
            ("C", self.C, (p, n)),
            ("D", self.D, (p, m)),
            ("K", self.K, (n, p)),
            ("innovation_covariance", self.innovation_covariance, (p, p)),
        ))
        self.sample_time_s = float(self.sample_time_s)


    @property
    def predictor_gain(self) -> np.ndarray:
        """``L = A K``, shape (n, p): the gain of ``x_{k+1|k} = A x + B u + L e``."""
        return self.A @ self.K

    def to_innovation_form(self) -> "InnovationModel":
        """Return ``self`` (already in innovation form)."""
        return self

    def to_noisy_state_space(self) -> "NoisyStateSpace":
        """The same process written with correlated process / measurement noise.

        ``w_k = A K e_k``, ``v_k = e_k``, hence ``Q = L Re L^T``, ``R = Re``, ``S = L Re``
        with ``L = A K``. The oracle applied to the result returns ``K`` and ``Re`` again.
        """
        L = self.predictor_gain
        Re = self.innovation_covariance
        return NoisyStateSpace(
            A=self.A, B=self.B, C=self.C, D=self.D,
            process_noise_covariance=L @ Re @ L.T,
            measurement_noise_covariance=Re,
            sample_time_s=self.sample_time_s,
            cross_covariance=L @ Re,
        )


@dataclass
class NoisyStateSpace(_Dimensions):
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
        self.A = _as2d(self.A, "A")
        self.B = _as2d(self.B, "B")
        self.C = _as2d(self.C, "C")
        self.D = _as2d(self.D, "D")
        self.process_noise_covariance = _as2d(self.process_noise_covariance, "Q")
        self.measurement_noise_covariance = _as2d(self.measurement_noise_covariance, "R")
        n, m, p = self.n_states, self.n_inputs, self.n_outputs
        if self.cross_covariance is None:
            self.cross_covariance = np.zeros((n, p))
        self.cross_covariance = _as2d(self.cross_covariance, "S")
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

        Uses :func:`okid_ros.sim.oracle.kalman_predictor`; ``K`` is in the paper's convention
        (predictor gain ``A K``) and ``innovation_covariance = C P C^T + R``.
        """
        from okid_ros.sim.oracle import kalman_predictor

        K, Re = kalman_predictor(self)
        return InnovationModel(self.A, self.B, self.C, self.D, K, Re, self.sample_time_s)


TrueSystem = Union[InnovationModel, NoisyStateSpace]


# ---------------------------------------------------------------------------
# Fast state recursion
# ---------------------------------------------------------------------------


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


# ---------------------------------------------------------------------------
# Inputs
# ---------------------------------------------------------------------------


def white_input(n_samples: int, n_inputs: int, seed: Optional[int] = None) -> np.ndarray:
    """Gaussian white input with unit variance per channel.

    Returns
    -------
    u : (n_samples, n_inputs)
    """
    rng = np.random.default_rng(seed)
    return rng.standard_normal((int(n_samples), int(n_inputs)))


def lowpass_input(n_samples: int, n_inputs: int, cutoff_hz: float, sample_time_s: float,
                  seed: Optional[int] = None, order: int = 4, oversample: int = 2,
                  normalize: bool = True) -> np.ndarray:
    """Gaussian white noise through a Butterworth low-pass filter, unit variance per channel.

    Mimics the paper's experiment: random thruster signals "filtered to concentrate the energy
    in the low frequency range", recorded at 250 Hz and decimated to 125 Hz by keeping every
    second sample.  The paper does not give the filter; here white noise at
    ``oversample / sample_time_s`` passes a digital Butterworth low-pass of ``order`` at
    ``cutoff_hz`` (-3 dB) and every ``oversample``-th sample is kept (no anti-alias filter:
    the input is known exactly, like the recorded thruster command).

    Why oversample: a digital Butterworth designed at the final rate has an ``order``-fold zero
    at the Nyquist frequency (bilinear transform), an artefact no analogue filter has; it makes
    even a "50 Hz" input at 125 Hz rank-deficient near Nyquist (subspace peers' prediction
    ratio rose from 1.01 to 2-3 on the paper model with it).  With ``oversample = 2`` the
    response at the final Nyquist frequency is that of the filter at half its design Nyquist,
    e.g. -4 dB for 50 Hz and about -100 dB for 15 Hz at 125 Hz.  The filter start-up transient
    (``ceil(20 / (cutoff_hz * dt_fine))`` fine samples) is discarded, so the sequence is
    stationary.

    Parameters
    ----------
    n_samples, n_inputs : output shape.
    cutoff_hz : -3 dB cut-off in Hz, below ``0.5 * oversample / sample_time_s``.
    sample_time_s : sample period of the returned sequence, seconds.
    seed : seed of ``numpy.random.default_rng``.
    order : Butterworth order.
    oversample : design/filter rate as a multiple of the output rate (1 = filter at the
        output rate).
    normalize : scale each channel to unit sample standard deviation.

    Returns
    -------
    u : (n_samples, n_inputs)
    """
    oversample = int(oversample)
    if oversample < 1:
        raise ValueError("oversample must be >= 1")
    dt_fine = sample_time_s / oversample
    nyquist_hz = 0.5 / dt_fine
    if not 0 < cutoff_hz < nyquist_hz:
        raise ValueError(f"cutoff_hz={cutoff_hz} must be in (0, {nyquist_hz}) Hz")
    sos = scipy.signal.butter(order, cutoff_hz, btype="low", fs=1.0 / dt_fine, output="sos")
    n_transient = int(np.ceil(20.0 / (cutoff_hz * dt_fine)))
    w = white_input(int(n_samples) * oversample + n_transient, n_inputs, seed)
    u = scipy.signal.sosfilt(sos, w, axis=0)[n_transient::oversample][: int(n_samples)]
    if normalize:
        u = u / u.std(axis=0, keepdims=True)
    return u


# ---------------------------------------------------------------------------
# Simulators
# ---------------------------------------------------------------------------


def _sqrt_psd(M: np.ndarray) -> np.ndarray:
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


def _initial_state(A, Qd, x0, rng) -> np.ndarray:
    n = A.shape[0]
    if x0 is None or (isinstance(x0, str) and x0 == "zero"):
        return np.zeros(n)
    if isinstance(x0, str):
        if x0 != "stationary":
            raise ValueError("x0 must be None, 'zero', 'stationary' or an array")
        P = _stationary_state_covariance(A, Qd)
        if P is None:
            return np.zeros(n)
        return _sqrt_psd(P) @ rng.standard_normal(n)
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
    e = rng.standard_normal((N, p)) @ _sqrt_psd(Re).T
    L = model.predictor_gain
    xi = _initial_state(model.A, L @ Re @ L.T, x0, rng)
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
    wv = rng.standard_normal((N, n + p)) @ _sqrt_psd(system.joint_noise_covariance()).T
    w, v = wv[:, :n], wv[:, n:]
    xi = _initial_state(system.A, system.process_noise_covariance, x0, rng)
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


# ---------------------------------------------------------------------------
# Modal structures
# ---------------------------------------------------------------------------


def _zoh(Ac: np.ndarray, Bc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    n, m = Bc.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = Ac
    M[:n, n:] = Bc
    E = scipy.linalg.expm(M * dt)
    return E[:n, :n], E[:n, n:]


def modal_structure(frequencies_hz: Sequence[float], damping_ratios: Sequence[float] | float,
                    n_inputs: int, n_outputs: int, sample_time_s: float, seed: int = 0,
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
    w = 2 * np.pi * f
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
        D = np.zeros((n_outputs, n_inputs))
        Dw = np.zeros((n_outputs, nd))
    else:
        for i in range(nm):
            Cq[:, 2 * i] = -phi_out[:, i] * w[i] ** 2
            Cq[:, 2 * i + 1] = -phi_out[:, i] * 2 * z[i] * w[i]
        D = phi_out @ phi_in
        Dw = phi_out @ phi_w
    A, BB = _zoh(Ac, np.hstack([Bc, Bwc]), sample_time_s)
    B, Bw = BB[:, :n_inputs], BB[:, n_inputs:]
    s2 = float(disturbance_std) ** 2
    Q = s2 * Bw @ Bw.T
    S = s2 * Bw @ Dw.T
    Rw = s2 * Dw @ Dw.T
    P = scipy.linalg.solve_discrete_lyapunov(A, B @ B.T)
    out_var = np.diag(Cq @ P @ Cq.T + D @ D.T)
    R = Rw + np.diag((measurement_noise_ratio ** 2) * out_var)
    return NoisyStateSpace(A, B, Cq, D, Q, R, sample_time_s, cross_covariance=S)


# ---------------------------------------------------------------------------
# Named benchmark cases
# ---------------------------------------------------------------------------


@dataclass
class BenchmarkCase:
    """One known-truth identification problem for the benchmark.

    Attributes
    ----------
    name : short identifier (used on the command line and in tables).
    description : one-paragraph description for the report.
    system : the true system (``InnovationModel`` or ``NoisyStateSpace``).
    make_input : ``make_input(n_samples, seed) -> u`` of shape (n_samples, m).
    n_samples : data lengths to run (identification data).
    arx_order : suggested ARX order ``q`` for ARX-based methods: ``5 / -ln rho(A - L C)``
        of the true predictor (the lag after which its memory has decayed to e^-5), rounded
        up to a multiple of 20 and capped at 200 (:func:`suggested_arx_order`); 100 for the
        paper case as in the paper.  A property of the system, not tuned per method.
    max_physical_damping : damping-ratio cut for "physical" modes when scoring.
    """

    name: str
    description: str
    system: TrueSystem
    make_input: Callable[[int, int], np.ndarray]
    n_samples: tuple = (3750, 15000)
    arx_order: int = 100
    max_physical_damping: float = 0.2
    tags: tuple = field(default_factory=tuple)

    @property
    def sample_time_s(self) -> float:
        return self.system.sample_time_s

    @property
    def n_states(self) -> int:
        return self.system.n_states


def suggested_arx_order(system: TrueSystem, decay: float = 5.0, step: int = 20,
                        cap: int = 200) -> int:
    """ARX order covering the memory of the true one-step predictor.

    ``q = decay / -ln rho(A - L C)`` with ``L`` the oracle predictor gain, rounded up to a
    multiple of ``step`` and capped at ``cap``.
    """
    from okid_ros.sim.oracle import kalman_predictor

    K, _ = kalman_predictor(system)
    rho = float(np.max(np.abs(np.linalg.eigvals(system.A - system.A @ K @ system.C))))
    q = decay / -np.log(rho)
    return int(min(cap, step * np.ceil(q / step)))


def _paper_case(cutoff_hz: Optional[float]) -> BenchmarkCase:
    from okid_ros.sim.paper_model import paper_model

    model = paper_model()
    dt = model.sample_time_s
    if cutoff_hz is None:
        name = "paper-white"
        desc = ("Published model of Chen, Huang & Juang (1991) at 125 Hz (3 modes: 37.10 rad/s "
                "0.28 %, 46.13 rad/s 2.87 %, 304.49 rad/s 0.40 %), 2 white unit-variance inputs, "
                "innovation covariance I.")

        def make_input(N, seed):
            return white_input(N, model.n_inputs, seed)
    else:
        name = f"paper-lp{cutoff_hz:g}"
        desc = (f"Published model of Chen, Huang & Juang (1991) at 125 Hz (3 modes: 37.10 rad/s "
                f"0.28 %, 46.13 rad/s 2.87 %, 304.49 rad/s 0.40 %), 2 random inputs through a "
                f"4th-order Butterworth low-pass at {cutoff_hz:g} Hz (unit variance), innovation "
                f"covariance I.")

        def make_input(N, seed):
            return lowpass_input(N, model.n_inputs, cutoff_hz, dt, seed)
    return BenchmarkCase(name, desc, model, make_input, (3750, 15000), 100, tags=("paper",))


def paper_lowpass15_case() -> BenchmarkCase:
    """(a) Paper model, inputs low-passed at 15 Hz (the experiment-like case)."""
    return _paper_case(15.0)


def paper_lowpass50_case() -> BenchmarkCase:
    """(b) Paper model, inputs low-passed at 50 Hz (nearly broadband at 125 Hz)."""
    return _paper_case(50.0)


def paper_white_case() -> BenchmarkCase:
    """Paper model with white inputs."""
    return _paper_case(None)


def light_damping_case() -> BenchmarkCase:
    """(c) Three modes at 0.3 % damping, acceleration outputs, white input, 50 Hz sampling."""
    dt = 1.0 / 50.0
    f = [1.9, 4.4, 8.1]
    sys_ = modal_structure(f, 0.003, n_inputs=2, n_outputs=2, sample_time_s=dt, seed=11,
                           output="acceleration", disturbance_std=0.3, measurement_noise_ratio=0.05)
    desc = ("Lightly damped structure: modes at 1.9, 4.4, 8.1 Hz, all 0.3 % damping "
            "(decay time constants 28, 12, 6.5 s, i.e. 3750 samples span 75 s), 2 force inputs, "
            "2 accelerometers (D != 0), 50 Hz sampling, white input; disturbance forces "
            "(std 0.3 of the input) and 5 % measurement noise (correlated S through D).")
    return BenchmarkCase("light-damping", desc, sys_,
                         lambda N, seed: white_input(N, 2, seed), (3750, 15000),
                         suggested_arx_order(sys_))


def close_pair_case() -> BenchmarkCase:
    """(d) A close pair 1.6 % apart plus two other modes, band-limited input, 100 Hz."""
    dt = 1.0 / 100.0
    f = [3.10, 3.15, 7.3, 12.6]
    zeta = [0.01, 0.008, 0.02, 0.015]
    sys_ = modal_structure(f, zeta, n_inputs=2, n_outputs=3, sample_time_s=dt, seed=7,
                           output="acceleration", disturbance_std=0.3, measurement_noise_ratio=0.05)
    desc = ("Close pair: modes at 3.10 and 3.15 Hz (1.6 % apart; 1.0 % and 0.8 % damping) plus "
            "7.3 Hz (2 %) and 12.6 Hz (1.5 %), 2 inputs, 3 accelerometers, 100 Hz sampling, "
            "inputs low-passed at 20 Hz; disturbance forces (std 0.3) and 5 % measurement noise.")
    return BenchmarkCase("close-pair", desc, sys_,
                         lambda N, seed: lowpass_input(N, 2, 20.0, dt, seed), (3750, 15000),
                         suggested_arx_order(sys_))


def more_outputs_case() -> BenchmarkCase:
    """(e) 2 inputs, 6 outputs, 4 modes, band-limited input, 100 Hz."""
    dt = 1.0 / 100.0
    f = [2.4, 5.2, 9.7, 16.5]
    zeta = [0.005, 0.01, 0.015, 0.02]
    sys_ = modal_structure(f, zeta, n_inputs=2, n_outputs=6, sample_time_s=dt, seed=3,
                           output="acceleration", disturbance_std=0.3, measurement_noise_ratio=0.05)
    desc = ("More outputs than inputs: 4 modes at 2.4, 5.2, 9.7, 16.5 Hz (0.5-2 % damping), "
            "2 inputs, 6 accelerometers, 100 Hz sampling, inputs low-passed at 25 Hz; "
            "disturbance forces (std 0.3) and 5 % measurement noise.")
    return BenchmarkCase("more-outputs", desc, sys_,
                         lambda N, seed: lowpass_input(N, 2, 25.0, dt, seed), (3750, 15000),
                         suggested_arx_order(sys_))


def separate_noise_case() -> BenchmarkCase:
    """(f) Displacement sensors, separate (uncorrelated) process and measurement noise."""
    dt = 1.0 / 100.0
    f = [1.5, 4.0, 6.8]
    zeta = [0.01, 0.02, 0.01]
    sys_ = modal_structure(f, zeta, n_inputs=1, n_outputs=3, sample_time_s=dt, seed=5,
                           output="displacement", disturbance_std=0.5, measurement_noise_ratio=0.2)
    desc = ("Separate process and measurement noise: 3 modes at 1.5, 4.0, 6.8 Hz (1-2 % "
            "damping), 1 input, 3 displacement sensors (D = 0, S = 0), 100 Hz sampling, white "
            "input; disturbance forces std 0.5 and 20 % measurement noise (noisy sensors).")
    return BenchmarkCase("separate-noise", desc, sys_,
                         lambda N, seed: white_input(N, 1, seed), (3750, 15000),
                         suggested_arx_order(sys_))


_CASES = {
    "paper-lp15": paper_lowpass15_case,
    "paper-lp50": paper_lowpass50_case,
    "paper-white": paper_white_case,
    "light-damping": light_damping_case,
    "close-pair": close_pair_case,
    "more-outputs": more_outputs_case,
    "separate-noise": separate_noise_case,
}


def benchmark_case(name: str) -> BenchmarkCase:
    """The named benchmark case (see :func:`benchmark_cases` for the names)."""
    try:
        return _CASES[name]()
    except KeyError:
        raise KeyError(f"unknown case {name!r}; known: {', '.join(_CASES)}") from None


def benchmark_cases(names: Optional[Sequence[str]] = None) -> list[BenchmarkCase]:
    """All named benchmark cases (or the listed ones), in a fixed order."""
    names = list(_CASES) if names is None else list(names)
    return [benchmark_case(n) for n in names]
