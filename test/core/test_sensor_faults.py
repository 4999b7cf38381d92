"""A record's drift removed and its clipping named, against records whose truth is known."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from okid_ros.core.output_only import identify_output_only
from okid_ros.core.output_only_harmonics import without_harmonics
from okid_ros.core.pipeline import identify
from okid_ros.core.sensor_faults import (
    TREND_SHARE,
    clipped_samples,
    held_channel_warnings,
    record_fault_warnings,
    record_faults,
    remove_trends,
)
from okid_ros.sim.inputs import lowpass_input
from okid_ros.sim.models import modal_structure
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation, simulate_noisy

DT = 0.008


@pytest.fixture(scope="module")
def clean_modes(paper_record):
    u, y = paper_record
    return sorted(m.frequency_hz for m in identify(u, y, DT).modes)


def _ramp(n: int, rise: float) -> np.ndarray:
    return np.linspace(0.0, rise, n)[:, None]


def test_a_drifting_output_is_identified_as_the_record_without_it(paper_record, clean_modes) -> None:
    # A ramp of one output spread over the record holds 8 and 22 % of the outputs' variance;
    # kept, every order's realization has a pole at z = 1 and the model lists no mode.
    u, y = paper_record
    drifted = y + _ramp(y.shape[0], y.std(axis=0).max())
    model = identify(u, drifted, DT)
    found = sorted(m.frequency_hz for m in model.modes)
    assert len(found) == len(clean_modes) == 3
    np.testing.assert_allclose(found, clean_modes, rtol=2e-4)
    drifts = [w for w in model.warnings if "drifts" in w]
    assert [w.split(" drifts")[0] for w in drifts] == ["output 0", "output 1"]
    assert all("removed before identification" in w for w in drifts)
    np.testing.assert_allclose(model.output_offset, drifted.mean(axis=0), rtol=1e-12)


def test_raw_signals_keep_their_drift_and_say_so(paper_record) -> None:
    u, y = paper_record
    drifted = y + _ramp(y.shape[0], y.std(axis=0).max())
    model = identify(u, drifted, DT, offsets="none")
    assert any("drifts" in w and "NOT removed" in w for w in model.warnings)


def test_stationary_records_are_left_as_they_are(paper_record) -> None:
    u, y = paper_record
    for x, name in ((u, "input"), (y, "output")):
        same, warnings = remove_trends(x, name)
        assert same is x and warnings == []
    for x, name in ((u, "input"), (y, "output")):
        clipped, named = clipped_samples(x, name)
        assert not clipped.any() and named == []


def test_the_line_is_fitted_to_the_samples_present_and_the_mean_kept() -> None:
    rng = np.random.default_rng(0)
    n = 2000
    x = rng.standard_normal((n, 2)) + np.column_stack([np.linspace(-3, 3, n), np.zeros(n)])
    valid = np.ones(n, dtype=bool)
    valid[500:700] = False
    x[~valid] = 0.0  # missing samples hold zeros, as checked_record leaves them
    out, warnings = remove_trends(x, "output", valid=valid)
    assert len(warnings) == 1 and warnings[0].startswith("output 0 drifts: a straight line rising by")
    np.testing.assert_array_equal(out[~valid], 0.0)
    np.testing.assert_array_equal(out[:, 1], x[:, 1])
    np.testing.assert_allclose(out[valid].mean(axis=0), x[valid].mean(axis=0), atol=1e-12)
    t = np.flatnonzero(valid)
    assert abs(np.polyfit(t, out[valid, 0], 1)[0]) < 1e-12


@settings(max_examples=40, deadline=None)
@given(st.integers(min_value=3, max_value=400), st.floats(min_value=-1e6, max_value=1e6),
       st.sampled_from([1e-300, 1.0, 1e300]), st.integers(min_value=0, max_value=2**32 - 1))
def test_a_removed_line_leaves_no_slope_and_the_mean(n, slope, scale, seed) -> None:
    rng = np.random.default_rng(seed)
    x = (rng.standard_normal((n, 1)) + slope * np.arange(n)[:, None] / n) * scale
    out, warnings = remove_trends(x, "input")
    assert np.all(np.isfinite(out))
    if warnings:
        unit = out[:, 0] / scale
        assert abs(np.polyfit(np.arange(n), unit, 1)[0]) <= 1e-9 * max(1.0, np.abs(unit).max())
        np.testing.assert_allclose(out.mean() / scale, x.mean() / scale, atol=1e-9 * max(1.0, np.abs(x / scale).max()))
    else:
        assert out is x


def test_a_clipped_output_is_named_with_its_share(paper_record) -> None:
    # Output 0 clipped at 80 % of its peak: its flat tops gave modes at 18.1 and 29.7 Hz, nothing said.
    u, y = paper_record
    level = 0.8 * np.abs(y[:, 0]).max()
    clipped = y.copy()
    clipped[:, 0] = np.clip(y[:, 0], -level, level)
    model = identify(u, clipped, DT)
    named = [w for w in model.warnings if "clipped" in w]
    at_top = np.count_nonzero(clipped[:, 0] == level)
    assert len(named) == 1 and named[0].startswith(
        f"output 0 is clipped (a sensor's or recorder's range exceeded?): {100 * at_top / y.shape[0]:.1f} % of its "
        "samples sit at its largest value")
    assert named[0].endswith("; the model may list spurious modes from it")


def test_two_level_and_quantized_signals_are_not_clipped() -> None:
    prbs = np.sign(np.random.default_rng(1).standard_normal((4000, 2)))  # a two-level test signal
    t = np.arange(20000) * 0.001
    slow_sine = np.round(1000 * np.sin(2 * np.pi * 0.5 * t))[:, None]  # dwells at its top count each period
    rng = np.random.default_rng(2)
    quantized = np.round(200 * rng.standard_normal((20000, 1)))
    for x, name in ((prbs, "input"), (slow_sine, "output"), (quantized, "output")):
        clipped, named = clipped_samples(x, name)
        assert named == [] and not clipped.any()
    # The same quantized record clipped at a converter's rails is named at both ends.
    rail = np.clip(quantized, -300, 300)
    clipped, named = clipped_samples(rail, "output")
    assert len(named) == 1 and "its largest value 300" in named[0] and "its smallest value -300" in named[0]
    np.testing.assert_array_equal(clipped, np.abs(rail[:, 0]) == 300)


def test_clipping_is_judged_before_the_drift_tilts_the_flat_tops() -> None:
    rng = np.random.default_rng(3)
    x = np.clip(rng.standard_normal((5000, 1)), -1.5, 1.5) + _ramp(5000, 6.0)
    x = np.clip(x, -np.inf, 4.0)
    _, _, _, warnings = record_faults(np.zeros((5000, 0)), x)
    named = [w.split(" (")[0].split(":")[0] for w in warnings if w.startswith("output 0")]
    assert named == ["output 0 is clipped", "output 0 drifts"]


@pytest.mark.parametrize(("method", "rtol"), [("ssi-cov", 1e-5), ("ssi-cva", 1e-3)])
def test_output_only_identification_removes_a_drift(method: str, rtol: float) -> None:
    # rtol: the canonical-variate route's whole-record correlations keep more of what the removed
    # drift leaves (1.4e-4 of a damping whose own standard deviation is some 10 %).
    system = modal_structure([3.0, 7.0, 12.0], 0.01, 1, 4, 1 / 50, seed=3, output="acceleration",
                             disturbance_std=1.0)
    rng = np.random.default_rng(5)
    y = simulate_noisy(system, np.zeros((12000, 1)), seed=5)
    clean = identify_output_only(y, 1 / 50, method=method).modes
    drifted = y + np.linspace(0.0, 2.0, y.shape[0])[:, None] * y.std(axis=0) * (1 + rng.random(y.shape[1]))
    model = identify_output_only(drifted, 1 / 50, method=method)
    assert len(clean) == len(model.modes) == 3
    # The record's modes as without the drift (kept, it moves the 7 Hz mode by 3e-4 and its damping by 2 %).
    for attribute in ("frequency_hz", "damping_ratio"):
        np.testing.assert_allclose([getattr(m, attribute) for m in model.modes],
                                   [getattr(m, attribute) for m in clean], rtol=rtol)
    assert sum("drifts" in w for w in model.warnings) == y.shape[1]


def test_the_threshold_sits_above_stationary_records() -> None:
    # The module's calibration, kept honest: a record of 20 periods of its slowest mode holds
    # a trend far below the share (a pure sine at its worst phase: 0.0015).
    t = np.linspace(0.0, 20.0, 4000)
    x = np.sin(2 * np.pi * t)[:, None]
    assert remove_trends(x, "output")[1] == []
    assert TREND_SHARE > 10 * 0.0015


def _sine(n: int, frequency_hz: float) -> np.ndarray:
    return np.sqrt(2.0) * np.sin(2 * np.pi * frequency_hz * np.arange(n) * DT + 0.3)[:, None]


def test_an_unmeasured_harmonic_in_the_outputs_is_removed_not_listed(paper_record) -> None:
    # Mains hum or a machine's rotation at 20 Hz, half the outputs' spread: kept, the chain listed
    # a mode at 20 Hz with 0.0 % damping and lost the 48.5 Hz mode.
    u, y = paper_record
    clean = identify(u, y, DT).modes
    model = identify(u, y + 0.5 * y.std(axis=0) * _sine(y.shape[0], 20.0), DT)
    assert [w for w in model.warnings if w.startswith("harmonic disturbance removed")] == [
        "harmonic disturbance removed before identification (not a mode; the inputs hold no such line): 20 Hz"]
    assert len(model.modes) == len(clean) == 3
    for attribute in ("frequency_hz", "damping_ratio"):
        np.testing.assert_allclose([getattr(m, attribute) for m in model.modes],
                                   [getattr(m, attribute) for m in clean], rtol=5e-3)


@pytest.mark.parametrize("dropped", [5, 40])
def test_a_harmonic_is_removed_from_a_record_with_dropped_samples(paper_record, dropped) -> None:
    # The lines were looked for only in a record without missing samples: 5 dropped samples in
    # a hum-laden record and the chain listed the 20 Hz line as a mode (bench/record_faults.py,
    # hum-gaps: 9 of 10 records, 10 spurious modes in all).
    u, y = paper_record
    clean = identify(u, y, DT).modes
    hum = y + 0.5 * y.std(axis=0) * _sine(y.shape[0], 20.0)
    rng = np.random.default_rng(dropped)
    gaps = rng.choice(np.arange(100, y.shape[0] - 100), dropped, replace=False)
    hum[gaps, 1] = np.nan
    valid = np.all(np.isfinite(hum), axis=1)
    model = identify(u, hum, DT, valid=valid)
    assert any(w.startswith("harmonic disturbance removed") and w.endswith(": 20 Hz") for w in model.warnings)
    assert len(model.modes) == len(clean) == 3
    np.testing.assert_allclose([m.frequency_hz for m in model.modes], [m.frequency_hz for m in clean], rtol=5e-3)


def test_the_sinusoid_is_fitted_to_the_samples_present_and_the_missing_keep_their_values() -> None:
    rng = np.random.default_rng(1)
    n, dt = 4000, 0.01
    t = np.arange(n) * dt
    noise = 0.1 * rng.standard_normal((n, 2))
    y = 3.0 + noise + np.column_stack([np.sin(2 * np.pi * 7.3 * t + 0.4), 0.5 * np.cos(2 * np.pi * 7.3 * t)])
    valid = np.ones(n, bool)
    valid[rng.choice(n, 30, replace=False)] = False
    y[~valid] = -1e6  # any value at a missing sample: neither the line found nor its fit may see it
    cleaned, warnings = without_harmonics(y, dt, valid=valid)
    assert warnings and warnings[0].endswith(": 7.3 Hz")
    np.testing.assert_array_equal(cleaned[~valid], y[~valid])
    np.testing.assert_allclose(cleaned[valid], 3.0 + noise[valid], atol=0.02)


def test_a_measured_harmonic_force_stays_in_the_record() -> None:
    truth = paper_model()
    u = lowpass_input(3750, 2, 15.0, DT, seed=3)
    u = u + 0.5 * u.std(axis=0) * _sine(u.shape[0], 20.0)  # a shaker's sine on top of its noise
    y, _ = simulate_innovation(truth, u, seed=4)
    model = identify(u, y, DT)
    assert not any("harmonic" in w for w in model.warnings)
    found = sorted(m.frequency_hz for m in model.modes)
    np.testing.assert_allclose(found, [5.904, 7.342, 48.461], rtol=0.01)  # the published model's modes


def test_an_output_that_drops_out_alone_is_named(paper_record) -> None:
    # Output 1 at 0 over 600 samples (a loose cable) while output 0 responds: a spurious 48.9 Hz
    # mode was listed with nothing said.
    u, y = paper_record
    dropped = y.copy()
    dropped[1000:1600, 1] = 0.0
    model = identify(u, dropped, DT)
    assert [w for w in model.warnings if "dropped out" in w] == [
        "output 1 holds the value 0 over samples 1000-1599 (16 % of the record) while the others respond: a sensor "
        "that dropped out? Those samples are identified as measured; cut them out or leave the channel out"]
    # Every output held is the record held (frozen_output_warnings), and a short hold is no dropout.
    both = y.copy()
    both[1000:1600] = 0.0
    assert held_channel_warnings(both) == []
    short = y.copy()
    short[1000:1040, 1] = 0.0
    assert held_channel_warnings(short) == []


def test_faults_named_only_are_those_record_faults_names_and_the_record_stays(paper_record) -> None:
    # One rule for both (track names what identify names and takes out): the same channels in the
    # same order, the record not changed, and the missing samples left out whatever they hold (NaN).
    u, y = paper_record
    faulty = y + _ramp(y.shape[0], y.std(axis=0).max()) + 0.5 * y.std(axis=0) * _sine(y.shape[0], 20.0)
    faulty[:, 0] = np.clip(faulty[:, 0], None, 0.8 * faulty[:, 0].max())
    faulty[1000:1600, 1] = 0.0
    before = faulty.copy()
    named = record_fault_warnings(u, faulty, sample_time_s=DT)
    np.testing.assert_array_equal(faulty, before)
    _, _, _, taken_out = record_faults(u, faulty, sample_time_s=DT)
    assert [w.split(" ")[:3] for w in named] == [
        ["output", "1", "holds"], ["output", "0", "is"], ["output", "0", "drifts:"], ["output", "1", "drifts:"],
        ["harmonic", "disturbance", "in"]]
    # The same findings, up to what is done about them.
    assert [w.split(";")[0] for w in named[:4]] == [w.split(";")[0] for w in taken_out[:4]]
    assert "NOT removed" in named[2] and "removed before identification" in taken_out[2]
    assert taken_out[4].endswith("line): 20 Hz") and "line): 20 Hz; kept: track fits its windows" in named[4]
    valid = np.ones(y.shape[0], dtype=bool)
    valid[2000:2300] = False  # zeros there would hold every output over 8 % of the record
    missing = faulty.copy()
    missing[~valid] = np.nan
    _, _, _, with_zeros = record_faults(u, np.where(valid[:, None], faulty, 0.0), valid=valid)
    kept = record_fault_warnings(u, missing, valid=valid, sample_time_s=DT)
    assert [w.split(";")[0] for w in kept] == [w.split(";")[0] for w in with_zeros] and len(kept) == 4
    assert not any("hold every output" in w for w in kept)  # a gap is no held value
