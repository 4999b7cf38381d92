"""Ambient records of physical structures (mass, damping and stiffness models) with exact discrete truth.

Unlike :func:`okid_bench.output_only_cases.random_case` (random shapes, an independent white force
on every mode), each structure here is a physical ``M q'' + C q' + K q = F d(t)``: a shear building,
two lightly coupled, slightly mistuned identical chains (close pairs), or a simply supported beam
(its modal model, sine shapes). White forces ``d`` act at 1-3 points only (the modal forces are
correlated, and a mode with a node near every force is barely excited), the outputs are the
accelerations at a subset of the degrees of freedom or at beam sensors, plus 2-10 % sensor noise.
The forces are held over a sample (zero-order hold, ``scipy.linalg.expm`` through
:func:`okid_ros.sim.models.zero_order_hold`), so the discrete poles are exactly ``exp(s dt)`` of the
continuous model's.

Truth: the discrete system's modes (:func:`okid_bench.output_only_cases.system_modes`); a mode is a
*true* mode when the record shows it: in at least one channel its share of the output variance (the
stationary variance of its own modal coordinates seen in that channel, over the channel's whole
variance with noise) is at least :data:`VISIBLE_SHARE`. The other modes are scored neither found nor
missed (:meth:`PhysicalCase.hidden_hz`: a method listing one is not charged a spurious mode).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from okid_bench.output_only_cases import OutputOnlyCase, system_modes
from okid_ros.sim.models import NoisyStateSpace, zero_order_hold

__all__ = ["KOMA_FRAME", "PHYSICAL_FAMILIES", "VISIBLE_SHARE", "PhysicalCase", "koma_frame_case", "physical_case",
           "physical_system", "trapezoidal_system", "variance_shares"]

#: The families, drawn in turn (structure ``index`` is of family ``index % 3``).
PHYSICAL_FAMILIES = ("building", "twin-chains", "beam")
#: Smallest share of one channel's variance that makes a mode one the record shows.
VISIBLE_SHARE = 0.01
#: Sampling rates drawn from [Hz].
SAMPLING_RATES_HZ = (20.0, 50.0, 100.0, 200.0, 256.0, 512.0, 1000.0, 2048.0)
#: Samples of a record: at least, at most.
MIN_SAMPLES, MAX_SAMPLES = 3000, 60000
#: The name of :func:`koma_frame_case` among the bench's ``--cases``.
KOMA_FRAME = "koma-frame"


@dataclass
class PhysicalCase(OutputOnlyCase):
    """One physical structure's ambient record (no unmeasured force through ``B``: it is zero).

    Attributes
    ----------
    family : one of :data:`PHYSICAL_FAMILIES`.
    """

    family: str = ""

    def truth(self) -> list[dict]:
        """The modes the record shows (share at least :data:`VISIBLE_SHARE` in a channel), by frequency."""
        return [m for m, share in zip(system_modes(self.system), variance_shares(self.system))
                if share >= VISIBLE_SHARE]

    def hidden_hz(self) -> list[float]:
        """Frequencies of the modes the record does not show: neither found nor missed, nor spurious."""
        return [m["frequency_hz"] for m, share in zip(system_modes(self.system), variance_shares(self.system))
                if share < VISIBLE_SHARE]


def variance_shares(system: NoisyStateSpace) -> np.ndarray:
    """Each mode's largest share of one channel's variance, the modes by frequency (as ``system_modes``).

    The state is put in real modal coordinates (a 2x2 block per pole pair); a mode's part of channel
    ``j`` is ``c_j P_ii c_j^T`` with ``P_ii`` its block of the stationary state covariance (the
    cross terms between modes are left out), over the channel's variance (state, feed-through and
    sensor noise).
    """
    z, psi = linalg.eig(system.A)
    upper = np.flatnonzero(z.imag > 0)
    if 2 * upper.size != z.size:
        raise ValueError("every pole of a structure is one of a complex pair")
    order = upper[np.argsort(np.abs(np.log(z[upper])))]
    T = np.hstack([np.column_stack([psi[:, i].real, psi[:, i].imag]) for i in order])
    T_inv = np.linalg.inv(T)
    P = linalg.solve_discrete_lyapunov(T_inv @ system.A @ T, T_inv @ system.process_noise_covariance @ T_inv.T)
    P_x = T @ P @ T.T
    C_modal = system.C @ T
    total = np.diag(system.C @ P_x @ system.C.T + system.measurement_noise_covariance)
    parts = np.column_stack([np.einsum("jk,kl,jl->j", C_modal[:, 2 * i:2 * i + 2], P[2 * i:2 * i + 2, 2 * i:2 * i + 2],
                                       C_modal[:, 2 * i:2 * i + 2]) for i in range(order.size)])
    return (parts / total[:, None]).max(axis=0)


def physical_system(M: np.ndarray, C: np.ndarray, K: np.ndarray, *, forces: np.ndarray, sensors: np.ndarray,
                    sample_time_s: float, noise_ratio: float) -> NoisyStateSpace:
    """``M q'' + C q' + K q = forces d``, its accelerations at ``sensors`` observed, white ``d`` held over a sample.

    Parameters
    ----------
    M, C, K : (n, n) mass, damping and stiffness.
    forces : (n, f) where each unit-variance white force acts.
    sensors : (p, n) what each accelerometer sees of ``q''``.
    sample_time_s : sample period.
    noise_ratio : sensor noise standard deviation over each noise-free output's.

    Returns
    -------
    NoisyStateSpace with state ``[q; q']``, one zero input and ``S != 0`` (the forces reach the
    accelerations directly).
    """
    n = M.shape[0]
    M_inv_K, M_inv_C, M_inv_F = np.linalg.solve(M, K), np.linalg.solve(M, C), np.linalg.solve(M, forces)
    Ac = np.block([[np.zeros((n, n)), np.eye(n)], [-M_inv_K, -M_inv_C]])
    Bc = np.vstack([np.zeros_like(M_inv_F), M_inv_F])
    A, Bw = zero_order_hold(Ac, Bc, sample_time_s)
    C_out = sensors @ np.hstack([-M_inv_K, -M_inv_C])
    Dw = sensors @ M_inv_F
    Q, S = Bw @ Bw.T, Bw @ Dw.T
    noise_free = np.diag(C_out @ linalg.solve_discrete_lyapunov(A, Q) @ C_out.T + Dw @ Dw.T)
    R = Dw @ Dw.T + np.diag(noise_ratio ** 2 * noise_free)
    p = sensors.shape[0]
    return NoisyStateSpace(A, np.zeros((2 * n, 1)), C_out, np.zeros((p, 1)), Q, R, sample_time_s,
                           cross_covariance=S)


def trapezoidal_system(M: np.ndarray, C: np.ndarray, K: np.ndarray, *, sample_time_s: float,
                       noise_ratio: float) -> NoisyStateSpace:
    """``M q'' + C q' + K q = d``, white ``d`` at every degree of freedom, stepped by the trapezoidal rule, ``q`` seen.

    The trapezoidal rule (Newmark's average acceleration) is ``x_{k+1} = A x_k + B (d_k + d_{k+1})``
    with ``A = (I - Ac dt/2)^-1 (I + Ac dt/2)`` (the Tustin images of the continuous poles) and
    ``B = (I - Ac dt/2)^-1 Bc dt/2``; with ``xi_k = x_k - B d_k`` it is the state space
    ``xi_{k+1} = A xi_k + (A + I) B d_k``, ``y_k = C_q xi_k + C_q B d_k + v_k``, whose forces reach
    the outputs directly too. The sensor noise ``v`` has the same standard deviation on every
    channel: ``noise_ratio`` times the noise-free record's, over all channels (koma's recipe).
    """
    n = M.shape[0]
    Ac = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
    Bc = np.vstack([np.zeros((n, n)), np.linalg.inv(M)])
    left = np.eye(2 * n) - Ac * sample_time_s / 2
    A = np.linalg.solve(left, np.eye(2 * n) + Ac * sample_time_s / 2)
    B = np.linalg.solve(left, Bc * sample_time_s / 2)
    Bw, C_out = (A + np.eye(2 * n)) @ B, np.hstack([np.eye(n), np.zeros((n, n))])
    Dw = C_out @ B
    Q, S = Bw @ Bw.T, Bw @ Dw.T
    noise_free = np.diag(C_out @ linalg.solve_discrete_lyapunov(A, Q) @ C_out.T + Dw @ Dw.T)
    R = Dw @ Dw.T + noise_ratio ** 2 * noise_free.mean() * np.eye(n)
    return NoisyStateSpace(A, np.zeros((2 * n, 1)), C_out, np.zeros((n, 1)), Q, R, sample_time_s,
                           cross_covariance=S)


def koma_frame_case() -> OutputOnlyCase:
    """The koma shear frame's own recipe as a case with noise seeds (``../shared/data/oma/koma-shear-frame``).

    koma's example: 5 storeys, masses 500, storey stiffnesses 8000, a damper of 50 from every
    storey to the ground (modes 0.18-1.22 Hz, damping 4.4-0.65 %), white forces at every storey,
    Newmark's average acceleration at 12 Hz for 1200 s, the displacements with white noise of
    0.6 times their standard deviation. The truth is the trapezoidal rule's discrete modes, the
    record's own ``discrete_frequency_hz`` / ``discrete_damping_ratio``; every mode is scored (the
    record shows all five).
    """
    storeys, m, k, c = 5, 500.0, 8000.0, 50.0
    top_first = _chain_stiffness(np.full(storeys, k))[::-1, ::-1]  # koma's channel order: the top storey first
    system = trapezoidal_system(m * np.eye(storeys), c * np.eye(storeys), top_first, sample_time_s=1 / 12,
                                noise_ratio=0.6)
    return OutputOnlyCase(KOMA_FRAME, system, 14_400, "koma's 5-storey shear frame, fs 12 Hz, 1200 s")


def _chain_stiffness(k: np.ndarray) -> np.ndarray:
    """Stiffness of a fixed-free chain of springs ``k`` (k[0] to the ground)."""
    K = np.diag(k + np.append(k[1:], 0.0))
    K -= np.diag(k[1:], 1) + np.diag(k[1:], -1)
    return K


def _rayleigh(M, K, w_low, w_high, z_low, z_high):
    """``a M + b K`` with damping ratio ``z_low`` at ``w_low`` and ``z_high`` at ``w_high``."""
    a, b = np.linalg.solve([[1 / (2 * w_low), w_low / 2], [1 / (2 * w_high), w_high / 2]], [z_low, z_high])
    return a * M + b * K


def _modal_damping(M, K, zeta):
    """The damping matrix giving mode ``i`` (by frequency) the damping ratio ``zeta[i]``."""
    w2, phi = linalg.eigh(K, M)  # mass-normalized: phi^T M phi = I
    modal = M @ phi
    return modal @ np.diag(2 * np.asarray(zeta) * np.sqrt(w2)) @ modal.T


def _scaled_to_band(M, K, rng, fs):
    """K scaled: the highest mode at 15-40 % of ``fs``, the slowest above 0.6 %; the natural frequencies [rad/s]."""
    w2 = linalg.eigh(K, M, eigvals_only=True)
    top = rng.uniform(max(0.15, 0.006 * np.sqrt(w2[-1] / w2[0])), 0.4) * fs * 2 * np.pi
    scale = top ** 2 / w2[-1]
    return K * scale, np.sqrt(w2 * scale)


def _selection(rng, n, count):
    """(count, n) rows picking ``count`` distinct degrees of freedom of ``n``."""
    return np.eye(n)[np.sort(rng.choice(n, size=count, replace=False))]


def _building(rng, fs):
    storeys = int(rng.integers(4, 11))
    M = np.diag(rng.uniform(0.8, 1.2, storeys))
    K, w = _scaled_to_band(M, _chain_stiffness(rng.uniform(0.7, 1.3, storeys)), rng, fs)
    z_ends = np.exp(rng.uniform(np.log(0.005), np.log(0.03), 2))
    if rng.random() < 0.5:
        C, damping = _rayleigh(M, K, w[0], w[-1], *z_ends), "Rayleigh"
    else:
        C, damping = _modal_damping(M, K, np.exp(rng.uniform(np.log(0.005), np.log(0.03), storeys))), "modal"
    return M, C, K, w, f"{storeys}-storey shear building, {damping} damping"


def _twin_chains(rng, fs):
    masses = int(rng.integers(3, 7))
    k = rng.uniform(0.7, 1.3, masses)
    m = rng.uniform(0.8, 1.2, masses)
    mistuning = rng.uniform(0.006, 0.04)  # the pairs' frequencies differ by about half of it
    chain = _chain_stiffness(k)
    # weak enough to leave the slowest pair about as close as the mistuning makes it
    coupling = rng.uniform(0.1, 1.0) * mistuning * linalg.eigh(chain, np.diag(m), eigvals_only=True)[0]
    M = np.diag(np.concatenate([m, m]))
    K = linalg.block_diag(chain, (1 + mistuning) * chain)
    top_a, top_b = masses - 1, 2 * masses - 1
    K[[top_a, top_b], [top_a, top_b]] += coupling
    K[[top_a, top_b], [top_b, top_a]] -= coupling
    K, w = _scaled_to_band(M, K, rng, fs)
    C = _modal_damping(M, K, rng.uniform(0.005, 0.01, 2 * masses))
    return M, C, K, w, f"two {masses}-mass chains, {100 * mistuning:.1f} % mistuned, coupled at the top"


def _beam(rng, fs):
    modes = int(rng.integers(3, 8))
    M = np.eye(modes)
    K, w = _scaled_to_band(M, np.diag(np.arange(1.0, modes + 1) ** 4), rng, fs)
    zeta = np.exp(rng.uniform(np.log(0.005), np.log(0.03), modes))
    return M, np.diag(2 * zeta * w), K, w, f"simply supported beam, {modes} modes"


def _beam_points(positions, modes):
    """(points, modes) sine shapes of a simply supported beam of unit length at ``positions``."""
    return np.sin(np.pi * np.outer(positions, np.arange(1, modes + 1)))


def physical_case(index: int) -> PhysicalCase:
    """Structure number ``index`` of the physical families, drawn at random (one record each, seed ``index``).

    Families in turn (``index % 3``): a shear building of 4-10 storeys (masses and storey
    stiffnesses +-20-30 %, Rayleigh or modal damping 0.5-3 %); two chains of 3-6 masses, the second
    0.6-4 % stiffer, coupled by a weak spring at their tops (close pairs 0.3-3 % apart, damping 0.5-1 %); a
    simply supported beam's 3-7 sine modes (``f_k = k^2 f_1``, damping 0.5-3 %, 8-20 equally spaced
    sensors, so some modes have a node at or near a sensor). The highest mode at 15-40 % of a
    sampling rate of 20-2048 Hz; white forces at 1-3 points; accelerations at 2 to all degrees of
    freedom (the beam: its sensors); sensor noise 2-10 %; 300-3000 periods of the slowest mode
    (3000-60000 samples).
    """
    family = PHYSICAL_FAMILIES[index % len(PHYSICAL_FAMILIES)]
    rng = np.random.default_rng(40_000 + index)
    fs = float(rng.choice(SAMPLING_RATES_HZ))
    M, C, K, w, description = {"building": _building, "twin-chains": _twin_chains, "beam": _beam}[family](rng, fs)
    n = M.shape[0]
    n_forces = int(rng.integers(1, 4))
    if family == "beam":
        p = int(rng.integers(8, 21))
        sensors = _beam_points(np.arange(1, p + 1) / (p + 1), n)
        forces = _beam_points(rng.uniform(0.05, 0.95, n_forces), n).T
    else:
        p = int(rng.integers(2, n + 1))
        sensors = _selection(rng, n, p)
        forces = _selection(rng, n, min(n_forces, n)).T
    noise = float(rng.uniform(0.02, 0.1))
    system = physical_system(M, C, K, forces=forces, sensors=sensors, sample_time_s=1.0 / fs, noise_ratio=noise)
    f_slowest = w.min() / (2 * np.pi)
    n_samples = int(min(max(rng.uniform(300, 3000) * fs / f_slowest, MIN_SAMPLES), MAX_SAMPLES))
    return PhysicalCase(f"{family}-{index}", system, n_samples,
                        f"{description}, {n_forces} force(s), {p} accelerometers, fs {fs:g} Hz, "
                        f"{n_samples / fs:.0f} s", family=family)
