"""Property-based test: node 2's sample ring returns the samples it holds, in order, whatever the wrap.

:class:`okid_ros.service.sample_buffer.SampleBuffer` reads its ring by slices (a fancy index of
thousands of rows held the lock the sample path appends under 10x longer), and after it grows
holds no sample the smaller ring had let go (they came back as zeros stamped 0); checked here
against every sample appended, kept aside in plain arrays.
"""

from __future__ import annotations

import math

import numpy as np
from _hypothesis_profiles import settings  # noqa: F401 - registers and loads the profile
from hypothesis import given
from hypothesis import strategies as st

from okid_ros.service.sample_buffer import SampleBuffer


@given(capacity=st.integers(16, 64), appended=st.integers(0, 300), m=st.integers(0, 2), p=st.integers(1, 3),
       lo=st.integers(-20, 320), length=st.integers(-5, 100), grow=st.integers(0, 40), seed=st.integers(0, 2**16))
def test_get_returns_the_stored_samples_in_order(capacity, appended, m, p, lo, length, grow, seed):
    rng = np.random.default_rng(seed)
    stamps = np.arange(appended) * 0.01
    u, y = rng.standard_normal((appended, m)), rng.standard_normal((appended, p))
    skipped = rng.integers(-1, 3, appended)
    ring = SampleBuffer(capacity, m, p)
    half, oldest = appended // 2, 0
    for k in range(appended):
        if k == half and grow:
            oldest = max(k - ring.cap, 0)  # what the ring has let go is not held after it grows
            ring.resize(ring.cap + grow)  # midway, with the ring wrapped
        assert ring.append(stamps[k], u[k], y[k], int(skipped[k])) == k
    stored = ring.first
    assert stored == max(appended - ring.cap, oldest)
    a, b = max(lo, stored), min(lo + length, appended)
    want = slice(a, max(a, b))
    got = ring.get(lo, lo + length)
    for g, w in zip(got, (stamps[want], u[want], y[want], skipped[want])):
        assert g.shape == w.shape and np.array_equal(g, w)
        assert not np.shares_memory(g, ring.stamps) and not np.shares_memory(g, ring.y)
    if appended > stored:  # the newest timeline starts after the last restart among the stored samples
        restarts = [k for k in range(stored, appended) if skipped[k] < 0]
        start = restarts[-1] if restarts else stored
        j = min(max(lo, start), appended - 1)
        assert ring.find_end(stamps[j], 1e-9) == (j, stamps[j])
        assert ring.first_at_or_after(stamps[j]) == j
        assert ring.timeline_start_stamp() == stamps[start]
    else:
        assert math.isnan(ring.timeline_start_stamp())


def test_a_ring_that_grew_holds_only_what_it_held():
    ring = SampleBuffer(16, 1, 1)
    for k in range(30):
        ring.append(float(k), [k], [k], 0)
    ring.resize(56)  # samples 0-13 were let go; 14-29 are held
    for k in range(30, 40):
        ring.append(float(k), [k], [k], 0)
    assert ring.first == 14
    stamps, u, y, skipped = ring.get(0, 40)
    np.testing.assert_array_equal(stamps, np.arange(14, 40))
    np.testing.assert_array_equal(y[:, 0], np.arange(14, 40))
    assert ring.find_end(5.0, 0.1)[0] == -1  # none held at or before 5 s
