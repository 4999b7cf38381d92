"""The ARX normal equations from lagged products equal those of the row matrix (core/arx_gram.py)."""

from __future__ import annotations

import numpy as np
import pytest

from okid_ros.core.arx_gram import arx_normal_equations, arx_regressor_product, lagged_gram
from okid_ros.core.least_squares import normal_equations
from okid_ros.core.regressors import arx_regressors
from okid_ros.core.state_gram import StateGram


def _assert_equal_normal_equations(got, want, rtol=1e-12):
    assert got.n_rows == want.n_rows
    for name in ("R", "r", "yy", "phi_sum", "y_sum"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.shape == b.shape, name
        np.testing.assert_allclose(a, b, rtol=0, atol=rtol * max(np.abs(b).max(), 1.0), err_msg=name)


@pytest.mark.parametrize(("n_samples", "m", "p", "q"), [
    (3750, 2, 2, 100),  # the paper's size
    (1200, 2, 28, 5),   # many outputs
    (900, 0, 4, 12),    # a vector autoregression (no input)
    (260, 1, 1, 40),    # few rows per lag: summed from the row matrix
    (45, 1, 2, 3),
])
def test_equal_to_the_row_matrix(n_samples, m, p, q):
    rng = np.random.default_rng(n_samples + q)
    # Offsets far from zero: the end corrections subtract large sums.
    u = rng.standard_normal((n_samples, m)) + 30.0
    y = rng.standard_normal((n_samples, p)) * 1e-3 - 5.0
    _assert_equal_normal_equations(arx_normal_equations(u, y, q), normal_equations(*arx_regressors(u, y, q)[:2]))


def test_equal_to_the_row_matrix_with_gaps():
    """Rows whose past crosses an invalid sample are left out, in long and short runs alike."""
    rng = np.random.default_rng(3)
    u, y = rng.standard_normal((2000, 2)), rng.standard_normal((2000, 3))
    valid = np.ones(2000, dtype=bool)
    valid[[300, 330, 1000, 1001, 1990]] = False  # a run of 29 samples, a long one, a short tail
    for q in (1, 8, 25):
        _assert_equal_normal_equations(arx_normal_equations(u, y, q, valid),
                                       normal_equations(*arx_regressors(u, y, q, valid)[:2]))


def test_no_row_gives_empty_sums():
    got = arx_normal_equations(np.ones((5, 1)), np.ones((5, 2)), 5)
    assert got.n_rows == 0 and got.R.shape == (16, 16) and not got.R.any() and not got.y_sum.any()
    with pytest.raises(ValueError, match="order"):
        lagged_gram(np.ones((5, 1)), np.ones((5, 2)), 0)


def test_regressor_product_is_the_rows_times_theta():
    rng = np.random.default_rng(5)
    for m in (0, 2):
        u, y = rng.standard_normal((700, m)), rng.standard_normal((700, 3))
        theta = rng.standard_normal((m + 9 * (3 + m), 3))
        want = arx_regressors(u, y, 9)[0] @ theta
        np.testing.assert_allclose(arx_regressor_product(u, y, 9, theta), want, rtol=0, atol=1e-12 * np.abs(want).max())


def test_state_gram_rows_and_gram_as_before():
    """StateGram's Gram (from lagged sums) and its state sequence (rows rebuilt) match the row matrix."""
    rng = np.random.default_rng(8)
    u, y = rng.standard_normal((1500, 2)), rng.standard_normal((1500, 3))
    valid = np.ones(1500, dtype=bool)
    valid[700] = False
    gram = StateGram(u, y, 10, valid)
    phi, targets, rows = arx_regressors(u, y, 10, valid)
    extended = np.hstack([targets, phi])
    np.testing.assert_array_equal(gram.rows, rows)
    np.testing.assert_allclose(gram.gram, extended.T @ extended / rows.size, rtol=0, atol=1e-12)
    transform = rng.standard_normal((5 * 10, 6))
    gram.set_states(transform)
    np.testing.assert_allclose(gram.states(4), phi[:, 2:] @ transform[:, :4], rtol=0, atol=1e-12)
