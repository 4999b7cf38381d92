"""bench/record_parts.py: the pairing of two pieces' modes and the normalized differences."""

from __future__ import annotations

import numpy as np
import pytest
import record_parts

from okid_ros.records import save_record
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import PAPER_SAMPLE_TIME_S, paper_model
from okid_ros.sim.simulators import simulate_innovation


def test_modes_are_paired_within_the_match_and_their_difference_divided_by_the_combined_std():
    a = [(5.0, 0.010, 0.003, 0.001), (20.0, 0.020, 0.010, 0.002)]
    b = [(5.004, 0.012, 0.004, 0.001), (21.0, 0.020, 0.010, 0.002)]  # 21 Hz is 5 % away: no pair
    rows = record_parts._pairs([a, b], 0.005)
    assert len(rows) == 1 and rows[0]["pieces"] == (0, 1)
    np.testing.assert_allclose(rows[0]["z_f"], -0.004 / 0.005)
    np.testing.assert_allclose(rows[0]["z_zeta"], -0.002 / np.hypot(0.001, 0.001))


def test_the_halves_of_a_simulated_record_agree_within_their_standard_deviations(tmp_path, capsys):
    model, dt = paper_model(), PAPER_SAMPLE_TIME_S
    u = white_input(8000, 2, seed=3)
    y, _ = simulate_innovation(model, u, seed=4)
    path = tmp_path / "rec.npz"
    save_record(path, u, y, dt)
    out = tmp_path / "parts.md"
    assert record_parts.main([str(path), "--out", str(out)]) == 0
    text = out.read_text()
    assert "frequency: 3 pairs of modes (0 without a standard deviation)" in text, text
    rms = float(text.split("frequency: ")[1].split("RMS ")[1].split(",")[0])
    assert 0.1 < rms < 3.0, text
    with pytest.raises(SystemExit) as refused:  # an existing output without --force
        record_parts.main([str(path), "--out", str(out)])
    assert refused.value.code == 2 and "exists" in capsys.readouterr().err
