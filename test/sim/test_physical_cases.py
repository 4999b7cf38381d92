"""The physical structures of bench/okid_bench/physical_cases.py: their truth against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg

from okid_bench.output_only_cases import system_modes
from okid_bench.physical_cases import (
    PHYSICAL_FAMILIES,
    VISIBLE_SHARE,
    koma_frame_case,
    physical_case,
    physical_system,
    trapezoidal_system,
    variance_shares,
)


def _two_storeys(*, m, k, zeta):
    """A 2-storey shear building (equal masses and storey stiffnesses), damping ``zeta`` on both modes."""
    M = m * np.eye(2)
    K = k * np.array([[2.0, -1.0], [-1.0, 1.0]])
    w2, phi = np.linalg.eigh(K / m)
    phi = phi / np.sqrt(m)  # mass-normalized
    C = M @ phi @ np.diag(2 * zeta * np.sqrt(w2)) @ phi.T @ M
    return M, C, K


def test_a_two_storey_buildings_modes_are_the_closed_form():
    m, k, dt = 2.0, 3000.0, 1 / 200
    M, C, K = _two_storeys(m=m, k=k, zeta=0.02)
    system = physical_system(M, C, K, forces=np.array([[0.0], [1.0]]), sensors=np.eye(2), sample_time_s=dt,
                             noise_ratio=0.05)
    modes = system_modes(system)
    # w^2 = (k / m) (3 -+ sqrt 5) / 2; shapes (1, phi) with phi the golden ratio's (1 +- sqrt 5) / 2
    w = np.sqrt(k / m * (3 - np.array([1, -1]) * np.sqrt(5)) / 2)
    np.testing.assert_allclose([mode["frequency_hz"] for mode in modes], w / (2 * np.pi), rtol=1e-10)
    np.testing.assert_allclose([mode["damping_ratio"] for mode in modes], 0.02, rtol=1e-8)
    ratios = [mode["shape"][1] / mode["shape"][0] for mode in modes]  # top over first storey
    np.testing.assert_allclose(ratios, (1 + np.array([1, -1]) * np.sqrt(5)) / 2, rtol=1e-8)
    # accelerometers see the force directly: the noise of w and v is correlated
    assert np.abs(system.cross_covariance).max() > 0


def test_a_mode_the_record_does_not_show_is_hidden_and_one_it_shows_is_true():
    # two uncoupled chains; the force and the sensors on the first: the second's modes are not seen
    m, k = 1.0, 1000.0
    M1, C1, K1 = _two_storeys(m=m, k=k, zeta=0.01)
    M2, C2, K2 = _two_storeys(m=m, k=1.2 * k, zeta=0.01)
    zeros = np.zeros((2, 2))
    M, C, K = (np.block([[a, zeros], [zeros, b]]) for a, b in ((M1, M2), (C1, C2), (K1, K2)))
    system = physical_system(M, C, K, forces=np.array([[0.0, 1.0, 0.0, 0.0]]).T, sensors=np.eye(4)[:2],
                             sample_time_s=0.01, noise_ratio=0.05)
    shares = variance_shares(system)
    w_first = np.sqrt(k / m * (3 - np.array([1, -1]) * np.sqrt(5)) / 2) / (2 * np.pi)
    f = np.array([mode["frequency_hz"] for mode in system_modes(system)])
    seen = np.isin(np.round(f, 9), np.round(w_first, 9))
    assert seen.sum() == 2
    assert np.all(shares[seen] > 0.05) and np.all(shares[~seen] < 1e-12)


@pytest.mark.parametrize("index", range(6))
def test_every_physical_structure_is_well_posed(index):
    case = physical_case(index)
    assert case.family == PHYSICAL_FAMILIES[index % 3]
    modes = system_modes(case.system)
    fs = 1 / case.sample_time_s
    f = np.array([mode["frequency_hz"] for mode in modes])
    assert 0.006 * fs * 0.99 <= f.min() and f.max() <= 0.4 * fs * 1.01
    assert np.all(np.array([mode["damping_ratio"] for mode in modes]) < 0.2)
    true_hz = [mode["frequency_hz"] for mode in case.truth()]
    assert sorted(true_hz + case.hidden_hz()) == pytest.approx(sorted(f))
    shares = variance_shares(case.system)
    assert len(true_hz) == int((shares >= VISIBLE_SHARE).sum()) >= 1
    y = case.simulate(index, 2000)
    assert y.shape == (2000, case.system.C.shape[0]) and np.all(np.isfinite(y))
    if case.family == "twin-chains":  # close pairs: each mode has a partner within 3 %
        gaps = np.diff(f) / f[:-1]
        assert np.all(gaps[::2] < 0.03)


def test_the_trapezoidal_systems_output_covariances_are_the_rules():
    # The rule x_{k+1} = A x_k + B (d_k + d_{k+1}) written with the force as part of the state,
    # z_k = [x_k; d_k]: its stationary covariances, against the system's form.
    M, C, K = _two_storeys(m=2.0, k=3000.0, zeta=0.02)
    dt = 1 / 100
    system = trapezoidal_system(M, C, K, sample_time_s=dt, noise_ratio=0.0)
    Ac = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
    Bc = np.vstack([np.zeros((2, 2)), np.linalg.inv(M)])
    A = np.linalg.solve(np.eye(4) - Ac * dt / 2, np.eye(4) + Ac * dt / 2)
    B = np.linalg.solve(np.eye(4) - Ac * dt / 2, Bc * dt / 2)
    F = np.block([[A, B], [np.zeros((2, 4)), np.zeros((2, 2))]])
    G = np.vstack([B, np.eye(2)])
    P_z = linalg.solve_discrete_lyapunov(F, G @ G.T)
    seen = np.hstack([np.eye(2), np.zeros((2, 4))])  # q of z
    P = linalg.solve_discrete_lyapunov(system.A, system.process_noise_covariance)
    lag0 = system.C @ P @ system.C.T + system.measurement_noise_covariance
    lag1 = system.C @ (system.A @ P @ system.C.T + system.cross_covariance)
    np.testing.assert_allclose(lag0, seen @ P_z @ seen.T, rtol=1e-9)
    np.testing.assert_allclose(lag1, seen @ F @ P_z @ seen.T, rtol=1e-9)


def test_the_koma_frames_modes_are_the_tustin_images_of_komas_shear_frame():
    case = koma_frame_case()
    # koma's frame: w_j = 2 sqrt(k / m) sin((2 j - 1) pi / 22), a damper c to the ground: zeta_j = c / (2 m w_j)
    w = 2 * np.sqrt(8000 / 500) * np.sin((2 * np.arange(1, 6) - 1) * np.pi / 22)
    zeta = 50 / (2 * 500 * w)
    s = -zeta * w + 1j * w * np.sqrt(1 - zeta ** 2)
    dt = case.sample_time_s
    s_discrete = np.log((1 + s * dt / 2) / (1 - s * dt / 2)) / dt
    modes = case.truth()
    np.testing.assert_allclose([m["frequency_hz"] for m in modes], np.abs(s_discrete) / (2 * np.pi), rtol=1e-10)
    np.testing.assert_allclose([m["damping_ratio"] for m in modes], -s_discrete.real / np.abs(s_discrete), rtol=1e-8)
    assert dt == pytest.approx(1 / 12) and case.n_samples == 14_400
    slowest = modes[0]["shape"].real  # the top storey, koma's first channel, moves most
    assert np.argmax(np.abs(slowest)) == 0 and np.all(np.abs(np.diff(np.abs(slowest))) > 0)
    y = case.simulate(0, 3000)
    assert y.shape == (3000, 5) and np.all(np.isfinite(y))
