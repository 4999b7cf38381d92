"""The Cramer-Rao bound of output-only frequencies (bench/okid_bench/resolvability.py) against theory."""

from __future__ import annotations

import numpy as np

from okid_bench.resolvability import frequency_covariance, independent_modal_forces, modal_predictor
from okid_ros.sim.models import modal_structure


def _bound_pct(system, n_samples):
    model = modal_predictor(system)
    upper = model.upper_by_frequency()
    cov = frequency_covariance(model, list(upper), n_samples)
    s = np.log(model.lam[upper]) / model.sample_time_s
    return 100 * np.sqrt(np.diag(cov)) / (np.abs(s) / (2 * np.pi)), s


def test_a_clean_mode_is_at_the_single_mode_rule():
    """Far apart, nearly noise-free modes: sigma_f / f = sqrt(zeta / (omega T)), a mode's own decay."""
    n_samples, dt = 20_000, 0.02
    system = modal_structure([2.0, 7.0], [0.01, 0.02], 1, 3, dt, seed=4, output="displacement",
                             disturbance_std=1.0, measurement_noise_ratio=1e-3)
    bound, s = _bound_pct(independent_modal_forces(system), n_samples)
    rule = 100 * np.sqrt(-s.real / (np.abs(s) ** 2 * n_samples * dt))
    np.testing.assert_allclose(bound, rule, rtol=0.05)


def test_a_closer_pair_on_one_channel_is_harder_to_place():
    """One channel (no shapes to tell them apart), a pair 1 % and then 0.1 % apart: the bound grows as they merge."""
    n_samples, dt = 20_000, 0.02
    spread = []
    for gap in (0.01, 0.001):
        system = modal_structure([5.0, 5.0 * (1 + gap)], [0.01, 0.01], 1, 1, dt, seed=2, output="displacement",
                                 disturbance_std=1.0, measurement_noise_ratio=0.05)
        bound, _ = _bound_pct(independent_modal_forces(system), n_samples)
        spread.append(bound.max())
    assert spread[1] > 1.5 * spread[0]


def test_the_information_density_is_the_trace_formula():
    """Each term pair's density equals 2 Re [tr(E_a E_b) + tr(E_a E_b^H)] with the matrices E = H^-1 u w^T formed."""
    from okid_bench.resolvability import _rank_one_terms, _term_density

    system = modal_structure([3.0, 3.05, 8.0], [0.02, 0.01, 0.01], 1, 2, 0.02, seed=6, output="acceleration",
                             disturbance_std=1.0, measurement_noise_ratio=0.1)
    model = modal_predictor(system)
    free = list(model.upper_by_frequency()[:2])
    z = np.exp(1j * np.array([0.5, 0.94, 1.2]))
    U, W, _, _ = _rank_one_terms(model, free, z)
    density = _term_density(model, z, U, W)
    for f in range(z.size):
        H = np.eye(2) + model.c @ np.diag(1.0 / (z[f] - model.lam)) @ model.g
        E = [np.linalg.solve(H, np.outer(U[f, :, a], W[f, :, a])) for a in range(U.shape[2])]
        direct = np.array([[2 * (np.trace(Ea @ Eb) + np.trace(Ea @ Eb.conj().T)).real for Eb in E] for Ea in E])
        np.testing.assert_allclose(density[f], direct, rtol=1e-9, atol=1e-9 * np.abs(direct).max())
