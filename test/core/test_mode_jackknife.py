"""The jackknife standard deviations of the modes where the prediction-error covariance is out of reach.

Each replicate's pieces against a direct computation on the rows it keeps, and the standard
deviations against the scatter of a simulated 24-output structure's modes over seeds.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from scipy import linalg

from okid_bench.cases import benchmark_case
from okid_bench.scoring import modes_of
from okid_ros.core import mode_jackknife as jk
from okid_ros.core.arx import fit_arx
from okid_ros.core.arx_gram import lagged_gram, segment_lagged_grams
from okid_ros.core.least_squares import center_normal_equations, normal_equations
from okid_ros.core.pipeline import identify
from okid_ros.core.regressors import arx_regressors
from okid_ros.core.state_gram import StateGram
from okid_ros.core.uncertainty import uncertainty_problem
from okid_ros.sim.simulators import simulate


def _record(n_samples: int = 1200, p: int = 3, m: int = 2, seed: int = 0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n_samples, m)), rng.normal(size=(n_samples, p))


@pytest.mark.parametrize("with_gap", [False, True])
def test_the_segments_grams_add_up_to_the_window_gram(with_gap):
    u, y = _record()
    valid = None
    if with_gap:
        valid = np.ones(len(y), dtype=bool)
        valid[610:614] = False
    gram, sums, rows = lagged_gram(u, y, 7, valid)
    bounds = jk._segment_bounds(rows, 5)
    parts = segment_lagged_grams(u, y, 7, bounds, valid)
    assert len(parts) == 5
    assert sum(part[2] for part in parts) == rows.size
    np.testing.assert_allclose(sum(part[0] for part in parts), gram, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(sum(part[1] for part in parts), sums, rtol=1e-12, atol=1e-9)


def test_a_replicates_arx_model_is_the_fit_on_the_rows_it_keeps():
    u, y = _record()
    q = 6
    arx = fit_arx(u, y, q, regularization="ridge", center=True)
    gram, sums, rows = lagged_gram(u, y, q)
    bounds = jk._segment_bounds(rows, 4)
    parts = segment_lagged_grams(u, y, q, bounds)
    fits = jk._arx_replicates(arx, gram, sums, rows.size, parts)
    phi, targets, kept_rows = arx_regressors(u, y, q)
    # The window's prior (channel scales of all its rows), the penalty scaled to the rows kept.
    centered = center_normal_equations(normal_equations(phi, targets))
    precision = jk.prior_precision(q, 3, 2, jk.channel_mean_square(centered, 3, 2, q), "ridge")
    for j, fit in enumerate(fits):
        keep = (kept_rows < bounds[j]) | (kept_rows >= bounds[j + 1])
        normal = center_normal_equations(normal_equations(phi[keep], targets[keep]))
        direct = linalg.solve(normal.R + arx.penalty * keep.sum() / rows.size * precision, normal.r)
        np.testing.assert_allclose(fit.theta, direct, rtol=1e-7, atol=1e-9 * np.abs(direct).max())
    spread = np.std([fit.theta for fit in fits], axis=0).max()
    assert spread > 1e-4, "the replicates differ"


def test_the_leading_subspace_of_a_perturbed_hankel_matrix_is_found():
    rng = np.random.default_rng(1)
    left = linalg.qr(rng.normal(size=(60, 6)), mode="economic")[0]
    right = linalg.qr(rng.normal(size=(50, 6)), mode="economic")[0]
    h0 = left @ np.diag([50, 40, 30, 20, 12, 10]) @ right.T + 0.01 * rng.normal(size=(60, 50))
    weight = np.eye(50) + 0.05 * rng.normal(size=(50, 50))
    start = linalg.svd(left @ np.diag([50, 40, 30, 20, 12, 10]) @ right.T)[0][:, :10]
    vectors, values = jk._leading_subspace(h0, weight, start, 6)
    exact_u, exact_s, _ = linalg.svd(h0 @ weight)
    np.testing.assert_allclose(values, exact_s[:6], rtol=1e-8)
    # Same subspace: the projection of each exact vector on the computed ones keeps its length.
    np.testing.assert_allclose(np.linalg.norm(vectors.T @ exact_u[:, :6], axis=0), 1.0, rtol=1e-8)


def test_state_gram_without_a_segment_is_the_gram_of_the_other_rows():
    u, y = _record()
    whole = StateGram(u, y, 5)
    bounds = jk._segment_bounds(whole.rows, 4)
    gram_part, _, n_part = segment_lagged_grams(u, y, 5, bounds)[2]
    replicate = whole.without(gram_part, n_part)
    index = whole.rows[(whole.rows < bounds[2]) | (whole.rows >= bounds[3])]
    extended = whole._extended(index)
    np.testing.assert_allclose(replicate.gram, extended.T @ extended / index.size, rtol=1e-10, atol=1e-12)
    assert replicate.n_samples == index.size


def test_many_outputs_get_jackknife_standard_deviations_of_the_size_of_their_errors():
    """16 accelerometers, 6 modes (``many-outputs`` of the benchmarks): 6 seeds x 6 modes x 2.

    The case is beyond the budget of the prediction-error covariance.
    The normalized errors (estimate - truth) / std have an RMS near 1 (a 7-degree-of-freedom
    jackknife: about 1.2 when calibrated) and most lie within 2.5 std; stds 3x too small or too
    large fail. The calibration proper: bench/mode_uncertainty.py, docs/benchmarks-uncertainty.md.
    """
    case = benchmark_case("many-outputs")
    truth = modes_of(case.system.A, case.sample_time_s)
    normalized = []
    for seed in range(6):
        u = case.make_input(5000, seed)
        y = simulate(case.system, u, seed=1000 + seed)
        model = identify(u, y, case.sample_time_s, order=40)
        assert uncertainty_problem(model.A.shape[0], 16, 2, 5000, burn_in=40), "the covariance would have run"
        assert model.uncertainty.computed and model.uncertainty.method == "jackknife", model.uncertainty
        for true in truth:
            mode = min(model.modes, key=lambda md: abs(md.frequency_hz - true.frequency_hz))
            assert abs(mode.frequency_hz / true.frequency_hz - 1) < 0.02
            assert mode.frequency_hz_std > 0 and mode.damping_ratio_std > 0
            normalized += [(mode.frequency_hz - true.frequency_hz) / mode.frequency_hz_std,
                           (mode.damping_ratio - true.damping_ratio) / mode.damping_ratio_std]
    normalized = np.array(normalized)
    rms = float(np.sqrt(np.mean(normalized**2)))
    assert 0.5 < rms < 2.0, normalized
    assert np.mean(np.abs(normalized) <= 2.5) >= 0.8, normalized


def test_no_jackknife_when_it_is_switched_off():
    case = benchmark_case("many-outputs")
    u = case.make_input(4000, 0)
    y = simulate(case.system, u, seed=1000)
    model = identify(u, y, case.sample_time_s, order=30, jackknife_segments=0)
    assert model.modes and not model.uncertainty.computed
    assert "budget" in model.uncertainty.reason
    assert all(np.isnan(mode.frequency_hz_std) for mode in model.modes)


def _peak_bytes(function) -> int:
    """Peak of the memory numpy and Python allocate while ``function()`` runs (tracemalloc)."""
    tracemalloc.start()
    try:
        function()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_the_jackknife_holds_one_segment_gram_at_a_time():
    """Its memory does not grow with the segments (node 2 allows 64; the core any number).

    Each segment's lagged Gram is ((q + 1)(p + m))^2 numbers (50 MB at 16 outputs, q = 138): all
    of them at once took 3.3 GB for 58 segments of a 6000-sample record.
    """
    u, y = _record(3000, p=8, m=2)
    arx = fit_arx(u, y, 40, regularization="ridge", center=True)
    targets = np.exp(2j * np.pi * np.array([0.05, 0.1]))

    def run(segments):
        return lambda: jk.realization_jackknife(arx, u, y, targets, 8, 1.0, hankel_rows=20, hankel_cols=20,
                                                n_segments=segments)

    gram_bytes = (41 * 10) ** 2 * 8
    few, many = _peak_bytes(run(2)), _peak_bytes(run(24))
    assert many < few + 4 * gram_bytes, (few, many, gram_bytes)


def test_a_replicate_without_an_oscillating_pole_leaves_the_stds_not_computed():
    """No complex pole in a replicate gave NaN standard deviations with ``computed`` and no reason."""
    rng = np.random.default_rng(0)
    u, y = rng.normal(size=(3000, 2)), rng.normal(size=(3000, 16))
    arx = fit_arx(u, y, 20, regularization="ridge", center=True)
    f_std, z_std, reason = jk.realization_jackknife(arx, u, y, np.array([0.9 * np.exp(0.5j)]), 2, 0.01,
                                                    hankel_rows=10, hankel_cols=10, n_segments=8)
    assert "no complex pole" in reason, reason
    assert np.isnan(f_std).all() and np.isnan(z_std).all()


def test_a_move_the_replicates_do_not_repeat_is_added_to_the_std():
    """The chain's model is the state regression moved on by its re-estimation passes.

    The replicates repeat the regression only; the move from the window's own regression to the
    model handed in is added in quadrature (before, a mode moved by the passes kept the
    regression's scatter: 78-80 % coverage for the higher modes of ``many-outputs``).
    """
    case = benchmark_case("many-outputs")
    u = case.make_input(4000, 0)
    y = simulate(case.system, u, seed=1000)
    u, y = u - u.mean(axis=0), y - y.mean(axis=0)
    arx = fit_arx(u, y, 30, regularization="ridge", center=True)
    dt, n_states = case.sample_time_s, 20
    whole = StateGram(u, y, 15)
    full = jk.decompose_hankel(arx.observer_markov, 15, 15, whole.past_weight())
    poles = jk._regressed_poles(whole, full.h0, full.U, full.s, n_states)
    upper = poles[poles.imag > 0]
    s_upper = np.log(upper) / dt
    # The window's own poles of three structural modes (not noise poles, whose scatter is wide).
    own = np.array([upper[np.argmin(np.abs(np.abs(s_upper) / (2 * np.pi) - f))] for f in (5.2, 9.7, 16.5)])

    def stds(targets):
        f_std, z_std, reason = jk.realization_jackknife(arx, u, y, targets, n_states, dt, hankel_rows=15,
                                                        hankel_cols=15, n_segments=8)
        assert not reason, reason
        return f_std, z_std

    f_own, z_own = stds(own)
    assert np.all(f_own > 0) and np.all(z_own > 0)
    s = np.log(own) / dt
    f, zeta = np.abs(s) / (2 * np.pi), -s.real / np.abs(s)
    df, dz = 3 * f_own, 3 * z_own  # moves well beyond the regression's scatter
    f_moved, z_moved = f + df, zeta + dz
    wn = 2 * np.pi * f_moved
    moved = np.exp((-z_moved * wn + 1j * wn * np.sqrt(1 - z_moved**2)) * dt)
    # Each moved target is still far nearer its own pole than any other (no near tie to flip).
    distance = np.abs(np.log(moved)[:, None] / dt - s_upper[None, :])
    assert np.all(np.sort(distance, axis=1)[:, 1] > 3 * np.min(distance, axis=1)), distance
    f_std, z_std = stds(moved)
    np.testing.assert_allclose(f_std, np.hypot(f_own, df), rtol=1e-6)
    np.testing.assert_allclose(z_std, np.hypot(z_own, dz), rtol=1e-6)


def _window_and_poles(u, y, arx, hankel: int, n_states: int):
    """The window of the jackknife, its state Gram, leading vectors and its own regression's poles."""
    gram, sums, rows = lagged_gram(u, y, max(arx.order, hankel))
    window = jk._ArxWindow.of(arx, gram, sums, rows.size)
    whole = StateGram(u, y, hankel)
    full = jk.decompose_hankel(arx.observer_markov, hankel, hankel, whole.past_weight())
    start = full.U[:, : n_states + jk.SPARE_COLUMNS].copy()
    return window, whole, start, jk._regressed_poles(whole, full.h0, full.U, full.s, n_states)


def test_the_penalty_bias_is_estimated_from_one_more_tikhonov_step():
    """A ridge fit's bias, which the replicates share and cannot see, is estimated and added.

    The step estimates, to first order in the penalty, the move from the ridge fit to the
    unregularized one, ``(R + lam P)^-1 lam P theta_LS``. ``many-outputs`` (16 outputs, q = 40,
    GCV's penalty): the estimate has the sign of the modes' actual move to the unregularized
    fit's poles and 0.3-3 times its size (measured 0.5-1.2); an unregularized fit has no
    penalty bias.
    """
    case = benchmark_case("many-outputs")
    u = case.make_input(6000, 0)
    y = simulate(case.system, u, seed=1000)
    u, y = u - u.mean(axis=0), y - y.mean(axis=0)
    dt, hankel, n_states, q = case.sample_time_s, 20, 20, 40
    window, whole, start, center = _window_and_poles(u, y, fit_arx(u, y, q, regularization="ridge", center=True),
                                                     hankel, n_states)
    own = np.array([center[np.argmin(np.abs(center - np.exp((-t.damping_ratio + 1j * np.sqrt(1 - t.damping_ratio**2))
                                                              * t.frequency_rad_s * dt)))]
                    for t in modes_of(case.system.A, dt)])
    f_bias, z_bias = jk._penalty_bias(window, whole, jk.nearest_modes(center, own, dt), own, dt, hankel_rows=hankel,
                                      hankel_cols=hankel, start=start, n_states=n_states)
    window, whole, start, unregularized = _window_and_poles(u, y, fit_arx(u, y, q, regularization="none", center=True),
                                                            hankel, n_states)
    f_move, z_move = (value - base for value, base in zip(jk.nearest_modes(unregularized, own, dt),
                                                          jk.nearest_modes(own, own, dt)))
    for bias, move in ((f_bias, f_move), (z_bias, z_move)):
        assert np.all(np.sign(bias) == np.sign(move)), (bias, move)
        ratio = np.abs(bias) / np.abs(move)
        assert np.all((ratio > 1 / 3) & (ratio < 3)), (bias, move)

    zero = jk._penalty_bias(window, whole, jk.nearest_modes(unregularized, own, dt), own, dt, hankel_rows=hankel,
                            hankel_cols=hankel, start=start, n_states=n_states)
    assert not np.any(zero[0]) and not np.any(zero[1])
