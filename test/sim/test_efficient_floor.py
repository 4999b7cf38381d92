"""The yardstick of bench/efficient_floor.py: the whitened truth and the script's refusals."""

from __future__ import annotations

import efficient_floor
import numpy as np
import pytest

from okid_bench.cases import benchmark_case
from okid_bench.oracle import one_step_predictions
from okid_bench.scoring import modes_of
from okid_ros.sim.simulators import simulate


def test_the_whitened_truth_has_the_same_modes_and_white_unit_innovations():
    """Its one-step errors on ``W y`` are ``W`` times the truth's on ``y``: identity covariance."""
    case = benchmark_case("more-outputs")  # four outputs of different innovation variances
    truth = case.system.to_innovation_form()
    white, W = efficient_floor.whitened(truth)
    assert np.allclose(W @ truth.innovation_covariance @ W.T, np.eye(W.shape[0]))
    assert np.array_equal(white.A, truth.A) and np.array_equal(white.B, truth.B)
    u = case.make_input(4000, 1)
    y = simulate(case.system, u, 2)
    _, errors = one_step_predictions(truth.A, truth.B, truth.C, truth.D, truth.K, u, y)
    _, white_errors = one_step_predictions(white.A, white.B, white.C, white.D, white.K, u, y @ W.T)
    assert np.allclose(white_errors, errors @ W.T, atol=1e-9 * np.abs(errors).max())
    covariance = np.cov(white_errors[200:].T)
    assert np.allclose(covariance, np.eye(W.shape[0]), atol=0.1), covariance


def test_the_bound_and_the_floor_agree_on_a_few_records():
    """The maximum-likelihood estimate from the truth scatters as the Cramer-Rao bound says."""
    case = efficient_floor.input_output_case("paper-lp15", 3750)
    result = efficient_floor.run_case(case, seeds=6, log=lambda line: None)
    assert result["floor_kept_truth"] == 0 and result["okid_failed"] == 0
    z = result["floor_f"] / result["bound_f"]
    assert np.all(np.isfinite(z)) and 0.5 < np.sqrt(np.mean(z ** 2)) < 1.6, z
    assert len(result["truth"]) == len(modes_of(case.truth.A, case.truth.sample_time_s)) == 3


def test_a_random_structure_is_scored_on_the_record_the_output_only_bench_draws(capsys):
    """``--cases random``: structure K's record is ``random_case(K).simulate(K)``; the summary counts its modes."""
    from okid_bench.output_only_cases import random_case

    case = efficient_floor.output_only_floor_case("random-3", None)
    _, y = case.record(0)
    drawn = random_case(3).simulate(3)
    assert np.allclose(y, drawn - drawn.mean(axis=0))
    assert efficient_floor.main(["--output-only", "--cases", "random", "--first-seed", "3", "--seeds", "1",
                                 "--quiet"]) == 0
    summary = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| all |")]
    assert summary and summary[0].split("|")[2].strip() == str(len(random_case(3).truth())), summary


def test_an_input_output_random_structure_is_scored_on_the_record_of_random_structures():
    """``--cases random`` without ``--output-only``: bench/random_structures.py's record of structure K."""
    from okid_bench.cases import random_case
    from okid_ros.sim.simulators import simulate_noisy

    case = efficient_floor.random_input_output_case(5)
    u, y = case.record(0)
    drawn = random_case(5)
    u_drawn = drawn.make_input(drawn.n_samples[0], 5)
    assert np.array_equal(u, u_drawn) and np.array_equal(y, simulate_noisy(drawn.system, u_drawn, seed=5))
    result = efficient_floor.run_case(case, seeds=1, log=lambda line: None)
    assert result["floor_f"].shape == (1, len(modes_of(drawn.system.A, drawn.sample_time_s)))
    assert np.nanmax(np.abs(result["floor_f"])) < 1.0  # the floor places every mode of this record


@pytest.mark.parametrize("argv, message", [
    (["--cases", "no-such-case"], "unknown case"),
    (["--output-only", "--cases", "harmonic"], "not white"),
    (["--seeds", "2"], "at least 3 seeds"),
])
def test_the_script_refuses_what_it_cannot_score(argv, message, capsys):
    with pytest.raises(SystemExit) as exited:
        efficient_floor.main(argv)
    assert exited.value.code == 2 and message in capsys.readouterr().err


def test_an_existing_table_is_not_replaced_without_force(tmp_path, capsys):
    out = tmp_path / "floor.md"
    out.write_text("kept\n")
    with pytest.raises(SystemExit):
        efficient_floor.main(["--out", str(out), "--seeds", "3"])
    assert out.read_text() == "kept\n" and "--force" in capsys.readouterr().err


def test_the_koma_frame_is_scored_on_the_output_only_bench_records_against_its_discrete_modes():
    """``--output-only --cases koma-frame``: koma's recipe, seed K's record, its trapezoidal rule's modes as truth."""
    from okid_bench.physical_cases import koma_frame_case

    case = efficient_floor.output_only_floor_case("koma-frame", None)
    drawn = koma_frame_case()
    _, y = case.record(2)
    record = drawn.simulate(2)
    assert np.allclose(y, record - record.mean(axis=0))
    truth = sorted(drawn.truth(), key=lambda mode: mode["frequency_hz"])
    assert np.allclose([mode.frequency_hz for mode in case.true_modes], [mode["frequency_hz"] for mode in truth])
    assert np.allclose([mode.damping_ratio for mode in case.true_modes], [mode["damping_ratio"] for mode in truth])
