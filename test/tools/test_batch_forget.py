"""`okid-ros batch --forget BAG... --out DIR`: a bag taken out of a campaign's journal and tables.

There was no way to take a bag (a bad run, a test recording) out of a campaign: the tables hold
every bag of the journal, given or not (campaign/forget.py).
"""

from __future__ import annotations

import json
import shutil

from batch_helpers import batch, read_summary, table_rows, write_bag_without_inputs, write_good_bag, write_params

from okid_ros.tools.campaign.lock import campaign_lock


def _journal_names(out) -> list[str]:
    lines = (out / "manifest.jsonl").read_text().splitlines()
    return sorted(json.loads(line)["key"].rsplit("/", 1)[-1] for line in lines)


def test_forget_takes_bags_out_of_the_journal_and_tables_and_keeps_their_outputs_unless_forced(tmp_path, capsys):
    params, out, inputs = write_params(tmp_path / "params.yaml"), tmp_path / "c", tmp_path / "in"
    for index in range(2):
        write_good_bag(inputs / f"run_{index:03d}", index)
    write_bag_without_inputs(inputs / "test_recording.mcap")
    assert batch(inputs, "--params", params, "--out", out, "--workers", 1) == 1
    folders = {name: row["outputs"] for name, row in read_summary(out).items()}
    capsys.readouterr()
    # By name (as a shell completes a folder: run_001/, refused before unless cwd held it): its line and
    # rows gone, its folder kept (and said), nothing processed.
    assert batch("--forget", "run_001/", "--params", params, "--out", out) == 0
    captured = capsys.readouterr()
    assert f"forgot 1 bag(s) of the campaign: {inputs.resolve() / 'run_001'}\n" in captured.err, captured.err
    assert f"kept their outputs under {out / 'bags'}: {folders['run_001'][5:]} (--force removes them)" in captured.err
    assert "0 processed now" in captured.out
    assert sorted(read_summary(out)) == ["run_000", "test_recording.mcap"] == _journal_names(out)
    assert {row["bag"].rsplit("/", 1)[-1] for row in table_rows(out)} == {"run_000"}
    assert (out / folders["run_001"] / "result.json").is_file()
    # A name the journal does not hold is refused, naming those it holds; nothing changes.
    assert batch("--forget", "run_001", "--out", out) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert f"--forget run_001: no bag of the campaign {out} has that path, name or output folder (its journal " \
           "holds run_000, test_recording.mcap)" in err, err
    # By path, the bag itself deleted (a failed test recording), and by output folder with --force: removed.
    shutil.rmtree(inputs / "test_recording.mcap")
    assert batch("--forget", inputs / "test_recording.mcap", folders["run_000"], "--force", "--out", out) == 0
    assert f"removed their outputs under {out / 'bags'} (--force): {folders['run_000'][5:]}" in capsys.readouterr().err
    assert read_summary(out) == {} and table_rows(out) == [] and _journal_names(out) == []
    assert sorted(p.name for p in (out / "bags").iterdir()) == [folders["run_001"][5:]]
    # Given again, a forgotten bag is processed again.
    assert batch(inputs / "run_001", "--params", params, "--out", out, "--workers", 1) == 0
    assert read_summary(out)["run_001"]["reused"] == "False"


def test_forget_is_refused_with_bags_to_process_outside_a_campaign_and_while_another_run_holds_it(tmp_path, capsys):
    params, out = write_params(tmp_path / "params.yaml"), tmp_path / "c"
    bag = write_good_bag(tmp_path / "in" / "run_000", 0)
    assert batch(bag, "--params", params, "--out", out, "--workers", 1) == 0
    summary = (out / "summary.csv").read_text()
    capsys.readouterr()
    assert batch(bag, "--forget", "run_000", "--out", out) == 2
    assert "--forget BAG... processes and plans no bag: " in capsys.readouterr().err
    assert batch("--out", out) == 2
    assert "give the bags to process (BAG_OR_DIR...), or --forget BAG... --out DIR" in capsys.readouterr().err
    other = tmp_path / "not_a_campaign"
    other.mkdir()
    assert batch("--forget", "run_000", "--out", other) == 2
    assert f"--out {other}: not a campaign of okid-ros batch (no manifest.jsonl)" in capsys.readouterr().err
    with campaign_lock(out):
        assert batch("--forget", "run_000", "--out", out) == 2
    assert "another okid-ros batch is running on this campaign" in capsys.readouterr().err
    assert (out / "summary.csv").read_text() == summary and _journal_names(out) == ["run_000"]
    shutil.rmtree(out / "bags")  # a forgotten bag whose folder is gone: nothing to keep or remove
    assert batch("--forget", "run_000", "--force", "--out", out) == 0
    assert "outputs" not in capsys.readouterr().err


