"""A record's stamps (``stamp_s`` of an .npz as `export` writes it, or a CSV column) that jump are refused.

`identify` and `track` take a record's samples as consecutive on one grid; a record glued from two
exports (100 s apart) was read in silence, its seam taken as two neighbouring samples.
"""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.core.record_stamps import stamp_jump_problem
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

DT = 0.008
N = 3000
START_S = 1_700_000_000.0


def _samples() -> tuple[np.ndarray, np.ndarray]:
    u = lowpass_input(N, 2, 15.0, DT, seed=1)
    y, _ = simulate_innovation(paper_model(), u, seed=2)
    return u, y


def _glued_stamps() -> np.ndarray:
    """The stamps of two exports 100 s apart, each with the jitter of its messages' stamps (< half a sample time)."""
    jitter = np.random.default_rng(3).uniform(-0.4 * DT, 0.4 * DT, N)
    return START_S + DT * np.arange(N) + np.where(np.arange(N) >= N // 2, 100.0, 0.0) + jitter


@pytest.mark.parametrize("command", [["identify", "--json", "out.json"], ["track", "--jsonl", "out.jsonl"]])
@pytest.mark.parametrize("kind", ["npz", "csv"])
def test_a_record_glued_from_two_is_refused_naming_the_seam(tmp_path, capsys, command, kind):
    u, y = _samples()
    stamps = _glued_stamps()
    record = tmp_path / f"glued.{kind}"
    if kind == "npz":
        np.savez(record, u=u, y=y, sample_time_s=DT, stamp_s=stamps)
        where = "between samples 1499 and 1500"
    else:
        rows = "\n".join(",".join(repr(float(v)) for v in (stamps[k], *u[k], *y[k])) for k in range(N))
        record.write_text(f"# sample_time_s={DT}\nstamp_s,u1,u2,y1,y2\n{rows}\n")
        where = "between data rows 1500 and 1501"
    code, _, err = run_cli(capsys, command[0], record, command[1], tmp_path / command[2])
    assert_one_line_error(code, err, f"{record}: stamp_s jumps by +100.0", f"sample times of 0.008 s) {where}",
                          "identify and track take the samples as consecutive on one grid")
    assert not (tmp_path / command[2]).exists()


def test_stamps_on_the_grid_with_their_jitter_are_taken(tmp_path, capsys):
    u, y = _samples()
    jitter = np.random.default_rng(3).uniform(-0.4 * DT, 0.4 * DT, N)
    record = tmp_path / "one.npz"
    np.savez(record, u=u, y=y, sample_time_s=DT, stamp_s=START_S + DT * np.arange(N) + jitter)
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "out.json", "--order", "20")
    assert code == 0, err


def test_the_stamps_rule():
    grid = START_S + DT * np.arange(10)
    assert stamp_jump_problem(grid, DT, n_samples=10) == ""
    back = grid - np.where(np.arange(10) >= 4, 5.0, 0.0)  # a second export of earlier data
    assert stamp_jump_problem(back, DT, n_samples=10).startswith("stamp_s jumps by -4.992 s (-624 sample times of "
                                                                 "0.008 s) between samples 3 and 4:")
    assert stamp_jump_problem(grid, DT, n_samples=11) == "stamp_s holds 10 stamps for 11 samples"
    assert stamp_jump_problem(grid, -1.0, n_samples=10) == ""  # the sample time's own check refuses it


@pytest.mark.parametrize("kind", ["npz", "csv"])
def test_a_record_with_two_samples_out_of_time_order_is_refused(tmp_path, capsys, kind):
    """Two rows swapped step back by one sample time, within the slip: were identified in silence."""
    _, y = _samples()  # output-only: no u
    stamps = START_S + DT * np.arange(N)
    stamps[[700, 701]] = stamps[[701, 700]]
    record = tmp_path / f"swapped.{kind}"
    if kind == "npz":
        np.savez(record, y=y, sample_time_s=DT, stamp_s=stamps)
        where = "between samples 700 and 701"
    else:
        rows = "\n".join(",".join(repr(float(v)) for v in (stamps[k], *y[k])) for k in range(N))
        record.write_text(f"# sample_time_s={DT}\nstamp_s,y1,y2\n{rows}\n")
        where = "between data rows 701 and 702"
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "out.json")
    assert_one_line_error(code, err, f"{record}: stamp_s steps back by 0.008", f" s {where}: ",
                          "the samples are not in time order")
    assert not (tmp_path / "out.json").exists()
    assert stamp_jump_problem(np.sort(stamps), DT, n_samples=N) == ""
