"""Paths and topic names holding a line break, ESC or an undecodable byte: shown escaped, on one line.

A file name may hold any byte but "/" and NUL; printed raw, a line break cut a one-line message in
two, ESC changed the terminal, and a byte that is no UTF-8 (a surrogate in Python) raised
UnicodeEncodeError on a strict stdout. Such a name is shown as Python's repr shows it
(:func:`okid_ros.errors.shown_path`); an ordinary name as it is.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from batch_helpers import batch, write_bag_without_inputs, write_params
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.errors import one_line, shown_path

_REPO = Path(__file__).resolve().parents[2]


def _record(path: Path) -> Path:
    rng = np.random.default_rng(3)
    u = rng.standard_normal((600, 1))
    y = np.column_stack([np.convolve(u[:, 0], [0.0, 0.5, 0.3])[:600] + 0.05 * rng.standard_normal(600)])
    np.savez(path, u=u, y=y, sample_time_s=0.01)
    return path


@pytest.mark.parametrize(("name", "shown"), [
    ("run.npz", "run.npz"), ("é ü.npz", "é ü.npz"), ("a\\b.npz", "a\\b.npz"),
    ("a\nb.npz", "'a\\nb.npz'"), ("a\x1b[31mb", "'a\\x1b[31mb'"), ("a\tb\rc", "'a\\tb\\rc'"),
    ("a\x85b", "'a\\x85b'"), (os.fsdecode(b"a\xffb"), "'a\\udcffb'"), (b"a\xffb", "'a\\udcffb'"),
])
def test_shown_path_escapes_only_names_holding_an_unprintable_character(name, shown) -> None:
    assert shown_path(name) == shown
    assert shown_path(Path(os.fsdecode(name))) == shown


def test_one_line_escapes_what_is_left_unprintable_and_joins_the_lines() -> None:
    assert one_line("x: a\x1bb\n  c\udcff") == "x: a\\x1bb c\\udcff"
    assert one_line("plain text") == "plain text"


def test_batch_names_a_failed_bag_with_a_line_break_on_one_line(tmp_path: Path, capsys) -> None:
    bag = write_bag_without_inputs(tmp_path / "in" / "no\ninputs")
    params = write_params(tmp_path / "params.yaml")
    capsys.readouterr()
    assert batch(tmp_path / "in", "--params", params, "--out", tmp_path / "c") == 1
    out = capsys.readouterr().out
    assert f"  failed: {repr(str(bag.resolve()))}: no topic /okid/io_sample" in out, out
    assert all(line.startswith(("batch:", "  ", "wrote ")) for line in out.splitlines()), out


def test_identify_shows_a_record_named_with_esc_escaped(tmp_path: Path, capsys) -> None:
    path = _record(tmp_path / "run\x1b[2J.npz")
    json_path = tmp_path / "model\x1b.json"
    code, out, err = run_cli(capsys, "identify", path, "--json", json_path, "--order", "4")
    assert code == 0, err
    assert f"record: {repr(str(path))}\n" in out and f"-> {repr(str(json_path))}\n" in out, out
    assert "\x1b" not in out + err, out + err


def test_an_error_naming_a_record_with_esc_is_one_escaped_line(tmp_path: Path, capsys) -> None:
    path = tmp_path / "gone\x1b\n.npz"
    code, out, err = run_cli(capsys, "identify", path, "--json", tmp_path / "m.json")
    assert_one_line_error(code, err, f"{repr(str(path))}: no such file")
    assert "\x1b" not in err


def test_a_name_that_is_no_utf8_is_shown_on_a_strict_utf8_stdout(tmp_path: Path) -> None:
    path = _record(tmp_path / os.fsdecode(b"run\xff.npz"))
    env = {**os.environ, "PYTHONIOENCODING": "utf-8", "PYTHONPATH": os.pathsep.join([str(_REPO), *sys.path])}
    done = subprocess.run([sys.executable, "-m", "okid_ros.cli", "identify", path, "--json", tmp_path / "m.json",
                           "--order", "4"], capture_output=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr.decode(errors="replace")
    assert f"record: {repr(str(path))}\n".encode() in done.stdout, done.stdout


def test_a_parameter_file_named_with_a_tab_is_shown_quoted_in_its_errors_and_warnings(tmp_path: Path, capsys) -> None:
    """Was the name raw, its tab a blank in the one-line message: ``bad p.yaml: parameter arx.order ...``."""
    bad = tmp_path / "bad\tp.yaml"
    bad.write_text("/**:\n  ros__parameters:\n    arx.order: ten\n")
    code, _, err = run_cli(capsys, "process", tmp_path / "no_bag", "--params", bad, "--out", tmp_path / "out")
    assert_one_line_error(code, err, f"{repr(str(bad))}: parameter arx.order must be a number, got 'ten'")
    unknown = tmp_path / "unknown\x1bp.yaml"
    unknown.write_text("/**:\n  ros__parameters:\n    arx.ordr: 10\n")
    code, _, err = run_cli(capsys, "process", tmp_path / "no_bag", "--params", unknown, "--out", tmp_path / "out")
    assert f"warning: {repr(str(unknown))}: section '/**': unknown parameter(s) arx.ordr" in err, err
    assert code == 2 and "\x1b" not in err


def test_a_bag_named_with_a_tab_whose_metadata_is_missing_is_shown_quoted(tmp_path: Path, capsys) -> None:
    """The warning of an MCAP read without its metadata.yaml showed the bag's name raw."""
    bag = write_bag_without_inputs(tmp_path / "no\tmeta")
    (bag / "metadata.yaml").unlink()
    code, _, err = run_cli(capsys, "export", bag, "--npz", tmp_path / "r.npz")
    assert f"warning: {repr(str(bag))}: metadata.yaml missing or unreadable" in err, err
    assert code == 2 and "\t" not in err


def test_a_bag_that_cannot_be_created_is_named_once_with_the_reason(tmp_path: Path, capsys) -> None:
    """Was the path twice: ``cannot create the bag ([Errno 2] No such file or directory: '/proc/x<TAB>bag')``."""
    code, _, err = run_cli(capsys, "simulate", "--out", "/proc/x\tbag", "--duration", "1")
    assert_one_line_error(code, err, "'/proc/x\\tbag': cannot create the bag (No such file or directory)")
    assert err.count("x\\tbag") == 1


def test_a_remap_given_twice_shows_its_topics_quoted() -> None:
    from okid_ros.tools.errors import ToolParameterError
    from okid_ros.tools.replay import parse_remaps

    with pytest.raises(ToolParameterError) as refused:
        parse_remaps(["/a\tb:=/x", "/a\tb:=/y\x1b"])
    assert str(refused.value) == "--remap '/a\\tb' is given twice, to /x and to '/y\\x1b': a topic is published on one"
