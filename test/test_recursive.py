"""Tests of the recursive ARX window (okid_ros.core.recursive) against batch least squares.

The reference is always an independent batch computation on exactly the rows that should be in
the window: ``arx_regressors`` (with ``valid`` for gaps) and ``numpy.linalg.lstsq`` of the
stacked, augmented system ``[Phi; sqrt(penalty) L^T] Theta = [Y; 0]`` with ``P^{-1} = L L^T``.
"""

from __future__ import annotations

import numpy as np
import pytest

from okid_ros.core.arx import (
    channel_mean_square,
    fit_arx,
    normal_equations,
    prior_precision,
    solve_normal_equations,
)
from okid_ros.core.recursive import SlidingWindowArx
from okid_ros.core.regressors import arx_regressors

RTOL = 1e-9


def simulate(n: int, p: int = 2, m: int = 2, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A stable, well-excited MIMO ARX(2) system with white inputs and noise."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, m))
    y = np.zeros((n, p))
    a1 = 0.5 * np.eye(p) + 0.1 * rng.standard_normal((p, p)) / np.sqrt(p)
    a2 = -0.2 * np.eye(p)
    b1 = rng.standard_normal((p, m))
    e = 0.1 * rng.standard_normal((n, p))
    for k in range(2, n):
        y[k] = a1 @ y[k - 1] + a2 @ y[k - 2] + b1 @ u[k - 1] + e[k]
    return u, y


def batch_theta(u, y, order, window, precision, penalty, valid=None, forgetting=1.0):
    """Regularized LS on the last ``window`` valid rows (all of them if None), by lstsq."""
    phi, targets, _ = arx_regressors(u, y, order, valid)
    if window is not None:
        phi, targets = phi[-window:], targets[-window:]
    if forgetting != 1.0:
        w = np.sqrt(forgetting ** np.arange(phi.shape[0] - 1, -1, -1))
        phi, targets = phi * w[:, None], targets * w[:, None]
    chol = np.linalg.cholesky(precision)
    aug_phi = np.vstack([phi, np.sqrt(penalty) * chol.T])
    aug_t = np.vstack([targets, np.zeros((phi.shape[1], targets.shape[1]))])
    return np.linalg.lstsq(aug_phi, aug_t, rcond=None)[0], phi.shape[0]


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_window_equals_batch_after_every_update():
    q, p, m, W = 3, 2, 2, 120
    u, y = simulate(900, p, m, seed=1)
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.05, block_size=16)
    rng = np.random.default_rng(5)
    k, checks, worst = 0, 0, 0.0
    while k < u.shape[0]:
        n = int(rng.integers(1, 40))
        stop = min(k + n, u.shape[0])
        if rng.random() < 0.5:
            for j in range(k, stop):
                est.push(u[j], y[j])
        else:
            est.update(u[k:stop], y[k:stop])
        k = stop
        ref, rows = batch_theta(u[:k], y[:k], q, W, est.precision, 0.05)
        assert est.status.rows_in_window == rows
        if rows >= 2 * est.n_params:  # filling, full and wrapped around
            worst = max(worst, rel(est.coefficients(), ref))
            checks += 1
    assert checks > 20
    assert worst <= RTOL
    assert est.status.window_fill == 1.0


def test_single_sample_pushes_match_batch_at_every_sample():
    q, p, m, W = 2, 1, 1, 25
    u, y = simulate(200, p, m, seed=2)
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.0, block_size=4)
    for k in range(u.shape[0]):
        est.push(u[k], y[k])
        if k >= q + 10:
            ref, _ = batch_theta(u[: k + 1], y[: k + 1], q, W, est.precision, 0.0)
            assert rel(est.coefficients(), ref) <= RTOL


def test_matches_solve_normal_equations_with_same_prior():
    q, p, m, W = 4, 2, 1, 300
    u, y = simulate(700, p, m, seed=3)
    phi, t, _ = arx_regressors(u, y, q)
    ms = channel_mean_square(normal_equations(phi, t), p, m, q)
    est = SlidingWindowArx.from_prior(q, p, m, ms, kind="tc", decay=0.8, window=W, penalty=2.0)
    est.update(u, y)
    normal = normal_equations(phi[-W:], t[-W:])
    ref = solve_normal_equations(normal, prior_precision(q, p, m, ms, "tc", 0.8), 2.0)[0]
    assert rel(est.coefficients(), ref) <= RTOL
    # GCV at solve time chooses the same penalty as the batch routine.
    est_gcv = SlidingWindowArx.from_prior(q, p, m, ms, kind="tc", decay=0.8, window=W, penalty="gcv")
    est_gcv.update(u, y)
    ref_gcv, lam, _, _ = solve_normal_equations(normal, prior_precision(q, p, m, ms, "tc", 0.8), "gcv")
    sol = est_gcv.solve()
    assert sol.ok and sol.penalty == pytest.approx(lam, rel=1e-4)  # scalar-search tolerance
    assert rel(sol.theta, ref_gcv) <= 1e-5


