"""`okid-ros track` runs node 2's innovation watch (service/watch.InnovationWatch) over its record.

The paper's structure, unchanged, driven by a quiet force of 0.01 (seed 4), with one sample of
the measured input 1e3 times its spread at sample 3004 (a glitch: the structure never felt it);
order 20, window 800, an update every 250 samples. Node 2 (the services as `okid-ros process`
runs them) keeps the samples its watchdog finds diverged out of its change test and declares
nothing; `track`, without the watchdog, declared a change at 3249.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from okid_bench.live_chain import run_pipeline
from okid_ros.cli import main as okid_ros_main
from okid_ros.records import save_record
from okid_ros.sim import paper_model, simulate_innovation

N, GLITCH_AT, Q, WINDOW, EVERY = 6000, 3004, 20, 800, 250
NODE_1 = {"arx.order": Q, "arx.window_length": WINDOW}
#: The counts of node 2's watch that every line of `track` carries (its diagnostics' names).
WATCH_COUNTS = ("diverged_samples", "divergence_restarts", "state_jumps", "divergences_beyond_window",
                "change_glitches", "change_alarms_state_jump", "change_alarms_noise", "change_alarms_excitation",
                "change_alarms_unconfirmed")


def _quiet_record(output_only: bool):
    """The quiet-force record with its glitch: (u, y, dt); u of shape (N, 0) when ``output_only``."""
    model = paper_model()
    rng = np.random.default_rng(4)
    u = 0.01 * rng.standard_normal((N, 2))
    y, _ = simulate_innovation(model, u, seed=5)
    if output_only:  # every output far off at one sample
        y[GLITCH_AT] += 1e3 * y.std(axis=0)
        return np.zeros((N, 0)), y, model.sample_time_s
    u[GLITCH_AT, 1] += 1e3 * u[:, 1].std()  # after the simulation: the structure never felt it
    return u, y, model.sample_time_s


def _track(tmp_path, u, y, dt) -> list[dict]:
    path = tmp_path / "glitch.npz"
    save_record(path, u, y, dt)
    out = tmp_path / "glitch.jsonl"
    status = okid_ros_main(["track", str(path), "--order", str(Q), "--window", str(WINDOW), "--every", str(EVERY),
                            "--jsonl", str(out), "--no-progress"])
    assert status == 0
    return [json.loads(line) for line in out.read_text().splitlines()]


@pytest.mark.parametrize("output_only", [False, True], ids=["input-output", "output-only"])
def test_a_glitch_over_a_quiet_stretch_is_no_change_in_track_as_in_node_2(tmp_path, output_only):
    u, y, dt = _quiet_record(output_only)
    lines = _track(tmp_path, u, y, dt)
    pipeline, _ = run_pipeline(u, y, dt, {**NODE_1, "publish_rate_hz": 1.0 / (EVERY * dt)})
    node_2 = pipeline.est.diagnostics()
    assert node_2["changes_detected"] == 0 and pipeline.changes == []
    assert [line["sample_index"] for line in lines if line["change_detected"]] == []
    # The watch's counts in every line, as node 2's diagnostics name them; its watchdog saw the glitch.
    for line in lines:
        assert set(WATCH_COUNTS) <= set(line["watch"]), line
    before, after = ([line for line in lines if line["sample_index"] < GLITCH_AT][-1],
                     [line for line in lines if line["sample_index"] > GLITCH_AT + 60][0])
    assert before["watch"]["diverged_samples"] == 0 < after["watch"]["diverged_samples"]
    assert node_2["diverged_samples"] > 0
