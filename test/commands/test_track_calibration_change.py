"""`okid-ros track` through a structural change during the reference's calibration.

The change test calibrates on the first ``change.reference_samples`` (1000) innovations after its reference is
armed; a change among them becomes the baseline and is declared late or never: strict expected failures (the
split rule that declared it was measured, not adopted: docs/benchmarks-change.md, forty-sixth session). The
2-mode structure of test_track_change.py (6 and 21 Hz, 250 Hz sampling, frequencies down 6 %), ARX order 40,
window 2000: the first model arms the test at sample 2040, the change comes 600 samples into its calibration.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from okid_bench.switching import added_mass_structure, simulate_switched
from okid_ros.cli import main as okid_ros_main
from okid_ros.records import save_record
from okid_ros.sim.inputs import lowpass_input

DT, Q, WINDOW, EVERY = 1.0 / 250.0, 40, 2000, 250
ARMED = WINDOW + Q  # the first model takes over at the sample after its update (2039)
CHANGE = ARMED + 600
FREQS = np.array([6.0, 21.0])


def _record(directory, n_samples: int):
    before, after = added_mass_structure(FREQS, [0.01, 0.015], 2, 2, DT, frequency_factor=0.94, seed=1)
    u = lowpass_input(n_samples, 2, 40.0, DT, seed=3)
    y = simulate_switched([before, after], CHANGE, u, seed=4)
    path = directory / "change_in_calibration.npz"
    save_record(path, u, y, DT)
    return path


def _declared(path, out, *extra) -> list[dict]:
    status = okid_ros_main(["track", str(path), "--order", str(Q), "--window", str(WINDOW), "--every", str(EVERY),
                            "--jsonl", str(out), "--no-progress", *extra])
    assert status == 0
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert lines[0]["sample_index"] == ARMED - 1 and lines[0]["modes"]  # the reference: a model before the change
    return [e for e in lines if e["change_detected"]]


@pytest.mark.xfail(strict=True, reason="the calibration takes the change in as its baseline; the split rule that "
                   "declares it was measured, not adopted (docs/benchmarks-change.md, forty-sixth session)")
def test_a_change_during_the_calibration_is_declared_input_output(tmp_path):
    declared = _declared(_record(tmp_path, CHANGE + 3000), tmp_path / "io.jsonl", "--states", "4")
    assert len(declared) == 1, declared
    e = declared[0]
    assert CHANGE < e["change_declared_index"] < ARMED + 1000 + 1000  # within a second calibration's length
    assert abs(e["change_sample_index"] - CHANGE) <= 50


@pytest.mark.xfail(strict=True, reason="an output-only reference's innovations barely grow in power in the 400 "
                   "calibration samples after the change (docs/benchmarks-change.md, forty-sixth session)")
def test_a_change_during_the_calibration_is_declared_output_only(tmp_path):
    # Output-only, the alarm waits for the modes after it (40 periods of 6 Hz, 1667 samples; again at the
    # reference's 2000 rows when no mode moved): declared once they moved.
    declared = _declared(_record(tmp_path, CHANGE + 4500), tmp_path / "oo.jsonl", "--output-only")
    assert len(declared) == 1, declared
    e = declared[0]
    assert CHANGE + 1667 <= e["change_declared_index"] <= CHANGE + 4000
    assert abs(e["change_sample_index"] - CHANGE) <= 50