def test_forget_warns_of_the_options_of_processing_and_refuses_a_name_several_bags_share(tmp_path, capsys):
    params, out = write_params(tmp_path / "params.yaml"), tmp_path / "c"
    first, second = write_good_bag(tmp_path / "a" / "run_000", 0), write_good_bag(tmp_path / "b" / "run_000", 1)
    assert batch(first, second, "--params", params, "--out", out, "--workers", 1) == 0
    summary = (out / "summary.csv").read_text()
    capsys.readouterr()
    # Both bags are run_000: the name is refused, naming their paths; nothing changes.
    assert batch("--forget", "run_000", "--params", params, "--out", out) == 2
    err = capsys.readouterr().err
    assert f"--forget run_000: names 2 bags of the campaign {out} ({first.resolve()}, {second.resolve()}); give " \
           "the one's path" in err, err
    assert (out / "summary.csv").read_text() == summary and _journal_names(out) == ["run_000", "run_000"]
    # Options of processing bags were passed over in silence: named, ignored, the bag forgotten by its path.
    assert batch("--forget", first, "--params", params, "--out", out, "--workers", 2, "--retry-failed",
                 "--max-failures", 1, "--scheduler-timeout", 3, "--csv") == 0
    err = capsys.readouterr().err
    assert "okid-ros batch: warning: --workers, --scheduler-timeout, --max-failures, --retry-failed: options of " \
           "processing bags; ignored with --forget (it processes no bag)" in err, err
    assert _journal_names(out) == ["run_000"] and (out / "modes.csv").is_file()
    assert batch("--forget", second, "--params", params, "--out", out, "--scheduler", "tcp://127.0.0.1:1") == 0
    assert "warning: --scheduler: options of processing bags" in capsys.readouterr().err


def test_a_journal_line_nested_too_deeply_is_an_unreadable_line() -> None:
    # json's RecursionError ended batch with an internal error (exit 70) at its journal's reading.
    import tempfile
    from pathlib import Path

    from okid_ros.tools.campaign.manifest import Manifest

    with tempfile.TemporaryDirectory() as folder:
        (Path(folder) / "manifest.jsonl").write_text("[" * 100_000 + "]" * 100_000 + "\n{}\n")
        assert Manifest(Path(folder)).unreadable == 1


def test_forget_says_the_journal_lines_it_cannot_read(tmp_path, capsys):
    # The journal is rewritten without them, as by any run; a run processing bags said so, --forget
    # dropped them in silence.
    params, out = write_params(tmp_path / "params.yaml"), tmp_path / "c"
    for index in range(2):
        write_good_bag(tmp_path / "in" / f"run_{index:03d}", index)
    assert batch(tmp_path / "in", "--params", params, "--out", out, "--workers", 1) == 0
    with open(out / "manifest.jsonl", "a") as journal:
        journal.write('{"key": "/cut/by/a/crash\n')
    capsys.readouterr()
    assert batch("--forget", "run_000", "--params", params, "--out", out) == 0
    err = capsys.readouterr().err
    assert f"okid-ros batch: warning: {out / 'manifest.jsonl'}: 1 unreadable line(s) ignored (not JSON text): their " \
           "bags are left out of the tables, and processed again when given\n" in err, err
    assert _journal_names(out) == ["run_001"]