def test_arx_fit_of_window_equals_fit_arx_on_window_samples():
    q, p, m, W = 5, 2, 2, 400
    u, y = simulate(1500, p, m, seed=4)
    est = SlidingWindowArx(q, p, m, window=W, penalty=1.0)
    est.update(u, y)
    window_fit = est.arx_fit("ridge", 0.5)
    batch = fit_arx(u[-(W + q):], y[-(W + q):], q, "ridge", 0.5)
    assert window_fit.n_rows == batch.n_rows == W
    assert rel(window_fit.theta, batch.theta) <= RTOL
    # With GCV the penalties agree to the tolerance of the scalar search of the batch routine.
    gcv_fit, gcv_batch = est.arx_fit("ridge", "gcv"), fit_arx(u[-(W + q):], y[-(W + q):], q, "ridge", "gcv")
    assert gcv_fit.penalty == pytest.approx(gcv_batch.penalty, rel=1e-4)
    assert rel(gcv_fit.theta, gcv_batch.theta) <= 1e-5
    u_w, y_w, start = est.window_samples()
    np.testing.assert_array_equal(u_w, u[-(W + q):])
    np.testing.assert_array_equal(y_w, y[-(W + q):])
    assert start[0] and not start[1:].any()


@pytest.mark.parametrize("prior", ["scalar", "diagonal", "full"])
def test_prior_forms(prior):
    q, p, m, W = 2, 2, 2, 80
    u, y = simulate(300, p, m, seed=6)
    d = m + q * (p + m)
    rng = np.random.default_rng(0)
    if prior == "scalar":
        given, full = 3.0, 3.0 * np.eye(d)
    elif prior == "diagonal":
        given = rng.uniform(0.5, 2.0, d)
        full = np.diag(given)
    else:
        a = rng.standard_normal((d, d))
        given = full = a @ a.T / d + np.eye(d)
    est = SlidingWindowArx(q, p, m, window=W, prior_precision=given, penalty=0.7)
    est.update(u, y)
    ref, _ = batch_theta(u, y, q, W, full, 0.7)
    assert rel(est.coefficients(), ref) <= RTOL


def test_forgetting_equals_weighted_batch():
    q, p, m, lam = 3, 2, 2, 0.98
    u, y = simulate(600, p, m, seed=7)
    est = SlidingWindowArx(q, p, m, window=None, forgetting=lam, penalty=0.3, block_size=32)
    for k0 in range(0, 600, 37):
        est.update(u[k0 : k0 + 37], y[k0 : k0 + 37])
        k = min(k0 + 37, 600)
        if k > 60:
            ref, _ = batch_theta(u[:k], y[:k], q, None, est.precision, 0.3, forgetting=lam)
            assert rel(est.coefficients(), ref) <= RTOL
    assert est.memory_bytes() < 10 * (est._D**2 * 8)  # no window is stored


def test_forget_prior_equals_classic_rls():
    """With the prior discounted like the data, the estimate is that of classic RLS with P0."""
    q, p, m, lam = 2, 1, 1, 0.99
    u, y = simulate(400, p, m, seed=8)
    d = m + q * (p + m)
    p0 = 100.0
    est = SlidingWindowArx(q, p, m, window=None, forgetting=lam, prior_precision=1.0 / p0,
                           penalty=1.0, forget_prior=True, block_size=8)
    est.update(u, y)
    phi, t, _ = arx_regressors(u, y, q)
    P = p0 * np.eye(d)
    theta = np.zeros((d, p))
    for x, target in zip(phi, t):
        g = P @ x / (lam + x @ P @ x)
        theta += np.outer(g, target - x @ theta)
        P = (P - np.outer(g, x @ P)) / lam
    assert rel(est.coefficients(), theta) <= 1e-8


