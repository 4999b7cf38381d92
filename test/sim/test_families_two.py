"""The second round of structure families (bench/okid_bench/families_two.py): truth against the records' own poles."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from okid_bench.families_two import FAMILIES_TWO, _kaimal_filter, family_two_case, true_mpc

CHANNELS = {"damped-building": (3, 8), "tower": (4, 8), "deck": (20, 30)}


@pytest.mark.parametrize("index", range(6))
def test_every_structure_is_scored_on_the_simulated_records_own_poles(index):
    case = family_two_case(index)
    assert case.family == FAMILIES_TWO[index % 3]
    dt = case.sample_time_s
    discrete = np.linalg.eigvals(case.system.A)
    structural = np.exp(np.asarray(case.structural_poles) * dt)
    assert np.min(np.abs(discrete[:, None] - structural[None, :]), axis=0) == pytest.approx(0, abs=1e-9)
    scored = sorted([mode["frequency_hz"] for mode in case.truth()] + case.hidden_hz())
    assert scored == pytest.approx(sorted(np.abs(np.log(structural)) / (2 * np.pi * dt)), rel=1e-9)
    assert len(case.truth()) >= 3 and all(mode["damping_ratio"] < 0.1 for mode in case.truth())
    low, high = CHANNELS[case.family]
    assert low <= case.system.C.shape[0] <= high
    y = case.simulate(index, 1000)
    assert y.shape == (1000, case.system.C.shape[0]) and np.all(np.isfinite(y))


def test_a_damped_buildings_true_shapes_are_complex_and_scored_so():
    shapes = [mode["shape"] for mode in family_two_case(3).truth()]
    assert np.iscomplexobj(shapes[0])
    assert min(true_mpc(shape) for shape in shapes) < 0.6  # far from any real shape: local dampers
    assert true_mpc(np.array([1.0, -2.0, 0.5]) * np.exp(0.7j)) == pytest.approx(1.0)
    assert true_mpc(np.array([1.0, 1j])) == pytest.approx(0.0, abs=1e-12)


def test_a_towers_two_directions_give_pairs_a_fraction_of_a_percent_apart():
    case = family_two_case(1)
    hz = np.sort(np.abs(case.structural_poles)) / (2 * np.pi)
    gaps = hz[1::2] / hz[0::2] - 1
    assert np.all((gaps > 0.0014) & (gaps < 0.013))


def test_the_wind_filter_falls_as_the_five_thirds_power_and_has_no_mode():
    a, b, c, d = _kaimal_filter(0.1, 20.0)
    assert np.all(np.linalg.eigvals(a).imag == 0)
    _, response = signal.freqresp((a, b, c, d), 2 * np.pi * np.array([1.0, 10.0]))
    assert np.log10(np.abs(response[1] / response[0]) ** 2) == pytest.approx(-5 / 3, abs=0.25)


def test_a_decks_traffic_record_is_modulated_white_forces_of_the_stationary_truth():
    case = family_two_case(2)
    driven, system = case.driven, case.system
    np.testing.assert_allclose(driven.A, system.A)
    np.testing.assert_allclose(driven.B @ driven.B.T, system.process_noise_covariance, atol=1e-12)
    np.testing.assert_allclose(driven.D @ driven.D.T + driven.measurement_noise_covariance,
                               system.measurement_noise_covariance)
    assert np.mean(case.envelope ** 2, axis=0) == pytest.approx(1.0)
    window = case.envelope.shape[0] // 20
    power = (case.envelope[:20 * window] ** 2).reshape(20, window, -1).mean(axis=1)
    assert power.max() > 2 * power.min()  # nonstationary: the traffic comes and goes
