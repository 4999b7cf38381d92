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
    out = grid.add(0, back, [7.0])
    assert grid.counters.time_jumps == 1 and out == []
    assert grid.add(1, T0 + 10 * DT, [0.0]) == []  # source 1 still at the old time: late
    assert grid.counters.late == 1
    out = grid.add(1, back, [8.0]) + grid.add(2, back, [9.0])
    assert len(out) == 1 and out[0].restart and out[0].slot == 0
    np.testing.assert_array_equal(out[0].y, [8.0, 9.0])


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
