"""Property-based test: the ARX sums from lagged products equal the row matrix's for any shape and gaps."""

from __future__ import annotations

import numpy as np
from _hypothesis_profiles import settings  # noqa: F401 - registers and loads the profile
from hypothesis import given
from hypothesis import strategies as st

from okid_ros.core.arx_gram import arx_normal_equations
from okid_ros.core.least_squares import normal_equations
from okid_ros.core.regressors import arx_regressors


@given(n_samples=st.integers(1, 400), m=st.integers(0, 3), p=st.integers(1, 4), q=st.integers(1, 30),
       seed=st.integers(0, 2**16), gaps=st.lists(st.integers(0, 399), max_size=6), offset=st.floats(-1e3, 1e3))
def test_lagged_sums_equal_the_row_matrix(n_samples, m, p, q, seed, gaps, offset):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n_samples, m)) + offset
    y = rng.standard_normal((n_samples, p)) - offset
    valid = np.ones(n_samples, dtype=bool)
    valid[[g for g in gaps if g < n_samples]] = False
    got = arx_normal_equations(u, y, q, valid)
    want = normal_equations(*arx_regressors(u, y, q, valid)[:2])
    assert got.n_rows == want.n_rows
    for a, b in ((got.R, want.R), (got.r, want.r), (got.yy, want.yy), (got.phi_sum, want.phi_sum),
                 (got.y_sum, want.y_sum)):
        assert a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(np.abs(b).max(initial=0.0), 1.0))
