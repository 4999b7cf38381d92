"""The canonical-variate route's correlations are the record's biased ones: their taper is taken off the poles."""

from __future__ import annotations

import numpy as np
import pytest

from okid_bench.output_only_cases import OutputOnlyCase, score_modes
from okid_ros.core.output_covariance import RecordSums
from okid_ros.core.output_only import identify_output_only
from okid_ros.sim.models import modal_structure


def test_the_mean_damping_error_of_short_records_is_below_the_tapers_bias() -> None:
    # Six modes of one zeta omega over 120 s: R_k (1 - k / N) adds 1 / (zeta omega T) = 13 % to each
    # damping ratio. Realized as they are, the mean error over 20 records is +22 % (the record's own
    # skew to the high side and the taper's share); with the taper taken off, +9 %.
    frequencies = np.array([1.0, 1.6, 2.5, 3.7, 5.2, 7.0])
    damping = 0.01 / frequencies
    system = modal_structure(frequencies, damping, 1, 3, 0.04, seed=4, output="acceleration", disturbance_std=1.0)
    case = OutputOnlyCase("taper", system, 3000, "six lightly damped modes, 120 s")
    taper_share = 1 / (0.01 * 2 * np.pi * case.n_samples * case.sample_time_s)
    errors, spurious = [], 0
    for seed in range(20):
        model = identify_output_only(case.simulate(seed), case.sample_time_s)
        found = [{"frequency_hz": m.frequency_hz, "damping_ratio": m.damping_ratio, "shape": m.shape}
                 for m in model.modes]
        score = score_modes(found, case.truth())
        spurious += score["spurious"]
        errors += [row["damping_error"] for row in score["modes"] if np.isfinite(row["damping_error"])]
    assert spurious == 0 and len(errors) >= 110
    assert np.mean(errors) < taper_share


@pytest.mark.parametrize("present_all", [True, False])
def test_the_taper_is_each_lags_share_of_present_pairs(present_all) -> None:
    rng = np.random.default_rng(2)
    present = np.ones(3000, bool)
    if not present_all:
        present[700:760] = False
        present[rng.integers(0, 3000, 40)] = False
    y = rng.standard_normal((3000, 2))
    sums = RecordSums.of(y, 60, present)
    pairs = np.array([np.sum(present[: present.size - k] & present[k:]) for k in range(61)])
    np.testing.assert_allclose(sums.taper, pairs / present.sum(), rtol=1e-12)
    masked = np.where(present[:, None], y, 0.0)
    for k in (0, 1, 37, 60):  # each lag's sum over its own pairs
        expected = masked[k:].T @ masked[: masked.shape[0] - k] / pairs[k]
        np.testing.assert_allclose(sums.unbiased[k], expected, rtol=1e-9, atol=1e-12)
    # c exp(-rate k) through the Hankels' lags 1 .. 60: 1 / N without gaps (to the curvature, 60 / N of it);
    # a missing sample takes pairs off every lag but 0 (a step at lag 1), a missing run 2 k more at lag k.
    lags = np.arange(1, 61)
    fitted = np.exp(-sums.taper_rate * lags)
    fitted *= np.exp(np.mean(np.log(sums.taper[1:] / fitted)))
    np.testing.assert_allclose(fitted, sums.taper[1:], rtol=1e-4 if present_all else 1e-3)
    assert sums.taper_rate == pytest.approx(1 / 3000 if present_all else 2 / 2900, rel=0.05)
