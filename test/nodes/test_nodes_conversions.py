"""Message <-> numpy conversions, duck-typed.

Plain namespaces stand in for rclpy or rosbags message classes (okid_ros/nodes/conversions.py
imports no ROS package).
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import replace
from types import SimpleNamespace as NS

import numpy as np
import pytest

from okid_ros.nodes import conversions as cv
from okid_ros.service.estimation import ModalEstimationParams, ModalEstimationService
from okid_ros.service.grid_samples import NO_DATA
from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
from okid_ros.service.inputs import parse_source
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

TYPES = cv.MessageTypes(NS, NS, NS, NS, NS, NS, NS)  # every "class" takes the fields as keywords


def stamped(t: float, **fields):
    sec = int(t)
    return NS(header=NS(stamp=NS(sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id=""), **fields)


def vec(x, y, z):
    return NS(x=x, y=y, z=z)


def test_source_values_of_every_kind():
    imu = stamped(12.5, linear_acceleration=vec(1.0, 2.0, 3.0), angular_velocity=vec(4.0, 5.0, 6.0),
                  linear_acceleration_covariance=np.zeros(9), angular_velocity_covariance=np.zeros(9))
    source = parse_source("imu /a linear_acceleration.z=y1 angular_velocity.x=y0", 2, 2)
    stamp, values = cv.source_values(imu, source, 2, 2)
    assert stamp == pytest.approx(12.5) and values.tolist() == [3.0, 4.0]
    imu.angular_velocity_covariance[0] = -1.0  # REP 145: no angular velocity
    assert cv.source_values(imu, source, 2, 2)[1] is NO_DATA
    wrench = stamped(1.0, wrench=NS(force=vec(7.0, 8.0, 9.0), torque=vec(0.1, 0.2, 0.3)))
    _, values = cv.source_values(wrench, parse_source("wrench /w force.y=u0 torque.z=u1", 2, 2), 2, 2)
    assert values.tolist() == [8.0, 0.3]
    accel = stamped(1.0, accel=NS(linear=vec(1.5, 0.0, 0.0), angular=vec(0.0, 0.0, 2.5)))
    _, values = cv.source_values(accel, parse_source("accel /x accel.linear.x=y0 angular.z=y1", 1, 2), 1, 2)
    assert values.tolist() == [1.5, 2.5]
    array = NS(data=[3.25, 10.0, 20.0])
    stamp, values = cv.source_values(array, parse_source("array /d data[0]=stamp data[2]=u0 data[1]=y0", 1, 1), 1, 1)
    assert stamp == 3.25 and values.tolist() == [20.0, 10.0]
    stamp, values = cv.source_values(NS(data=[1.0]), parse_source("array /d data[2]=u0 data[0]=y0", 1, 1), 1, 1)
    assert stamp is None and values.size == 0  # too short: wrong size
    io = stamped(2.0, u=[1.0, 2.0], y=[3.0, 4.0])
    _, values = cv.source_values(io, parse_source("io_sample /io", 2, 2), 2, 2)
    assert values.tolist() == [1.0, 2.0, 3.0, 4.0]
    _, values = cv.source_values(stamped(2.0, u=[1.0], y=[3.0, 4.0]), parse_source("io_sample /io", 2, 2), 2, 2)
    assert values.size == 0
    _, values = cv.source_values(io, parse_source("io_sample /io y[1]=y0", 1, 1), 1, 1)
    assert values.tolist() == [4.0]


def test_stamps_round_trip_to_the_nanosecond():
    t = 1732212345.123456789
    stamp = cv.seconds_to_stamp(t, TYPES)
    assert stamp.sec == 1732212345 and abs(stamp.nanosec - 123456789) < 500
    assert cv.stamp_to_seconds(cv.seconds_to_stamp(12.008, TYPES)) == pytest.approx(12.008, abs=1e-12)


@pytest.fixture(scope="module")
def identified():
    model = paper_model()
    dt = model.sample_time_s
    u = lowpass_input(1500, 2, 50.0, dt, seed=5)
    y, _ = simulate_innovation(model, u, seed=6)
    ident = ArxIdentificationService(ArxIdentificationParams(dt, 20, 2, 2, 1000))
    est = ModalEstimationService(ModalEstimationParams(dt, 2, 2, n_states=6))
    result = None
    for k in range(1500):
        ident.push(k * dt, u[k], y[k])
        result = est.step(k * dt, u[k], y[k]) or result
        if k == 1200:
            snap = ident.snapshot()
            est.submit_arx(snap.fit, snap.stamp_s, snap.model_id, snap.window_rows)
            est.process_pending()
    return snap, est, result


def test_arx_model_round_trip(identified):
    snap, _, _ = identified
    msg = cv.arx_model_msg(snap, TYPES, frame_id="rig")
    assert msg.valid and msg.order == 20 and msg.coefficients_rows == 2 + 20 * 4
    assert msg.markov_parameters_count == 21 and msg.markov_parameters.size == 21 * 4
    assert msg.condition_number == pytest.approx(np.sqrt(snap.condition_number))
    fit, stamp, rows = cv.arx_fit_from_msg(msg, msg.sample_time_s)
    np.testing.assert_array_equal(fit.theta, snap.fit.theta)
    for other in (0.5, float("nan"), msg.sample_time_s * (1 + 1e-6)):  # another grid's model: refused
        with pytest.raises(ValueError, match="this node's sample_time_s is"):
            cv.arx_fit_from_msg(msg, other)
    assert stamp == pytest.approx(snap.stamp_s) and rows == snap.window_rows
    np.testing.assert_allclose(fit.residual_covariance, snap.fit.residual_covariance)
    msg.coefficients = msg.coefficients[:-1]
    with pytest.raises(ValueError, match="needs 82 x 2"):
        cv.arx_fit_from_msg(msg)


@pytest.mark.parametrize("covariance, text", [
    ([np.nan, 0.0, 0.0, 1.0], "not finite"),
    ([np.inf, 0.0, 0.0, 1.0], "not finite"),
    ([1.0, 0.5, 0.0, 1.0], "not symmetric"),
    ([-1.0, 0.0, 0.0, -1.0], "not positive semidefinite"),
    ([1.0, 2.0, 2.0, 1.0], "not positive semidefinite"),  # eigenvalues 3 and -1
    ([1.0, 0.0, 0.0], "has 3 values; 2 outputs need 2 x 2"),  # was replaced by the identity
    ([], "has 0 values"),
])
def test_an_arx_model_whose_residual_covariance_is_no_covariance_is_malformed(identified, covariance, text):
    msg = cv.arx_model_msg(identified[0], TYPES)
    msg.residual_covariance = np.array(covariance, dtype=float)
    with pytest.raises(ValueError, match=f"ArxModel residual_covariance (is )?{text}"):
        cv.arx_fit_from_msg(msg, msg.sample_time_s)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_an_arx_model_whose_coefficients_are_not_finite_is_malformed(identified, bad):
    # Was taken, and spent a realization on node 2's worker: "realization failed: array must not
    # contain infs or NaNs", counted as a rejected model instead of a malformed message.
    msg = cv.arx_model_msg(identified[0], TYPES)
    coefficients = np.array(msg.coefficients)
    coefficients[7] = bad
    msg.coefficients = coefficients
    with pytest.raises(ValueError, match=r"ArxModel coefficients are not finite \(1 of 164 values NaN or Inf\)"):
        cv.arx_fit_from_msg(msg, msg.sample_time_s)


@pytest.mark.parametrize("scale, index, text", [
    (1e150, None, "overflow float64"),  # every coefficient: the fuzz's model
    (1e10, None, "reach 9.4e[+]205"),  # finite, and squared beyond float64 in the modes' fit
    (1e150, 7, "overflow float64"),  # one lag coefficient (was 'realization failed: ... numerical rank 2')
])
def test_an_arx_model_of_absurd_finite_coefficients_is_malformed_without_a_warning(identified, scale, index, text):
    # Was taken and realized on node 2's worker: 'realization failed: array must not contain infs or
    # NaNs', counted in models_rejected, numpy's overflow warnings printed from the worker (times 1e10:
    # accepted, with scipy's 'overflow encountered in square').
    msg = cv.arx_model_msg(identified[0], TYPES)
    coefficients = np.array(msg.coefficients)
    if index is None:
        coefficients *= scale
    else:
        coefficients[index] = scale
    msg.coefficients = coefficients
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=f"ArxModel coefficients are absurd: its Markov parameters "
                                             rf"\(paper Eq. 24, 21 terms\) {text}.*beyond 1e\+150"):
            cv.arx_fit_from_msg(msg, msg.sample_time_s)
    msg.coefficients = np.array(cv.arx_model_msg(identified[0], TYPES).coefficients) * 1e3  # within: taken
    assert cv.arx_fit_from_msg(msg, msg.sample_time_s)[0].order == 20


@pytest.mark.parametrize("order, text", [
    (5000, "arx.order 5000 with 2 inputs and 2 outputs gives regressors of d = m + q (p + m) = 20002 coefficients; "
           "at most 2500"),
    (1, "arx.order 1: node 2 realizes models from an ARX order of at least 2"),
])
def test_an_arx_model_of_an_order_node_1_never_publishes_is_malformed(identified, order, text):
    # Well formed, coefficients of the size the order gives: one of order 5000 (the limit of arx.order
    # alone) was taken and realized, node 2's worker busy for more than 4 minutes with its window of
    # 20000 rows and no other model realized meanwhile; node 1 refuses both orders at its start.
    msg = cv.arx_model_msg(identified[0], TYPES)
    d = 2 + order * 4
    msg.order, msg.coefficients_rows, msg.coefficients = order, d, np.full(2 * d, 1e-4)
    with pytest.raises(ValueError, match=re.escape(f"ArxModel beyond what node 1 publishes: {text}")):
        cv.arx_fit_from_msg(msg, msg.sample_time_s)
    msg.order, msg.coefficients_rows, msg.coefficients = 2, 10, np.full(20, 1e-4)
    assert cv.arx_fit_from_msg(msg, msg.sample_time_s)[0].order == 2


def test_node_1_never_publishes_a_covariance_node_2_refuses(identified):
    snap = identified[0]
    # Round-off of a near-exact fit: an eigenvalue a hair below 0, published as 0.
    exact = np.array([[1e-18, 2e-18], [2e-18, 3.9999e-18]])
    msg = cv.arx_model_msg(replace(snap, fit=replace(snap.fit, residual_covariance=exact)), TYPES)
    fit, _, _ = cv.arx_fit_from_msg(msg, msg.sample_time_s)
    assert np.linalg.eigvalsh(fit.residual_covariance)[0] >= -1e-30
    np.testing.assert_allclose(fit.residual_covariance, exact, atol=1e-21)
    zero = cv.arx_model_msg(replace(snap, fit=replace(snap.fit, residual_covariance=np.zeros((2, 2)))), TYPES)
    assert not cv.arx_fit_from_msg(zero, zero.sample_time_s)[0].residual_covariance.any()


@pytest.mark.parametrize("u, y", [([1.0] * 5, [3.0, 4.0]), ([1.0], [3.0, 4.0]), ([1.0, 2.0], [3.0] * 3), ([], [])])
def test_an_io_sample_of_the_wrong_sizes_gives_no_values(u, y):
    # No values: the sample grid counts the message as wrong_size, before it anchors anything.
    _, values = cv.source_values(stamped(2.0, u=u, y=y), parse_source("io_sample /io", 2, 2), 2, 2)
    assert values.size == 0


def test_state_space_and_modal_states_round_trip(identified):
    _, est, result = identified
    assert result is not None and est.has_model
    update = NS(model=est.current_model, model_id=3, arx_model_id=7, stamp_s=4.0, modes=est.current_modes)
    back = cv.state_space_from_msg(cv.state_space_model_msg(update, TYPES))
    model = est.current_model
    for name in ("A", "B", "C", "D", "K", "innovation_covariance"):
        np.testing.assert_array_equal(back[name], getattr(model, name))
    assert back["model_id"] == 3 and back["arx_model_id"] == 7
    assert [m["id"] for m in back["modes"]] == [m.id for m in est.current_modes]
    states = cv.modal_states_from_msg(cv.modal_states_msg(result, TYPES))
    np.testing.assert_array_equal(states["coordinates"], result.coordinates)
    np.testing.assert_array_equal(states["innovation"], result.innovation)
    mode = states["modes"][0]
    assert mode["frequency_rad_s"] == pytest.approx(result.modes[0].frequency_rad_s)
    np.testing.assert_allclose(mode["shape"], result.modes[0].shape)
    reused = stamped(0.0, model_id=0, modes=[], modal_coordinates=None, y_estimated=None, innovation=None)
    modes = [cv.mode_msg(m, TYPES) for m in result.modes]
    cv.fill_modal_states(reused, result, modes)
    again = cv.modal_states_from_msg(reused)
    np.testing.assert_array_equal(again["coordinates"], result.coordinates)
    assert again["stamp_s"] == pytest.approx(result.stamp_s) and reused.modes is modes


def _state_space_msg(identified):
    _, est, _ = identified
    update = NS(model=est.current_model, model_id=3, arx_model_id=7, stamp_s=4.0, modes=est.current_modes)
    return cv.state_space_model_msg(update, TYPES)


def _set(name, value):
    return lambda msg: setattr(msg, name, value(getattr(msg, name)))


def _set_mode(name, value):
    return lambda msg: setattr(msg.modes[0], name, value(getattr(msg.modes[0], name)))


@pytest.mark.parametrize("spoil, reason", [
    (_set("a", lambda a: a[:-1]), "a has 35 values, its sizes give 6 x 6"),
    (_set("n_states", lambda n: n + 1), "a has 36 values, its sizes give 7 x 7"),
    (_set("b", lambda b: np.r_[b, 0.0]), "b has 13 values, its sizes give 6 x 2"),
    (_set("c", lambda c: np.where(np.arange(c.size) == 3, np.nan, c)), "c holds values that are not finite"),
    (_set("k", lambda k: np.full(k.size, np.inf)), "k holds values that are not finite"),
    (_set("innovation_covariance", lambda v: v[:0]), "innovation_covariance has 0 values, its sizes give 2 x 2"),
    (_set("hankel_singular_values", lambda v: np.r_[v, np.nan]), "hankel_singular_values holds values that are not"),
    (_set("output_offset", lambda v: v[:1]), "output_offset has 1 values, its sizes give 2"),
    (_set("sample_time_s", lambda t: math.nan), "sample_time_s nan is not a positive number of seconds"),
    (_set("sample_time_s", lambda t: 0.0), "sample_time_s 0.0 is not a positive number of seconds"),
    (_set_mode("shape_real", lambda v: v[:0]), "its shape has 0 real and 2 imaginary values, the model 2 outputs"),
    (_set_mode("damping_ratio", lambda z: math.nan), "frequency_hz .*, damping_ratio nan"),
])
def test_a_state_space_model_not_of_its_sizes_or_not_finite_is_refused_with_the_reason(identified, spoil, reason):
    """Was decoded in silence (NaN, a short shape, a sample time of 0) or refused by a reshape naming no field."""
    msg = _state_space_msg(identified)
    spoil(msg)
    with pytest.raises(ValueError, match=reason):
        cv.state_space_from_msg(msg)


def test_a_state_space_model_without_offsets_or_imaginary_shapes_is_read_as_zeros_and_real_shapes(identified):
    """A message from before the offsets, or of real shapes, is a model (the real shapes were a broadcast error)."""
    msg = _state_space_msg(identified)
    msg.input_offset, msg.output_offset = np.zeros(0), np.zeros(0)
    for mode in msg.modes:
        mode.shape_imag = np.zeros(0)
    back = cv.state_space_from_msg(msg)
    assert back["input_offset"].shape == (2,) and not back["output_offset"].any()
    np.testing.assert_array_equal(back["modes"][0]["shape"], msg.modes[0].shape_real)
