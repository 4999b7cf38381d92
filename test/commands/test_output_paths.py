"""Where `identify` and `track` write.

Never over the record, never two outputs on one path, into a device instead of over it, and a
failed write is one line.

`process` has the same rules for its bag and JSON lines (test/tools/test_process_outputs_guard.py).
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.errors import write_atomically


@pytest.fixture()
def record(tmp_path: Path) -> Path:
    """Two inputs, two outputs of a lightly damped system: enough samples for a model."""
    rng = np.random.default_rng(3)
    u = rng.standard_normal((1500, 2))
    y = np.zeros((1500, 2))
    for k in range(2, 1500):
        y[k] = 1.8 * y[k - 1] - 0.9 * y[k - 2] + 0.1 * u[k - 1] + 0.01 * rng.standard_normal(2)
    path = tmp_path / "rec.npz"
    np.savez(path, u=u, y=y, sample_time_s=0.01)
    return path


def test_identify_never_writes_over_its_record(record, tmp_path, capsys):
    before = record.read_bytes()
    for option in ("--json", "--csv"):
        args = ["--json", str(tmp_path / "m.json")] if option == "--csv" else []
        code, _, err = run_cli(capsys, "identify", record, option, record, *args, "--force")
        assert_one_line_error(code, err, "cannot be the record", "not even with --force")
        assert record.read_bytes() == before


def test_two_outputs_on_one_path_are_refused_before_the_work(record, tmp_path, capsys):
    out = tmp_path / "same.out"
    code, _, err = run_cli(capsys, "identify", record, "--json", out, "--csv", out)
    assert_one_line_error(code, err, "the modes CSV cannot be the JSON model", "one would replace the other")
    assert not out.exists()
    code, _, err = run_cli(capsys, "track", record, "--jsonl", record, "--window", "500", "--force", "--no-progress")
    assert_one_line_error(code, err, "the JSON lines file cannot be the record")


def test_a_device_is_written_into_not_replaced(record, tmp_path, capsys):
    # A link to /dev/null: the output goes into the device, no --force needed, the link stays.
    sink = tmp_path / "sink"
    sink.symlink_to("/dev/null")
    code, _, err = run_cli(capsys, "identify", record, "--json", sink, "--csv", tmp_path / "modes.csv")
    assert code == 0, err
    assert sink.is_symlink() and os.readlink(sink) == "/dev/null"
    # A FIFO: the bytes arrive through it and it is still a FIFO afterwards.
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    received = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()), daemon=True)
    reader.start()
    write_atomically(fifo, lambda stream: stream.write(b"model"))
    reader.join(timeout=10)
    assert not reader.is_alive() and received == [b"model"] and fifo.is_fifo()


def test_a_full_disk_is_one_line(record, tmp_path, capsys):
    assert Path("/dev/full").is_char_device()  # Linux: writes to it fail with ENOSPC
    full = tmp_path / "full"
    full.symlink_to("/dev/full")
    code, _, err = run_cli(capsys, "track", record, "--jsonl", full, "--window", "500", "--every", "500",
                           "--no-progress")
    assert_one_line_error(code, err, f"{full}: cannot write the JSON lines file", "No space left on device")
    # process too; its clean-up after the error removes the bag it began, never the device (or the link).
    bag = tmp_path / "bag"
    assert run_cli(capsys, "simulate", "--out", bag, "--duration", "12")[0] == 0
    code, _, err = run_cli(capsys, "process", bag, "--out", tmp_path / "out", "--jsonl", full, "--no-progress",
                           "--param", "publish_rate_hz=1.0", "--param", "arx.window_length=800",
                           "--param", "arx.order=20")
    assert_one_line_error(code, err, f"{full}: cannot write the JSON lines file", "No space left on device")
    assert full.is_symlink() and not (tmp_path / "out").exists()


@pytest.mark.parametrize("option", ["--false-alarm-samples", "--penalty"])
def test_track_refuses_an_infinite_option(record, tmp_path, capsys, option):
    with pytest.raises(SystemExit) as exited:
        run_cli(capsys, "track", record, "--jsonl", tmp_path / "t.jsonl", option, "inf")
    assert exited.value.code == 2
    assert f"argument {option}" in capsys.readouterr().err


def test_a_name_of_the_longest_legal_length_is_written(tmp_path):
    # The temporary name beside it was ".{name}.{pid}.{n}.part": 255 characters made it too long
    # ("File name too long" after a whole identification); a multi-byte name is cut on its bytes.
    for name in ("m" * 250 + ".json", "é" * 125 + ".json"):
        target = tmp_path / name
        write_atomically(target, lambda stream: stream.write(b"{}"))
        assert target.read_bytes() == b"{}"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["m" * 250 + ".json", "é" * 125 + ".json"])


def test_identify_refuses_a_folder_for_a_file_before_the_work_and_names_what_it_wrote(record, tmp_path, capsys):
    # --csv an existing folder with --force: the JSON was written, then "Is a directory", and the
    # corrected rerun was refused for the JSON; a full disk for the CSV did not say the JSON was written.
    folder = tmp_path / "modes"
    folder.mkdir()
    model = tmp_path / "m.json"
    code, _, err = run_cli(capsys, "identify", record, "--json", model, "--csv", folder, "--force")
    assert_one_line_error(code, err, f"{folder}: a folder; the modes CSV is a file")
    assert not model.exists() and folder.is_dir()
    full = tmp_path / "full"
    full.symlink_to("/dev/full")
    code, _, err = run_cli(capsys, "identify", record, "--json", model, "--csv", full)
    assert_one_line_error(code, err, "No space left on device", f"the JSON model is written ({model})")


def test_track_force_replaces_a_link_never_what_it_points_to(record, tmp_path, capsys):
    # --force opened OUT in place: a hard link to the record destroyed the record, a symlink
    # overwrote the file it points to. Now the lines replace the name, as identify's JSON does.
    before = record.read_bytes()
    hard = tmp_path / "hard.jsonl"
    hard.hardlink_to(record)
    notes = tmp_path / "notes.txt"
    notes.write_text("precious notes\n")
    soft = tmp_path / "soft.jsonl"
    soft.symlink_to(notes.name)
    for out in (hard, soft):
        code, _, err = run_cli(capsys, "track", record, "--jsonl", out, "--window", "500", "--every", "500",
                               "--no-progress", "--force")
        assert code == 0, err
        assert not out.is_symlink() and out.read_text().startswith('{"sample_index"')
    assert record.read_bytes() == before and notes.read_text() == "precious notes\n"


def test_a_failed_track_leaves_the_old_lines_and_an_interrupted_one_keeps_its_own(record, tmp_path, capsys,
                                                                                  monkeypatch):
    # The lines go to a temporary file renamed at the end: an error half-way left a half-written
    # OUT in place of the old one. Ctrl-C keeps the lines so far (the user stopped the run).
    import okid_ros.commands.track as track

    out = tmp_path / "t.jsonl"
    out.write_text("old lines\n")
    real = track._window_model
    for stop in (KeyboardInterrupt, MemoryError):
        calls = []

        def stopping(*args, stop=stop, calls=calls, **kwargs):
            calls.append(1)
            if len(calls) == 2:
                raise stop
            return real(*args, **kwargs)

        monkeypatch.setattr(track, "_window_model", stopping)
        code, _, err = run_cli(capsys, "track", record, "--jsonl", out, "--window", "500", "--every", "300",
                               "--no-progress", "--force")
        assert code in (130, 2) and len(calls) == 2, err
        if stop is KeyboardInterrupt:
            lines = [json.loads(line) for line in out.read_text().splitlines()]
            assert len(lines) == 1 and lines[0]["rows"] == 500, lines  # the first update, before the stop
            out.write_text("old lines\n")
        else:
            assert out.read_text() == "old lines\n"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npz", "t.jsonl"]  # no temporary file left


@pytest.mark.parametrize("force", [[], ["--force"]])
def test_a_missing_parent_folder_is_made_with_force_too(record, tmp_path, capsys, force):
    # With --force the parent folder was not made ("No such file or directory") where without it it was.
    model, lines = tmp_path / "a" / "b" / "m.json", tmp_path / "c" / "d" / "t.jsonl"
    code, _, err = run_cli(capsys, "identify", record, "--json", model, "--no-refine", *force)
    assert code == 0 and model.is_file(), err
    code, _, err = run_cli(capsys, "track", record, "--jsonl", lines, "--window", "500", "--every", "500",
                           "--no-progress", *force)
    assert code == 0 and lines.is_file(), err


@pytest.mark.parametrize("ending", ["/", "/."])
def test_an_output_named_as_a_folder_is_refused(record, tmp_path, capsys, ending):
    # "out/" wrote a file named "out" (Path drops the slash).
    out = f"{tmp_path / 'out'}{ending}"
    code, _, err = run_cli(capsys, "identify", record, "--json", out)
    assert_one_line_error(code, err, f"{out}: names a folder; the JSON model is a file: give a file name")
    code, _, err = run_cli(capsys, "track", record, "--jsonl", out, "--window", "500", "--no-progress", "--force")
    assert_one_line_error(code, err, f"{out}: names a folder; the JSON lines file is a file: give a file name")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npz"]


def test_a_failed_command_leaves_no_empty_folder_it_made(record, tmp_path, capsys):
    # The outputs' parent folders are made before the work; a run that then failed left them, empty.
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a record")
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "a" / "b" / "m.json", "--order", "700")
    assert_one_line_error(code, err, "too few samples for ARX order 700")
    code, _, err = run_cli(capsys, "track", garbage, "--jsonl", tmp_path / "c" / "t.jsonl", "--no-progress")
    assert_one_line_error(code, err, "not a readable .npz file")
    code, _, err = run_cli(capsys, "export", garbage, "--npz", tmp_path / "d" / "r.npz")
    assert_one_line_error(code, err, "not a readable rosbag2")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.npz", "rec.npz"]
    # A folder that holds an output written before the failure stays, with it; so does one that was there.
    (tmp_path / "there").mkdir()
    full = tmp_path / "full.csv"
    full.symlink_to("/dev/full")
    model = tmp_path / "kept" / "m.json"
    code, _, err = run_cli(capsys, "identify", record, "--json", model, "--csv", full, "--plot-dir",
                           tmp_path / "there" / "figures" / "new", "--no-refine")
    assert_one_line_error(code, err, "the JSON model is written")
    assert model.is_file() and sorted(p.name for p in (tmp_path / "there").iterdir()) == []


def test_a_folder_that_takes_no_file_is_refused_before_the_work(record, tmp_path, capsys):
    # /proc takes no new file: identify wrote the JSON, then failed on --uff (exit 2 after the work);
    # export read the whole bag first. Now every output's folder is tried before the work.
    model = tmp_path / "m.json"
    for option, path in (("--uff", "/proc/nope.uff"), ("--csv", "/proc/nope.csv"), ("--plot-dir", "/proc")):
        code, out, err = run_cli(capsys, "identify", record, "--json", model, option, path, "--no-refine")
        assert_one_line_error(code, err, f"{path}", "in the folder /proc")
        assert out == "" and not model.exists()
    code, _, err = run_cli(capsys, "track", record, "--jsonl", "/proc/t.jsonl", "--no-progress")
    assert_one_line_error(code, err, "/proc/t.jsonl: cannot write the JSON lines file in the folder /proc")
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"not a bag")
    code, _, err = run_cli(capsys, "export", garbage, "--npz", "/proc/r.npz")
    assert_one_line_error(code, err, "/proc/r.npz: cannot write the record in the folder /proc")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.mcap", "rec.npz"]


def test_a_file_given_for_a_folder_is_named_as_one(record, tmp_path, capsys):
    # A file as --plot-dir (or above it, or above an output) said "cannot create the parent folder (File exists)".
    afile = tmp_path / "afile"
    afile.write_text("mine")
    model = tmp_path / "m.json"
    code, _, err = run_cli(capsys, "identify", record, "--json", model, "--plot-dir", afile)
    assert_one_line_error(code, err, f"--plot-dir {afile}: is a file, not a folder")
    code, _, err = run_cli(capsys, "identify", record, "--json", model, "--plot-dir", afile / "figs")
    assert_one_line_error(code, err, f"--plot-dir {afile / 'figs'}: {afile} is a file, not a folder")
    code, _, err = run_cli(capsys, "identify", record, "--json", afile / "m.json")
    assert_one_line_error(code, err, f"{afile / 'm.json'}: {afile} is a file, not a folder")
    code, _, err = run_cli(capsys, "batch", tmp_path, "--out", afile)
    assert_one_line_error(code, err, f"--out {afile}: is a file, not a folder")
    code, _, err = run_cli(capsys, "simulate", "--out", afile / "bag", "--duration", "1")
    assert_one_line_error(code, err, f"{afile / 'bag'}: {afile} is a file, not a folder")
    assert afile.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["afile", "rec.npz"]


@pytest.fixture()
def record_never_read(monkeypatch) -> list:
    """The record reader of `identify` replaced by one that fails the test: the calls it had."""
    import okid_ros.tools.bag_record

    calls: list = []

    def read(*args, **kwargs):
        calls.append(args)
        raise AssertionError("the record was read before the outputs were checked")

    monkeypatch.setattr(okid_ros.tools.bag_record, "load_any_record", read)
    return calls


def test_identify_refuses_a_bad_output_before_it_reads_the_record(record, tmp_path, capsys, record_never_read,
                                                                   monkeypatch):
    # Each was found only after the record was read (a big bag read in vain); now before, making nothing.
    afile, folder, kept = tmp_path / "afile", tmp_path / "figs", tmp_path / "old.csv"
    afile.write_text("mine")
    folder.mkdir()
    kept.write_text("old")
    model = ["--json", str(tmp_path / "m.json")]
    for argv, says in (
        (["--json", afile / "m.json"], f"{afile / 'm.json'}: {afile} is a file, not a folder"),
        ([*model, "--uff", afile / "sub" / "x.uff"], f"{afile / 'sub' / 'x.uff'}: {afile} is a file, not a folder"),
        ([*model, "--csv", kept], f"{kept}: exists already, not overwriting (use --force to replace the modes CSV)"),
        ([*model, "--csv", f"{folder}/"], f"{folder}/: names a folder; the modes CSV is a file"),
        ([*model, "--uff", folder], f"{folder}: a folder; the UFF file is a file"),
    ):
        code, out, err = run_cli(capsys, "identify", record, *argv)
        assert_one_line_error(code, err, says)
        assert out == ""
    import okid_ros.tools.output_paths

    # root writes where a mode forbids it: a folder this user may not write in is os.access's answer
    monkeypatch.setattr(okid_ros.tools.output_paths.os, "access", lambda path, mode: Path(path) != folder)
    code, _, err = run_cli(capsys, "identify", record, *model, "--uff", folder / "new" / "x.uff")
    assert_one_line_error(code, err, f"{folder / 'new' / 'x.uff'}: its folder {folder / 'new'} cannot be made: "
                          f"cannot write the UFF file in the folder {folder} (not writable by this user)")
    code, _, err = run_cli(capsys, "identify", record, *model, "--plot-dir", folder)
    assert_one_line_error(code, err, f"cannot write the figure in the folder {folder} (not writable by this user)")
    assert record_never_read == [] and kept.read_text() == "old" and afile.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "figs", "old.csv", "rec.npz"]
    assert list(folder.iterdir()) == []
