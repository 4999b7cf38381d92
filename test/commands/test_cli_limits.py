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


@pytest.mark.parametrize("n_samples, fragments", [
    # was: "... needs 31 samples; a given order may fit fewer (at most 0 here)"
    (5, ["5 samples are too few for any ARX order: the smallest a given order can be, 2 (with 2 inputs and 2 "
         "outputs), needs 14 samples, the automatic order's smallest, 3 (2 states' worth), 31"]),
    # was: "... a given order up to 2 fits them", where --order 2 then failed: "12 samples are too few to fit a
    # 2-state model"
    (13, ["13 samples are too few for any ARX order", "needs 14 samples"]),
    # was: "(at most 1 here)" although --order 2 and 3 fit 20 samples
    (20, ["20 samples are too few for an automatic ARX order", "needs 31 samples; a given order up to 3 fits them"]),
])
def test_a_record_too_short_for_an_automatic_order_says_its_samples_and_what_fits(tmp_path, capsys, n_samples,
                                                                                  fragments):
    record = _paper_record(tmp_path / "short.npz", n_samples)
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "out.json")
    assert_one_line_error(code, err, *fragments)
    assert "at most 0" not in err and not (tmp_path / "out.json").exists()
    if n_samples == 20:  # the largest order said to fit does
        code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "out.json", "--order", "3")
        assert code == 0, err


@pytest.mark.parametrize("n_inputs, n_outputs", [(1, 1), (2, 1), (2, 2), (1, 4), (3, 3), (4, 4)])
def test_the_fewest_samples_export_takes_are_the_fewest_identify_takes(tmp_path, capsys, n_inputs, n_outputs):
    # export took 13 samples of 2 inputs and 2 outputs (the ARX fit of order 2) that identify refused: its
    # realization of 2 states regresses them on 12 states, too few (one rule now, arx_order.fewest_samples_to_identify).
    from okid_ros.tools.bag_record import fewest_usable_samples

    fewest = fewest_usable_samples(n_outputs, n_inputs)
    rng = np.random.default_rng(1)
    for n_samples, status in ((fewest, 0), (fewest - 1, 2)):
        u = rng.standard_normal((n_samples, n_inputs))
        y = np.cumsum(rng.standard_normal((n_samples, n_outputs)), axis=0) * 0.1 + u @ rng.standard_normal(
            (n_inputs, n_outputs))
        path = tmp_path / f"{n_samples}.npz"
        np.savez(path, u=u, y=y, sample_time_s=DT)
        code, _, err = run_cli(capsys, "identify", path, "--order", 2, "--json", tmp_path / f"{n_samples}.json")
        assert code == status, (n_samples, err)
