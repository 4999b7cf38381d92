"""`plot` and the input bag it draws from: the recording `process` read, or one that overlaps it in time.

Second hostile sweep (session s31): a source bag recorded again at the same path, or an `--input`
of another experiment, was drawn against the models without a word.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.cli import main

FAST = ["--param", "publish_rate_hz=0.25", "--param", "realization.max_states=8"]  # as test_hostile_bags.py


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> dict[str, Path]:
    """A 22 s simulated bag processed once; another recording 1e6 s later."""
    root = tmp_path_factory.mktemp("plotsource")
    bag, out, other = root / "experiment", root / "out", root / "other"
    assert main(["simulate", "--out", str(bag), "--duration", "22", "--start-time", "1000000"]) == 0
    assert main(["process", str(bag), "--out", str(out), "--no-progress", *FAST]) == 0
    assert main(["simulate", "--out", str(other), "--duration", "8", "--start-time", "2000000"]) == 0
    return {"root": root, "bag": bag, "out": out, "other": other}


def _reprocess(run: dict, tmp_path: Path, monkeypatch) -> Path:
    """The run processed again from tmp_path, so that the output records this copy of the source."""
    shutil.copytree(run["bag"], tmp_path / "experiment")
    monkeypatch.chdir(tmp_path)
    assert main(["process", "experiment", "--out", "out", "--no-progress", *FAST]) == 0
    return tmp_path / "out"


def test_the_source_as_process_read_it_is_drawn_without_a_word(run, tmp_path, capsys, monkeypatch):
    out = _reprocess(run, tmp_path, monkeypatch)
    code, stdout, err = run_cli(capsys, "plot", out, "--out-dir", tmp_path / "fig")
    assert code == 0 and not err, err
    assert "measured outputs from experiment (" in stdout


def test_a_source_recorded_again_at_its_path_is_drawn_with_a_warning(run, tmp_path, capsys, monkeypatch):
    # Was: exit 0, nothing said, fig5 comparing the models' estimates with another recording's outputs.
    out = _reprocess(run, tmp_path, monkeypatch)
    assert main(["simulate", "--out", "experiment", "--force", "--duration", "22", "--start-time", "1000000",
                 "--seed", "9"]) == 0
    code, stdout, err = run_cli(capsys, "plot", out, "--out-dir", tmp_path / "fig")
    assert code == 0, err
    assert "warning: experiment: not the bag `process` read (" in err and "another recording" in err, err
    assert "measured outputs from experiment (" in stdout


def test_an_input_apart_from_the_run_in_time_is_refused(run, tmp_path, capsys):
    # Was: "measured outputs from other (0 samples); FRF from 1000 samples", the FRF of another experiment.
    code, _, err = run_cli(capsys, "plot", run["out"], "--input", run["other"], "--out-dir", tmp_path / "fig")
    assert_one_line_error(code, err, f"--input {run['other']}: its samples (2000000.000-2000007.992 s) and those "
                                     "of the run that wrote the models (1000000.000-", "do not overlap")
    assert not (tmp_path / "fig").exists()


def test_a_source_replaced_by_a_recording_apart_in_time_is_left_out(run, tmp_path, capsys, monkeypatch):
    out = _reprocess(run, tmp_path, monkeypatch)
    shutil.rmtree(tmp_path / "experiment")
    shutil.copytree(run["other"], tmp_path / "experiment")
    code, stdout, err = run_cli(capsys, "plot", out, "--out-dir", tmp_path / "fig")
    assert code == 0, err
    assert "experiment: its samples (2000000.000-2000007.992 s)" in err and "not drawn from" in err, err
    assert "no input bag" in stdout and "FRF from" not in stdout


def test_an_input_within_the_run_but_on_other_stamps_is_refused(run, tmp_path, capsys):
    # Was: "measured outputs from shifted (0 samples)": nothing drawn, the FRF from the other bag.
    shifted = tmp_path / "shifted"
    assert main(["simulate", "--out", str(shifted), "--duration", "8", "--start-time", "1000004.003"]) == 0
    code, _, err = run_cli(capsys, "plot", run["out"], "--input", shifted, "--out-dir", tmp_path / "fig")
    assert_one_line_error(code, err, f"--input {shifted}: none of its samples has the stamp of a ModalStates",
                          "another recording?")
    assert not (tmp_path / "fig").exists()


def test_the_storage_file_of_a_bag_is_drawn_as_the_bag(run, tmp_path, capsys):
    # Was: `plot OUT/out.mcap` read the file alone, without OUT/metadata.yaml: no source bag, no
    # stabilization data, no truth ("wrote 6 figures (no truth); no input bag: ...").
    code, whole, err = run_cli(capsys, "plot", run["out"], "--out-dir", tmp_path / "bag")
    assert code == 0, err
    code, alone, err = run_cli(capsys, "plot", run["out"] / "out.mcap", "--out-dir", tmp_path / "file")
    assert code == 0 and not err, err
    assert alone.splitlines()[0] == whole.splitlines()[0].replace(str(tmp_path / "bag"), str(tmp_path / "file"))
    assert "(no truth)" not in alone and "measured outputs from" in alone
    assert sorted(p.name for p in (tmp_path / "file").iterdir()) == sorted(p.name for p in (tmp_path / "bag").iterdir())
    # One file of a split recording is read alone, and what that leaves out is said.
    split = tmp_path / "split"
    shutil.copytree(run["out"], split)
    metadata = (split / "metadata.yaml").read_text()
    (split / "metadata.yaml").write_text(metadata.replace("  - out.mcap\n", "  - out.mcap\n  - out_1.mcap\n", 1))
    code, alone, err = run_cli(capsys, "plot", split / "out.mcap", "--out-dir", tmp_path / "part")
    assert code == 0, err
    assert f"{split / 'out.mcap'}: one of the 2 storage files of the bag {split}, read alone: the bag's " in err
    assert "no input bag" in alone
