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

from okid_ros.service.sample_grid import MAX_STAMP_S, REJECTION_REASONS, SampleGrid, StampSequence, StampStep

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


LATENCY = 3  # the grids' latency_samples in the test below
# Stray offsets either way, from just over time_jump_s to beyond any ROS 2 time, on the grid's phase or off it.
stray_offset = st.builds(lambda sign, size, phase: sign * size + phase * DT, st.sampled_from([1.0, -1.0]),
                         st.one_of(st.sampled_from([1.2, 60.0, 1e9, 3e9, 1e300]), st.floats(1.1, 1e6)),
                         st.sampled_from([0.0, 0.37]))


# Seven parameters, and the corner that matters most (r >= 2 off the grid's phase) is rare: more examples.
@settings(max_examples=4 * settings().max_examples)
@given(r=st.integers(1, 5), burst=st.booleans(), k0=st.integers(1, 15), half=st.integers(0, 1),
       source=st.integers(0, 1), jitter=st.floats(-0.2, 0.2), offset=stray_offset)
def test_a_source_off_the_timeline_for_r_messages_then_back(r, burst, k0, half, source, jitter, offset) -> None:
    """One source's stamps ``offset`` off the timeline for ``r`` messages in a row, then back on it.

    The stray messages are ``r`` extra ones in a burst (before message ``half`` of slot ``k0``), or
    the source's own messages of slots k0 .. k0+r-1 while the other source goes on. One (r = 1) is
    refused: the samples are those of the stream without it, only a count changes. Two or more
    confirm each other, a step the grid cannot tell from a real one, and coming back is a second
    step: one time jump, the first sample after both marked as a time jump, and samples lost only from
    k0 until the grid has taken the timeline back. For any r: no exception, no stray or mixed
    value in a sample, samples in order, every message counted.
    """
    n = 30  # slots: at least LATENCY + 6 of them after the source is back
    stream = []  # (source, stamp_s, values, stray)
    for k in range(n):
        for s in (0, 1):
            stamp = 10.0 + (k + jitter) * DT
            values = [float(k)] if s == 0 else [2.0 * k, -float(k)]
            if burst and (k, s) == (k0, half):
                stream += [(source, 10.0 + (k0 + i + jitter) * DT + offset, [1000.0 + i] * len(SOURCES[source]), True)
                           for i in range(r)]
            if not burst and s == source and k0 <= k < k0 + r:
                stream.append((s, stamp + offset, [1000.0 + k] * len(values), True))
            else:
                stream.append((s, stamp, values, False))
    back = k0 if burst else k0 + r  # the first slot of the source's messages on the timeline again
    last_stray = max(i for i, message in enumerate(stream) if message[3])

    def run(batch):
        grid = SampleGrid(DT, 1, 2, SOURCES, latency_samples=LATENCY)
        out = [(i, sample) for i, (s, stamp, values, _) in enumerate(batch) for sample in grid.add(s, stamp, values)]
        unflushed = grid.counters.as_dict()
        return grid, out + [(len(batch), sample) for sample in grid.flush()], unflushed

    def fields(s):
        return s.slot, s.stamp_s, s.skipped, s.restart, s.time_jump, list(s.u), list(s.y)

    clean_grid, clean_out, clean_unflushed = run([message for message in stream if not message[3]])
    grid, out, unflushed = run(stream)  # never raises
    samples = [sample for _, sample in out]
    c, per_source = grid.counters, [grid.source_counters(s) for s in range(2)]
    assert grid.pending_slots == 0 and c.samples_emitted == len(samples)
    assert c.messages == len(stream) == sum(sc.messages for sc in per_source)
    for reason in REJECTION_REASONS:
        assert getattr(c, reason) == sum(getattr(sc, reason) for sc in per_source)
    # A message not refused fills a slot, which is emitted (one message of each source) or counted
    # missing; missing counts the slots a step skips too, hence a bound, not an equality.
    placed = [sc.messages - sc.rejected_messages for sc in per_source]
    assert min(placed) >= c.samples_emitted and sum(placed) <= 2 * c.samples_emitted + c.missing
    for sample in samples:
        k = sample.u[0]  # slot k of the clean stream, whole: no stray value, none mixed with a clean one
        assert np.isfinite(sample.u).all() and np.isfinite(sample.y).all() and math.isfinite(sample.stamp_s)
        assert k in range(n) and list(sample.y) == [2.0 * k, -k] and sample.skipped >= 0
    assert [s.u[0] for s in samples] == sorted({s.u[0] for s in samples})
    for a, b in zip(samples, samples[1:]):
        assert b.restart or (b.slot > a.slot and b.skipped == b.slot - a.slot - 1)

    beyond = abs(offset) > MAX_STAMP_S  # refused as nonfinite before the timeline is asked, any r
    if r == 1 or beyond:
        assert [fields(s) for _, s in out] == [fields(s) for _, s in clean_out]
        expected = clean_grid.counters.as_dict()
        reason = "nonfinite" if beyond else "off_timeline"
        expected.update({"messages": expected["messages"] + r, reason: expected[reason] + r,
                         "rejected_messages": expected["rejected_messages"] + r})
        assert c.as_dict() == expected
        # Refused on arrival or when its source goes on on the old timeline, not only by the final flush.
        assert unflushed[reason] - clean_unflushed[reason] == r
        return
    # Of the step there and the step back, one is backward: a time jump. Each was confirmed by the
    # next message, so nothing was refused as a lone stamp.
    assert c.time_jumps == 1 and c.off_timeline == 0
    first_back = next(sample for i, sample in out if i > last_stray)
    # The jump is marked on the first sample after it, whether or not the grid had to re-anchor
    # on the way (a return off its phase): the nodes restart on that mark.
    assert first_back.gap_before and first_back.time_jump and first_back.restart
    # Back on a timeline off the grid's phase (after a step back), the grid refuses up to LATENCY
    # slots of both sources as off_grid before it re-anchors, plus the slot it came back in.
    lost = {sample.u[0] for _, sample in clean_out} - {sample.u[0] for sample in samples}
    assert all(k0 <= k < back + LATENCY + 1 for k in lost), sorted(lost)
