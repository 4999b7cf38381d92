"""The structure families of bench/okid_bench/new_families.py: their truth against the structures' own poles."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg

from okid_bench.new_families import NEW_FAMILIES, mode_shares, new_family_case, shaped_system
from okid_bench.output_only_cases import system_modes
from okid_bench.physical_cases import physical_case, variance_shares


def test_the_shares_of_a_white_record_are_the_physical_cases_shares():
    case = physical_case(0)  # a building driven by white forces: no filter, every pole complex
    np.testing.assert_allclose(mode_shares(case.system), variance_shares(case.system), rtol=1e-9)


def test_a_shaping_filters_poles_are_simulated_but_neither_true_nor_hidden():
    M, K = np.diag([1.0, 1.5]), 1e4 * np.array([[2.0, -1.0], [-1.0, 1.0]])
    C = 1e-3 * K
    w = np.sqrt(linalg.eigh(K, M, eigvals_only=True))
    low_pass = (np.array([[0.0, 1.0], [-w[0] ** 2, -np.sqrt(2) * w[0]]]), np.array([[0.0], [1.0]]),
                np.array([[w[0] ** 2, 0.0]]), np.array([[0.0]]))
    system = shaped_system(M, C, K, forces=np.array([[0.0], [1.0]]), sensors=np.eye(2), sample_time_s=1e-3,
                           noise_ratio=0.05, shaping=low_pass)
    assert system.A.shape == (6, 6)
    zeta = sorted(mode["damping_ratio"] for mode in system_modes(system))
    assert zeta[-1] == pytest.approx(np.sqrt(0.5), rel=1e-9)  # the filter's pole pair is in the record
    shares = mode_shares(system)
    assert shares.shape == (3,) and np.all(shares >= 0)


@pytest.mark.parametrize("index", range(9))
def test_every_new_structure_is_well_posed_and_scored_on_its_own_poles(index):
    case = new_family_case(index)
    assert case.family == NEW_FAMILIES[index % 3]
    dt = case.sample_time_s
    structural = np.exp(np.asarray(case.structural_poles) * dt)
    true_hz = [mode["frequency_hz"] for mode in case.truth()]
    scored = sorted(true_hz + case.hidden_hz())
    assert scored == pytest.approx(sorted(np.abs(np.log(structural)) / (2 * np.pi * dt)), rel=1e-9)
    assert len(true_hz) >= 1
    assert all(mode["damping_ratio"] < 0.1 for mode in case.truth())
    assert 3 <= case.system.C.shape[0] <= 40
    assert 3 * 0.99 <= 1 / (dt * max(scored)) <= 20 * 1.01
    if case.family == "coloured-building":  # the filter's states are simulated, its poles not scored
        assert case.system.A.shape[0] > 2 * len(scored)
    y = case.simulate(index, 2000)
    assert y.shape == (2000, case.system.C.shape[0]) and np.all(np.isfinite(y))


def test_a_torsion_frames_dashpots_make_its_modes_complex():
    case = new_family_case(1)
    assert case.family == "torsion-frame"
    z, psi = linalg.eig(case.system.A)
    shapes = case.system.C @ psi[:, z.imag > 0]
    # a proportionally damped mode's shape is real up to one phase: its imaginary part then vanishes
    phased = shapes * np.exp(-1j * np.angle(shapes[np.argmax(np.abs(shapes), axis=0), range(shapes.shape[1])]))
    assert np.max(np.linalg.norm(phased.imag, axis=0) / np.linalg.norm(phased, axis=0)) > 0.01
