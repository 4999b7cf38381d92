"""The output-only bench's pairing of identified with true modes (bench/okid_bench/output_only_cases.py)."""

from __future__ import annotations

import numpy as np

from okid_bench.output_only_cases import pair_modes, score_modes


def _mode(frequency_hz, damping_ratio, shape):
    return {"frequency_hz": frequency_hz, "damping_ratio": damping_ratio, "shape": np.asarray(shape, complex)}


def test_a_close_pair_whose_frequencies_cross_is_paired_by_shape_and_keeps_each_damping():
    # Two sway modes 0.17 % apart, one damped by a dashpot: the identified poles lie within their
    # uncertainty of each other with the order of their frequencies crossed.
    truth = [_mode(7.804, 0.0019, [1.0, 0.0, 0.1]), _mode(7.817, 0.0336, [0.0, 1.0, -0.1])]
    found = [_mode(7.805, 0.0330, [0.05, 1.0, -0.1]), _mode(7.812, 0.0020, [1.0, 0.03, 0.1])]
    rows = score_modes(found, truth, match_tolerance=0.005)["modes"]
    errors = np.array([row["damping_error"] for row in rows])
    assert np.all(np.abs(errors) < 0.1), errors
    assert min(row["mac"] for row in rows) > 0.99


def test_the_most_pairs_within_the_tolerance_are_kept():
    # Nearest first would give 10.035 Hz to the 10.04 Hz mode and leave 10.00 Hz without a partner
    # (10.08 is 0.8 % from it); one assignment pairs both.
    truth = [_mode(10.00, 0.01, [1.0, 0.0]), _mode(10.04, 0.01, [0.0, 1.0])]
    found = [_mode(10.035, 0.01, [1.0, 0.0]), _mode(10.08, 0.01, [0.0, 1.0])]
    assert pair_modes(found, truth, 0.005) == {0: 0, 1: 1}
    score = score_modes(found, truth, match_tolerance=0.005)
    assert score["spurious"] == 0
    assert all(row["frequency_error"] == row["frequency_error"] for row in score["modes"])


def test_without_shapes_the_pairing_is_by_frequency_and_leftovers_are_spurious():
    truth = [{"frequency_hz": 5.0, "damping_ratio": 0.02, "shape": None},
             {"frequency_hz": 5.02, "damping_ratio": 0.01, "shape": None}]
    found = [_mode(5.019, 0.011, [1.0]), _mode(5.001, 0.021, [1.0]), _mode(9.0, 0.01, [1.0])]
    score = score_modes(found, truth, match_tolerance=0.005)
    assert pair_modes(found, truth, 0.005) == {0: 1, 1: 0}
    assert score["spurious"] == 1
    assert np.isnan(score["modes"][0]["mac"])
    np.testing.assert_allclose([row["damping_error"] for row in score["modes"]], [0.05, 0.1])


def test_a_zero_shape_is_paired_by_frequency_as_unlike_every_true_shape():
    truth = [_mode(4.0, 0.01, [1.0, 0.0]), _mode(4.01, 0.02, [0.0, 1.0])]
    found = [_mode(4.0, 0.01, [0.0, 0.0]), _mode(4.011, 0.021, [0.0, 1.0])]
    assert pair_modes(found, truth, 0.005) == {0: 0, 1: 1}
    assert np.isnan(score_modes(found, truth, match_tolerance=0.005)["modes"][0]["mac"])