def test_reset_forgets_everything():
    q, p, m, W = 2, 2, 2, 50
    u, y = simulate(300, p, m, seed=9)
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.1)
    est.update(u[:200], y[:200])
    est.push([np.nan, 0.0], [0.0, 0.0])
    est.coefficients()
    est.reset()
    st = est.status
    assert st.samples_seen == 0 and st.rows_in_window == 0 and st.rejected_nonfinite == 0
    assert not est.solve().ok and np.all(est.coefficients() == 0.0)
    est.update(u[200:], y[200:])
    ref, _ = batch_theta(u[200:], y[200:], q, W, est.precision, 0.1)
    assert rel(est.coefficients(), ref) <= RTOL


def test_adaptation_off_keeps_window_but_gives_errors():
    q, p, m, W = 2, 2, 2, 100
    u, y = simulate(500, p, m, seed=10)
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.1)
    est.update(u[:250], y[:250])
    theta = est.coefficients().copy()
    est.adaptation_enabled = False
    errors = est.update(u[250:400], y[250:400])
    assert np.all(np.isfinite(errors))
    phi, t, rows = arx_regressors(u, y, q)
    sel = (rows >= 250) & (rows < 400)
    np.testing.assert_allclose(errors, t[sel] - phi[sel] @ theta, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(est.coefficients(), theta)
    assert est.status.samples_accepted == 400 and not est.status.adapting
    # Switched back on, the window continues with the rows before the pause, then the new ones.
    est.adaptation_enabled = True
    est.update(u[400:430], y[400:430])
    phi_w = np.vstack([phi[rows < 250], phi[(rows >= 400) & (rows < 430)]])[-W:]
    t_w = np.vstack([t[rows < 250], t[(rows >= 400) & (rows < 430)]])[-W:]
    ref = solve_normal_equations(normal_equations(phi_w, t_w), est.precision, 0.1)[0]
    assert rel(est.coefficients(), ref) <= RTOL


def test_prediction_errors_are_a_priori():
    """With a solve per row, each error uses the window solution before that sample."""
    q, p, m, W = 2, 2, 1, 60
    u, y = simulate(200, p, m, seed=11)
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.2, solve_every=1, max_condition_number=np.inf)
    pushed = [est.push(u[k], y[k]) for k in range(200)]
    assert all(e is None for e in pushed[:q])
    errors_push = np.array([np.full(p, np.nan) if e is None else e for e in pushed])
    phi, t, rows = arx_regressors(u, y, q)
    for i, k in enumerate(rows):
        if i == 0:
            expected = t[0]  # no rows yet: the coefficients are zero
        else:
            theta, _ = batch_theta(u[:k], y[:k], q, W, est.precision, 0.2)
            expected = t[i] - phi[i] @ theta
        np.testing.assert_allclose(errors_push[k], expected, rtol=1e-8, atol=1e-10)
    # The block path gives the same errors as single pushes.
    est2 = SlidingWindowArx(q, p, m, window=W, penalty=0.2, solve_every=1, max_condition_number=np.inf)
    errors_block = np.vstack([est2.update(u[k : k + 17], y[k : k + 17]) for k in range(0, 200, 17)])
    np.testing.assert_allclose(errors_block, errors_push, rtol=1e-9, atol=1e-12)


def test_default_errors_use_last_solved_coefficients():
    q, p, m, W = 2, 2, 2, 100
    u, y = simulate(400, p, m, seed=12)
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.1)
    est.update(u[:300], y[:300])
    theta = est.coefficients().copy()
    errors = est.update(u[300:], y[300:])
    phi, t, rows = arx_regressors(u, y, q)
    np.testing.assert_allclose(errors, t[rows >= 300] - phi[rows >= 300] @ theta, rtol=1e-10, atol=1e-12)


def test_nonfinite_sample_rejected_counted_and_breaks_regressors():
    q, p, m, W = 3, 2, 2, 150
    u, y = simulate(600, p, m, seed=13)
    bad = {100: ("y", 0, np.nan), 101: ("u", 1, np.inf), 350: ("y", 1, -np.inf), 352: ("u", 0, np.nan)}
    for k, (arr, c, val) in bad.items():
        (y if arr == "y" else u)[k, c] = val
    valid = np.isfinite(u).all(axis=1) & np.isfinite(y).all(axis=1)
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.1, block_size=8)
    for k in range(600):
        if k in bad:
            before = est._G.copy()
            n_before = est.status.rows_in_window
            assert est.push(u[k], y[k]) is None
            np.testing.assert_array_equal(est._G, before)  # window untouched
            assert est.status.rows_in_window == n_before
        else:
            est.push(u[k], y[k])
        if k > 200 and k % 23 == 0:
            ref, rows = batch_theta(u[: k + 1], y[: k + 1], q, W, est.precision, 0.1, valid[: k + 1])
            assert est.status.rows_in_window == rows
            assert rel(est.coefficients(), ref) <= RTOL
    st = est.status
    assert st.rejected_nonfinite == 4
    assert st.gaps == 3  # 100-101 is one break, 350 and 352 are two
    assert st.samples_accepted == 596


