"""`okid-ros track` with structural change detection: the flag in every line, the window restart.

A 2-mode structure (6 and 21 Hz, 250 Hz sampling) whose frequencies drop by 6 % at sample
4000; ARX order 40, window 2000, an update every 250 samples (`okid_bench.switching`).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from okid_bench.switching import added_mass_structure, simulate_switched
from okid_ros.cli import main as okid_ros_main
from okid_ros.core.noise_change import MIN_JUDGED_SAMPLES
from okid_ros.records import save_record
from okid_ros.sim.inputs import lowpass_input

DT, Q, WINDOW, EVERY = 1.0 / 250.0, 40, 2000, 250
CHANGE, N = 4000, 7000
FREQS = np.array([6.0, 21.0])


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    before, after = added_mass_structure(FREQS, [0.01, 0.015], 2, 2, DT, frequency_factor=0.94, seed=1)
    u = lowpass_input(N, 2, 40.0, DT, seed=3)
    y = simulate_switched([before, after], CHANGE, u, seed=4)
    path = tmp_path_factory.mktemp("track_change") / "change.npz"
    save_record(path, u, y, DT)
    return path


def track(path, out, *extra) -> list[dict]:
    status = okid_ros_main(["track", str(path), "--order", str(Q), "--window", str(WINDOW), "--every", str(EVERY),
                            "--states", "4", "--jsonl", str(out), "--no-progress", *extra])
    assert status == 0
    return [json.loads(line) for line in out.read_text().splitlines()]


def test_the_change_is_declared_once_and_the_window_restarts_at_it(record, tmp_path, capsys):
    lines = track(record, tmp_path / "on.jsonl")
    assert all("change_detected" in e for e in lines)
    declared = [e for e in lines if e["change_detected"]]
    assert len(declared) == 1
    e = declared[0]
    # Declared once the noise-change test has judged MIN_JUDGED_SAMPLES after the change point
    # (core/noise_change.py), so the change is reported by the second update after it.
    assert CHANGE <= e["change_declared_index"] <= min(e["sample_index"], CHANGE + MIN_JUDGED_SAMPLES + 50)
    assert e["sample_index"] < CHANGE + 2 * EVERY + 1
    assert abs(e["change_sample_index"] - CHANGE) <= 50
    assert e["change_statistic"] > e["change_threshold"] > 0
    assert "structural change at sample" in capsys.readouterr().out
    change = e["change_sample_index"]
    after = [x for x in lines if x["sample_index"] >= e["sample_index"]]
    for x in after:  # the window holds post-change samples only, and grows back
        assert x["window_first_index"] >= change
        assert x["rows"] == min(x["sample_index"] - change - Q + 1, WINDOW)
    waiting = [x for x in after if x["rows"] < WINDOW // 4]
    assert waiting and all(x["modes"] == [] and "waiting" in x for x in waiting)
    models = [x for x in after if x["rows"] >= WINDOW // 4]
    assert models[0]["sample_index"] - CHANGE <= WINDOW // 4 + Q + EVERY + 50
    for x in models:
        got = sorted(m["frequency_hz"] for m in x["modes"])
        np.testing.assert_allclose(got, 0.94 * FREQS, rtol=0.01)
    for x in lines:
        if x["sample_index"] < CHANGE:
            got = sorted(m["frequency_hz"] for m in x["modes"])
            np.testing.assert_allclose(got, FREQS, rtol=0.01)


def test_without_change_detection_the_window_only_slides(record, tmp_path):
    lines = track(record, tmp_path / "off.jsonl", "--no-change-detection")
    assert not any(e["change_detected"] for e in lines)
    assert all(e["rows"] == WINDOW for e in lines)
    # The old modes are still listed one window after the change (mixed windows).
    mixed = [e for e in lines if CHANGE < e["sample_index"] < CHANGE + WINDOW // 2]
    assert any(min(abs(m["frequency_hz"] / 6.0 - 1) for m in e["modes"]) < 0.01 for e in mixed)


def test_missing_samples_are_bridged_and_the_change_is_still_declared(record, tmp_path, capsys):
    data = np.load(record)
    y = data["y"].copy()
    for start in (2600, 3300, 4500):  # dropped readings of 5 samples, before and after the change
        y[start : start + 5, 1] = np.nan
    path = tmp_path / "gaps.npz"
    save_record(path, data["u"], y, DT)
    lines = track(path, tmp_path / "gaps.jsonl")
    declared = [e for e in lines if e["change_detected"]]
    assert len(declared) == 1 and abs(declared[0]["change_sample_index"] - CHANGE) <= 50
    for x in lines:
        if x["sample_index"] < CHANGE:  # the gaps before the change are no change
            got = sorted(m["frequency_hz"] for m in x["modes"])
            np.testing.assert_allclose(got, FREQS, rtol=0.01)


def test_without_the_noise_test_the_change_is_declared_sooner(record, tmp_path):
    on = [e for e in track(record, tmp_path / "on.jsonl") if e["change_detected"]]
    off = [e for e in track(record, tmp_path / "off.jsonl", "--no-noise-test") if e["change_detected"]]
    assert len(on) == len(off) == 1
    assert CHANGE <= off[0]["change_declared_index"] <= CHANGE + 100 < on[0]["change_declared_index"]


def test_a_change_after_the_last_update_is_said_in_the_summary(record, tmp_path, capsys):
    # The record ends 450 samples after the change and 411 after the last update (sample 4039,
    # an update every 500): the samples after the last update were not tested, and the change
    # went unsaid.
    import re

    data = np.load(record)
    path = tmp_path / "short.npz"
    save_record(path, data["u"][: CHANGE + 450], data["y"][: CHANGE + 450], DT)
    lines = track(path, tmp_path / "short.jsonl", "--every", "500")
    assert lines[-1]["sample_index"] == CHANGE + 39 and not any(e["change_detected"] for e in lines)
    out = capsys.readouterr().out
    said = re.search(r"structural change at sample (\d+) .* declared at sample (\d+) .*: no window of the new "
                     r"structure", out)
    assert said, out
    assert abs(int(said[1]) - CHANGE) <= 50 and CHANGE < int(said[2]) < CHANGE + 450
