"""The benchmarks' files: never replaced without --force (bench/okid_bench/report.py), before any work."""

from __future__ import annotations

import argparse

import identification_accuracy
import mode_uncertainty
import pytest

from okid_bench.report import add_output_options, refuse_existing, write_output


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    add_output_options(parser, json=True)
    return parser


def test_an_existing_output_is_refused_without_force_and_replaced_with_it(tmp_path, capsys):
    out, raw = tmp_path / "table.md", tmp_path / "sub" / "raw.json"
    parser = _parser()
    args = parser.parse_args(["--out", str(out), "--json", str(raw)])
    refuse_existing(parser, args)  # neither exists
    write_output(args.out, "first")
    write_output(args.json, "{}")  # its folder made
    assert out.read_text() == "first" and raw.read_text() == "{}"
    for argv in (["--out", str(out)], ["--json", str(raw)]):
        with pytest.raises(SystemExit) as refused:
            refuse_existing(parser, parser.parse_args(argv))
        assert refused.value.code == 2 and "add --force" in capsys.readouterr().err
    refuse_existing(parser, parser.parse_args(["--out", str(out), "--json", str(raw), "--force"]))
    empty = parser.parse_args(["--out", ""])  # no file, as an untyped --out "" was before
    assert empty.out is None
    refuse_existing(parser, empty)
    write_output(None, "nothing")  # no path: nothing written


@pytest.mark.parametrize("bench", [identification_accuracy, mode_uncertainty])
def test_the_benchmarks_that_replaced_their_tables_now_refuse_before_they_run(bench, tmp_path, capsys):
    # Both overwrote --out and --json in silence after a run of up to an hour.
    out = tmp_path / "table.md"
    out.write_text("the last run's table")
    with pytest.raises(SystemExit) as refused:
        bench.main(["--out", str(out), "--seeds", "1"])
    assert refused.value.code == 2 and "add --force" in capsys.readouterr().err
    assert out.read_text() == "the last run's table"
