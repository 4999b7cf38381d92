"""Sample assembly on the grid (okid_ros/service/sample_grid.py) and input source parsing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from okid_ros.service.inputs import parse_source, parse_sources
from okid_ros.service.sample_grid import SampleGrid, StampSequence, StampStep, classify_step

DT = 0.01
T0 = 100.0


def three_sources(**kwargs) -> SampleGrid:
    """M = 1, p = 2: source 0 gives u0, source 1 gives y0, source 2 gives y1."""
    return SampleGrid(DT, 1, 2, [[0], [1], [2]], **kwargs)


def feed(grid: SampleGrid, k: int, sources=(0, 1, 2), jitter: float = 0.0) -> list:
    out = []
    for s in sources:
        out += grid.add(s, T0 + k * DT + jitter * (s - 1), [100 * s + k])
    return out


def test_assembles_complete_samples_in_slot_order_with_jitter():
    grid = three_sources()
    out = []
    for k in range(5):
        out += feed(grid, k, jitter=0.1 * DT)  # sources 0.2 dt apart, within the 0.25 tolerance
    assert [s.slot for s in out] == list(range(5))
    assert out[0].restart and not any(s.restart for s in out[1:])
    assert all(s.skipped == 0 for s in out)
    np.testing.assert_array_equal(out[3].u, [3.0])
    np.testing.assert_array_equal(out[3].y, [103.0, 203.0])
    assert out[3].stamp_s == pytest.approx(T0 + 3 * DT - 0.1 * DT)  # the first message of the slot
    assert grid.counters.samples_emitted == 5 and grid.counters.rejected_messages == 0


def test_a_source_fills_its_channels_in_its_own_order_whether_or_not_they_are_a_run():
    """Values go to the channels the source names, in its order (a run, a reversed or scattered list)."""
    grid = SampleGrid(DT, 2, 4, [[5, 2], [3, 4], [1], [0]])  # u0 u1 | y0 y1 y2 y3
    out = []
    for k in range(3):
        out += grid.add(0, T0 + k * DT, [50.0 + k, 20.0 + k])
        out += grid.add(1, T0 + k * DT, [30.0 + k, 40.0 + k])
        out += grid.add(3, T0 + k * DT, [0.0 + k])
        assert out == [] or out[-1].slot == k - 1  # the slot waits for its last channel
        out += grid.add(2, T0 + k * DT, [10.0 + k])
    assert [s.slot for s in out] == [0, 1, 2]
    np.testing.assert_array_equal(out[2].u, [2.0, 12.0])
    np.testing.assert_array_equal(out[2].y, [22.0, 32.0, 42.0, 52.0])


def test_missing_channel_drops_the_slot_after_the_latency_budget_and_late_data_is_refused():
    grid = three_sources(latency_samples=2)
    out = feed(grid, 0)
    for k in range(1, 4):
        out += feed(grid, k, sources=(0, 1))  # source 2 (y1) is delayed
    assert [s.slot for s in out] == [0]
    out += feed(grid, 4, sources=(0, 1))  # 4 - 1 > 2 slots ahead: slot 1 is dropped
    assert grid.counters.missing == 1
    assert grid.add(2, T0 + 1 * DT, [1.0]) == []  # y1 of slot 1 arrives after the drop
    assert grid.counters.late == 1
    for k in range(2, 5):
        out += grid.add(2, T0 + k * DT, [200.0 + k])
    assert [s.slot for s in out] == [0, 2, 3, 4]
    assert out[1].skipped == 1 and out[1].gap_before and not out[2].gap_before


def test_slots_that_never_arrived_count_as_missing():
    grid = SampleGrid(DT, 1, 1, [[0, 1]])
    grid.add(0, T0, [0.0, 0.0])
    sample = grid.add(0, T0 + 4 * DT, [1.0, 1.0])[0]
    assert sample.skipped == 3 and grid.counters.missing == 3


def test_duplicates_and_out_of_order_stamps_are_rejected_keeping_the_first_value():
    grid = three_sources()
    feed(grid, 0)
    grid.add(0, T0 + DT, [1.0])
    assert grid.add(0, T0 + DT + 0.1 * DT, [99.0]) == []  # same slot again
    assert grid.add(0, T0, [98.0]) == []  # earlier slot
    out = grid.add(1, T0 + DT, [2.0]) + grid.add(2, T0 + DT, [3.0])
    assert out[0].u[0] == 1.0
    c = grid.counters
    assert (c.duplicate, c.out_of_order) == (1, 1)
    assert grid.source_counters(0).duplicate == 1 and grid.source_counters(1).duplicate == 0


def test_whole_sample_stream_uses_the_grid_rule():
    """StampSequence (the identification service's check) classifies steps as the grid does."""
    assert [classify_step(k) for k in (-2, -1, 0, 1, 2)] == [
        StampStep.OUT_OF_ORDER, StampStep.OUT_OF_ORDER, StampStep.DUPLICATE, StampStep.NEXT, StampStep.GAP,
    ]
    seq = StampSequence(DT)
    assert math.isnan(seq.newest_stamp_s) and seq.check(T0) is StampStep.NEXT
    seq.accept(T0)
    steps = {0.2: StampStep.DUPLICATE, -0.4: StampStep.DUPLICATE, -0.7: StampStep.OUT_OF_ORDER,
             0.7: StampStep.NEXT, 1.4: StampStep.NEXT, 1.6: StampStep.GAP, 6.0: StampStep.GAP}
    for step, expected in steps.items():
        assert seq.check(T0 + step * DT) is expected, step
    assert seq.newest_stamp_s == T0  # check does not advance
    seq.accept(T0 + DT)
    assert seq.check(T0 + 1.2 * DT) is StampStep.DUPLICATE
    seq.reset()
    assert seq.check(T0 - 100.0) is StampStep.NEXT
    with pytest.raises(ValueError, match="sample_time_s"):
        StampSequence(0.0)


def test_bad_values_and_off_grid_stamps_are_rejected():
    grid = three_sources()
    feed(grid, 0)
    assert grid.add(0, T0 + DT, [math.nan]) == []
    assert grid.add(1, T0 + DT, [1.0, 2.0]) == []
    assert grid.add(2, math.inf, [1.0]) == []
    assert grid.add(2, T0 + 1.4 * DT, [1.0]) == []  # 0.4 dt off the grid
    c = grid.counters
    assert (c.nonfinite, c.wrong_size, c.off_grid) == (2, 1, 1)
    assert len(feed(grid, 1)) == 1  # the sources go on normally


def test_persistent_off_grid_stamps_reanchor_the_grid():
    grid = SampleGrid(DT, 1, 1, [[0, 1]], latency_samples=2)
    grid.add(0, T0, [0.0, 0.0])
    out = []
    for k in range(1, 8):
        out += grid.add(0, T0 + (k + 0.5) * DT, [k, k])  # clock phase moved by half a sample
    assert grid.counters.reanchors == 1
    assert grid.counters.off_grid == 2  # the third off-grid stamp re-anchors
    assert out and out[0].restart and len(out) == 5


def test_time_jump_back_restarts_the_grid_and_drops_pre_jump_messages_of_other_sources():
    grid = three_sources()
    for k in range(10):
        feed(grid, k)
    back = T0 - 5.0  # a bag replayed from its start
    assert grid.add(0, back, [7.0]) == []  # held: one stamp alone is no new timeline yet
    assert grid.counters.time_jumps == 0
    assert grid.add(1, T0 + 10 * DT, [0.0]) == []  # source 1 has not looped yet: taken on the old grid
    assert grid.add(1, back, [8.0]) == []  # source 1 looped too: the jump is confirmed
    assert grid.counters.time_jumps == 1 and grid.counters.missing == 1  # slot 10, incomplete
    assert grid.add(2, T0 + 10 * DT, [0.0]) == []  # source 2 still at the old time: late
    assert grid.counters.late == 1
    out = grid.add(2, back, [9.0])
    assert len(out) == 1 and out[0].restart and out[0].time_jump and out[0].slot == 0
    np.testing.assert_array_equal(out[0].u, [7.0])  # the first message after the loop is kept
    np.testing.assert_array_equal(out[0].y, [8.0, 9.0])
    assert grid.counters.off_timeline == 0


def test_flush_emits_complete_and_drops_incomplete_slots():
    grid = three_sources(latency_samples=100)
    feed(grid, 0, sources=(0, 1))
    feed(grid, 1)
    out = grid.flush()
    assert [s.slot for s in out] == [1] and grid.counters.missing == 1


def test_channel_coverage_is_checked():
    with pytest.raises(ValueError, match="sources 0 and 1"):
        SampleGrid(DT, 1, 1, [[0, 1], [1]])
    with pytest.raises(ValueError, match="y0"):
        SampleGrid(DT, 1, 1, [[0]])


def test_source_specifications():
    spec = parse_source("imu /tip/accel1 linear_acceleration.z=y1", 2, 2)
    assert spec.msg_type == "sensor_msgs/msg/Imu"
    assert spec.fields == (("linear_acceleration", "z"),) and spec.channels == (3,)
    spec = parse_source("wrench /thruster force.x=u0 torque.y=u1", 2, 2)
    assert spec.fields == (("wrench", "force", "x"), ("wrench", "torque", "y")) and spec.channels == (0, 1)
    spec = parse_source("array /daq data[0]=stamp data[3]=y0", 1, 1)
    assert spec.stamp_index == 0 and spec.fields == (("data", 3),) and spec.channels == (1,)
    spec = parse_source("io_sample /okid/io_sample", 2, 2)
    assert spec.whole_sample and spec.channels == (0, 1, 2, 3)
    assert parse_source("accel /a accel.linear.y=y0", 1, 1).fields == (("accel", "linear", "y"),)
    for bad, message in [
        ("imu", "expected"),
        ("lidar /x a=y0", "unknown kind"),
        ("imu /x linear_acceleration.w=y0", "no field"),
        ("imu /x linear_acceleration.x=y2", "out of range"),
        ("imu /x linear_acceleration.x=z0", "u<i>"),
        ("wrench /x force.x=stamp", "only array"),
        ("imu /x", "maps no channel"),
    ]:
        with pytest.raises(ValueError, match=message):
            parse_source(bad, 2, 2)
    with pytest.raises(ValueError, match="mapped by two sources"):
        parse_sources(["io_sample /a", "imu /b linear_acceleration.x=y0"], 2, 2)
    with pytest.raises(ValueError, match="u1"):
        parse_sources(["wrench /a force.x=u0", "imu /b linear_acceleration.x=y0"], 2, 1)
    with pytest.raises(ValueError, match=r"field linear_acceleration.x of /b is mapped twice \(to y0 and y1\)"):
        parse_sources(["wrench /a force.x=u0", "imu /b linear_acceleration.x=y0 linear_acceleration.x=y1"], 1, 2)
    # two sources on one topic reading different fields are fine
    parse_sources(["wrench /a force.x=u0", "imu /b linear_acceleration.x=y0", "imu /b angular_velocity.z=y1"], 1, 2)


# ---------------------------------------------------------------------------------------------
# The timeline: one IoSample or Imu message stamped 0, or 1e6 s ahead, in a steady stream used to
# restart the grid as a looped bag does (both nodes then forgot their window and model), or to
# strand the grid's newest stamp so that every later message looked like a jump back. Such a
# stamp is now held: refused and counted ``off_timeline`` when the stream goes on where it was,
# taken as a time jump or a forward gap when the next message confirms it.

OUTLIERS = {"at_0": 0.0, "1e6_s_ahead": T0 + 1e6}


def grid_of(n_sources: int) -> SampleGrid:
    """One source (an IoSample topic) or two (u0 from one, y0 and y1 from the other); m = 1, p = 2."""
    return SampleGrid(DT, 1, 2, [[0, 1, 2]] if n_sources == 1 else [[0], [1, 2]])


def values(grid: SampleGrid, source: int, k: int) -> list[float]:
    """Slot k's values of one source: u0 = k, y0 = 10 + k, y1 = 20 + k."""
    whole = [float(k), 10.0 + k, 20.0 + k]
    return whole if grid.n_sources == 1 else whole[:1] if source == 0 else whole[1:]


def feed_slots(grid: SampleGrid, slots, *, t0: float = T0) -> list:
    out = []
    for k in slots:
        for s in range(grid.n_sources):
            out += grid.add(s, t0 + k * DT, values(grid, s, k))
    return out


def assert_steady(out: list, slots) -> None:
    """The samples of a clean stream: every slot once, values as sent, no gap after the first."""
    slots = list(slots)
    assert [s.slot for s in out] == [k - slots[0] for k in slots]
    assert not any(s.restart or s.time_jump or s.skipped for s in out[1:])
    np.testing.assert_array_equal([s.u[0] for s in out], slots)
    np.testing.assert_array_equal([s.y for s in out], [[10.0 + k, 20.0 + k] for k in slots])


@pytest.mark.parametrize("stamp", OUTLIERS.values(), ids=OUTLIERS.keys())
@pytest.mark.parametrize(("n_sources", "source", "after"), [(1, 0, 0), (2, 0, 0), (2, 0, 1), (2, 1, 0), (2, 1, 1)],
                         ids=["one_source", "two_src0_mid_slot", "two_src0", "two_src1_mid_slot", "two_src1"])
def test_a_lone_stamp_off_the_timeline_is_refused_and_the_stream_goes_on(stamp, n_sources, source, after):
    """The stray message comes right after source ``after``'s message of slot 10."""
    grid = grid_of(n_sources)
    out = feed_slots(grid, range(10))
    for s in range(n_sources):
        out += grid.add(s, T0 + 10 * DT, values(grid, s, 10))
        if s == after:
            assert grid.add(source, stamp, np.full(len(values(grid, source, 0)), 99.0)) == []
    out += feed_slots(grid, range(11, 20))
    assert_steady(out, range(20))
    c = grid.counters
    assert (c.off_timeline, c.time_jumps, c.reanchors, c.missing, c.late) == (1, 0, 0, 0, 0)
    assert c.rejections() == {"off_timeline": 1} and c.rejected_messages == 1
    assert grid.source_counters(source).off_timeline == 1
    assert sum(grid.source_counters(s).off_timeline for s in range(n_sources)) == 1


@pytest.mark.parametrize("n_sources", [1, 2])
def test_a_looped_bag_restarts_on_its_first_sample_one_message_later(n_sources):
    grid = grid_of(n_sources)
    feed_slots(grid, range(10))
    back = T0 - 5.0
    assert grid.add(0, back, values(grid, 0, 0)) == []  # held until the next message
    assert grid.counters.time_jumps == 0
    out = grid.add(n_sources - 1, back + (n_sources == 1) * DT, values(grid, n_sources - 1, n_sources == 1))
    assert grid.counters.time_jumps == 1
    out += feed_slots(grid, range(1 + (n_sources == 1), 8), t0=back)
    assert out[0].restart and out[0].time_jump and out[0].stamp_s == back
    assert_steady(out, range(8))  # the first message after the loop is kept
    c = grid.counters
    assert (c.off_timeline, c.missing, c.late) == (0, 0, 0)


def test_sources_that_loop_one_after_another_restart_once():
    """Source 1 sends once more on the old timeline after source 0 looped (two topics in flight)."""
    grid = grid_of(2)
    feed_slots(grid, range(10))
    back = T0 - 5.0
    assert grid.add(0, back, [0.0]) == []
    assert grid.add(1, T0 + 10 * DT, [20.0, 30.0]) == []  # the old timeline, another source: taken
    assert grid.add(0, back + DT, [1.0]) == []  # source 0 steps on: the jump is confirmed
    assert grid.counters.time_jumps == 1 and grid.counters.missing == 1  # slot 10 lacks source 0
    assert grid.add(1, T0 + 11 * DT, [21.0, 31.0]) == []  # source 1's last old message: late
    out = grid.add(1, back, [10.0, 20.0]) + grid.add(1, back + DT, [11.0, 21.0])  # source 1 looped
    out += feed_slots(grid, range(2, 8), t0=back)
    assert out[0].restart and out[0].time_jump
    assert_steady(out, range(8))  # both of source 0's first messages after the loop are kept
    c = grid.counters
    assert (c.time_jumps, c.late, c.off_timeline) == (1, 1, 0)


@pytest.mark.parametrize("n_sources", [1, 2])
def test_a_forward_gap_is_still_a_gap(n_sources):
    grid = grid_of(n_sources)
    out = feed_slots(grid, range(10))
    gap = 6000  # 60 s: a clock set forward
    out += feed_slots(grid, range(10 + gap, 20 + gap))
    assert [s.slot for s in out] == [*range(10), *range(10 + gap, 20 + gap)]
    assert out[10].skipped == gap and not out[10].restart and not out[10].time_jump
    assert not any(s.skipped or s.restart for s in out[11:])
    np.testing.assert_array_equal(out[10].u, [10.0 + gap])  # the first message after the step is kept
    c = grid.counters
    assert (c.missing, c.time_jumps, c.off_timeline, c.late) == (gap, 0, 0, 0)


def test_after_a_forward_step_old_messages_of_the_other_source_are_late():
    grid = grid_of(2)
    feed_slots(grid, range(10))
    ahead = T0 + 60.0
    assert grid.add(0, ahead, [0.0]) == []
    assert grid.add(1, T0 + 10 * DT, [0.0, 0.0]) == []  # source 1 not stepped yet: the old timeline
    assert grid.add(0, ahead + DT, [1.0]) == []  # confirmed
    assert grid.add(1, T0 + 11 * DT, [0.0, 0.0]) == []  # late, not a jump back
    out = grid.add(1, ahead, [10.0, 20.0]) + grid.add(1, ahead + DT, [11.0, 21.0])
    assert [s.u[0] for s in out] == [0.0, 1.0] and not any(s.restart for s in out)
    c = grid.counters
    assert (c.time_jumps, c.late, c.off_timeline) == (0, 1, 0)


def test_a_candidate_followed_by_another_outlier_is_refused_and_so_is_that_one():
    grid = grid_of(1)
    out = feed_slots(grid, range(10))
    assert grid.add(0, 0.0, [1.0, 2.0, 3.0]) == []
    assert grid.add(0, T0 + 1e6, [1.0, 2.0, 3.0]) == []  # off both timelines: the new candidate
    assert grid.counters.off_timeline == 1
    out += feed_slots(grid, range(10, 20))
    assert_steady(out, range(20))
    assert (grid.counters.off_timeline, grid.counters.time_jumps) == (2, 0)


def test_a_repeated_stray_stamp_is_no_timeline():
    """The same corrupt stamp twice from one source: a duplicate, not the confirmation of a jump."""
    grid = grid_of(1)
    out = feed_slots(grid, range(10))
    for _ in range(2):
        assert grid.add(0, 0.0, [1.0, 2.0, 3.0]) == []
    out += feed_slots(grid, range(10, 20))
    assert_steady(out, range(20))
    c = grid.counters
    assert (c.off_timeline, c.duplicate, c.time_jumps) == (1, 1, 0)


def test_a_candidate_whose_source_falls_silent_is_refused_once_the_old_timeline_moves_on():
    grid = grid_of(2)
    feed_slots(grid, range(10))
    grid.add(1, 0.0, [1.0, 2.0])
    for k in range(10, 10 + round(1.0 / DT)):
        grid.add(0, T0 + k * DT, [float(k)])  # source 1 silent for 1 s: still held
    assert grid.counters.off_timeline == 0
    grid.add(0, T0 + (11 + round(1.0 / DT)) * DT, [0.0])  # more than time_jump_s on
    assert (grid.counters.off_timeline, grid.counters.time_jumps) == (1, 0)


def test_a_candidate_still_held_at_the_end_is_refused_by_flush_and_forgotten_by_reset():
    grid = grid_of(1)
    out = feed_slots(grid, range(10))
    grid.add(0, 0.0, [1.0, 2.0, 3.0])
    assert grid.flush() == [] and grid.counters.off_timeline == 1
    assert_steady(out, range(10))
    grid = grid_of(1)
    feed_slots(grid, range(10))
    grid.add(0, 0.0, [1.0, 2.0, 3.0])
    grid.reset()
    out = feed_slots(grid, range(10, 15))  # starts afresh where the stream is, the stray stamp forgotten
    assert out[0].restart and not out[0].time_jump and grid.counters.off_timeline == 0
    assert_steady(out, range(10, 15))


def test_a_source_that_stepped_on_alone_and_comes_back_loses_no_sample_of_the_others():
    """Source 0's clock 60 s ahead for two messages (a step it confirmed itself), then back.

    Source 1 never moved: its message of the slot source 0 returns to agrees with source 0's
    held candidate and confirms it (it was dropped as ``late``, before the step, and with it the
    sample of that slot).
    """
    grid = grid_of(2)
    out = feed_slots(grid, range(10))
    ahead = T0 + 60.0
    assert grid.add(0, ahead, [0.0]) == [] and grid.add(0, ahead + DT, [1.0]) == []  # confirmed
    assert grid.add(0, T0 + 10 * DT, [10.0]) == []  # back: held as a candidate
    out += grid.add(1, T0 + 10 * DT, [20.0, 30.0])  # confirms it, not late
    out += feed_slots(grid, range(11, 20))
    assert [s.u[0] for s in out] == list(range(20))
    back = out[10]
    assert back.restart and back.time_jump and back.stamp_s == T0 + 10 * DT
    np.testing.assert_array_equal(back.y, [20.0, 30.0])
    assert_steady(out[10:], range(10, 20))
    c = grid.counters
    assert (c.late, c.off_timeline, c.time_jumps) == (0, 0, 1)


@pytest.mark.parametrize("stamp", [-1e306, 1e300, -(2.0**31), 2.0**31])
@pytest.mark.parametrize("n_sources", [1, 2])
def test_a_stamp_beyond_any_ros_time_is_refused_even_first(stamp, n_sources):
    """An array source's stamp field can hold anything: such a stamp is refused.

    Taken first, it anchored the grid where every later slot looked the same (all duplicates,
    for ever) or every later stamp a step of decades.
    """
    grid = grid_of(n_sources)
    assert grid.add(0, stamp, values(grid, 0, 0)) == []
    out = feed_slots(grid, range(20))
    assert_steady(out, range(20))
    assert grid.counters.rejections() == {"nonfinite": 1}
