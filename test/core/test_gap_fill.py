"""okid_ros/core/gap_fill.py: short gaps of a window filled by its ARX prediction."""

from __future__ import annotations

import numpy as np
import pytest

from okid_ros.core.arx import fit_arx
from okid_ros.core.gap_fill import MAX_FILLED_FRACTION, fill_short_gaps
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation


@pytest.fixture(scope="module")
def record():
    model = paper_model()
    u = lowpass_input(3000, 2, 20.0, model.sample_time_s, seed=1)
    y, _ = simulate_innovation(model, u, seed=2)
    return model, u, y, fit_arx(u, y, 20)


def test_filled_samples_are_the_arx_prediction_and_marked(record):
    model, u, y, fit = record
    lost = np.zeros(3000, dtype=bool)
    lost[[100, 101, 102, 700, 2999 - 5]] = True
    keep = ~lost
    skipped = np.diff(np.concatenate([[-1], np.flatnonzero(keep)])) - 1
    u_full, y_full, valid = fill_short_gaps(u[keep], y[keep], skipped, fit)
    assert u_full.shape == u.shape and y_full.shape == y.shape
    np.testing.assert_array_equal(valid, keep)
    np.testing.assert_array_equal(y_full[keep], y[keep])  # measured samples untouched
    # Each filled output misses only its innovation: its error is about the innovation's size.
    innovation_std = np.sqrt(np.diag(model.innovation_covariance))
    signal_std = y.std(axis=0)
    error = np.abs(y_full[lost] - y[lost])
    assert np.all(error < 4 * innovation_std) and np.all(innovation_std < 0.5 * signal_std)
    # The inputs are interpolated between the neighbours.
    np.testing.assert_allclose(u_full[101], u[99] + (u[103] - u[99]) * 2 / 4)


def test_too_many_lost_samples_or_a_restart_are_refused(record):
    _, u, y, fit = record
    n_lost = int(MAX_FILLED_FRACTION * 1000) + 20
    skipped = np.zeros(1000, dtype=np.int64)
    skipped[10:10 + n_lost] = 1
    with pytest.raises(ValueError, match="are missing; at most 10% are filled"):
        fill_short_gaps(u[:1000], y[:1000], skipped, fit)
    skipped = np.zeros(1000, dtype=np.int64)
    skipped[500] = -1
    with pytest.raises(ValueError, match="time restart"):
        fill_short_gaps(u[:1000], y[:1000], skipped, fit)


def test_a_window_without_gaps_comes_back_unchanged(record):
    _, u, y, fit = record
    u_full, y_full, valid = fill_short_gaps(u, y, np.zeros(3000, dtype=np.int64), fit)
    assert valid.all()
    np.testing.assert_array_equal(u_full, u)
    np.testing.assert_array_equal(y_full, y)


def test_fill_missing_fills_a_whole_record_as_fill_short_gaps_does(record):
    from okid_ros.core.gap_fill import fill_missing, mark_missing

    _, u, y, fit = record
    y_lost = y.copy()
    y_lost[[50, 51, 900]] = np.nan
    u_marked, y_marked, valid = mark_missing(u, y_lost, np.isfinite(y_lost).all(axis=1))
    assert np.all(np.isfinite(y_marked)) and valid.sum() == 2997
    u_full, y_full, same = fill_missing(u_marked, y_marked, valid, fit)
    keep = np.flatnonzero(valid)
    expected = fill_short_gaps(u[keep], y[keep], np.diff(keep, prepend=0) - 1, fit)
    np.testing.assert_array_equal(y_full, expected[1])
    np.testing.assert_array_equal(same, valid)
    assert mark_missing(u, y, np.ones(3000, dtype=bool))[2] is None  # nothing missing: no mask


def test_fill_missing_refuses_a_long_gap_and_a_missing_end(record):
    from okid_ros.core.gap_fill import MAX_GAP_SAMPLES, fill_missing

    _, u, y, fit = record
    valid = np.ones(3000, dtype=bool)
    valid[1000 : 1001 + MAX_GAP_SAMPLES] = False
    with pytest.raises(ValueError, match=f"{MAX_GAP_SAMPLES + 1} samples are missing in a row before sample 1011"):
        fill_missing(u, y, valid, fit)
    valid = np.ones(3000, dtype=bool)
    valid[-1] = False
    with pytest.raises(ValueError, match="start and end with a measured one"):
        fill_missing(u, y, valid, fit)


def test_an_output_only_record_is_filled_by_its_vars_prediction(record):
    from okid_ros.core.gap_fill import fill_missing_outputs

    _, _, y, _ = record
    lost = np.zeros(3000, dtype=bool)
    lost[[300, 301, 1700]] = True
    filled = fill_missing_outputs(np.where(lost[:, None], np.nan, y), ~lost)
    np.testing.assert_array_equal(filled[~lost], y[~lost])
    # Within a fraction of the signal's spread (measured: 0.02-0.13 of it; the lost samples
    # themselves lie 0.7-1.9 spreads from zero).
    assert np.all(np.abs(filled[lost] - y[lost]) < 0.3 * y.std(axis=0))
    with pytest.raises(ValueError, match="missing in a row"):
        fill_missing_outputs(np.where(np.arange(3000)[:, None] // 100 == 5, np.nan, y), np.arange(3000) // 100 != 5)
