"""`process` never writes over its input, keeps its outputs apart, and says why nothing came out.

Offline (no DDS): outputs that are, hold or lie in the input bag (even with --force), --jsonl
over --out, a file where the bag would go (even with --force), topic parameters that are not
ROS 2 names or put two message types on one topic,
messages of the wrong size, a rosbag2 directory named ``*.bag``, and names too long for the
file system.
"""

from __future__ import annotations

import hashlib
import re
import warnings
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.cli import main
from okid_ros.errors import ParameterError
from okid_ros.service.topics import resolve_topic
from okid_ros.tools.bagio import TRUTH_KEY, open_bag

LONG = "x" * 300  # longer than NAME_MAX (255) of the usual file systems


def digest(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    """A 2 s MCAP bag (enough for the error paths; no model comes from it)."""
    path = tmp_path_factory.mktemp("guard") / "victim"
    assert main(["simulate", "--out", str(path), "--duration", "2"]) == 0
    return path


@pytest.fixture()
def victim(bag, tmp_path, monkeypatch) -> Path:
    """A copy of the bag in a fresh working directory (relative paths as a user types them)."""
    import shutil

    monkeypatch.chdir(tmp_path)
    shutil.copytree(bag, tmp_path / "v")
    return Path("v")


def _mcap(victim: Path) -> str:
    return str(next(victim.glob("*.mcap")))


@pytest.mark.parametrize("argv, fragments", [
    (lambda v: [_mcap(v), "--out", v], ["output bag cannot be the input bag", "its directory"]),
    (lambda v: [v, "--out", "."], ["output bag cannot contain the input bag v"]),
    (lambda v: [v, "--out", v / "sub"], ["output bag cannot be inside the input bag v"]),
    (lambda v: [v, "--out", "o", "--jsonl", v / "metadata.yaml"], ["JSON lines file cannot be inside"]),
    (lambda v: [v, "--out", "o", "--jsonl", _mcap(v)], ["JSON lines file cannot be inside"]),
    (lambda v: [_mcap(v), "--out", "o", "--jsonl", v / "metadata.yaml"], ["JSON lines file cannot be inside"]),
])
def test_an_output_over_the_input_is_refused_even_with_force(victim, capsys, argv, fragments):
    before = digest(victim)
    args = argv(victim)
    code, _, err = run_cli(capsys, "process", *args, "--force", "--no-progress")
    assert_one_line_error(code, err, "not even with --force", *fragments)
    assert digest(victim) == before
    assert not Path("o").exists() and not (victim / "sub").exists()


@pytest.mark.parametrize("out, jsonl, relation", [
    ("o2", "o2", "cannot be the output bag"),
    ("o2", "o2/models.jsonl", "cannot be inside the output bag"),
    ("o2/bag", "o2", "cannot contain the output bag"),
])
def test_jsonl_over_the_output_bag_is_refused(victim, capsys, out, jsonl, relation):
    code, _, err = run_cli(capsys, "process", victim, "--out", out, "--jsonl", jsonl, "--force", "--no-progress")
    assert_one_line_error(code, err, f"{jsonl}: the JSON lines file {relation} {out}")
    assert not Path("o2").exists()


def test_a_file_at_the_output_bag_is_not_removed_even_with_force(victim, capsys):
    notes, lines = Path("notes.txt"), Path("old.jsonl")
    notes.write_text("precious")
    lines.write_text("identified before\n")
    code, _, err = run_cli(capsys, "process", victim, "--out", notes, "--jsonl", lines, "--force", "--no-progress")
    assert_one_line_error(code, err, "notes.txt: exists and is not a rosbag2 directory")
    # Every output is checked before any is replaced: the JSON lines of an earlier run stay too.
    assert notes.read_text() == "precious" and lines.read_text() == "identified before\n"


@pytest.mark.parametrize("ending", ["/", "/."])
def test_a_jsonl_named_as_a_folder_is_refused(victim, capsys, ending):
    # "--jsonl out/" wrote a file named "out" (Path drops the slash), as identify and track did.
    code, _, err = run_cli(capsys, "process", victim, "--out", "o", "--jsonl", f"lines{ending}", "--no-progress")
    assert_one_line_error(code, err, f"lines{ending}: names a folder; the JSON lines file is a file: give a file name")
    assert not Path("lines").exists() and not Path("o").exists()


@pytest.mark.parametrize("name, problem", [
    ("bad topic name!!", "not allowed"), ("", "empty"), ("a//b", "'//'"), ("a/", "ends with"),
    ("2d/x", "starts with a digit"), ("~/private", "substitutions are not supported"),
])
def test_topic_parameters_must_be_ros_names(victim, capsys, tmp_path, name, problem):
    with pytest.raises(ParameterError, match="parameter modal_states_topic: .*not a valid topic name"):
        resolve_topic(name, parameter="modal_states_topic")
    params = tmp_path / "p.yaml"
    params.write_text(f'/**/okid_modal_estimator:\n  ros__parameters:\n    modal_states_topic: "{name}"\n')
    code, _, err = run_cli(capsys, "process", victim, "--out", "o", "--params", params, "--no-progress")
    assert_one_line_error(code, err, "modal_states_topic of okid_modal_estimator", problem)
    assert not Path("o").exists()


def test_valid_topic_names_still_resolve():
    assert resolve_topic("sensors/imu_2", "/rig1") == "/rig1/sensors/imu_2"
    assert resolve_topic(" /my/imu ") == "/my/imu"


def test_two_message_types_on_one_topic_are_refused_up_front(victim, capsys):
    code, _, err = run_cli(capsys, "process", victim, "--out", "o", "--param", "arx_model_topic=modal_states",
                           "--no-progress")
    assert_one_line_error(code, err, "arx_model_topic of okid_arx_identifier (ArxModel)",
                          "modal_states_topic of okid_modal_estimator (ModalStates)", "/okid/modal_states")
    assert not Path("o").exists()


def test_messages_of_the_wrong_size_are_named_and_refused_when_no_sample_comes_out(victim, capsys):
    # As `identify` refuses such a bag: an empty output bag with exit status 0 read as success.
    code, _, err = run_cli(capsys, "process", victim, "--out", "o", "--jsonl", "m.jsonl", "--param",
                           "n_inputs=3", "--param", "n_outputs=5", "--no-progress")
    assert_one_line_error(code, err, "no input message made a complete sample",
                          "all 250 input messages were rejected: 250 wrong_size",
                          "n_inputs 3, n_outputs 5 expected; the first on /okid/io_sample has u of 2, y of 2 values")
    assert not Path("o").exists() and not Path("m.jsonl").exists()
    # A mapped field beyond the message: "n_inputs 2, n_outputs 2 expected; ... u of 2" read as 2 for 2.
    sources = '["io_sample /okid/io_sample u[5]=u0 u[1]=u1 y[0]=y0 y[1]=y1"]'
    code, _, err = run_cli(capsys, "process", victim, "--out", "o", "--param", f"inputs.sources={sources}",
                           "--no-progress")
    assert_one_line_error(code, err, "the fields of 'io_sample /okid/io_sample u[5]=u0 u[1]=u1 y[0]=y0 y[1]=y1' "
                          "expected; the first on /okid/io_sample has u of 2, y of 2 values")


def test_samples_beyond_the_windows_range_are_named_when_no_model_comes_out(tmp_path, capsys, monkeypatch):
    # Before: "no regressor rows in the window yet" and nothing on why. simulate refuses such a
    # bag now (MAX_INNOVATION_VARIANCE); one is still made here, for process to read.
    from okid_ros.tools import simulate_bag

    monkeypatch.setattr(simulate_bag, "MAX_INNOVATION_VARIANCE", float("inf"))
    bag = tmp_path / "loud"
    assert run_cli(capsys, "simulate", "--out", bag, "--duration", "3", "--noise", "1e300")[0] == 0
    code, out, err = run_cli(capsys, "process", bag, "--out", tmp_path / "o", "--no-progress")
    assert code == 0 and "no model was identified" in out, err
    assert re.search(r"okid-ros process: warning: node 1 refused \d+ of the samples \(\d+ beyond 1e150\)", err), err


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_rosbag2_directory_named_dot_bag_is_read_as_rosbag2(tmp_path, capsys, storage):
    path = tmp_path / "run.bag"
    assert run_cli(capsys, "simulate", "--out", path, "--duration", "1", "--storage", storage)[0] == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # read whole: no "metadata.yaml missing" salvage
        with open_bag(path) as opened:
            assert opened.read_note == "" and TRUTH_KEY in opened.custom_data
            assert opened.message_count() > 0
    code, _, err = run_cli(capsys, "export", path, "--npz", tmp_path / "run.npz")
    assert code == 0 and "warning" not in err, err


def test_names_too_long_are_one_line_errors(victim, capsys):
    cases = [
        ([victim, "--out", LONG], [LONG, "File name too long"]),
        ([victim, "--out", "o", "--jsonl", LONG + ".jsonl"], [LONG, "File name too long"]),
        ([LONG, "--out", "o"], [LONG, "cannot open the bag"]),
        ([victim, "--out", f"a/b/{LONG}/c"], ["cannot create the parent folder"]),
    ]
    for argv, fragments in cases:
        code, _, err = run_cli(capsys, "process", *argv, "--force", "--no-progress")
        assert_one_line_error(code, err, *fragments)
    assert sorted(p.name for p in Path().iterdir()) == ["v"]  # nothing half-made, not even a/b


def test_a_publish_period_longer_than_the_bag_is_the_reason_given(victim, capsys):
    # "no model was identified" and nothing else: the first ArxModel was never due.
    code, out, err = run_cli(capsys, "process", victim, "--out", "o", "--param", "publish_rate_hz=0.1",
                             "--no-progress")
    assert code == 0, err
    assert "no model was identified: no ArxModel was due: one every 10 s of sample time (publish_rate_hz)" in out


def test_force_keeps_the_previous_outputs_when_the_new_input_fails_late(victim, capsys):
    # Was: --force removed the old bag and JSON lines before reading the input; an input found at
    # its end to make no sample then left neither the old outputs nor new ones.
    code, _, err = run_cli(capsys, "process", victim, "--out", "o", "--jsonl", "m.jsonl", "--no-progress")
    assert code == 0, err
    before = (digest(Path("o")), Path("m.jsonl").read_bytes())
    code, _, err = run_cli(capsys, "process", victim, "--out", "o", "--jsonl", "m.jsonl", "--param", "n_inputs=3",
                           "--param", "n_outputs=5", "--force", "--no-progress")
    assert_one_line_error(code, err, "no input message made a complete sample")
    assert (digest(Path("o")), Path("m.jsonl").read_bytes()) == before
    assert sorted(p.name for p in Path().iterdir()) == ["m.jsonl", "o", "v"]  # nothing staged is left
    code, _, err = run_cli(capsys, "process", victim, "--out", "o", "--jsonl", "m.jsonl", "--param",
                           "publish_rate_hz=0.5", "--force", "--no-progress")
    assert code == 0, err  # a run that succeeds replaces both
    assert digest(Path("o")) != before[0] and sorted(p.name for p in Path().iterdir()) == ["m.jsonl", "o", "v"]
    with open_bag(Path("o")) as written:
        assert written.custom_json("okid_ros.process")["parameters"]["okid_arx_identifier"]["publish_rate_hz"] == 0.5
