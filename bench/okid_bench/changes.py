"""Structural changes with known truth at 250 Hz, for the change-detection benchmark.

Every case is a pair of :class:`~okid_ros.sim.models.NoisyStateSpace` systems in the same
state coordinates (the state carries over the change, :func:`~okid_bench.switching.simulate_switched`):

- ``frequency`` (:func:`truss_frequency_case`): a 4-mode structure (5.2, 14.1, 24.8, 37.5 Hz,
  1.5-2.5 % damping) whose frequencies all drop by the same fraction (a distributed added mass,
  :func:`~okid_bench.switching.added_mass_structure`; shapes unchanged);
- ``damping`` (:func:`truss_damping_case`): the same structure with every damping ratio
  multiplied by a factor (frequencies and shapes unchanged);
- ``stiffness`` (:func:`chain_stiffness_case`): a 4-storey shear frame (lumped masses and storey
  springs in physical coordinates) whose second storey loses a fraction of its stiffness: the
  frequencies drop by different amounts and the mode shapes change.

All: 2 force inputs low-passed at 40 Hz, 3 accelerometers, 250 Hz sampling, disturbance forces
(std 0.3 of the input) and 5 % sensor noise. The truth after the change is computed from the
continuous-time system matrices (eigenvalues ``s``: ``|s| / 2 pi``, ``-Re s / |s|``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg

from okid_bench.switching import added_mass_structure, simulate_switched
from okid_ros.sim.inputs import lowpass_input
from okid_ros.sim.models import NoisyStateSpace, modal_structure, zero_order_hold

__all__ = [
    "ChangeCase",
    "SAMPLE_TIME_S",
    "chain_stiffness_case",
    "change_case",
    "continuous_modes",
    "explained_fraction_by_lstsq",
    "truss_damping_case",
    "truss_frequency_case",
]

SAMPLE_TIME_S = 1.0 / 250.0
_FREQUENCIES_HZ = np.array([5.2, 14.1, 24.8, 37.5])
_DAMPING = np.array([0.015, 0.02, 0.02, 0.025])
_INPUT_CUTOFF_HZ = 40.0


@dataclass
class ChangeCase:
    """A structure that changes once, with its known truth.

    Attributes
    ----------
    name, description : identifier (``kind-size``) and one sentence.
    kind : "frequency", "damping" or "stiffness"; size : the change (fraction or factor).
    before, after : the systems (same state coordinates).
    old_frequencies_hz, new_frequencies_hz : (n_modes,) true natural frequencies.
    old_damping, new_damping : (n_modes,) true damping ratios.
    make_input : ``make_input(n_samples, seed) -> u`` (n_samples, m).
    """

    name: str
    description: str
    kind: str
    size: float
    before: NoisyStateSpace
    after: NoisyStateSpace
    old_frequencies_hz: np.ndarray
    new_frequencies_hz: np.ndarray
    old_damping: np.ndarray
    new_damping: np.ndarray
    make_input: Callable[[int, int], np.ndarray]

    @property
    def sample_time_s(self) -> float:
        return self.before.sample_time_s

    def simulate(self, n_samples: int, change_index: int | None, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """``(u, y)``; the change at ``change_index`` (None: the structure before throughout).

        Input seed ``100 + seed``, noise seed ``200 + seed``.
        """
        u = self.make_input(n_samples, 100 + seed)
        if change_index is None:
            return u, simulate_switched([self.before], [], u, seed=200 + seed)
        return u, simulate_switched([self.before, self.after], change_index, u, seed=200 + seed)


def continuous_modes(Ac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Natural frequencies [Hz] and damping ratios of a continuous-time A, ascending."""
    s = scipy.linalg.eigvals(Ac)
    s = s[s.imag > 0]
    s = s[np.argsort(np.abs(s))]
    return np.abs(s) / (2 * np.pi), -s.real / np.abs(s)


def _input(n_samples: int, seed: int) -> np.ndarray:
    return lowpass_input(n_samples, 2, _INPUT_CUTOFF_HZ, SAMPLE_TIME_S, seed)


