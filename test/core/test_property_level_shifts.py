"""Property-based tests of a record's fault rules (level shifts, spikes, drift, clipping) on hostile records.

Records shorter than the level shifts' windows, steps at the first and last samples, several in
one channel or one in every channel, quantized, two-level and constant channels, missing samples,
float32 and integer arrays, units from 2^-980 to 2^980: ``record_faults`` and
``record_fault_warnings`` never raise nor let numpy warn, leave every value finite, and find the
same level shifts in any units (a power of two scales every value exactly).
"""

from __future__ import annotations

import warnings

import numpy as np
from _hypothesis_profiles import settings  # noqa: F401 - registers and loads the profile
from hypothesis import example, given
from hypothesis import strategies as st

from okid_ros.core.level_shifts import level_shifts
from okid_ros.core.sensor_faults import record_fault_warnings, record_faults

KINDS = ["noise", "walk", "quantized", "constant", "two-level", "sparse"]


@st.composite
def records(draw):
    n = draw(st.sampled_from([30, 399, 400, 401, 650, 1200]))
    p, m = draw(st.integers(1, 3)), draw(st.integers(0, 2))
    kind, seed = draw(st.sampled_from(KINDS)), draw(st.integers(0, 2**16))
    steps = draw(st.lists(st.tuples(st.integers(0, p - 1), st.integers(0, n - 1), st.floats(-100, 100)), max_size=6))
    missing = draw(st.sampled_from([0.0, 0.0, 0.01, 0.3]))
    dtype = draw(st.sampled_from(["f8", "f4", "i8"]))
    exponent = draw(st.sampled_from([0, -980, -500, 500, 980]))
    return n, p, m, kind, seed, steps, missing, dtype, exponent


def _record(n, p, m, kind, seed, steps, missing, dtype):
    rng = np.random.default_rng(seed)
    y = {"noise": lambda: rng.standard_normal((n, p)), "walk": lambda: np.cumsum(rng.standard_normal((n, p)), axis=0),
         "quantized": lambda: np.round(0.7 * rng.standard_normal((n, p))), "constant": lambda: np.full((n, p), 3.0),
         "two-level": lambda: (rng.random((n, p)) > 0.9).astype(float),
         "sparse": lambda: np.where(rng.random((n, p)) > 0.99, rng.standard_normal((n, p)), 0.0)}[kind]()
    for i, k, size in steps:
        y[k:, i] += size
    u = rng.standard_normal((n, m))
    if dtype == "i8":
        u, y = np.round(10 * u).astype(np.int64), np.round(10 * y).astype(np.int64)
    u, y = u.astype(dtype), y.astype(dtype)
    valid = rng.random(n) >= missing
    if valid.all():
        return u, y, None
    return np.where(valid[:, None], u, 0).astype(dtype), np.where(valid[:, None], y, 0).astype(dtype), valid


@given(records())
# Found by the bench profile on 8644b37: a step of 29 at sample 319 of 399 (its edge a spike) in units of
# 2^980: the spike's spread by np.std overflowed (numpy's warning), the spike called small.
@example((399, 1, 0, "noise", 0, [(0, 319, 29.0)], 0.0, "f8", 980))
def test_the_fault_rules_take_any_record_in_any_units(case) -> None:
    *shape, exponent = case
    u, y, valid = _record(*shape)
    units = 2.0**exponent
    # The record as given (float32, integers) in its units; in far units as float64 (float32 ends at 3e38).
    far_u, far_y = (u, y) if exponent == 0 else (u.astype(float) * units, y.astype(float) * units)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        shifts = level_shifts(u, y, valid=valid)
        far = level_shifts(far_u, far_y, valid=valid)
        u_out, y_out, _, said = record_faults(far_u, far_y, valid=valid, sample_time_s=0.01, leave_out_spikes=True)
        named = record_fault_warnings(far_u, far_y, valid=valid, sample_time_s=0.01)
    assert np.isfinite(u_out).all() and np.isfinite(y_out).all()
    assert all(isinstance(text, str) and "\n" not in text for text in said + named)
    assert sorted(far.by_output) == sorted(shifts.by_output) and sorted(far.unusable) == sorted(shifts.unusable)
    for i, (samples, sizes) in shifts.by_output.items():
        np.testing.assert_array_equal(far.by_output[i][0], samples)
        assert ((0 < samples) & (samples < y.shape[0])).all()
        np.testing.assert_allclose(far.by_output[i][1], sizes * units, rtol=1e-9)
