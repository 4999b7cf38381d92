"""The sample grid's time-jump threshold: never below ``inputs.latency_samples + 2`` sample times.

Hostile sweep of session 31 (``inputs.time_jump_s=0.001`` on a 0.008 s grid: every message off the
timeline, `export` wrote a record of one sample), and what it showed about slow grids: with the
default 1 s, every message of one source on a grid slower than 1 Hz was off the timeline, at 1 Hz
one in five with a stamp jitter of 5 % of a sample time, and a source lagging another by more than
1 s restarted the grid and lost every sample.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from okid_ros.errors import OkidWarning
from okid_ros.service.inputs import sources_and_grid, time_jump_note
from okid_ros.service.params import ARX_NODE, resolve_parameters
from okid_ros.service.sample_grid import SampleGrid, least_time_jump_s
from okid_ros.tools.node_parameters import load_node_parameters

T0 = 1000.0


def stream(dt: float, *, n: int = 200, sources: int = 1, lag: int = 0, jitter: float = 0.0,
           loop_at: int | None = None, **kwargs) -> tuple[list, SampleGrid]:
    """``n`` samples of dt on a grid of m = 2, p = 2 from one source (all channels) or two (u, y).

    ``lag``: the second source's messages arrive that many slots after the first's; ``jitter``:
    the stamps' standard deviation in sample times; ``loop_at``: the stamps start again from T0 at
    that sample (a looped bag).
    """
    rng = np.random.default_rng(1)
    channels = [[0, 1, 2, 3]] if sources == 1 else [[0, 1], [2, 3]]
    grid = SampleGrid(dt, 2, 2, channels, **kwargs)
    messages = []
    for k in range(n):
        t = T0 + (k if loop_at is None or k < loop_at else k - loop_at) * dt
        for s, chans in enumerate(channels):
            messages.append((k + lag * s, s, t + rng.normal(0.0, jitter * dt), [float(k)] * len(chans)))
    messages.sort(key=lambda m: (m[0], m[1]))
    out = [sample for _, s, t, v in messages for sample in grid.add(s, t, v)]
    return out + grid.flush(), grid


@pytest.mark.parametrize("dt", [1.0, 2.0, 5.0])
def test_the_default_takes_every_sample_of_one_source_on_a_slow_grid(dt):
    # Was: every message after the first off the timeline from dt 1.5 s on (1 sample of 200), and
    # at 1 s a fifth of them with a jitter of 5 %.
    out, grid = stream(dt, jitter=0.05)
    assert len(out) == 200 and grid.counters.rejected_messages == 0 and grid.counters.time_jumps == 0
    assert grid.jump_threshold_s == 7 * dt


def test_a_source_lagging_within_the_latency_is_no_time_jump():
    # 2 Hz, the second source 3 slots (1.5 s) behind the first: was a time jump, then every message late.
    out, grid = stream(0.5, sources=2, lag=3)
    assert len(out) == 200 and grid.counters.time_jumps == 0 and grid.counters.rejected_messages == 0


def test_a_time_jump_threshold_below_the_sample_time_is_raised_and_a_loop_still_restarts():
    out, grid = stream(0.008, time_jump_s=0.001)
    assert len(out) == 200 and grid.counters.rejected_messages == 0  # was: 1 sample, 199 off_timeline
    assert grid.time_jump_s == 0.001 and grid.jump_threshold_s == pytest.approx(0.056)
    out, grid = stream(0.008, n=400, time_jump_s=0.001, loop_at=200)
    assert len(out) == 400 and grid.counters.time_jumps == 1 and out[200].time_jump


def test_a_loop_on_a_slow_grid_is_a_time_jump():
    out, grid = stream(2.0, n=120, loop_at=60)  # a bag of 120 s looped; the threshold is 14 s
    assert len(out) == 120 and grid.counters.time_jumps == 1 and out[60].time_jump and out[60].restart


def test_the_threshold_follows_the_latency_and_time_jump_set_at_run_time():
    grid = SampleGrid(0.5, 1, 1, [[0, 1]])
    assert grid.jump_threshold_s == 3.5  # 5 + 2 sample times, above the default 1 s
    grid.latency_samples, grid.time_jump_s = 0, 10.0  # as the live node applies a change
    assert grid.jump_threshold_s == 10.0
    grid.time_jump_s = 0.001
    assert grid.jump_threshold_s == least_time_jump_s(0.5, 0) == 1.0


def test_a_time_jump_set_too_low_is_told_once_the_default_raised_is_not(recwarn):
    low = resolve_parameters(ARX_NODE, {"inputs.time_jump_s": 0.001})
    assert time_jump_note(low) == (
        "parameter inputs.time_jump_s 0.001 s raised to 0.056 s: a time jump must be longer than "
        "inputs.latency_samples 5 + 2 sample times of 0.008 s (a source lagging within the latency, or the "
        "next sample, is no jump)")
    assert sources_and_grid(low)[1].jump_threshold_s == pytest.approx(0.056)
    assert time_jump_note(resolve_parameters(ARX_NODE, {"sample_time_s": 5.0})) == ""  # the default on 0.2 Hz
    assert time_jump_note(resolve_parameters(ARX_NODE, {"inputs.time_jump_s": 0.056})) == ""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_node_parameters(overrides=["inputs.time_jump_s=0.001"])
        load_node_parameters(overrides=["sample_time_s=2.0"])
    notes = [str(w.message) for w in caught if issubclass(w.category, OkidWarning)]
    assert notes == [time_jump_note(low)]  # both nodes read it: said once
