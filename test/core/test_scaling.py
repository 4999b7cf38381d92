"""Units of each channel: identification on a record times 1e+-150 per channel gives the same modes.

Truth: the paper's two-mode model (okid_ros/sim/paper_model.py). The scaled record is identified
without any RuntimeWarning (overflow, underflow, invalid) and gives the frequencies and damping
ratios of the unscaled record within rounding, and a model that predicts the scaled outputs as
well as the unscaled model predicts the unscaled ones.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from okid_ros.core.arx import fit_arx
from okid_ros.core.channels import (
    channel_mean,
    channel_scales,
    channel_spread,
    channel_std,
    column_peaks,
    group_scales,
    record_units,
)
from okid_ros.core.pipeline import IdentificationError, identify
from okid_ros.core.statespace import one_step_prediction
from okid_ros.sim.inputs import lowpass_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation

DT = 0.008
# Per channel, different: inputs (1e150, 1e-150), outputs (1e-150, 1e150) and a mixed set.
UNITS = [
    (np.array([1e150, 1e-150]), np.array([1e-150, 1e150])),
    (np.array([3.7e-150, 1.0]), np.array([2.0e150, 1e-3])),
]


@pytest.fixture(scope="module")
def paper_record() -> tuple[np.ndarray, np.ndarray]:
    u = lowpass_input(2500, 2, 15.0, DT, seed=4)
    y, _ = simulate_innovation(paper_model(), u, seed=1004)
    return u, y


def _modes(model) -> np.ndarray:
    return np.array([[m.frequency_rad_s, m.damping_ratio] for m in model.modes])


@pytest.mark.parametrize("units", range(len(UNITS)))
def test_modes_do_not_depend_on_the_units_of_each_channel(paper_record, units: int) -> None:
    u, y = paper_record
    input_units, output_units = UNITS[units]
    reference = identify(u, y, DT, order=60, refine=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        scaled = identify(u * input_units, y * output_units, DT, order=60, refine=False)
    assert len(reference.modes) >= 2 and _modes(scaled).shape == _modes(reference).shape
    np.testing.assert_allclose(_modes(scaled), _modes(reference), rtol=1e-8)
    # The model is in the record's units: D, B, C, K, covariance and offsets scale as the channels.
    np.testing.assert_allclose(scaled.D, reference.D * output_units[:, None] / input_units[None, :], rtol=1e-6)
    np.testing.assert_allclose(np.diag(scaled.innovation_covariance),
                               np.diag(reference.innovation_covariance) * output_units**2, rtol=1e-6)
    np.testing.assert_allclose(scaled.output_offset, reference.output_offset * output_units, rtol=1e-6)
    for a, b in zip(scaled.modes, reference.modes):  # shapes: unit norm in the record's units
        assert abs(np.linalg.norm(a.shape) - 1) < 1e-12
        expected = b.shape * output_units / np.linalg.norm(b.shape * output_units)
        assert abs(abs(np.vdot(a.shape, expected)) - 1) < 1e-6
    _, e_ref = one_step_prediction(reference,
                                   u - reference.input_offset, y - reference.output_offset)
    _, e = one_step_prediction(scaled,
                               u * input_units - scaled.input_offset, y * output_units - scaled.output_offset)
    np.testing.assert_allclose(e / output_units, e_ref, rtol=1e-5, atol=1e-8 * np.abs(e_ref).max())
    assert scaled.stability_problem() is None or scaled.stability_problem() == ""


@pytest.mark.parametrize("peak, offset", [(None, 0.0), (1e306, 1e307)])
def test_beyond_the_float64_range_is_a_clear_refusal(paper_record, peak, offset) -> None:
    # Outputs about 1e307 made the means' sums overflow first: numpy's warning before the refusal.
    u, y = paper_record
    scale = 1e200 if peak is None else peak / np.abs(y).max()
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(IdentificationError, match="beyond the float64 range"):
            identify(u, y * scale + offset, DT, order=40, refine=False)


def test_inputs_of_a_subnormal_unit_are_a_clear_refusal_not_a_model_of_nan(paper_record) -> None:
    # Inputs of a subnormal unit: B = B_s / Su beyond 1e308, written as NaN (after numpy's overflow warning), exit 0.
    u, y = paper_record
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(IdentificationError, match=r"input gains B and D in the record's units are beyond the "
                                                      r"float64 range \(input spreads 1e-312, 1; "):
            identify(u * np.array([1e-312, 1.0]), y, DT, order=40, refine=False)


def test_channel_mean_is_the_mean_without_its_overflow(paper_record) -> None:
    u, y = paper_record
    np.testing.assert_array_equal(channel_mean(y), y.mean(axis=0))  # divided by powers of two: exact
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        big = channel_mean(np.column_stack([y[:, 0] * 1e305 + 1e307, np.zeros(y.shape[0])]))
    np.testing.assert_allclose(big, [y[:, 0].mean() * 1e305 + 1e307, 0.0], rtol=1e-12)


def test_channels_near_the_float64_limit_are_scaled_without_overflow() -> None:
    # A peak above 2**1023.5 (1.27e308) was rounded to the power of two 2**1024: Inf, numpy's overflow
    # warning, and the mean or the scaled window NaN (`track`, `identify` of a record in such units).
    x = np.array([[1.7e308, 1.0], [-1.5e308, 2.0], [1.0e308, 4.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        mean = channel_mean(x)
        scaled_u, scaled_y = group_scales(x[:, :1], x[:, 1:]).scale(x[:, :1], x[:, 1:])
    np.testing.assert_allclose(mean, [math.fsum(x[:, 0] / 3), 7 / 3], rtol=1e-15)
    assert np.isfinite(scaled_u).all() and np.abs(scaled_u).max() < 2 and np.array_equal(scaled_y, x[:, 1:] / 4)


def test_arx_fit_of_extreme_units_has_no_overflow(paper_record) -> None:
    u, y = paper_record
    reference = fit_arx(u, y, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        scaled = fit_arx(u * 1e150, y * 1e-150, 20)
    assert np.isfinite(scaled.theta).all()
    # One-step predictions agree once the units are taken out (the fit is of the same system).
    np.testing.assert_allclose(scaled.D * 1e300, reference.D, rtol=1e-3, atol=1e-6 * np.abs(reference.D).max())


def test_channel_spread_handles_extremes_and_dead_channels() -> None:
    x = np.column_stack([np.linspace(-1, 1, 101) * 1e300, np.full(101, -5e-300), np.zeros(101)])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        spread, std = channel_spread(x), channel_std(x)
    np.testing.assert_allclose(spread, [np.linspace(-1, 1, 101).std() * 1e300, 5e-300, 1.0])
    np.testing.assert_allclose(std, [np.linspace(-1, 1, 101).std() * 1e300, 0.0, 0.0])
    scales = channel_scales(x[:, :2], x[:, 2:])
    u_s, y_s = scales.scale(x[:, :2], x[:, 2:])
    assert np.isfinite(u_s).all() and np.abs(u_s).max() < 2


def test_column_peaks_are_numpys_largest_magnitudes() -> None:
    """``column_peaks`` against ``np.max(np.abs(x), axis=0)``: the same values, NaN, Inf and no rows included."""
    rng = np.random.default_rng(2)
    x = rng.standard_normal((5000, 5)) * np.array([1e-300, 1.0, 1e300, 3.0, 0.0])
    x[17, 3] = -np.inf
    for matrix in (x, np.asfortranarray(x), x[::3, 1:4]):
        assert np.array_equal(column_peaks(matrix), np.max(np.abs(matrix), axis=0))
    x[4, 1] = np.nan
    peaks = column_peaks(x)
    assert np.isnan(peaks[1]) and np.array_equal(np.delete(peaks, 1), np.delete(np.max(np.abs(x), axis=0), 1))
    assert np.array_equal(column_peaks(np.zeros((0, 3))), np.zeros(3))


def test_record_units_scale_each_group_by_its_channels_typical_size() -> None:
    # The power of two of a group's median magnitudes: inputs near 1e150 scaled, unit-size outputs left at 1.
    rng = np.random.default_rng(3)
    u, y = 1e150 * rng.standard_normal((500, 2)), rng.standard_normal((500, 3))
    units = record_units(u, y)
    assert units.input[0] == 2.0 ** round(np.log2(np.median(np.abs(u), axis=0)).mean()) and np.all(units.output == 1)
