"""Limits of the CLI said as the option or the record they concern (found by a fuzzing pass).

Each message names what the user gave and its bound: ``--states`` and the most states the ARX
fit allows, a record too short for any order by its sample counts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

DT = 0.008


def _paper_record(path: Path, n_samples: int) -> Path:
    """``n_samples`` of the paper's structure (2 inputs, 2 outputs) as an .npz record."""
    model = paper_model()
    u = lowpass_input(n_samples, 2, 15.0, DT, seed=1)
    y, _ = simulate_innovation(model, u, seed=2)
    np.savez(path, u=u, y=y, sample_time_s=DT)
    return path


@pytest.fixture(scope="module")
def record(tmp_path_factory) -> Path:
    return _paper_record(tmp_path_factory.mktemp("limits") / "run.npz", 5000)


@pytest.mark.parametrize("command", [["identify", "--json"], ["track", "--jsonl"]])
def test_too_many_states_are_said_as_the_states_and_their_bound(record, tmp_path, capsys, command):
    """Was: "no ARX order can be fitted ... (cost: ARX order 1000001 has 4000006 coefficients ...)"."""
    out = tmp_path / "out.json"
    code, _, err = run_cli(capsys, command[0], record, command[1], out, "--states", "1000000")
    assert_one_line_error(code, err, "--states 1000000: needs an ARX order of at least 1000001",
                          "states fit within")
    assert "cost:" not in err and not out.exists()


def test_the_most_states_follow_the_cost_limit_and_the_record():
    from okid_ros.core.arx_order import min_arx_order, most_states, states_problem
    from okid_ros.core.options import ArxOrderOptions
    from okid_ros.core.regressors import regressor_length

    orders = ArxOrderOptions()
    most, why = most_states(100_000, 2, 2, arx_orders=orders)
    assert (most, why) == (622, "the limit of 2500 ARX coefficients per output")
    assert regressor_length(min_arx_order(most, 2), 2, 2) <= 2500 < regressor_length(min_arx_order(most + 1, 2), 2, 2)
    assert states_problem(most, 100_000, 2, 2, arx_orders=orders) == ""
    most, why = most_states(500, 2, 2, arx_orders=orders)
    assert (most, why) == (54, "the 500 samples of the fit")
    assert "at most 54 states fit within the 500 samples" in states_problem(55, 500, 2, 2, arx_orders=orders)