def truss_frequency_case(drop: float = 0.06) -> ChangeCase:
    """Every frequency of the 4-mode structure drops by ``drop`` (0.06: 6 %)."""
    factor = 1.0 - float(drop)
    before, after = added_mass_structure(_FREQUENCIES_HZ, _DAMPING, 2, 3, SAMPLE_TIME_S,
                                         frequency_factor=factor, seed=3)
    return ChangeCase(
        f"frequency-{100 * drop:g}%", f"all frequencies drop by {100 * drop:g} % (added mass)", "frequency",
        float(drop), before, after, _FREQUENCIES_HZ.copy(), factor * _FREQUENCIES_HZ, _DAMPING.copy(),
        _DAMPING.copy(), _input,
    )


def truss_damping_case(factor: float = 2.0) -> ChangeCase:
    """Every damping ratio of the 4-mode structure is multiplied by ``factor``."""
    before = modal_structure(_FREQUENCIES_HZ, _DAMPING, 2, 3, SAMPLE_TIME_S, seed=3)
    raw = modal_structure(_FREQUENCIES_HZ, factor * _DAMPING, 2, 3, SAMPLE_TIME_S, seed=3,
                          measurement_noise_ratio=0.0)
    quiet = modal_structure(_FREQUENCIES_HZ, _DAMPING, 2, 3, SAMPLE_TIME_S, seed=3, measurement_noise_ratio=0.0)
    sensor_noise = before.measurement_noise_covariance - quiet.measurement_noise_covariance  # same sensors
    after = NoisyStateSpace(raw.A, raw.B, raw.C, raw.D, raw.process_noise_covariance,
                            raw.measurement_noise_covariance + sensor_noise, SAMPLE_TIME_S,
                            cross_covariance=raw.cross_covariance)
    return ChangeCase(
        f"damping-x{factor:g}", f"every damping ratio multiplied by {factor:g}", "damping", float(factor),
        before, after, _FREQUENCIES_HZ.copy(), _FREQUENCIES_HZ.copy(), _DAMPING.copy(), factor * _DAMPING, _input,
    )


