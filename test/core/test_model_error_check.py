"""The model-error check's explained fraction: every output's least-squares fit, as lstsq per output gives it."""

from __future__ import annotations

import numpy as np
import pytest

from okid_bench.changes import explained_fraction_by_lstsq
from okid_ros.core.model_error_check import explained_fraction


def record(kind: str, n: int, p: int, m: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, m))
    w = rng.standard_normal((n, p))
    w[1:] += 0.5 * w[:-1]  # residuals the own lags explain a part of
    if m:
        w[2:, 0] += 0.8 * u[:-2, 0]  # and one the inputs explain
    if kind == "constant input" and m:
        u[:, -1] = 3.0  # no column of its lags survives the mean's removal
    elif kind == "still output":
        w[:, -1] = 1.5  # an output whose residual does not move: its own lags are all zero
    elif kind == "repeated output":
        w[:, -1] = w[:, 0]
    elif kind == "input as residual" and m:
        w[:, -1] = u[:, 0]  # its own lags lie in the span of the inputs' lags
    elif kind == "late spike":
        w[:, -1] = 0.0
        w[-1, -1] = 1.0  # its own lags are all the same column; its target is not in their span
    return w, u


@pytest.mark.parametrize(
    "kind", ["random", "constant input", "still output", "repeated output", "input as residual", "late spike"])
@pytest.mark.parametrize(("n", "p", "m", "lags"), [(266, 28, 2, 10), (2010, 6, 2, 10), (300, 3, 0, 10), (80, 2, 1, 3)])
def test_the_fraction_is_each_outputs_lstsq_fit_pooled(kind, n, p, m, lags):
    w, u = record(kind, n, p, m, seed=n + p)
    fraction, rows = explained_fraction(w, u, lags)
    assert rows == n - lags
    assert fraction == pytest.approx(explained_fraction_by_lstsq(w, u, lags)[0], rel=1e-10, abs=1e-14)


def test_residuals_that_never_move_explain_nothing():
    assert explained_fraction(np.ones((50, 3)), np.zeros((50, 1)), 4) == (0.0, 46)
