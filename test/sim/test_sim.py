"""Tests of okid_ros.sim: the paper's model, simulators, oracle predictor, scoring, peers."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from okid_bench.cases import benchmark_cases
from okid_bench.oracle import kalman_predictor, one_step_predictions
from okid_bench.peers import PEERS, peer_identify
from okid_bench.scoring import (
    match_modes,
    modes_of,
    physical_modes,
    prediction_error_ratio,
    stochastic_markov_error,
)
from okid_ros.core.statespace import InnovationModel
from okid_ros.sim.inputs import lowpass_input, white_input
from okid_ros.sim.models import NoisyStateSpace, as_noisy_state_space, modal_structure
from okid_ros.sim.paper_model import PAPER_A, PAPER_B, PAPER_K, paper_model, paper_modes
from okid_ros.sim.simulators import _propagate_loop, propagate_states, simulate_innovation, simulate_noisy


def _autocorr_max(e: np.ndarray, lags: int) -> float:
    """Largest |normalized cross/auto-correlation| of the columns of e over lags 1..lags."""
    e = e - e.mean(axis=0)
    s = e.std(axis=0)
    N = len(e)
    worst = 0.0
    for k in range(1, lags + 1):
        c = (e[k:].T @ e[:-k]) / (N * np.outer(s, s))
        worst = max(worst, float(np.max(np.abs(c))))
    return worst


# ---------------------------------------------------------------------------
# paper model
# ---------------------------------------------------------------------------


def test_paper_model_has_the_published_modes():
    modes = paper_modes()
    assert len(modes) == 3
    f = [md["frequency_rad_s"] for md in modes]
    z = [md["damping_ratio"] for md in modes]
    # issue 3: mode 1 (37.10 rad/s, 0.28 %), mode 2 (46.13 rad/s, 2.87 %); third near 304.5 rad/s
    assert f[0] == pytest.approx(37.10, abs=0.005)
    assert 100 * z[0] == pytest.approx(0.28, abs=0.005)
    assert f[1] == pytest.approx(46.13, abs=0.005)
    assert 100 * z[1] == pytest.approx(2.87, abs=0.005)
    assert f[2] == pytest.approx(304.49, abs=0.01)
    assert 100 * z[2] == pytest.approx(0.399, abs=0.001)
    # the independent scorer agrees
    sm = modes_of(PAPER_A, 0.008)
    np.testing.assert_allclose([m.frequency_rad_s for m in sm], f, rtol=1e-12)
    np.testing.assert_allclose([m.damping_ratio for m in sm], z, rtol=1e-12)


def test_paper_matrices_are_transposed_right():
    m = paper_model()
    assert m.B.shape == (6, 2) and m.K.shape == (6, 2) and m.C.shape == (2, 6)
    # first column of B^T as printed is the first state's row
    np.testing.assert_allclose(PAPER_B[0], [0.1725, -0.1789])
    np.testing.assert_allclose(PAPER_K[5], [0.0357, -0.0182])
    assert m.sample_time_s == 0.008
    np.testing.assert_allclose(m.innovation_covariance, np.eye(2))
    # the published predictor is stable (required for an innovation model)
    assert np.max(np.abs(np.linalg.eigvals(m.A - m.A @ m.K @ m.C))) < 0.95


# ---------------------------------------------------------------------------
# simulators
# ---------------------------------------------------------------------------


def test_propagate_states_matches_plain_loop():
    rng = np.random.default_rng(0)
    F = paper_model().A - 0.1 * rng.standard_normal((6, 6)) * 0.1
    W = rng.standard_normal((500, 6))
    x0 = rng.standard_normal(6)
    np.testing.assert_allclose(propagate_states(F, W, x0), _propagate_loop(F, W, x0), atol=1e-9)
    # defective (Jordan block): falls back to the loop, same answer
    J = np.array([[0.9, 1.0], [0.0, 0.9]])
    W2 = rng.standard_normal((200, 2))
    np.testing.assert_allclose(propagate_states(J, W2), _propagate_loop(J, W2, np.zeros(2)), atol=1e-9)


def test_lowpass_input_concentrates_energy_below_cutoff():
    dt = 0.008
    u = lowpass_input(8192, 2, 15.0, dt, seed=1)
    assert u.shape == (8192, 2)
    np.testing.assert_allclose(u.std(axis=0), 1.0, rtol=1e-12)
    spec = np.abs(np.fft.rfft(u, axis=0)) ** 2
    f = np.fft.rfftfreq(len(u), dt)
    frac_above = spec[f > 30.0].sum() / spec.sum()
    assert frac_above < 1e-3
    # reproducible, and different seeds differ
    np.testing.assert_array_equal(u, lowpass_input(8192, 2, 15.0, dt, seed=1))
    assert not np.allclose(u, lowpass_input(8192, 2, 15.0, dt, seed=2))
    w = white_input(1000, 3, seed=0)
    assert w.shape == (1000, 3)


def test_modal_structure_is_exact_zoh_of_the_requested_modes():
    f = [1.5, 4.0, 6.8]
    z = [0.01, 0.02, 0.003]
    acc = modal_structure(f, z, 2, 3, 0.01, seed=4, output="acceleration")
    dis = modal_structure(f, z, 2, 3, 0.01, seed=4, output="displacement")
    for s in (acc, dis):
        md = modes_of(s.A, 0.01)
        np.testing.assert_allclose([m.frequency_hz for m in md], f, rtol=1e-10)
        np.testing.assert_allclose([m.damping_ratio for m in md], z, rtol=1e-8)
    assert np.abs(acc.D).max() > 0.1 and np.abs(acc.cross_covariance).max() > 0
    assert np.all(dis.D == 0) and np.all(dis.cross_covariance == 0)


def test_simulate_innovation_returns_the_drawn_innovations():
    m = paper_model()
    u = white_input(3000, 2, seed=3)
    y, e = simulate_innovation(m, u, seed=4)
    _, e_hat = one_step_predictions(m.A, m.B, m.C, m.D, m.K, u, y)
    # the predictor starts at x = 0, the simulation at a stationary random state
    np.testing.assert_allclose(e_hat[400:], e[400:], atol=1e-6)
    assert np.abs(e_hat[:5] - e[:5]).max() > 1e-3


# ---------------------------------------------------------------------------
# oracle
# ---------------------------------------------------------------------------


def test_oracle_returns_the_innovation_models_own_gain():
    m = paper_model(innovation_variance=2.0)
    K, Re = kalman_predictor(m)
    np.testing.assert_array_equal(K, m.K)
    # the same process written with correlated process / measurement noise
    K2, Re2 = kalman_predictor(as_noisy_state_space(m))
    np.testing.assert_allclose(K2, m.K, atol=1e-8)
    np.testing.assert_allclose(Re2, 2.0 * np.eye(2), atol=1e-8)


@pytest.mark.parametrize("output", ["acceleration", "displacement"])
def test_oracle_innovations_are_white_with_the_predicted_covariance(output):
    s = modal_structure([2.0, 5.5, 9.0], [0.01, 0.02, 0.005], 2, 3, 0.02, seed=9,
                        output=output, disturbance_std=0.5, measurement_noise_ratio=0.1)
    K, Re = kalman_predictor(s)
    inn = s.to_innovation_form()
    np.testing.assert_allclose(inn.K, K)
    u = white_input(40000, 2, seed=5)
    y = simulate_noisy(s, u, seed=6)
    _, e = one_step_predictions(s.A, s.B, s.C, s.D, K, u, y)
    e = e[500:]
    N = len(e)
    # covariance matches Re (relative error ~ sqrt(2/N) = 0.7 %)
    cov = e.T @ e / N
    np.testing.assert_allclose(np.diag(cov), np.diag(Re), rtol=0.04)
    corr = cov / np.sqrt(np.outer(np.diag(Re), np.diag(Re)))
    corr_true = Re / np.sqrt(np.outer(np.diag(Re), np.diag(Re)))
    np.testing.assert_allclose(corr, corr_true, atol=0.03)
    assert _autocorr_max(e, 20) < 4.5 / np.sqrt(N)
    # and a wrong gain (K = 0: pure simulation) leaves correlated, larger errors
    _, e0 = one_step_predictions(s.A, s.B, s.C, s.D, None, u, y)
    assert _autocorr_max(e0[500:], 5) > 0.1
    assert np.trace(e0[500:].T @ e0[500:] / N) > 1.2 * np.trace(Re)


def test_oracle_with_noisy_state_space_is_optimal_among_perturbed_gains():
    s = modal_structure([3.0, 7.0], [0.02, 0.01], 1, 2, 0.01, seed=2, disturbance_std=0.4)
    K, _ = kalman_predictor(s)
    u = white_input(20000, 1, seed=1)
    y = simulate_noisy(s, u, seed=2)
    best = prediction_error_ratio({"A": s.A, "B": s.B, "C": s.C, "D": s.D, "K": K}, s, u, y)
    assert best == pytest.approx(1.0, abs=1e-12)
    for scale in (0.7, 1.3):
        r = prediction_error_ratio({"A": s.A, "B": s.B, "C": s.C, "D": s.D, "K": scale * K}, s, u, y)
        assert r > 1.002


# ---------------------------------------------------------------------------
# scoring
# ---------------------------------------------------------------------------


def _modal_A(freqs_hz, zetas, dt):
    blocks = []
    for f, z in zip(freqs_hz, zetas):
        w = 2 * np.pi * f
        lam = np.exp((-z * w + 1j * w * np.sqrt(1 - z * z)) * dt)
        blocks.append(np.array([[lam.real, lam.imag], [-lam.imag, lam.real]]))
    from scipy.linalg import block_diag
    return block_diag(*blocks)


def test_scoring_detects_missed_and_spurious_modes():
    dt = 0.01
    true = modes_of(_modal_A([1.0, 2.0, 3.0], [0.01, 0.02, 0.01], dt), dt)
    # identified: 1.01 Hz (1 % off), 3 Hz with 1.5 % damping, a spurious 4.5 Hz mode, a 30 %
    # damped noise mode (not physical) and an unstable 2 Hz pole (not physical): 2 Hz missed
    A_id = _modal_A([1.01, 3.0, 4.5, 2.5], [0.01, 0.015, 0.02, 0.3], dt)
    unstable = 1.01 * _modal_A([2.0], [0.001], dt)
    from scipy.linalg import block_diag
    A_id = block_diag(A_id, unstable, [[0.5]])
    ident = physical_modes(modes_of(A_id, dt), dt)
    assert len(modes_of(A_id, dt)) == 5 and len(ident) == 3
    mm = match_modes(ident, true, tol=0.05)
    assert mm.missed == 1 and mm.matched[1] is None
    assert mm.n_spurious == 1 and mm.spurious[0].frequency_hz == pytest.approx(4.5, rel=1e-9)
    assert mm.frequency_error_pct[0] == pytest.approx(1.0, rel=1e-6)
    assert mm.damping_error_pp[2] == pytest.approx(0.5, rel=1e-6)
    assert np.isnan(mm.frequency_error_pct[1])


def test_match_modes_is_one_to_one_for_a_close_pair():
    dt = 0.01
    true = modes_of(_modal_A([3.10, 3.15], [0.01, 0.01], dt), dt)
    one = modes_of(_modal_A([3.13], [0.01], dt), dt)      # one mode between the pair
    mm = match_modes(one, true)
    assert mm.missed == 1 and mm.n_spurious == 0
    two = modes_of(_modal_A([3.149, 3.101], [0.01, 0.01], dt), dt)
    mm2 = match_modes(two, true)
    assert mm2.missed == 0
    assert np.max(np.abs(mm2.frequency_error_pct)) < 0.05


def test_true_model_ratio_is_one_and_markov_error_is_similarity_invariant():
    m = paper_model()
    u = lowpass_input(6000, 2, 15.0, m.sample_time_s, seed=7)
    y, _ = simulate_innovation(m, u, seed=8)
    T = np.random.default_rng(0).standard_normal((6, 6)) + 3 * np.eye(6)
    Ti = np.linalg.inv(T)
    moved = {"A": T @ m.A @ Ti, "B": T @ m.B, "C": m.C @ Ti, "D": m.D, "K": T @ m.K}
    assert prediction_error_ratio(moved, m, u, y) == pytest.approx(1.0, abs=1e-6)
    assert stochastic_markov_error(moved, m, 100) < 1e-9
    # a 2 % error in K shows up in both metrics
    off = dict(moved, K=1.02 * moved["K"])
    assert stochastic_markov_error(off, m, 100) == pytest.approx(0.02, rel=1e-6)
    assert prediction_error_ratio(off, m, u, y) > 1.0
    # the innovation weighting makes the error independent of output units
    Sy = np.diag([100.0, 1.0])
    scaled_truth = InnovationModel(m.A, m.B, Sy @ m.C, Sy @ m.D, m.K @ np.linalg.inv(Sy),
                                   Sy @ m.innovation_covariance @ Sy, m.sample_time_s)
    dK = 0.05 * np.random.default_rng(1).standard_normal(moved["K"].shape)
    off2 = dict(off, K=moved["K"] + dK)
    off2_scaled = dict(off2, C=Sy @ off2["C"], D=Sy @ off2["D"], K=off2["K"] @ np.linalg.inv(Sy))
    e1 = stochastic_markov_error(off2, m, 100)
    assert stochastic_markov_error(off2_scaled, scaled_truth, 100) == pytest.approx(e1, rel=1e-9)
    raw = stochastic_markov_error(off2, m, 100, weighting=None)
    raw_scaled = stochastic_markov_error(off2_scaled, scaled_truth, 100, weighting=None)
    assert abs(raw_scaled / raw - 1) > 0.05


# ---------------------------------------------------------------------------
# peers
# ---------------------------------------------------------------------------


def _peer_available(name: str) -> bool:
    mod = {"control-era": "control", "nfoursid": "nfoursid"}.get(name, "sippy_unipi")
    return importlib.util.find_spec(mod) is not None


@pytest.fixture(scope="module")
def paper_white_record():
    m = paper_model()
    u = white_input(4000, 2, seed=11)
    y, _ = simulate_innovation(m, u, seed=12)
    u_val = white_input(6000, 2, seed=13)
    y_val, _ = simulate_innovation(m, u_val, seed=14)
    return m, u, y, u_val, y_val


@pytest.mark.parametrize("name", list(PEERS))
def test_peer_wrappers_identify_the_paper_model(name, paper_white_record):
    if not _peer_available(name):
        pytest.skip(f"{name}: package not installed")
    m, u, y, u_val, y_val = paper_white_record
    model, why = peer_identify(name, u, y, m.sample_time_s, 6)
    assert model is not None, why
    assert why == ""
    assert model["A"].shape == (6, 6) and model["B"].shape == (6, 2)
    assert model["C"].shape == (2, 6) and model["D"].shape == (2, 2)
    dt = m.sample_time_s
    if name == "control-era":
        # FIR Markov parameters (200 terms) + ERA, no noise model: the 0.28 % mode rings for
        # 1250 samples and is driven by the innovations, so its estimate is poor (sometimes
        # slightly unstable); the well-excited modes are found
        assert model["K"] is None and model["predictor_gain"] is None
        found = [md.frequency_rad_s for md in modes_of(model["A"], dt)]
        assert len(found) == 3
        assert min(abs(f - 304.49) for f in found) < 0.005 * 304.49
        assert min(abs(f - 37.10) for f in found) < 0.02 * 37.10
        return
    mm = match_modes(physical_modes(modes_of(model["A"], dt), dt), modes_of(m.A, dt))
    assert mm.missed == 0 and mm.n_spurious == 0
    assert np.max(np.abs(mm.frequency_error_pct)) < 2.0
    # K conventions: predictor gain = A K (paper), checked by the prediction ratio
    np.testing.assert_allclose(model["A"] @ model["K"], model["predictor_gain"], atol=1e-8)
    ratio = prediction_error_ratio(model, m, u_val, y_val)
    assert 0.98 < ratio < 1.08
    assert stochastic_markov_error(model, m, 100) < 0.3


def test_peer_identify_reports_failures_without_raising():
    model, why = peer_identify("no-such-peer", np.zeros((10, 1)), np.zeros((10, 1)), 1.0, 2)
    assert model is None and "unknown" in why
    if _peer_available("sippy-moesp"):
        model, why = peer_identify("sippy-moesp", np.full((50, 1), np.nan), np.zeros((50, 1)), 1.0, 2)
        assert model is None and why


def test_benchmark_cases_are_well_posed():
    cases = benchmark_cases()
    names = [c.name for c in cases]
    assert len(set(names)) == len(names) >= 7
    for c in cases:
        s = c.system
        assert isinstance(s, (InnovationModel, NoisyStateSpace))
        nyq_hz = 0.5 / c.sample_time_s
        md = modes_of(s.A, c.sample_time_s)
        assert len(md) == s.n_states // 2
        assert max(m.frequency_hz for m in md) < 0.8 * nyq_hz
        u = c.make_input(300, 0)
        assert u.shape == (300, s.n_inputs)
        K, Re = kalman_predictor(s)
        assert np.max(np.abs(np.linalg.eigvals(s.A - s.A @ K @ s.C))) < 1.0
        assert np.all(np.linalg.eigvalsh(Re) > 0)
    assert any(c.system.n_outputs > c.system.n_inputs + 2 for c in cases)
    assert any(min(m.damping_ratio for m in modes_of(c.system.A, c.sample_time_s)) < 0.0035
               for c in cases if c.name == "light-damping")