def test_gaps_by_mark_gap_and_by_stamps_equal_batch_with_valid_mask():
    q, p, m, W, dt = 4, 2, 2, 400, 0.01
    u, y = simulate(1000, p, m, seed=14)
    # The batch reference marks a gap with an invalid sample between the segments.
    gap_after = [199, 204, 500, 505, 700]  # close gaps: a segment shorter than q + 1
    cuts = np.zeros(1000, dtype=bool)
    cuts[np.array(gap_after) + 1] = True
    ub = np.insert(u, np.array(gap_after) + 1, np.nan, axis=0)
    yb = np.insert(y, np.array(gap_after) + 1, np.nan, axis=0)
    valid = np.isfinite(ub[:, 0])
    stamps = np.arange(1000) * dt + np.cumsum(cuts) * 5 * dt  # a jump of 6 sample times
    est_mark = SlidingWindowArx(q, p, m, window=W, penalty=0.1, block_size=16)
    est_stamp = SlidingWindowArx(q, p, m, window=W, penalty=0.1, block_size=16, sample_time_s=dt)
    for k in range(1000):
        if cuts[k]:
            est_mark.mark_gap()
        est_mark.push(u[k], y[k])
    for k0 in range(0, 1000, 50):
        est_stamp.update(u[k0 : k0 + 50], y[k0 : k0 + 50], stamps[k0 : k0 + 50])
    ref, rows = batch_theta(ub, yb, q, W, est_mark.precision, 0.1, valid)
    for est in (est_mark, est_stamp):
        assert est.status.gaps == len(gap_after)
        assert est.status.rows_in_window == rows
        assert rel(est.coefficients(), ref) <= RTOL
    # No stored regressor row straddles a gap: the window's samples show the segment starts.
    u_w, _, start = est_stamp.window_samples()
    np.testing.assert_array_equal(u_w[start][1:], u[np.array([701])])  # the gap after 700
    np.testing.assert_array_equal(u_w[-299:], u[-299:])


def test_heavy_gaps_compact_buffer_and_stay_exact():
    """Gaps every few samples force the buffer to keep scattered histories: still exact."""
    q, p, m, W = 3, 1, 1, 60
    u, y = simulate(3000, p, m, seed=15)
    rng = np.random.default_rng(3)
    nan_at = np.flatnonzero(rng.random(3000) < 0.08)
    y[nan_at, 0] = np.nan
    valid = np.isfinite(y[:, 0])
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.1, block_size=8)
    for k0 in range(0, 3000, 97):
        est.update(u[k0 : k0 + 97], y[k0 : k0 + 97])
        k = min(k0 + 97, 3000)
        ref, rows = batch_theta(u[:k], y[:k], q, W, est.precision, 0.1, valid[:k])
        if rows >= 30:
            assert rel(est.coefficients(), ref) <= RTOL
    assert est.status.rejected_nonfinite == nan_at.size
    assert est._cap <= 4 * (W * (q + 1) + q + est.block_size) + 64


def test_out_of_order_and_duplicate_stamps_rejected():
    q, p, m, W, dt = 2, 1, 1, 50, 0.1
    u, y = simulate(200, p, m, seed=16)
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.1, sample_time_s=dt)
    for k in range(150):
        est.push(u[k], y[k], stamp=k * dt)
    G = est._G.copy()
    assert est.push([9.0], [9.0], stamp=149 * dt) is None  # duplicate
    assert est.push([9.0], [9.0], stamp=149 * dt + 0.2 * dt) is None  # within the tolerance
    assert est.push([9.0], [9.0], stamp=120 * dt) is None  # backwards
    errors = est.update([[9.0], [9.0]], [[9.0], [9.0]], stamps=[100 * dt, 149 * dt])
    assert np.all(np.isnan(errors))
    np.testing.assert_array_equal(est._G, G)
    st = est.status
    assert (st.rejected_duplicate, st.rejected_out_of_order, st.gaps) == (3, 2, 0)
    for k in range(150, 200):  # the stream goes on without a gap
        est.push(u[k], y[k], stamp=k * dt)
    ref, _ = batch_theta(u, y, q, W, est.precision, 0.1)
    assert rel(est.coefficients(), ref) <= RTOL


