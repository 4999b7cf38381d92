"""Property-based tests of the sample grid (stamps out of order, duplicated, jumping, NaN, sizes, gaps).

Never an exception; every emitted sample finite and in slot order; every
message accounted for; and for clean sources with gaps, exactly the complete slots come out with
the gaps marked.
"""

from __future__ import annotations

import math

import numpy as np
from _hypothesis_profiles import settings  # noqa: F401 - registers and loads the profile
from hypothesis import given
from hypothesis import strategies as st

from okid_ros.service.sample_grid import MAX_STAMP_S, SampleGrid, StampSequence, StampStep

DT = 0.01
SOURCES = [[0], [1, 2]]  # one input (u0), two outputs (y0, y1) from a second source

hostile_float = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-1e6, max_value=1e6),
    st.sampled_from([0.0, -0.0, 1e308, -1e308, 5e-324]),
)


@st.composite
def messages(draw):
    """A list of (source, stamp_s, values): mostly near the grid, with every kind of fault."""
    count = draw(st.integers(0, 60))
    out = []
    for _ in range(count):
        source = draw(st.integers(0, 1))
        kind = draw(st.sampled_from(["grid", "grid", "grid", "jitter", "any", "jump"]))
        slot = draw(st.integers(-5, 80))
        if kind == "grid":
            stamp = 100.0 + slot * DT
        elif kind == "jitter":
            stamp = 100.0 + (slot + draw(st.floats(-0.6, 0.6))) * DT
        elif kind == "jump":
            stamp = draw(st.sampled_from([0.0, 50.0, 1e9, -1e9, 1e300]))
        else:
            stamp = draw(hostile_float)
        size = len(SOURCES[source]) + draw(st.sampled_from([0, 0, 0, 0, -1, 1]))
        values = draw(st.lists(st.one_of(st.floats(-10, 10), hostile_float), min_size=max(size, 0),
                               max_size=max(size, 0)))
        out.append((source, stamp, values))
    return out


@given(batch=messages())
def test_any_message_stream_is_handled_and_accounted_for(batch) -> None:
    grid = SampleGrid(DT, 1, 2, SOURCES, latency_samples=3)
    emitted = []
    for source, stamp, values in batch:
        emitted += grid.add(source, stamp, values)
    emitted += grid.flush()
    assert grid.pending_slots == 0
    counters = grid.counters
    assert counters.messages == len(batch) == sum(grid.source_counters(s).messages for s in range(2))
    assert counters.samples_emitted == len(emitted)
    assert counters.rejected_messages <= len(batch)
    previous = None
    for sample in emitted:
        assert sample.u.shape == (1,) and sample.y.shape == (2,)
        assert np.isfinite(sample.u).all() and np.isfinite(sample.y).all() and math.isfinite(sample.stamp_s)
        assert sample.skipped >= 0
        if previous is not None and not sample.restart:
            assert sample.slot > previous.slot and sample.skipped == sample.slot - previous.slot - 1
        previous = sample


@given(present=st.lists(st.booleans(), min_size=1, max_size=120),
       lost=st.lists(st.integers(0, 119), max_size=10), jitter=st.floats(-0.2, 0.2))
def test_clean_sources_with_gaps_give_exactly_the_complete_slots(present, lost, jitter) -> None:
    """Slot k is sent by both sources when present[k]; ``lost`` drops one source's message."""
    grid = SampleGrid(DT, 1, 2, SOURCES, latency_samples=2)
    lost = set(lost)
    emitted = []
    for k, sent in enumerate(present):
        if not sent:
            continue
        stamp = 10.0 + (k + jitter) * DT
        emitted += grid.add(0, stamp, [float(k)])
        if k not in lost:
            emitted += grid.add(1, stamp, [2.0 * k, -float(k)])
    emitted += grid.flush()
    complete = [k for k, sent in enumerate(present) if sent and k not in lost]
    first = next((k for k, sent in enumerate(present) if sent), 0)
    assert [int(s.u[0]) for s in emitted] == complete
    assert [s.slot for s in emitted] == [k - first for k in complete]
    for a, b in zip(emitted, emitted[1:]):
        assert b.skipped == b.slot - a.slot - 1 and b.gap_before == (b.slot - a.slot > 1)
    for sample in emitted:
        k = int(sample.u[0])
        np.testing.assert_array_equal(sample.y, [2.0 * k, -float(k)])


@given(steps=st.lists(st.one_of(st.floats(-3, 5), st.floats(allow_nan=True, allow_infinity=True)), max_size=50))
def test_stamp_sequence_classifies_any_step(steps) -> None:
    sequence = StampSequence(DT)
    stamp = 0.0
    for step in steps:
        candidate = stamp + step * DT
        result = sequence.check(candidate)
        assert isinstance(result, StampStep)
        if result in (StampStep.NEXT, StampStep.GAP) and math.isfinite(candidate):
            sequence.accept(candidate)
            stamp = candidate
    assert math.isnan(sequence.newest_stamp_s) or math.isfinite(sequence.newest_stamp_s)


@given(n=st.integers(2, 60), at=st.integers(0, 1000), source=st.integers(0, 1),
       stamp=st.sampled_from([0.0, -1e9, 50.0, 1e6, 1e9, 1e300]), jitter=st.floats(-0.2, 0.2))
def test_a_lone_stamp_off_the_timeline_changes_nothing_but_its_count(n, at, source, stamp, jitter) -> None:
    """One message with a stray stamp, anywhere after the first, in a clean stream of two sources."""
    clean = [(s, 10.0 + (k + jitter) * DT, [float(k)] if s == 0 else [2.0 * k, -float(k)])
             for k in range(n) for s in (0, 1)]
    at = 1 + at % len(clean)  # before the first message there is no timeline to be off
    stray = (source, stamp, [7.0] * len(SOURCES[source]))

    def run(batch):
        grid = SampleGrid(DT, 1, 2, SOURCES, latency_samples=3)
        out = [sample for message in batch for sample in grid.add(*message)] + grid.flush()
        return grid.counters.as_dict(), [(s.slot, s.stamp_s, s.skipped, s.restart, s.time_jump, list(s.u), list(s.y))
                                         for s in out]

    expected_counts, expected = run(clean)
    counts, samples = run(clean[:at] + [stray] + clean[at:])
    assert samples == expected
    # Beyond any ROS 2 time a stamp is refused as unusable (nonfinite) before the timeline is asked.
    reason = "off_timeline" if abs(stamp) <= MAX_STAMP_S else "nonfinite"
    expected_counts.update({"messages": expected_counts["messages"] + 1, reason: 1,
                            "rejected_messages": expected_counts["rejected_messages"] + 1})
    assert counts == expected_counts
