"""`okid-ros track`: JSON lines per window update, equal to the batch pipeline on each window."""

from __future__ import annotations

import json

import numpy as np
import pytest

from okid_ros.cli import main as okid_ros_main
from okid_ros.core.arx import fit_arx
from okid_ros.core.pipeline import identify_from_arx
from okid_ros.records import save_record
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation

DT = 0.008


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    truth = paper_model()
    u = white_input(2600, 2, seed=3)
    y, _ = simulate_innovation(truth, u, seed=4)
    path = tmp_path_factory.mktemp("track") / "paper.npz"
    save_record(path, u, y, DT)
    return path, u, y


def test_track_writes_one_line_per_update_matching_batch(record, tmp_path, capsys):
    path, u, y = record
    out = tmp_path / "track.jsonl"
    q, window, every = 20, 1500, 400
    status = okid_ros_main([
        "track", str(path), "--order", str(q), "--window", str(window), "--every", str(every),
        "--states", "6", "--jsonl", str(out), "--no-progress",
    ])
    assert status == 0
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    first = window + q - 1
    assert [entry["sample_index"] for entry in lines] == list(range(first, 2600, every))
    for entry in lines:
        assert entry["rows"] == window
        assert entry["window_first_index"] == entry["sample_index"] - window - q + 1
        assert entry["n_states"] == 6 and entry["modes"]
        for mode in entry["modes"]:
            assert {"frequency_rad_s", "frequency_hz", "damping_ratio"} <= set(mode)
            assert mode["frequency_hz"] == pytest.approx(mode["frequency_rad_s"] / (2 * np.pi))
    # The last update equals the batch chain on the same samples.
    k = lines[-1]["sample_index"]
    u_w, y_w = u[k - window - q + 1 : k + 1], y[k - window - q + 1 : k + 1]
    batch = identify_from_arx(fit_arx(u_w, y_w, q, "ridge", "gcv"), u_w, y_w, DT, n_states=6)
    got = sorted(mode["frequency_rad_s"] for mode in lines[-1]["modes"])
    want = sorted(mode.frequency_rad_s for mode in batch.modes)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert "updates" in capsys.readouterr().out


def test_track_too_few_samples_is_one_line_error(record, tmp_path, capsys):
    path, _, _ = record
    status = okid_ros_main(["track", str(path), "--order", "20", "--window", "3000",
                            "--jsonl", str(tmp_path / "x.jsonl")])
    assert status == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "at least 3020 needed" in err
