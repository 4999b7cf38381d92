"""The listed modes' standard deviations from a jackknife of more segments (okid_ros/core/output_only_std.py)."""

from __future__ import annotations

import numpy as np
import pytest

from okid_bench.changes import change_case
from okid_bench.switching import simulate_switched
from okid_ros.core.identified_model import IdentificationError
from okid_ros.core.output_only import identify_output_only
from okid_ros.core.output_only_std import FINER_SEGMENTS, MIN_SEGMENT_LAGS, STD_SEGMENTS, std_segment_count


def _stationary(n: int, seed: int = 0) -> tuple[np.ndarray, float]:
    case = change_case("frequency", 0.06)  # the change bench's structure, unchanged
    return simulate_switched([case.before], [], case.make_input(n, 100 + seed), seed=200 + seed), case.sample_time_s


def test_a_first_stage_record_gets_deviations_of_more_segments_and_the_same_modes():
    # 40 periods of the structure's 5.2 Hz mode, the mode confirmation's first stage: the screening's
    # jackknife holds five segments there (four degrees of freedom per variance); main gave those.
    y, dt = _stationary(1923)
    finer = identify_output_only(y, dt, std_segments=FINER_SEGMENTS)
    screening = identify_output_only(y, dt)  # the default: the screening's deviations
    assert screening.uncertainty.rows_used == 5
    assert STD_SEGMENTS == 0 and finer.uncertainty.rows_used == FINER_SEGMENTS
    assert [(m.eigenvalue, m.frequency_hz, m.damping_ratio) for m in finer.modes] == [
        (m.eigenvalue, m.frequency_hz, m.damping_ratio) for m in screening.modes]
    np.testing.assert_array_equal(finer.A, screening.A)
    np.testing.assert_array_equal(finer.K, screening.K)
    f_finer = np.array([m.frequency_hz_std for m in finer.modes])
    f_screening = np.array([m.frequency_hz_std for m in screening.modes])
    assert np.all(f_finer > 0) and not np.array_equal(f_finer, f_screening)


@pytest.mark.parametrize(("n", "max_lag", "most", "expected"), [
    (1923, 38, FINER_SEGMENTS, min(FINER_SEGMENTS, 1923 // (MIN_SEGMENT_LAGS * 38))),
    (1000, 100, FINER_SEGMENTS, 1000 // (MIN_SEGMENT_LAGS * 100)),
    (10 ** 6, 10, FINER_SEGMENTS, FINER_SEGMENTS),
    (1923, 38, 0, 0),
])
def test_segment_count_is_bounded_by_the_lag_windows_and_the_most(n, max_lag, most, expected):
    assert std_segment_count(n, max_lag, most) == expected


@pytest.mark.parametrize("bad", [-1, 2.5, True, "20"])
def test_a_bad_segment_count_is_refused_by_name(bad):
    y, dt = _stationary(600)
    with pytest.raises(IdentificationError, match="std_segments"):
        identify_output_only(y, dt, std_segments=bad)