def test_unexcited_window_keeps_last_good_estimate():
    q, p, m, W = 3, 2, 2, 200
    u, y = simulate(800, p, m, seed=17)
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.0)
    est.update(u[:400], y[:400])
    good = est.solve()
    assert good.ok and good.condition_number < 1e6
    # The inputs stop: the input columns of R vanish, R is singular.
    est.update(np.zeros((300, m)), y[400:700])
    sol = est.solve()
    assert not sol.ok and "unexcited" in sol.reason
    assert sol.condition_number > 1e12
    np.testing.assert_array_equal(sol.theta, good.theta)
    st = est.status
    assert not st.last_solve_ok and st.condition_number == sol.condition_number
    # Excited again: a full window of good rows gives a good solution again.
    est.update(u[:W + q], y[:W + q])
    assert est.solve().ok


def test_condition_estimate_is_close_to_exact():
    q, p, m, W = 3, 2, 2, 300
    u, y = simulate(600, p, m, seed=18)
    u[:, 1] = 0.999 * u[:, 0] + 0.001 * u[:, 1]  # nearly collinear inputs
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.1)
    est_exact = SlidingWindowArx(q, p, m, window=W, penalty=0.1, exact_condition=True)
    est.update(u, y)
    est_exact.update(u, y)
    c_est, c_exact = est.solve().condition_number, est_exact.solve().condition_number
    assert c_exact > 1e4
    assert c_exact / 10 <= c_est <= 10 * est.n_params * c_exact


def test_wrong_sizes_raise_clear_errors():
    est = SlidingWindowArx(2, 2, 1, window=10)
    with pytest.raises(ValueError, match="1 inputs and 2 outputs"):
        est.push([1.0, 2.0], [1.0, 2.0])
    with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
        est.update(np.zeros((5, 1)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="different lengths"):
        est.update(np.zeros((5, 1)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="one entry per sample"):
        est.update(np.zeros((5, 1)), np.zeros((5, 2)), stamps=[0.0, 1.0])
    with pytest.raises(ValueError, match="prior precision"):
        SlidingWindowArx(2, 2, 1, prior_precision=np.ones(3))
    with pytest.raises(ValueError, match="forgetting"):
        SlidingWindowArx(2, 2, 1, window=10, forgetting=0.9)
    with pytest.raises(ValueError, match="penalty"):
        SlidingWindowArx(2, 2, 1, penalty=-1.0)


def test_long_run_no_drift_and_flat_memory():
    """10^5 samples through add/remove cycles: still batch-exact, memory constant."""
    q, p, m, W = 5, 2, 2, 500
    n = 100_000
    u, y = simulate(n, p, m, seed=19)
    y += 3.0  # an offset makes the rounding of add/remove cycles larger
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.01, refactor_every=40_000)
    sizes, worst = [], 0.0
    for k0 in range(0, n, 10_000):
        est.update(u[k0 : k0 + 10_000], y[k0 : k0 + 10_000])
        k = k0 + 10_000
        ref, _ = batch_theta(u[k - W - q : k], y[k - W - q : k], q, W, est.precision, 0.01)
        worst = max(worst, rel(est.coefficients(), ref))
        sizes.append(est.memory_bytes())
    assert worst <= RTOL
    assert len(set(sizes[1:])) == 1
    assert est.status.refactorizations == 2


def test_to_arx_fit_packages_the_current_window_estimate():
    q, p, m, W = 3, 2, 2, 300
    u, y = simulate(800, p, m, seed=20)
    est = SlidingWindowArx(q, p, m, window=W, penalty=0.5)
    est.update(u, y)
    fit = est.to_arx_fit()
    np.testing.assert_array_equal(fit.theta, est.coefficients())
    assert (fit.order, fit.n_outputs, fit.n_inputs, fit.n_rows) == (q, p, m, W)
    phi, t, _ = arx_regressors(u, y, q)
    resid = t[-W:] - phi[-W:] @ fit.theta
    np.testing.assert_allclose(fit.residual_covariance * (W - fit.effective_parameters), resid.T @ resid, rtol=1e-8)
    assert 0 < fit.effective_parameters < est.n_params