def _shear_frame(storey_stiffness: np.ndarray, damping_matrix: np.ndarray | None,
                 damping_ratios: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass (unit storeys), stiffness and damping matrices of a shear frame.

    Without ``damping_matrix`` the damping is classical with ``damping_ratios`` per mode.
    """
    k = np.asarray(storey_stiffness, dtype=float)
    n = k.size
    K = np.zeros((n, n))
    for i in range(n):  # spring i joins storey i to storey i - 1 (the ground for i = 0)
        K[i, i] += k[i]
        if i > 0:
            K[i - 1, i - 1] += k[i]
            K[i, i - 1] -= k[i]
            K[i - 1, i] -= k[i]
    M = np.eye(n)
    if damping_matrix is None:
        w2, phi = scipy.linalg.eigh(K, M)  # mass-normalized shapes
        w = np.sqrt(w2)
        damping_matrix = M @ phi @ np.diag(2 * damping_ratios * w) @ phi.T @ M
    return M, K, damping_matrix


def _frame_system(M, K, Cd, sensor_noise_std: np.ndarray | None) -> tuple[NoisyStateSpace, np.ndarray, np.ndarray]:
    """Physical-coordinate state space ``[x; x']`` of the storey structure.

    Forces at storeys 2 and 4 (inputs) and at
    every storey (disturbances, std 0.3), accelerometers at storeys 1, 3, 4.
    """
    n = M.shape[0]
    Minv = np.linalg.inv(M)
    Ac = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ Cd]])
    F_in = np.zeros((n, 2))
    F_in[1, 0] = F_in[3, 1] = 1.0
    F_w = np.eye(n)
    Bc = np.vstack([np.zeros((n, 2)), Minv @ F_in])
    Bwc = np.vstack([np.zeros((n, n)), Minv @ F_w])
    S_out = np.zeros((3, n))
    S_out[0, 0] = S_out[1, 2] = S_out[2, 3] = 1.0
    C = S_out @ Ac[n:, :]
    D = S_out @ Minv @ F_in
    Dw = S_out @ Minv @ F_w
    A, BB = zero_order_hold(Ac, np.hstack([Bc, Bwc]), SAMPLE_TIME_S)
    B, Bw = BB[:, :2], BB[:, 2:]
    s2 = 0.3**2
    if sensor_noise_std is None:  # 5 % of each output's std under unit white input
        P = scipy.linalg.solve_discrete_lyapunov(A, B @ B.T)
        sensor_noise_std = 0.05 * np.sqrt(np.diag(C @ P @ C.T + D @ D.T))
    R = s2 * Dw @ Dw.T + np.diag(sensor_noise_std**2)
    system = NoisyStateSpace(A, B, C, D, s2 * Bw @ Bw.T, R, SAMPLE_TIME_S, cross_covariance=s2 * Bw @ Dw.T)
    return system, Ac, sensor_noise_std


def chain_stiffness_case(reduction: float = 0.2) -> ChangeCase:
    """The second storey of a 4-storey shear frame loses ``reduction`` of its stiffness.

    Unit storey masses, storey stiffnesses in the ratio 6 : 5 : 4 : 3 (frequencies 7.71, 20.09,
    30.66, 39.96 Hz), 1.5-2.5 % classical damping; the damping matrix (the dampers) stays. A
    20 % loss lowers the frequencies by 3.9, 0.5, 1.1 and 5.5 % and the MAC of the shapes at
    the sensors (storeys 1, 3, 4) to 0.98.
    """
    k = np.array([6000.0, 5000.0, 4000.0, 3000.0]) * (2 * np.pi) ** 2 / 10.0
    M, K, Cd = _shear_frame(k, None, _DAMPING)
    before, Ac0, noise = _frame_system(M, K, Cd, None)
    k_after = k.copy()
    k_after[1] *= 1.0 - float(reduction)
    _, K1, _ = _shear_frame(k_after, Cd, _DAMPING)
    after, Ac1, _ = _frame_system(M, K1, Cd, noise)
    f0, z0 = continuous_modes(Ac0)
    f1, z1 = continuous_modes(Ac1)
    return ChangeCase(
        f"stiffness-{100 * reduction:g}%", f"second storey of a shear frame loses {100 * reduction:g} % of its "
        "stiffness (mode shapes change)", "stiffness", float(reduction), before, after, f0, f1, z0, z1, _input,
    )


def change_case(kind: str, size: float) -> ChangeCase:
    """One case by kind ('frequency', 'damping', 'stiffness') and size."""
    makers = {"frequency": truss_frequency_case, "damping": truss_damping_case, "stiffness": chain_stiffness_case}
    if kind not in makers:
        raise ValueError(f"unknown change kind {kind!r}; kinds are {', '.join(makers)}")
    return makers[kind](size)


def explained_fraction_by_lstsq(w: np.ndarray, u: np.ndarray, lags: int) -> tuple[float, int]:
    """The model-error check's explained fraction by its definition: numpy's lstsq per output.

    Each output of ``w`` (N, p), less its mean, on the inputs' lags 0 .. ``lags`` of ``u``
    (N, m), less their means, and its own lags 1 .. ``lags``; explained energy over total energy
    pooled over the outputs, and the rows n = N - lags. What
    :func:`okid_ros.core.model_error_check.explained_fraction` computed until the
    twenty-ninth session, kept as the reference its tests and bench/model_error_check_speed.py
    compare with.
    """
    n = w.shape[0] - lags
    w = w - w.mean(axis=0)
    shared = [u[lags - j: lags - j + n] - u[lags - j: lags - j + n].mean(axis=0) for j in range(lags + 1)]
    explained = total = 0.0
    for i in range(w.shape[1]):
        regressors = np.hstack(shared + [w[lags - j: lags - j + n, i:i + 1] for j in range(1, lags + 1)])
        target = w[lags:, i]
        coef, *_ = np.linalg.lstsq(regressors, target, rcond=None)
        fitted = regressors @ coef
        explained += float(fitted @ fitted)
        total += float(target @ target)
    return (explained / total if total > 0 else 0.0), n
