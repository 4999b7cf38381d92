"""Inputs that are not regular files (a FIFO) and a --reference far too large: one line, exit 2, at once.

Opening a FIFO waits for a writer: a record, bag or --reference given as one blocked for ever. Each
FIFO here gets a writer that opens it as soon as a reader does and closes it, so that code which
still opens it fails the test (on an empty read) instead of hanging it.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.commands.identify import MAX_REFERENCE_BYTES


@contextlib.contextmanager
def _fifo(path: Path) -> Iterator[Path]:
    """A FIFO at ``path`` with a writer that closes it at once if anything opens it for reading."""
    os.mkfifo(path)
    writer = threading.Thread(target=lambda: open(path, "wb").close(), daemon=True)
    writer.start()
    try:
        yield path
    finally:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # lets the writer's open return if no reader came
        writer.join(timeout=10)
        os.close(fd)


@pytest.fixture
def record(tmp_path: Path) -> Path:
    rng = np.random.default_rng(1)
    path = tmp_path / "rec.npz"
    np.savez(path, u=rng.standard_normal((400, 1)), y=rng.standard_normal((400, 2)), sample_time_s=0.01)
    return path


@pytest.mark.parametrize("command", ["identify", "track"])
@pytest.mark.parametrize("name", ["rec.npz", "rec.csv"])
def test_a_fifo_as_the_record_is_refused(tmp_path, capsys, command, name):
    output = ["--json", tmp_path / "m.json"] if command == "identify" else ["--jsonl", tmp_path / "t.jsonl"]
    with _fifo(tmp_path / name) as fifo:
        code, _, err = run_cli(capsys, command, fifo, *output)
    assert_one_line_error(code, err, f"{fifo}: not a regular file (a FIFO); a record is an .npz or .csv file")


@pytest.mark.parametrize("command", [["export", "--npz", "x.npz"], ["process", "--out", "out"], ["plot"],
                                     ["identify", "--json", "m.json"]])
def test_a_fifo_as_the_bag_or_in_it_is_refused(tmp_path, capsys, monkeypatch, command):
    monkeypatch.chdir(tmp_path)
    with _fifo(tmp_path / "run.mcap") as fifo:
        code, _, err = run_cli(capsys, command[0], fifo, *command[1:])
    assert_one_line_error(code, err, f"{fifo}: not a regular file (a FIFO); a bag is a rosbag2 folder")
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    with _fifo(bag / "bag_0.mcap"):
        code, _, err = run_cli(capsys, command[0], bag, *command[1:])
    assert_one_line_error(code, err, f"{bag}: bag_0.mcap in the bag is not a regular file (a FIFO)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "run.mcap"]  # nothing written


def test_a_fifo_or_a_huge_file_as_the_reference_is_refused(record, tmp_path, capsys):
    with _fifo(tmp_path / "ref.json") as fifo:
        code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json", "--reference", fifo)
    assert_one_line_error(code, err, f"--reference {fifo}: not a regular file (a FIFO)")
    huge = tmp_path / "huge.json"
    with open(huge, "wb") as stream:
        stream.truncate(MAX_REFERENCE_BYTES + 1)  # sparse: no disk used, and refused before it is read
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json", "--reference", huge)
    assert_one_line_error(code, err, f"--reference {huge}: more than the 64 MiB read for a reference model")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["huge.json", "rec.npz", "ref.json"]


def test_a_reference_nested_too_deeply_is_refused_as_no_model(record, tmp_path, capsys):
    # json's RecursionError was taken for a bug: "internal error, please report it", exit 70.
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json", "--reference", deep)
    assert_one_line_error(code, err, f"--reference {deep}: not an `okid-ros identify --json` output (maximum "
                          "recursion depth exceeded")
    assert not (tmp_path / "m.json").exists()


def test_a_fifo_given_to_batch_is_refused_as_no_bag(tmp_path, capsys):
    """It was searched as a folder: "left out 1 folder(s) ... that cannot be read (no permission?)"."""
    with _fifo(tmp_path / "run.mcap") as fifo:
        code, _, err = run_cli(capsys, "batch", fifo, "--out", tmp_path / "campaign")
    assert_one_line_error(code, err, f"{fifo}: not a regular file (a FIFO); a bag is a rosbag2 folder")
    assert "permission" not in err and not (tmp_path / "campaign").exists()


def test_a_reference_from_a_pipe_the_shell_opened_is_read(record, tmp_path, capsys):
    """``--reference <(cmd)`` (``/dev/fd/63``: a pipe whose writer runs) was read before FIFOs were refused."""
    assert run_cli(capsys, "identify", record, "--json", tmp_path / "ref.json", "--order", "4")[0] == 0
    read, write = os.pipe()
    writer = threading.Thread(target=lambda: (os.write(write, (tmp_path / "ref.json").read_bytes()), os.close(write)),
                              daemon=True)
    writer.start()  # the shell's writer: it may fill the pipe's buffer before the reader comes
    try:
        code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json", "--order", "4",
                               "--reference", f"/dev/fd/{read}")
    finally:
        os.close(read)  # a writer still blocked (the reference not read) gets EPIPE and ends
        writer.join(timeout=10)
    assert code == 0 and "not a regular file" not in err, err


def test_a_fifo_as_a_parameter_file_is_refused_and_a_shell_pipe_read(record, tmp_path, capsys):
    """``--params FIFO`` waited for a writer for ever; ``--params <(cmd)`` keeps working."""
    bag = tmp_path / "bag"
    assert run_cli(capsys, "simulate", "--out", bag, "--duration", "1")[0] == 0
    with _fifo(tmp_path / "p.yaml") as fifo:
        code, _, err = run_cli(capsys, "export", bag, "--npz", tmp_path / "x.npz", "--params", fifo)
    assert_one_line_error(code, err, f"parameter file {fifo}: not a regular file (a FIFO)")
    read, write = os.pipe()
    os.write(write, b"/**:\n  ros__parameters:\n    arx.order: 10\n")
    os.close(write)
    try:
        code, _, err = run_cli(capsys, "export", bag, "--npz", tmp_path / "x.npz", "--params", f"/dev/fd/{read}")
    finally:
        os.close(read)
    assert code == 0 and "regular file" not in err, err
