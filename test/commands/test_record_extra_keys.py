""".npz keys and CSV columns the reader does not read: checked, refused or named (docs/robustness.md).

Each was passed over in silence before the forty-sixth session: a rate in Hz under ``fs`` that
contradicts ``sample_time_s``, times ``t`` stepping another sample time, inputs stored as ``U``
(the record then identified as one of outputs only), channels stored one a key.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.record_keys import _TIME_NAMES

N = 400
DT = 0.01


def _arrays() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(4)
    u = rng.standard_normal((N, 1))
    return u, np.column_stack([np.convolve(u[:, 0], [0.0, 0.5, 0.3])[:N] + 0.05 * rng.standard_normal(N),
                               rng.standard_normal(N)])


def _npz(path: Path, **arrays) -> Path:
    u, y = _arrays()
    np.savez(path, **{"u": u, "y": y, "sample_time_s": DT, **arrays})
    return path


def _csv(path: Path, comments: str, header: str, extra, tail: str = "") -> Path:
    """A CSV of the record's columns u1, y1, y2 after ``extra(k)`` (the text of the first columns of row k)."""
    u, y = _arrays()
    rows = [f"{extra(k)}{float(a)!r},{float(b)!r},{float(c)!r}{tail}"
            for k, (a, b, c) in enumerate(zip(u[:, 0], *y.T))]
    path.write_text(comments + header + "\n" + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("key, value, says", [
    ("fs", 50.0, "fs = 50 Hz (a sample time of 0.02 s), and sample_time_s = 0.01 s: they contradict"),
    ("sample_rate_hz", 200, "sample_rate_hz = 200 Hz (a sample time of 0.005 s), and sample_time_s = 0.01 s"),
    ("dt", 0.02, "dt = 0.02 s, and sample_time_s = 0.01 s: they contradict"),
    ("t", 0.02 * np.arange(N), "t steps 0.02 s a sample (0 to 7.98 s over 400 samples), and sample_time_s = 0.01 s"),
    ("time_s", 10.0 * np.arange(N), "time_s steps 10 s a sample"),
])
def test_a_sample_time_under_another_key_that_contradicts_sample_time_s_is_refused(tmp_path: Path, capsys, key,
                                                                                  value, says) -> None:
    record = _npz(tmp_path / "two_rates.npz", **{key: value})
    for command, output in (("identify", "--json"), ("track", "--jsonl")):
        code, _, err = run_cli(capsys, command, record, output, tmp_path / "out", "--order", "4")
        assert_one_line_error(code, err, f"two_rates.npz: {says}", f"leave {key} out")
        assert not (tmp_path / "out").exists()
    if key == "time_s":
        assert "(in milliseconds, or a rate in kHz?)" in err


def test_keys_that_agree_with_sample_time_s_are_read_in_silence_and_others_are_named(tmp_path: Path, capsys) -> None:
    y = _arrays()[1]
    jitter = np.random.default_rng(5).uniform(-0.3, 0.3, N) * DT  # times a logger's clock stamped
    agreeing = _npz(tmp_path / "agreeing.npz", fs=100, dt=0.01, Ts=np.float32(0.01), t=5.0 + DT * np.arange(N) + jitter)
    code, _, err = run_cli(capsys, "identify", agreeing, "--json", tmp_path / "a.json", "--order", "4")
    assert code == 0 and "agreeing.npz" not in err, err
    notes = np.array({"a": 1}, dtype=object)  # pickled: never opened
    extra = _npz(tmp_path / "extra.npz", labels=np.array(["left", "right"]), Y=y, notes=notes)
    code, _, err = run_cli(capsys, "identify", extra, "--json", tmp_path / "e.json", "--order", "4")
    assert code == 0, err
    named = [line for line in err.splitlines() if "extra.npz" in line]
    assert named == [f"okid-ros identify: warning: {extra}: not read: labels, Y (beside y, which is read), notes; an "
                     f".npz record is read from u, y, sample_time_s, stamp_s alone"], err
    assert json.loads((tmp_path / "e.json").read_text())["n_inputs"] == 1


@pytest.mark.parametrize("arrays, says", [
    (lambda u, y: {"U": u, "y": y}, ["no key u, but U: the inputs are read from u alone (keys are case-sensitive): "
                                     "store U as u (for a record of outputs only, leave U out)"]),
    (lambda u, y: {"inputs": u, "outputs": y}, ["missing key(s) y (has sample_time_s, inputs, outputs)",
                                                "store inputs as u", "store outputs as y"]),
    (lambda u, y: {"u": u, "y1": y[:, 0], "y2": y[:, 1]},
     ["missing key(s) y", "as one array (samples, outputs): store them as y, np.column_stack([y1, y2])"]),
])
def test_channels_under_another_key_say_what_to_store(tmp_path: Path, capsys, arrays, says) -> None:
    """``U`` beside ``y`` was read as a record without inputs: identified output-only, in silence."""
    record = tmp_path / "renamed.npz"
    np.savez(record, sample_time_s=DT, **arrays(*_arrays()))
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json")
    assert_one_line_error(code, err, "renamed.npz: ", *says)


@pytest.mark.parametrize("arrays, says", [
    ({"fs": 100.0}, "fs = 100 Hz (a sample time of 0.01 s): if that is the sample time, store sample_time_s=0.01"),
    ({"t": DT * np.arange(N)}, "t steps 0.01 s a sample (0 to 3.99 s over 400 samples): if that is the sample time"),
    ({"sampel_time_s": DT}, "sampel_time_s: a misspelt sample_time_s? store it as sample_time_s"),
])
def test_a_missing_sample_time_names_the_key_that_seems_to_hold_it(tmp_path: Path, capsys, arrays, says) -> None:
    u, y = _arrays()
    record = tmp_path / "no_dt.npz"
    np.savez(record, u=u, y=y, **arrays)
    code, _, err = run_cli(capsys, "track", record, "--jsonl", tmp_path / "m.jsonl")
    assert_one_line_error(code, err, "no_dt.npz: missing key(s) sample_time_s", says)


def test_csv_time_column_or_rate_comment_that_contradicts_the_sample_time_is_refused(tmp_path: Path, capsys) -> None:
    record = _csv(tmp_path / "t.csv", f"# sample_time_s={DT}\n", "t,u1,y1,y2", lambda k: f"{0.02 * k:.2f},")
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json")
    assert_one_line_error(code, err, "t.csv: the column t steps 0.02 s a sample (0 to 7.98 s over 400 samples), and "
                          "sample_time_s = 0.01 s: they contradict", "leave the column 't' out")
    record = _csv(tmp_path / "fs.csv", f"# sample_time_s={DT}\n# fs: 50\n", "u1,y1,y2", lambda k: "")
    code, _, err = run_cli(capsys, "track", record, "--jsonl", tmp_path / "m.jsonl")
    assert_one_line_error(code, err, "fs.csv: the comment fs = 50 Hz (a sample time of 0.02 s), and sample_time_s = "
                          "0.01 s: they contradict")
    record = _csv(tmp_path / "only_fs.csv", "# fs=100\n", "u1,y1,y2", lambda k: "")
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json")
    assert_one_line_error(code, err, "only_fs.csv: no '# sample_time_s=...' line and no time_s column (the comment "
                          "fs = 100 Hz (a sample time of 0.01 s) is not read: if that is the sample time, write "
                          "'# sample_time_s=0.01')")


def test_csv_columns_not_read_are_named_once(tmp_path: Path, capsys) -> None:
    record = _csv(tmp_path / "label.csv", f"# sample_time_s={DT}\n", "time,label,u1,y1,y2,",
                  lambda k: f"{DT * k:.2f},run{k % 3},", tail=",")  # a trailing comma: an unnamed empty column
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json", "--order", "4")
    assert code == 0, err
    named = [line for line in err.splitlines() if "label.csv" in line]
    assert named == [f"okid-ros identify: warning: {record}: column(s) not read: 'label'; a CSV record is read from "
                     "its u... and y... columns, time_s and stamp_s alone"], err


def test_a_rate_agrees_with_a_sample_time_written_rounded(tmp_path: Path, capsys) -> None:
    # fs = 12 Hz beside sample_time_s = 0.0833 (1/12 to four decimals, 0.04 % off): the same sample time, written
    # rounded; was refused as a contradiction. A rate 2.4 % off a sample time of one digit still contradicts.
    u, y = _arrays()
    rounded = tmp_path / "rounded.npz"
    np.savez(rounded, u=u, y=y, sample_time_s=0.0833, fs=12)
    code, _, err = run_cli(capsys, "identify", rounded, "--json", tmp_path / "r.json", "--order", "4")
    assert code == 0 and "rounded.npz" not in err, err
    apart = tmp_path / "apart.npz"
    np.savez(apart, u=u, y=y, sample_time_s=0.001, fs=1024)
    code, _, err = run_cli(capsys, "identify", apart, "--json", tmp_path / "p.json", "--order", "4")
    assert_one_line_error(code, err, "apart.npz: fs = 1024 Hz", "they contradict")


@pytest.mark.parametrize("name", sorted(_TIME_NAMES) + ["Time Vector", "Sampling_Period", "Time [s]"])
def test_a_time_vector_is_pointed_at_alike_under_an_npz_key_and_a_csv_column(tmp_path: Path, capsys, name) -> None:
    # Both readers take the names of a time from one list (record_keys): the CSV pointed only at the columns of its own
    # pattern (t, time, timestamps, ...), so that dt, stamp, tvec or sampling_period stood unnamed beside the refusal.
    u, y = _arrays()
    np.savez(tmp_path / "no_dt.npz", u=u, y=y, **{name: DT * np.arange(N)})
    code, _, err = run_cli(capsys, "identify", tmp_path / "no_dt.npz", "--json", tmp_path / "m.json")
    assert_one_line_error(code, err, "no_dt.npz: missing key(s) sample_time_s", f"{name} steps 0.01 s a sample")
    record = _csv(tmp_path / "no_dt.csv", "", f"{name},u1,y1,y2", lambda k: f"{DT * k:.2f},")
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json")
    assert_one_line_error(code, err, "no_dt.csv: no '# sample_time_s=...' line and no time_s column",
                          f"(the column {name!r} is not read as the time: name it time_s")
