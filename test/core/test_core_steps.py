"""Each step of the core against known truth: ARX, Eq. 24, ERA, modal form, whitening gain."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import linalg

from okid_ros.core.arx import fit_arx, minimum_samples
from okid_ros.core.era import era
from okid_ros.core.gain import gain_by_whitening, invert_polynomial_matrix
from okid_ros.core.markov import markov_from_arx, markov_from_state_space
from okid_ros.core.modal import identify_modes, mac, match_modes, modal_form, mpc
from okid_ros.core.regressors import arx_regressors, regressor_at, regressor_length
from okid_ros.core.statespace import simulate
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation


def _random_stable_system(n: int, m: int, p: int, seed: int):
    rng = np.random.default_rng(seed)
    radii = rng.uniform(0.5, 0.95, n // 2)
    angles = rng.uniform(0.2, 2.5, n // 2)
    blocks = [r * np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]) for r, a in zip(radii, angles)]
    T = rng.standard_normal((n, n))
    A = T @ linalg.block_diag(*blocks) @ linalg.inv(T)
    return A, rng.standard_normal((n, m)), rng.standard_normal((p, n)), rng.standard_normal((p, m))


def test_regressor_layout_matches_single_row_builder():
    rng = np.random.default_rng(1)
    u, y = rng.standard_normal((30, 2)), rng.standard_normal((30, 3))
    phi, targets, rows = arx_regressors(u, y, 4)
    assert phi.shape == (26, regressor_length(4, 3, 2)) == (26, 2 + 4 * 5)
    np.testing.assert_array_equal(phi[7], regressor_at(u, y, rows[7], 4))
    np.testing.assert_array_equal(targets, y[4:])
    # Lag 1 block is [y_{k-1}; u_{k-1}].
    np.testing.assert_array_equal(phi[0, 2:7], np.concatenate([y[3], u[3]]))


def test_regressors_never_straddle_a_gap():
    rng = np.random.default_rng(2)
    u, y = rng.standard_normal((40, 1)), rng.standard_normal((40, 1))
    valid = np.ones(40, bool)
    valid[15] = False
    _, _, rows = arx_regressors(u, y, 3, valid)
    assert not np.any((rows >= 15) & (rows <= 18))
    assert rows[0] == 3 and 19 in rows


def test_unregularized_arx_is_the_least_squares_solution():
    rng = np.random.default_rng(3)
    u, y = rng.standard_normal((500, 2)), rng.standard_normal((500, 2))
    fit = fit_arx(u, y, 5, regularization="none")
    phi, targets, _ = arx_regressors(u, y, 5)
    expected = np.linalg.lstsq(phi, targets, rcond=None)[0]
    np.testing.assert_allclose(fit.theta, expected, rtol=1e-9, atol=1e-11)


def test_regularized_arx_recovers_a_known_arx_system():
    rng = np.random.default_rng(4)
    n = 20000
    u = rng.standard_normal((n, 2))
    y = np.zeros((n, 2))
    a1 = np.array([[1.2, 0.1], [0.0, 0.9]])
    a2 = np.array([[-0.5, 0.0], [0.05, -0.2]])
    b1 = np.array([[1.0, 0.3], [-0.4, 0.8]])
    for k in range(2, n):
        # Equation noise comparable to the input drive, so the output lags are not nearly
        # collinear with the input lags (which would make single ARX coefficients ill-determined).
        y[k] = a1 @ y[k - 1] + a2 @ y[k - 2] + b1 @ u[k - 1] + 0.5 * rng.standard_normal(2)
    for reg in ("ridge", "tc"):
        fit = fit_arx(u, y, 6, regularization=reg)
        np.testing.assert_allclose(fit.output_coefficients[0], a1, atol=0.03)
        np.testing.assert_allclose(fit.output_coefficients[1], a2, atol=0.03)
        np.testing.assert_allclose(fit.input_coefficients[0], b1, atol=0.03)
        assert np.abs(fit.output_coefficients[3:]).max() < 0.03
        assert fit.residual_covariance[0, 0] == pytest.approx(0.25, rel=0.1)


def test_arx_rejects_bad_data_with_reasons():
    u, y = np.zeros((100, 2)), np.zeros((100, 2))
    with pytest.raises(ValueError, match="different lengths"):
        fit_arx(u, y[:-1], 3)
    y_nan = y.copy()
    y_nan[10, 1] = np.nan
    with pytest.raises(ValueError, match="sample 10, channel 1"):
        fit_arx(u, y_nan, 3)
    with pytest.raises(ValueError, match=f"at least {minimum_samples(50, 2, 2)} needed"):
        fit_arx(u, np.ones((100, 2)), 50, regularization="none")


def test_markov_from_arx_is_eq_24_on_a_noise_free_system():
    A, B, C, D = _random_stable_system(4, 2, 2, seed=5)
    u = white_input(2000, 2, seed=6)
    y = simulate(A, B, C, D, u)
    fit = fit_arx(u, y, 8, regularization="none")
    markov = markov_from_arx(fit)
    np.testing.assert_allclose(markov, markov_from_state_space(A, B, C, D, 9), atol=1e-7)
    with pytest.raises(ValueError, match="Eq. 28"):
        markov_from_arx(fit, n_terms=20)


def test_era_recovers_poles_and_markov_parameters_with_and_without_weighting():
    A, B, C, D = _random_stable_system(6, 2, 3, seed=7)
    blocks = markov_from_state_space(A, B, C, D, 41)[1:]
    rng = np.random.default_rng(8)
    M = rng.standard_normal((40, 40))
    for weight in (None, linalg.cholesky(M @ M.T + np.eye(40), lower=True)):
        real = era(blocks, 6, n_rows=20, n_cols=20, right_weight=weight)
        np.testing.assert_allclose(
            np.sort_complex(linalg.eigvals(real.A)), np.sort_complex(linalg.eigvals(A)), atol=1e-8
        )
        rebuilt = markov_from_state_space(real.A, real.B, real.C, D, 10)
        np.testing.assert_allclose(rebuilt, markov_from_state_space(A, B, C, D, 10), atol=1e-8)


def test_paper_model_modes_and_normalized_modal_form_is_deterministic():
    truth = paper_model()
    modes, _ = identify_modes(truth.A, truth.B, truth.C, truth.sample_time_s)
    freqs = [m.frequency_rad_s for m in modes]
    np.testing.assert_allclose(freqs, [37.097, 46.1325, 304.489], rtol=2e-4)
    np.testing.assert_allclose([m.damping_ratio for m in modes[:2]], [0.002763, 0.028684], rtol=1e-3)
    reference = modal_form(truth.A, truth.B, truth.C, truth.K, truth.sample_time_s)
    # Blocks [[s, w], [-w, s]] and a zero in row 1 at each mode's second state.
    for i in range(3):
        blk = reference.A[2 * i : 2 * i + 2, 2 * i : 2 * i + 2]
        assert blk[0, 0] == pytest.approx(blk[1, 1]) and blk[0, 1] == pytest.approx(-blk[1, 0])
        assert blk[0, 1] > 0
        assert abs(reference.C[0, 2 * i + 1]) < 1e-12 and reference.C[0, 2 * i] > 0
    # Any other realization of the same system gives the same modal form.
    rng = np.random.default_rng(9)
    T = rng.standard_normal((6, 6))
    Ti = linalg.inv(T)
    other = modal_form(Ti @ truth.A @ T, Ti @ truth.B, truth.C @ T, Ti @ truth.K, truth.sample_time_s)
    for name in ("A", "B", "C", "K"):
        np.testing.assert_allclose(getattr(other, name), getattr(reference, name), atol=1e-9)


def test_shape_indicators():
    real = np.array([1.0, -2.0, 0.5])
    assert mpc(real * np.exp(0.7j)) == pytest.approx(1.0)
    assert mpc(np.array([1.0, 1j])) == pytest.approx(0.0, abs=1e-12)
    assert mac(real, 3 * real) == pytest.approx(1.0)
    assert mac(np.array([1.0, 0.0]), np.array([0.0, 1.0])) == pytest.approx(0.0)


def _shifted(mode, frequency_factor: float, shape_noise: float, rng) -> object:
    """A copy of ``mode`` at ``frequency_factor`` times its frequency with a perturbed shape."""
    size = mode.shape.size
    shape = mode.shape + shape_noise * (rng.standard_normal(size) + 1j * rng.standard_normal(size))
    return dataclasses.replace(
        mode,
        frequency_rad_s=mode.frequency_rad_s * frequency_factor,
        frequency_hz=mode.frequency_hz * frequency_factor,
        shape=shape / np.linalg.norm(shape),
    )


def test_match_modes_by_frequency_and_mac():
    truth = paper_model()
    modes, _ = identify_modes(truth.A, truth.B, truth.C, truth.sample_time_s)
    assert len(modes) == 3
    rng = np.random.default_rng(3)
    # Every mode moved by 1-3 % with its shape perturbed (MAC still > 0.9), listed in reverse.
    shifted = [_shifted(m, f, 0.1, rng) for m, f in zip(modes, (1.02, 0.97, 1.01))]
    assert all(0.9 < mac(a.shape, b.shape) < 1.0 for a, b in zip(modes, shifted))
    assert match_modes(modes, list(reversed(shifted))) == [2, 1, 0]
    # The two close modes (37 and 46 rad/s) swap frequencies: MAC decides, not the frequency.
    close = [dataclasses.replace(modes[0], frequency_rad_s=modes[1].frequency_rad_s * 0.99),
             dataclasses.replace(modes[1], frequency_rad_s=modes[0].frequency_rad_s * 1.01)]
    assert match_modes(modes, close, max_frequency_change=0.3) == [0, 1]
    # Too far in frequency, or a shape that is another mode's: new modes.
    far = _shifted(modes[0], 1.08, 0.0, rng)
    other_shape = dataclasses.replace(modes[0], shape=np.array([modes[0].shape[1].conj(), -modes[0].shape[0].conj()]))
    assert mac(other_shape.shape, modes[0].shape) < 0.7
    assert match_modes(modes, [far, other_shape, shifted[2]]) == [None, None, 2]
    assert match_modes(modes[:1], modes[1:]) == [None, None]


def test_polynomial_inverse_is_an_inverse():
    rng = np.random.default_rng(10)
    coeffs = 0.3 * rng.standard_normal((3, 2, 2))
    inv = invert_polynomial_matrix(coeffs, 30)
    full = np.concatenate([np.eye(2)[None], coeffs])
    for j in range(30):  # (N M)_j = sum_i N_i M_{j-i} = I if j = 0 else 0
        acc = sum(full[i] @ inv[j - i] for i in range(min(j, 3) + 1))
        np.testing.assert_allclose(acc, np.eye(2) if j == 0 else 0.0, atol=1e-12)


def test_whitening_gain_recovers_the_true_kalman_gain_on_the_true_model():
    truth = paper_model()
    # The paper: with the true (A, B, C, D) and a long enough whitening filter, K converges to
    # the optimal gain. Measured: C A^i K error 16 % with r = 20, 2 % with r = 60 (60000 samples).
    u = white_input(60000, 2, seed=11)
    y, e = simulate_innovation(truth, u, seed=12, x0=None)
    white = gain_by_whitening(truth.A, truth.B, truth.C, truth.D, u, y, ar_order=60, n_markov=30)
    true_markov = markov_from_state_space(truth.A, truth.A @ truth.K, truth.C, np.eye(2), 31)[1:]
    err = np.linalg.norm(white.stochastic_markov - true_markov) / np.linalg.norm(true_markov)
    assert err < 0.04
    assert np.abs(white.K - truth.K).max() < 0.01
    np.testing.assert_allclose(white.innovation_covariance, np.cov(e.T), rtol=0.03, atol=0.01)


def test_chunked_predictor_advance_gives_the_stepped_state_over_gaps():
    from okid_ros.core.statespace import InnovationPredictor
    from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

    model = paper_model()
    u = lowpass_input(1000, 2, 20.0, model.sample_time_s, seed=1)
    y, _ = simulate_innovation(model, u, seed=2)
    skipped = np.zeros(1000, dtype=int)
    skipped[300], skipped[700] = 2, -1  # a bridged gap and a restart
    stepped, chunked = InnovationPredictor(model), InnovationPredictor(model)
    held = stepped.run_with_gaps(u, y, skipped, None, 5)
    assert np.array_equal(chunked.run_with_gaps(u, y, skipped, None, 5, chunked=True), held)
    np.testing.assert_allclose(chunked.x, stepped.x, rtol=0, atol=1e-12 * np.abs(stepped.x).max())


def test_predictor_run_equals_its_steps():
    """``run`` over a block (one BLAS loop, then the innovations at once) equals ``step`` per sample."""
    from okid_ros.core.statespace import InnovationPredictor
    from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

    model = paper_model()
    model.input_offset, model.output_offset = np.array([0.3, -0.1]), np.array([2.0, -1.0])
    u = lowpass_input(400, 2, 20.0, model.sample_time_s, seed=3)
    y, _ = simulate_innovation(model, u, seed=4)
    x0 = np.linspace(-1.0, 1.0, model.n_states)
    block, stepped = InnovationPredictor(model, x0), InnovationPredictor(model, x0)
    got = block.run(u, y)
    want = np.array([stepped.step(u[k], y[k]) for k in range(u.shape[0])])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
    np.testing.assert_allclose(block.x, stepped.x, rtol=0, atol=1e-12 * np.abs(stepped.x).max())
    assert block.run(u[:0], y[:0]).shape == (0, 2)


def test_a_warm_start_over_the_settle_samples_gives_the_state_of_one_over_the_whole_record():
    """The state forgets its start after ``settle_samples``: the restart and the worker start there."""
    from okid_ros.core.statespace import SETTLE_MEMORIES, InnovationPredictor
    from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

    model = paper_model()
    u = lowpass_input(6000, 2, 20.0, model.sample_time_s, seed=5)
    y, _ = simulate_innovation(model, u, seed=6)
    whole = InnovationPredictor(model, np.full(model.n_states, 1e3))  # far off at the start
    whole.run(u, y)
    settle = whole.settle_samples
    assert settle == SETTLE_MEMORIES * whole.memory_samples and settle < 2000
    tail = InnovationPredictor(model)
    tail.run(u[-settle:], y[-settle:])
    scale = np.abs(whole.x).max()
    np.testing.assert_allclose(tail.x, whole.x, rtol=0, atol=1e-11 * scale)
    short = InnovationPredictor(model)  # a sixth of it leaves the start's trace (e^-5)
    short.run(u[-settle // 6:], y[-settle // 6:])
    assert np.abs(short.x - whole.x).max() > 1e-6 * scale
