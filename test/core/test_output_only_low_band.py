"""The decimated band's estimate replaces a slow mode's full-rate one only where it is the more certain.

Random records 82, 91 and 38 of ``bench/output_only.py --cases random`` (ssi-cva) lost a slow mode
found within 0.5 % at the full rate to a decimated estimate 0.56-0.63 % off with a larger
jackknife frequency standard deviation (docs/benchmarks-output-only.md, forty-third session).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from okid_bench.output_only_cases import random_case
from okid_ros.core.modal import Mode
from okid_ros.core.output_only import identify_output_only
from okid_ros.core.output_only_low_band import refine_low_modes


@pytest.mark.parametrize(("decimated_std", "replaced"), [(0.5e-3, True), (2e-3, False)])
def test_the_decimated_estimate_replaces_a_slow_mode_only_with_a_smaller_frequency_std(
        decimated_std: float, replaced: bool) -> None:
    y = np.random.default_rng(0).standard_normal((20000, 2))
    mode = Mode(2 * np.pi, 1.0, 0.02, 0.99 + 0.06j, np.ones(2, complex) / np.sqrt(2), 1.0, 1.0, 1.0, True, True,
                frequency_hz_std=1e-3, damping_ratio_std=2e-3)
    decimated = {"frequency_hz": 1.004, "damping_ratio": 0.025, "frequency_hz_std": decimated_std,
                 "damping_ratio_std": 1e-3}
    refine_low_modes(SimpleNamespace(modes=[mode]), y, 0.01, lambda low, dt, rows: [decimated])
    expected = decimated if replaced else {"frequency_hz": 1.0, "damping_ratio": 0.02, "frequency_hz_std": 1e-3,
                                           "damping_ratio_std": 2e-3}
    assert {key: getattr(mode, key) for key in expected} == expected
    assert ("full_rate_frequency_hz" in mode.extras) == replaced


@pytest.mark.parametrize("index", [38, 82])
def test_a_slow_mode_found_at_the_full_rate_is_kept(index: int) -> None:
    case = random_case(index)
    model = identify_output_only(case.simulate(index), case.sample_time_s, method="ssi-cva")
    listed = np.array([m.frequency_hz for m in model.modes])
    for true in case.truth():
        assert np.min(np.abs(listed / true["frequency_hz"] - 1)) <= 0.005, f"{true['frequency_hz']:.3f} Hz missed"
