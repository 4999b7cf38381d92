"""Damaged, truncated, empty, wrongly typed and extreme records: one line, exit 2, nothing written.

Each case is a file a user could hand to `okid-ros identify` (or `track`); the expected outcome is
the one-line error ``okid-ros COMMAND: error: FILE: reason`` with status 2 and no output file.
The property-based versions (random bytes, cuts, dtypes) are in test_property_records.py.
"""

from __future__ import annotations

import json
import os
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros import cli
from okid_ros.errors import DataError, OkidWarning, write_atomically
from okid_ros.records import Record, load_record, require_inputs, save_record
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

N = 400


def _good_arrays() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    u = rng.standard_normal((N, 1))
    return u, np.column_stack([u[:, 0] + 0.1 * rng.standard_normal(N), rng.standard_normal(N)])


def _npz_bytes(tmp_path: Path) -> bytes:
    u, y = _good_arrays()
    path = tmp_path / "source.npz"
    np.savez(path, u=u, y=y, sample_time_s=0.01)
    return path.read_bytes()


def _write_case(tmp_path: Path, case: str) -> Path:
    """The hostile file `case` (see HOSTILE_CASES) in tmp_path."""
    u, y = _good_arrays()
    good = _npz_bytes(tmp_path)
    path = tmp_path / f"{case}.npz"
    writers = {
        "truncated": lambda: path.write_bytes(good[: len(good) // 2]),
        "header_only": lambda: path.write_bytes(good[:30]),
        "empty": lambda: path.write_bytes(b""),
        "crc": lambda: path.write_bytes(good[:200] + bytes(64) + good[264:]),
        "random": lambda: path.write_bytes(np.random.default_rng(0).bytes(500)),
        "complex": lambda: np.savez(path, u=u + 1j, y=y, sample_time_s=0.01),
        "object": lambda: np.savez(path, u=np.array([None] * N, dtype=object), y=y, sample_time_s=0.01),
        "strings": lambda: np.savez(path, u=np.array(["1.0"] * N), y=y, sample_time_s=0.01),
        "cube": lambda: np.savez(path, u=u[:, :, None], y=y, sample_time_s=0.01),
        "structured": lambda: np.savez(path, u=np.zeros(N, dtype=[("a", float)]), y=y, sample_time_s=0.01),
        "complex_dt": lambda: np.savez(path, u=u, y=y, sample_time_s=0.01 + 1j),
        "string_dt": lambda: np.savez(path, u=u, y=y, sample_time_s="fast"),
        "vector_dt": lambda: np.savez(path, u=u, y=y, sample_time_s=[0.01, 0.02]),
        "tiny_dt": lambda: np.savez(path, u=u, y=y, sample_time_s=1e-300),
        "huge_dt": lambda: np.savez(path, u=u, y=y, sample_time_s=1e308),
        "no_samples": lambda: np.savez(path, u=np.zeros((0, 1)), y=np.zeros((0, 2)), sample_time_s=0.01),
        "no_y": lambda: np.savez(path, u=u, sample_time_s=0.01),
        "beyond_float64": lambda: np.savez(path, u=u.astype(np.longdouble) * np.longdouble(10) ** 400, y=y,
                                           sample_time_s=0.01),
        "nan": lambda: np.savez(path, u=np.where(np.arange(N)[:, None] == 7, np.nan, u), y=y, sample_time_s=0.01),
        "length": lambda: np.savez(path, u=u[:-1], y=y, sample_time_s=0.01),
        "a_npy": lambda: np.save(open(path, "wb"), u),
    }
    writers[case]()
    return path


HOSTILE_CASES = {
    "truncated": "not a readable .npz", "header_only": "not a readable .npz", "empty": "not a readable .npz",
    "crc": "not a readable .npz", "random": "not a readable .npz", "complex": "complex",
    "object": "not a readable .npz", "strings": "string", "cube": "2-D", "structured": "structured",
    "complex_dt": "sample_time_s", "string_dt": "sample_time_s", "vector_dt": "sample_time_s",
    "tiny_dt": "between 1e-06 and 3600 s", "huge_dt": "between 1e-06 and 3600 s",
    "no_samples": "no samples", "no_y": "missing key(s) y", "beyond_float64": "NaN/Inf",
    "nan": "first at sample 7", "length": "length mismatch", "a_npy": "single array",
}


@pytest.mark.parametrize("case", sorted(HOSTILE_CASES))
def test_hostile_npz_is_one_line_naming_the_file(tmp_path: Path, case: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    path = _write_case(tmp_path, case)
    with pytest.raises(DataError) as raised:
        load_record(path)
    assert str(path) in str(raised.value) and HOSTILE_CASES[case] in str(raised.value)
    if case == "nan":
        return  # identify fills it (test_identify_fills_dropped_samples_where_the_method_allows)
    out = tmp_path / "model.json"
    assert cli.main(["identify", str(path), "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"okid-ros identify: error: {path}: ")
    assert HOSTILE_CASES[case] in err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == sorted(["source.npz", path.name])



@pytest.mark.parametrize(("content", "says"), [
    (b"# sample_time_s=0.01\nu1,y1\n1,2\n", "not an .npz (zip) archive: it begins as text, a CSV named .npz?"),
    (bytes(range(256)) * 2, "not an .npz (zip) archive"),
])
def test_a_file_that_is_no_zip_archive_is_named_so_not_a_pickle(tmp_path: Path, content: bytes, says: str) -> None:
    # np.load took it for a pickle: "... load it unsafely using the `allow_pickle=` keyword argument".
    path = tmp_path / "rec.npz"
    path.write_bytes(content)
    with pytest.raises(DataError) as raised:
        load_record(path)
    assert str(raised.value) == f"{path}: not a readable .npz file ({says})"

CSV_CASES = {
    "empty": ("", "no header line"),
    "header_only": ("# sample_time_s=0.01\nu1,y1\n", "no samples"),
    "ragged": ("# sample_time_s=0.01\nu1,y1\n1,2\n3\n", "data row 2 has 1 values"),
    "text": ("# sample_time_s=0.01\nu1,y1\n1,abc\n", "non-numeric"),
    "digit_separator": ("# sample_time_s=0.01\nu1,y1\n1,2\n1_000,3\n", "row 2, column 'u1': '1_000' is not a plain"),
    "non_ascii_digits": ("# sample_time_s=0.01\nu1,y1\n1,\u0661\u0662\n", "'\u0661\u0662' is not a plain decimal"),
    "nan_dt": ("# sample_time_s=nan\nu1,y1\n1,2\n3,4\n", "sample_time_s"),
    "bad_dt": ("# sample_time_s=fast\nu1,y1\n1,2\n", "bad sample_time_s"),
    "separated_dt": ("# sample_time_s=0_01\nu1,y1\n1,2\n", "bad sample_time_s"),
    "no_y": ("# sample_time_s=0.01\nu1,u2\n1,2\n", "output columns"),
    "time_nan": ("u1,y1,time_s\n1,2,0\n3,4,nan\n5,6,0.2\n", "time_s is not uniformly"),
    "two_dt": ("# sample_time_s=0.01\nu1,y1\n1,2\n# sample_time_s=0.5\n3,4\n", "two different sample_time_s"),
    "repeated_name": ("# sample_time_s=0.01\nu1,y1,y1\n1,2,2\n3,4,4\n", "the header names 2 columns 'y1'"),
    # A field past the csv module's limit (an unclosed quote swallows the rest of the file alike).
    "huge_field": ("# sample_time_s=0.01\ny1,note\n1,x\n2," + "x" * 140000 + "\n",
                   "not a CSV table the reader can take"),
}


@pytest.mark.parametrize("case", sorted(CSV_CASES))
def test_hostile_csv_is_one_line_naming_the_file(tmp_path: Path, case: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    text, reason = CSV_CASES[case]
    path = tmp_path / f"{case}.csv"
    path.write_text(text, encoding="utf-8")
    out = tmp_path / "track.jsonl"
    assert cli.main(["track", str(path), "--jsonl", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"okid-ros track: error: {path}: ") and reason in err, err
    assert not out.exists()


def test_csv_header_names_with_invisible_characters_and_a_contradicted_sample_time(tmp_path: Path) -> None:
    # Before: a zero-width space before 'u1' dropped the input silently, and the comment won over
    # a time_s column stepping twice its value.
    path = tmp_path / "r.csv"
    path.write_text("# sample_time_s=0.01\n\u200bu1,y1\x00\n1,2\n3,4\n5,7\n", encoding="utf-8")
    record = load_record(path)
    assert record.u.shape == (3, 1) and record.y.shape == (3, 1)
    path.write_text("# sample_time_s=0.01\ntime_s,u1,y1\n0,1,2\n0.02,3,4\n0.04,5,7\n")
    with pytest.raises(DataError, match="the sample_time_s comment says 0.01 s and the time_s column steps 0.02 s"):
        load_record(path)
    path.write_text("# sample_time_s=0.02\ntime_s,u1,y1\n0,1,2\n0.02,3,4\n0.04,5,7\n")
    assert load_record(path).sample_time_s == 0.02


def test_a_csv_time_column_with_a_gap_is_refused_and_one_written_to_few_decimals_is_read(tmp_path: Path) -> None:
    # With a sample_time_s comment the time_s column was not looked at: the samples either side of
    # a 0.5 s gap were joined as neighbours. 300 Hz stamps written to 3 decimals were "not uniform".
    u, y = _good_arrays()
    times = 0.01 * np.arange(N)
    times[200:] += 0.5
    body = "\n".join(f"{t:.6f},{a!r},{b!r},{c!r}" for t, a, b, c in zip(times, u[:, 0].tolist(), *y.T.tolist()))
    path = tmp_path / "gap.csv"
    for comment in ("", "# sample_time_s=0.01\n"):
        path.write_text(f"{comment}time_s,u1,y1,y2\n{body}\n")
        with pytest.raises(DataError, match="not uniformly increasing .data row 201 follows row 200 by 0.51 s"):
            load_record(path)
    path.write_text("time_s,u1,y1,y2\n" + "\n".join(
        f"{k / 300:.3f},{a!r},{b!r},{c!r}" for k, (a, b, c) in enumerate(zip(u[:, 0].tolist(), *y.T.tolist()))) + "\n")
    assert abs(load_record(path).sample_time_s - 1 / 300) < 1e-5


def test_csv_columns_taken_by_their_first_letter_only_are_named(tmp_path: Path) -> None:
    # 'uptime_s' became input 0 and 'year' output 2 in silence (the format's prefix rule).
    path = tmp_path / "named.csv"
    path.write_text("# sample_time_s=0.01\nuptime_s,u_1,y1,Y-2,year\n1,2,3,4,2024\n2,3,4,5,2024\n3,5,4,7,2024\n")
    with pytest.warns(OkidWarning, match=r"by their first letter: 'uptime_s' \(input 0\), 'year' \(output 2\);"):
        record = load_record(path)
    assert record.u.shape == (3, 2) and record.y.shape == (3, 3)
    path.write_text("# sample_time_s=0.01\nu,u_1,y1,Y-2,y.3\n1,2,3,4,5\n2,3,4,5,6\n")
    _load_without_warning(path)


def test_a_column_name_given_twice_is_refused_unless_the_column_is_ignored(tmp_path: Path) -> None:
    # 'u,y,y' was read as two outputs of one name, a second time_s column ignored, in silence.
    path = tmp_path / "twice.csv"
    for header, says in (("u,y,y", "'y'"), ("u1,u1,y1", "'u1'"), ("time_s,y1,time_s", "'time_s'")):
        path.write_text(f"# sample_time_s=0.01\n{header}\n0,1,0\n0.01,3,0.01\n0.02,5,0.02\n")
        with pytest.raises(DataError, match=re.escape(f"{path}: the header names 2 columns {says} ")):
            load_record(path)
    path.write_text("# sample_time_s=0.01\nnote,u1,y1,note\na,1,2,b\nc,3,4,d\ne,5,7,f\n")
    with pytest.warns(OkidWarning, match=re.escape("column(s) not read: 'note';")):
        assert load_record(path).y.shape == (3, 1)


def test_column_names_alike_but_for_their_case_are_refused_as_given_twice(tmp_path: Path) -> None:
    # 't,u1,y1,Y1' was read as two outputs, y1 then Y1, in silence: the reader takes 'Y' as 'y'.
    path = tmp_path / "case.csv"
    for header, says in (("t,u1,y1,Y1", "2 columns 'y1' and 'Y1', one name but for its case"),
                         ("U,u,y,t", "2 columns 'U' and 'u', one name but for its case"),
                         ("u1,y1,Y1,y1", "3 columns 'y1' and 'Y1', one name but for its case")):
        rows = "".join(f"{i},{i + 1},{i % 3},{i % 2}\n" for i in range(4))
        path.write_text(f"# sample_time_s=0.01\n{header}\n{rows}")
        with pytest.raises(DataError, match=re.escape(f"{path}: the header names {says} (a column given twice?)")):
            load_record(path)
    path.write_text("# sample_time_s=0.01\nTIME_S,time_s,u1,y1\n9,0,1,2\n9,0.01,3,4\n9,0.02,5,7\n")
    assert load_record(path).y.shape == (3, 1)  # 'TIME_S' is no time column to the reader: ignored, not twice


def test_a_commented_out_data_row_between_samples_is_named(tmp_path: Path) -> None:
    # A '#' before a data row dropped its sample and joined its neighbours, in silence.
    path = tmp_path / "hash.csv"
    path.write_text("# sample_time_s=0.01\nu1,y1\n1,2\n2,3\n# 3,4\n4,5\n# a note, not numbers\n5,6\n# 6,7\n")
    with pytest.warns(OkidWarning, match=r"1 commented-out data row\(s\) between the samples \(after data row 2\)"):
        record = load_record(path)
    assert record.y.shape == (4, 1)
    path.write_text("# sample_time_s=0.01\n# 0,1\nu1,y1\n1,2\n2,3\n# 3,4\n")  # before the header, after the end
    _load_without_warning(path)


def test_a_sample_time_stored_in_half_precision_is_named(tmp_path: Path) -> None:
    # float16 0.01 is 0.0100021: every frequency 2e-4 off, in silence.
    u, y = _good_arrays()
    path = tmp_path / "half.npz"
    np.savez(path, u=u, y=y, sample_time_s=np.float16(0.01))
    with pytest.warns(OkidWarning, match="sample_time_s is stored as float16"):
        assert load_record(path).sample_time_s == float(np.float16(0.01))
    np.savez(path, u=u, y=y, sample_time_s=np.float32(0.01))
    _load_without_warning(path)


def _load_without_warning(path: Path) -> Record:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return load_record(path)


def test_csv_with_epoch_stamps_and_a_text_column_loads(tmp_path: Path) -> None:
    # Stamps in epoch seconds step by 0.01 s to within their own float64 rounding (2e-7 s), and
    # a column of labels is one of the "other columns" the format ignores.
    u, y = _good_arrays()
    path = tmp_path / "epoch.csv"
    times = 1.7e9 + 0.01 * np.arange(N)
    rows = [f"{t!r},{a!r},{b!r},{c!r},run{k % 3}"
            for k, (t, a, b, c) in enumerate(zip(times.tolist(), u[:, 0].tolist(), *y.T.tolist()))]
    path.write_text("time_s,u1,y1,y2,label\n" + "\n".join(rows) + "\n")
    with pytest.warns(OkidWarning, match="column\\(s\\) not read: 'label'"):
        record = load_record(path)
    assert abs(record.sample_time_s - 0.01) < 1e-9
    np.testing.assert_array_equal(record.u[:, 0], u[:, 0])
    np.testing.assert_array_equal(record.y, y)
    path.write_text("time_s,u1,y1,y2,label\n" + "\n".join(rows).replace(",run1", ",") + "\n")
    with pytest.warns(OkidWarning, match="not read: 'label'"):
        assert load_record(path).y.shape == (N, 2)  # an empty cell of an ignored column too


def test_a_value_beyond_float64_is_a_missing_sample_to_identify_and_track(tmp_path: Path,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "overflow.csv"
    path.write_text("# sample_time_s=0.01\nu1,y1\n1e400,2\n3,4\n")
    assert cli.main(["identify", str(path), "--json", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"okid-ros identify: error: {path}: no two samples in a row are "
                                                   "free of NaN/Inf (1 of 2 hold them)"), err
    out = tmp_path / "track.jsonl"
    assert cli.main(["track", str(path), "--jsonl", str(out), "--order", "2"]) == 2  # track skips it as missing
    error = capsys.readouterr().err
    assert error.startswith(f"okid-ros track: error: {path}: 2 samples of 1 output: far too few to identify from")
    assert not out.exists()


def test_a_whitening_filter_longer_than_the_record_is_one_line(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "short.npz"
    path.write_bytes(_npz_bytes(tmp_path))
    out = tmp_path / "m.json"
    code = cli.main(["identify", str(path), "--order", "4", "--gain", "whitening", "--ar-order", "100000",
                     "--json", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert f"{path}: the whitening gain failed: {N} samples are too few for an AR(100000) whitening filter" in err
    assert not out.exists()


def test_binary_csv_and_yaml_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    noise = np.random.default_rng(3).bytes(400) + b"\xff\xfe"
    csv_path = tmp_path / "noise.csv"
    csv_path.write_bytes(noise)
    yaml_path = tmp_path / "noise.yaml"
    yaml_path.write_bytes(noise)
    assert cli.main(["identify", str(csv_path), "--json", str(tmp_path / "m.json")]) == 2
    assert "cannot read as UTF-8" in capsys.readouterr().err
    assert cli.main(["export", str(tmp_path / "no_bag"), "--npz", str(tmp_path / "x.npz"),
                     "--params", str(yaml_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(yaml_path) in err and "not UTF-8" in err


@pytest.mark.parametrize("text", ["", "# nothing set yet\n\n"])
def test_an_empty_parameter_file_is_named_empty(tmp_path: Path, capsys, text: str) -> None:
    """Was ``has no node sections (expected a mapping ..., got NoneType)``."""
    params = tmp_path / "empty.yaml"
    params.write_text(text)
    code, _, err = run_cli(capsys, "process", tmp_path / "no_bag", "--params", params, "--out", tmp_path / "out")
    assert_one_line_error(code, err, f"parameter file {params} has no node sections", "got an empty file)")


def test_record_without_inputs_loads_with_zero_input_channels(tmp_path: Path) -> None:
    _, y = _good_arrays()
    np.savez(tmp_path / "y_only.npz", y=y, sample_time_s=0.01)
    (tmp_path / "y_only.csv").write_text("# sample_time_s=0.01\ny1,y2\n" + "\n".join(f"{a},{b}" for a, b in y))
    for name in ("y_only.npz", "y_only.csv"):
        record = load_record(tmp_path / name)
        assert record.u.shape == (N, 0) and record.y.shape == (N, 2) and not record.has_inputs
        np.testing.assert_allclose(record.y, y)
        with pytest.raises(DataError, match="output-only identification"):
            require_inputs(record, tmp_path / name, "identify")
    assert Record(np.zeros((N, 0)), y, 0.01).validate().u.shape == (N, 0)


def test_track_without_inputs_runs_output_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # A record without u is tracked output-only (issue 18; test_track_output_only.py checks the
    # modes); white noise has no mode: each update fails, so the run fails, one line, no traceback.
    _, y = _good_arrays()
    np.savez(tmp_path / "y_only.npz", y=y, sample_time_s=0.01)
    assert cli.main(["track", str(tmp_path / "y_only.npz"), "--jsonl", str(tmp_path / "m.jsonl"),
                     "--window", "200", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "updates gave a model (" in err.splitlines()[-1], err
    assert not (tmp_path / "m.jsonl").exists()


@pytest.mark.parametrize("output_only", [False, True])
def test_identify_refuses_outputs_beyond_the_float64_range_before_the_work(tmp_path: Path, capsys, output_only) -> None:
    # Outputs about 1e308 (some beyond 1.8e308: Inf, missing): identify refused them after numpy's overflow
    # warnings, or for another reason ("too few samples for output-only identification: 31 < 200", "no ARX
    # order can be fitted ... 0 regressor rows"); now track's reason, at once.
    u, y = _good_arrays()
    with np.errstate(over="ignore"):
        np.savez(tmp_path / "huge.npz", u=u, y=y * 1e308, sample_time_s=0.01)
    code, _, err = run_cli(capsys, "identify", tmp_path / "huge.npz", "--json", tmp_path / "m.json",
                           *(["--output-only"] if output_only else []))
    assert_one_line_error(code, err, "the innovation covariance in the record's units is beyond the float64 range "
                          "(output spreads ")
    assert "RuntimeWarning" not in err and not (tmp_path / "m.json").exists()
    # A dead output of 1e308 is a dead output first, as track says (not "output spreads 1.48, inf").
    np.savez(tmp_path / "dead.npz", u=u, y=np.column_stack([y[:, 0], np.full(len(y), 1e308)]), sample_time_s=0.01)
    code, _, err = run_cli(capsys, "identify", tmp_path / "dead.npz", "--json", tmp_path / "m.json",
                           *(["--output-only"] if output_only else []))
    assert_one_line_error(code, err, "output channel 1 carries no response (constant 1e+308)")


def test_track_says_why_a_window_of_rejected_samples_waits(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Outputs 300 decades apart: after track's common scale of the outputs one is still beyond
    # 1e150, which the sliding window rejects (its squares would overflow), so no window fills;
    # the line said "restarted at the change" of a change that never was, and the lookup of that
    # change ended track with an IndexError (found by test_property_cli). (450 decades apart, a
    # covariance in the record's units is beyond float64: refused at the start, as identify does.)
    u, y = _good_arrays()
    np.savez(tmp_path / "wide.npz", u=u, y=y * np.array([1e-150, 1e300]), sample_time_s=0.01)
    assert cli.main(["track", str(tmp_path / "wide.npz"), "--jsonl", str(tmp_path / "w.jsonl"),
                     "--window", "200", "--order", "6", "--states", "4", "--no-progress"]) == 2
    assert "beyond the float64 range" in capsys.readouterr().err and not (tmp_path / "w.jsonl").exists()
    np.savez(tmp_path / "huge.npz", u=u, y=y * np.array([1e-150, 1e152]), sample_time_s=0.01)
    assert cli.main(["track", str(tmp_path / "huge.npz"), "--jsonl", str(tmp_path / "t.jsonl"),
                     "--window", "200", "--order", "6", "--states", "4", "--no-progress"]) == 2  # no model
    err = capsys.readouterr().err
    assert "waiting for rows); the first: " in err and "rejected for values beyond 1e150" in err, err
    assert "Traceback" not in err and not (tmp_path / "t.jsonl").exists()


def test_bool_and_integer_arrays_are_numbers(tmp_path: Path) -> None:
    u, y = _good_arrays()
    np.savez(tmp_path / "ints.npz", u=u > 0, y=(1000 * y).astype(np.int32), sample_time_s=np.int64(1))
    record = load_record(tmp_path / "ints.npz")
    assert record.u.dtype == float and set(np.unique(record.u)) == {0.0, 1.0} and record.sample_time_s == 1.0


def test_atomic_write_leaves_nothing_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")

    def fail(stream) -> None:
        stream.write(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError):
        write_atomically(target, fail)
    assert target.read_bytes() == b"old" and os.listdir(tmp_path) == ["out.bin"]
    u, y = _good_arrays()
    save_record(tmp_path / "r.npz", u, y, 0.01)
    np.testing.assert_array_equal(load_record(tmp_path / "r.npz").u, u)


def test_unexpected_exception_is_one_line_with_status_70(monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    def boom() -> int:
        raise ZeroDivisionError("a bug")

    monkeypatch.delenv("OKID_ROS_TRACEBACK", raising=False)
    assert cli.run_command("identify", boom) == 70
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error" in err and "ZeroDivisionError: a bug" in err
    monkeypatch.setenv("OKID_ROS_TRACEBACK", "1")
    with pytest.raises(ZeroDivisionError):
        cli.run_command("identify", boom)


def test_warnings_are_one_line_naming_the_command(capsys: pytest.CaptureFixture[str]) -> None:
    def warn() -> int:
        with np.errstate(over="warn"):
            np.float64(1e300) * np.float64(1e300)
        return 0

    assert cli.run_command("track", warn) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("okid-ros track: warning: overflow")


def test_identify_fills_dropped_samples_where_the_method_allows(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    from okid_ros.sim.inputs import white_input
    from okid_ros.sim.paper_model import paper_model
    from okid_ros.sim.simulators import simulate_innovation

    u = white_input(3000, 2, seed=3)
    y, _ = simulate_innovation(paper_model(), u, seed=4)
    u[500] = np.nan  # a dropped input reading, then a dropped output reading
    y[900:903, 1] = np.inf
    save_record(tmp_path / "gaps.npz", u, y, 0.008)
    save_record(tmp_path / "run.npz", u[903:], y[903:], 0.008)
    common = ["--order", "20", "--states", "6"]
    # The chain fills the 4 missing samples and identifies the whole record (as node 2 its window).
    assert cli.main(["identify", str(tmp_path / "gaps.npz"), *common, "--json", str(tmp_path / "filled.json")]) == 0
    assert ("warning: 4 of the 3000 samples hold NaN/Inf: identified on the whole record, its 4 missing samples "
            "filled by the ARX prediction (as node 2 fills its window); the fits and figures on its longest run "
            "without them (2097 samples)") in capsys.readouterr().err
    filled = json.loads((tmp_path / "filled.json").read_text())
    assert "filled by the ARX prediction" in filled["source"] and filled["n_states"] == 6
    # The paper's method needs contiguous samples: the longest run without them, as identify of that run.
    for name in ("gaps", "run"):
        out = tmp_path / f"paper-{name}.json"
        assert cli.main(["identify", str(tmp_path / f"{name}.npz"), "--order", "40", "--states", "6",
                         "--method", "paper", "--json", str(out)]) == 0
    assert ("4 of the 3000 samples hold NaN/Inf: identified on the longest run without them, samples 903 to 2999 "
            "(2097 samples)") in capsys.readouterr().err
    gaps, run = (json.loads((tmp_path / f"paper-{name}.json").read_text()) for name in ("gaps", "run"))
    assert gaps["modes"] == run["modes"] and "longest run without them" in gaps["source"]
    # Output-only identification ignores u, so its NaN does not count; y's are filled by a VAR.
    assert cli.main(["identify", str(tmp_path / "gaps.npz"), "--output-only", "--json", str(tmp_path / "oo.json")]) == 0
    assert ("3 of the 3000 samples hold NaN/Inf: identified on the whole record, its 3 missing samples filled"
            in capsys.readouterr().err)
    assert json.loads((tmp_path / "oo.json").read_text())["n_inputs"] == 0


def test_the_stretch_identify_fills_ends_at_a_long_gap() -> None:
    from okid_ros.records import Record, bridged_run

    u, y = np.ones((1000, 1)), np.arange(1000.0)[:, None]
    y[[100, 101, 700]] = np.nan  # short gaps
    y[300:320] = np.nan  # a long one: the stretch after it is the longest
    stretch, valid, note = bridged_run(Record(u, y, 0.01))
    assert stretch.y.shape[0] == 680 and stretch.y[0, 0] == 320 and valid.sum() == 679
    assert note.startswith("23 of the 1000 samples hold NaN/Inf: identified on samples 320 to 999 (the longest "
                           "stretch without a gap of more than 10 of them), its 1 missing samples filled")
    y[320:1000:8] = np.nan  # now too much to fill there (1 in 8): the stretch before the long gap
    stretch, valid, note = bridged_run(Record(u, y, 0.01))
    assert stretch.y.shape[0] == 300 and valid.sum() == 298 and "identified on samples 0 to 299" in note
    y[:300:5] = np.nan  # too much everywhere: the longest run without any missing sample
    stretch, valid, note = bridged_run(Record(u, y, 0.01))
    assert valid is None and stretch.y.shape[0] == 7 and "longest run without them, samples 321 to 327" in note
    clean = Record(u, np.arange(1000.0)[:, None], 0.01)
    assert bridged_run(clean) == (clean, None, "")


def _paper_record(n: int, noise: bool) -> tuple[np.ndarray, np.ndarray]:
    from okid_ros.core.statespace import simulate
    from okid_ros.sim.inputs import white_input
    from okid_ros.sim.paper_model import paper_model
    from okid_ros.sim.simulators import simulate_innovation

    truth, u = paper_model(), white_input(n, 2, seed=3)
    return u, simulate_innovation(truth, u, seed=4)[0] if noise else simulate(truth.A, truth.B, truth.C, truth.D, u)


# Conditions the code handles (an eigenbasis too ill-conditioned to use; cross-spectra of the inputs
# singular to working precision, one Welch segment of a short record, leaving the measured FRF
# undetermined), on records a user may well have: no scipy warning of them on stderr ("...
# (LinAlgWarning at stable_matrix.py:74)" thirteen times for the noise-free record, at
# validation.py:143 once per frequency for the short one). Nor scipy's note that a Welch segment
# is longer than the record (an output-only record under 256 samples), which it then shortens.
@pytest.mark.parametrize("case, n, noise, args", [
    ("noise_free", 3000, False, []),
    ("short_frf", 80, True, ["--plot-dir", "{tmp}/figures", "--uff", "{tmp}/m.uff"]),
    ("short_output_only", 210, True, ["--output-only"]),
])
def test_handled_conditions_put_no_scipy_warnings_on_stderr(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                            case: str, n: int, noise: bool, args: list[str]) -> None:
    u, y = _paper_record(n, noise)
    path = tmp_path / f"{case}.npz"
    save_record(path, u, y, 0.008)
    cli.main(["identify", str(path), "--json", str(tmp_path / "m.json"), *[a.format(tmp=tmp_path) for a in args]])
    err = capsys.readouterr().err
    assert "Warning at" not in err, err


@pytest.mark.parametrize("argv", [["identify", ""], ["track", ""], ["batch", "", "--plan"],
                                  ["export", "", "--npz", "x"], ["plot", ""], ["process", "", "--out", "x"],
                                  ["replay", ""], ["record", ""], ["demo", "--out-dir", ""]])
def test_an_empty_path_is_refused_not_taken_for_here(argv, capsys: pytest.CaptureFixture[str]) -> None:
    """An unset shell variable (`okid-ros batch "$DIR"`) must not mean the current folder."""
    with pytest.raises(SystemExit) as raised:
        cli.main(argv)
    assert raised.value.code == 2 and "an empty path" in capsys.readouterr().err


def test_frf_pairs_without_a_figure_folder_says_it_draws_nothing(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "record.npz"
    u = lowpass_input(1500, 2, 15.0, 0.008, seed=1)
    np.savez(path, u=u, y=simulate_innovation(paper_model(), u, seed=2)[0], sample_time_s=0.008)
    assert cli.main(["identify", str(path), "--json", str(tmp_path / "m.json"), "--frf-pairs", "1:1"]) == 0
    assert "--frf-pairs chooses the panels of frf.png, which only --plot-dir draws" in capsys.readouterr().err


@pytest.mark.parametrize("options, said", [
    (["--ar-order", "5"], "--ar-order is the order of the AR whitening filter of --gain whitening (and --method "
                          "paper): ignored with --gain refit"),
    (["--method", "paper", "--gain", "riccati", "--no-refine"],
     "--method paper identifies as published (the estimator gain by whitening, the order by the largest gap of the "
     "Hankel singular values, no refinement): --gain riccati, --no-refine ignored"),
    (["--method", "paper", "--max-states", "10"], "--method paper identifies as published (the estimator gain by "
     "whitening, the order by the largest gap of the Hankel singular values, no refinement): --max-states ignored"),
    (["--ar-order", "5", "--gain", "whitening"], None),
])
def test_gain_options_the_chain_passes_over_are_named(tmp_path: Path, capsys: pytest.CaptureFixture[str], options,
                                                      said) -> None:
    """Was: passed over in silence (the model's gain the default's, or the paper's whitening)."""
    path = tmp_path / "record.npz"
    u = lowpass_input(1500, 2, 15.0, 0.008, seed=1)
    np.savez(path, u=u, y=simulate_innovation(paper_model(), u, seed=2)[0], sample_time_s=0.008)
    cli.main(["identify", str(path), "--json", str(tmp_path / "m.json"), "--order", "20", *options])
    warnings = [line for line in capsys.readouterr().err.splitlines() if "ignored" in line]
    assert warnings == ([] if said is None else [f"okid-ros identify: warning: {said}"]), warnings


@pytest.mark.parametrize("options, said", [
    (["--penalty", "0.5", "--regularization", "none"],
     "--penalty 0.5 weighs a regularization: ignored with --regularization none"),
    (["--no-change-detection", "--false-alarm-samples", "1000", "--restart-min-fill", "0.5"],
     "--false-alarm-samples, --restart-min-fill: options of the change test, which --no-change-detection turns off; "
     "ignored"),
    (["--no-change-detection"], None),
])
def test_track_names_options_that_others_turn_off(tmp_path: Path, capsys: pytest.CaptureFixture[str], options,
                                                  said) -> None:
    """Was: passed over in silence."""
    path = tmp_path / "record.npz"
    u = lowpass_input(1500, 2, 15.0, 0.008, seed=1)
    np.savez(path, u=u, y=simulate_innovation(paper_model(), u, seed=2)[0], sample_time_s=0.008)
    assert cli.main(["track", str(path), "--jsonl", str(tmp_path / "t.jsonl"), "--order", "10", "--window", "600",
                     "--every", "1000", "--no-progress", *options]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "ignored" in line]
    assert warnings == ([] if said is None else [f"okid-ros track: warning: {said}"]), warnings


@pytest.mark.parametrize("argv, words", [
    # A channel without a single value: identify said "no two samples in a row are free of NaN/Inf",
    # track waited for rows on every update with exit 0; neither named the channel.
    (["identify", "{y_nan}", "--json", "{out}/m.json"], "output channel 1 holds no value (NaN/Inf in every sample)"),
    (["track", "{y_nan}", "--order", "10", "--window", "200", "--jsonl", "{out}/t.jsonl", "--no-progress"],
     "output channel 1 holds no value"),
    (["identify", "{u_nan}", "--json", "{out}/m.json"], "input channel 0 holds no value"),
    # One or two samples were "carries no response" or "linearly dependent" outputs.
    (["identify", "{two}", "--json", "{out}/m.json"], "2 samples of 2 outputs: far too few to identify from"),
    # --order auto on 20 samples cited the search's order 50 (454 samples) while order 2 fits 20.
    (["identify", "{twenty}", "--json", "{out}/m.json"], "20 samples are too few for an automatic ARX order"),
    # An output-only window shorter than its identification takes: exit 0 with every update failed.
    (["track", "{y_only}", "--output-only", "--window", "100", "--jsonl", "{out}/t.jsonl", "--no-progress"],
     "the realization needs at least 200"),
])
def test_records_no_identification_can_use_are_refused_naming_why(tmp_path: Path, capsys, argv, words) -> None:
    u, y = _good_arrays()
    files = {"y_nan": (u, np.column_stack([y[:, 0], np.full(N, np.nan)])), "u_nan": (np.full((N, 1), np.nan), y),
             "two": (u[:2], y[:2]), "twenty": (u[:20], y[:20]), "y_only": (u, y)}
    paths = {}
    for name, (inputs, outputs) in files.items():
        paths[name] = tmp_path / f"{name}.npz"
        np.savez(paths[name], u=inputs, y=outputs, sample_time_s=0.01)
    assert cli.main([a.format(out=tmp_path, **paths) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err, err
    assert not [p for p in tmp_path.iterdir() if p.suffix in (".json", ".jsonl")]


def test_a_line_break_in_a_file_name_keeps_the_error_on_one_line(tmp_path: Path, capsys) -> None:
    u, y = _good_arrays()
    path = tmp_path / "bad\nname.npz"
    np.savez(path, u=u[:2], y=y[:2], sample_time_s=0.01)
    assert cli.main(["identify", str(path), "--json", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"error: {str(path)!r}: 2 samples of 2 outputs" in err, err


def test_a_record_of_one_sample_and_an_empty_reference_are_said_plainly(tmp_path: Path, capsys) -> None:
    """Were ``y holds 1 samples ... 1 samples are too few`` and ``(Expecting value: line 1 column 1 (char 0))``."""
    u, y = _good_arrays()
    record = tmp_path / "one.npz"
    np.savez(record, u=u[:1], y=y[:1], sample_time_s=0.01)
    code, _, err = run_cli(capsys, "track", record, "--jsonl", tmp_path / "m.jsonl")
    assert_one_line_error(code, err, "one.npz: y holds 1 sample of 2 channels", "1 sample is too few to identify 2")
    np.savez(record, u=u, y=y, sample_time_s=0.01)
    (tmp_path / "empty.json").write_text("")
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json", "--reference",
                           tmp_path / "empty.json")
    assert_one_line_error(code, err, "empty.json: not an `okid-ros identify --json` output (the file is empty)")
    assert not (tmp_path / "m.json").exists()
