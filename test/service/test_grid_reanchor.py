"""Samples lost around a re-anchoring of the sample grid are counted (found by test_nodes_faults.py).

A node stopped during a 10x flood lost 2 s of messages and then saw more off-grid stamps in a
row than the grid allows: it re-anchored, and the 2 s of lost samples were not counted as
missing (the count restarted with the grid).
"""

from __future__ import annotations

from okid_ros.service.sample_grid import SampleGrid


def _grid() -> SampleGrid:
    return SampleGrid(1.0, 1, 1, [[0, 1]], tolerance=0.25, latency_samples=5)


def test_slots_skipped_before_a_reanchoring_count_as_missing():
    grid = _grid()
    emitted = [s for t in (0.0, 1.0, 2.0, 3.0) for s in grid.add(0, t, [1.0, 2.0])]
    assert len(emitted) == 4
    # Nothing for slots 4..9, then only stamps 0.4 off the grid: the sixth in a row re-anchors.
    for t in (10.4, 11.4, 12.4, 13.4, 14.4):
        assert grid.add(0, t, [1.0, 2.0]) == []
    after = grid.add(0, 15.4, [1.0, 2.0])
    assert grid.counters.reanchors == 1
    assert [s.stamp_s for s in after] == [15.4] and after[0].restart
    # Slots 4..15 of the old grid never gave a sample: 12 missing (10.4..14.4 also off_grid).
    assert grid.counters.missing == 12
    assert grid.counters.off_grid == 5


def test_a_reanchoring_right_after_the_last_sample_counts_only_the_off_grid_slots():
    grid = _grid()
    for t in (0.0, 1.0, 2.0):
        grid.add(0, t, [1.0, 2.0])
    for t in (2.4, 3.4, 4.4, 5.4, 6.4, 7.4):
        grid.add(0, t, [1.0, 2.0])
    assert grid.counters.reanchors == 1
    # Slots 3..7 were not emitted: their messages came off the grid (counted off_grid) and the
    # samples are missing; slot 2's own message came on time.
    assert grid.counters.missing == 5
