"""Property-based tests of the windowed least squares against the batch solution.

On random systems, window lengths, orders, block sizes, gaps, NaN samples and samples beyond
MAX_SAMPLE_MAGNITUDE, fed by single pushes and blocks in any mix, the sliding window's normal
equations equal the batch sums over the same regressor rows, its fixed-penalty fit equals the
batch least squares, and every rejected sample is counted by its reason.
"""

from __future__ import annotations

import numpy as np
from _hypothesis_profiles import settings  # noqa: F401 - registers and loads the profile
from hypothesis import given
from hypothesis import strategies as st

from okid_ros.core.arx import fit_arx, fit_from_normal_equations, normal_equations, solve_fixed_penalty
from okid_ros.core.recursive import MAX_SAMPLE_MAGNITUDE, SlidingWindowArx
from okid_ros.core.regressors import arx_regressors


@st.composite
def windows(draw):
    q, p, m = draw(st.integers(1, 4)), draw(st.integers(1, 3)), draw(st.integers(1, 2))
    d = m + q * (p + m)
    window = draw(st.integers(2 * d + 2, 4 * d + 40))
    n = draw(st.integers(window + q, 2 * window + 3 * q + 60))
    seed = draw(st.integers(0, 2**16))
    bad = draw(st.lists(st.tuples(st.integers(0, n - 1), st.sampled_from(["nan", "inf", "huge", "gap"])),
                        max_size=8))
    chunks = draw(st.lists(st.integers(1, 70), min_size=1, max_size=12))
    block_size = draw(st.sampled_from([1, 7, 32, 128]))
    return q, p, m, window, n, seed, bad, chunks, block_size


def _record(n: int, p: int, m: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, m))
    y = np.zeros((n, p))
    a = 0.6 * np.eye(p) + 0.2 * rng.standard_normal((p, p)) / np.sqrt(p)
    b = rng.standard_normal((p, m))
    for k in range(1, n):
        y[k] = a @ y[k - 1] * 0.9 + b @ u[k - 1] + 0.1 * rng.standard_normal(p)
    return u, y


@given(case=windows())
def test_window_equals_the_batch_fit_on_the_same_rows(case) -> None:
    q, p, m, window, n, seed, bad, chunks, block_size = case
    u, y = _record(n, p, m, seed)
    valid = np.ones(n, dtype=bool)
    gaps_before = {k for k, kind in bad if kind == "gap"}
    damaged = {k: kind for k, kind in bad if kind != "gap"}  # the last kind drawn for a sample wins
    for k, kind in damaged.items():
        u[k, 0] = {"nan": np.nan, "inf": -np.inf, "huge": 10 * MAX_SAMPLE_MAGNITUDE}[kind]
        valid[k] = False
    est = SlidingWindowArx(q, p, m, window=window, block_size=block_size)
    k = 0
    for size in np.resize(chunks, n):  # feed in blocks and single pushes, in the drawn sizes
        if k >= n:
            break
        stop = min(n, k + int(size))
        cut = next((g for g in sorted(gaps_before) if k < g < stop), stop)
        if k in gaps_before:
            est.mark_gap()
        if cut - k == 1:
            est.push(u[k], y[k])
        else:
            est.update(u[k:cut], y[k:cut])
        k = cut
    # The batch reference: a gap is an invalid sample inserted before the sample it precedes.
    marks = np.array(sorted(g for g in gaps_before if g > 0), dtype=int)
    ub, yb = np.insert(u, marks, np.nan, axis=0), np.insert(y, marks, np.nan, axis=0)
    vb = np.insert(valid, marks, False)
    phi, targets, _ = arx_regressors(np.where(vb[:, None], ub, 0.0), np.where(vb[:, None], yb, 0.0), q, vb)
    phi, targets = phi[-window:], targets[-window:]
    status = est.status
    assert status.samples_seen == n
    assert status.rejected_nonfinite == sum(kind in ("nan", "inf") for kind in damaged.values())
    assert status.rejected_magnitude == sum(kind == "huge" for kind in damaged.values())
    assert status.rows_in_window == phi.shape[0]
    got, ref = est.normal_equations(), normal_equations(phi, targets)
    scale = max(np.abs(ref.R).max(), 1.0)
    for name in ("R", "r", "yy", "phi_sum", "y_sum"):
        np.testing.assert_allclose(getattr(got, name), getattr(ref, name), rtol=0, atol=1e-10 * scale, err_msg=name)
    if phi.shape[0] >= phi.shape[1] + 2:
        precision = np.eye(est.n_params)
        theta = solve_fixed_penalty(got, precision, 0.05)
        theta_batch = np.linalg.solve(ref.R + 0.05 * precision, ref.r)
        assert np.linalg.norm(theta - theta_batch) <= 1e-8 * max(np.linalg.norm(theta_batch), 1.0)


@given(q=st.integers(2, 5), window=st.integers(150, 400), seed=st.integers(0, 2**16),
       regularization=st.sampled_from(["ridge", "tc"]))
def test_window_gcv_fit_equals_fit_arx_on_its_samples(q, window, seed, regularization) -> None:
    u, y = _record(window + q + 150, 2, 2, seed)
    est = SlidingWindowArx(q, 2, 2, window=window)
    est.update(u, y)
    u_w, y_w, _ = est.window_samples()
    fit = fit_from_normal_equations(est.normal_equations(), q, 2, 2, regularization, 0.3, decay=0.9)
    batch = fit_arx(u_w, y_w, q, regularization, 0.3, 0.9)
    assert fit.n_rows == batch.n_rows == window
    assert np.linalg.norm(fit.theta - batch.theta) <= 1e-8 * np.linalg.norm(batch.theta)
    assert np.isfinite(fit.residual_covariance).all()
