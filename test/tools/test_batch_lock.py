"""`okid-ros batch`: one run at a time on a campaign directory, and the folders a killed run left.

A second run on the same DIR is refused while the first runs (campaign/lock.py); the next run removes
the ``bags/.tmp-*`` (and ``.old-*``) folders a killed one left, which no run removed before.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

from batch_helpers import batch, read_summary, write_good_bag, write_params
from ros_helpers import REPO_ROOT


def test_the_folders_a_killed_run_left_are_removed_by_the_next_run(tmp_path, capsys):
    bag = write_good_bag(tmp_path / "in" / "run_000", 0)
    params = write_params(tmp_path / "params.yaml")
    out = tmp_path / "c"
    assert batch(bag, "--params", params, "--out", out, "--workers", 1) == 0
    done = (out / "bags").iterdir().__next__()
    # What kills leave: a worker's folder (SIGKILL mid-bag) and a bag's old folder (killed mid-replace).
    (out / "bags" / ".tmp-run_000-deadbeef" / "output").mkdir(parents=True)
    (out / "bags" / f".old-{done.name}-cafebabe").mkdir()
    capsys.readouterr()
    assert batch(bag, "--params", params, "--out", out, "--workers", 1) == 0
    err = capsys.readouterr().err
    assert "removed 2 unfinished folder(s) under" in err and err.count("removed") == 1, err
    assert sorted(p.name for p in (out / "bags").iterdir()) == [done.name]
    assert read_summary(out)["run_000"]["reused"] == "True"  # the bag done before is kept as it was
    # A first run killed before any bag was done: its folder is a campaign, continued by the next run.
    first = tmp_path / "first"
    killed = _started(bag, params, first)
    killed.kill()  # SIGKILL: no clean-up of any kind
    killed.wait()
    assert batch(bag, "--params", params, "--out", first, "--workers", 1) == 0
    assert [p.name for p in (first / "bags").iterdir() if p.name.startswith(".")] == []
    assert read_summary(first)["run_000"]["status"] == "ok"


def test_a_second_run_on_a_campaign_is_refused_while_the_first_runs(tmp_path, capsys):
    params = write_params(tmp_path / "params.yaml")
    out = tmp_path / "c"
    assert batch(write_good_bag(tmp_path / "in" / "run_000", 0), "--params", params, "--out", out) == 0
    write_good_bag(tmp_path / "in" / "run_001", 1, duration_s=30.0)  # new: a few seconds of work
    first = _started(tmp_path / "in", params, out)
    capsys.readouterr()
    assert batch(tmp_path / "in", "--params", params, "--out", out, "--workers", 1, "--force") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert f"--out {out}: another okid-ros batch is running on this campaign (pid {first.pid} on " in err, err
    assert first.wait(timeout=300) == 0, first.stderr.read()
    # Nothing was lost to the second run: both bags identified, journaled and in the tables.
    summary = read_summary(out)
    assert [summary[name]["status"] for name in ("run_000", "run_001")] == ["ok", "ok"]
    assert summary["run_000"]["reused"] == "True" and summary["run_001"]["reused"] == "False"
    assert [p.name for p in (out / "bags").iterdir() if p.name.startswith(".")] == []


def _started(bag, params, out) -> subprocess.Popen:
    """`okid-ros batch BAG --out OUT` in a process of its own, returned once it is processing the bag."""
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    process = subprocess.Popen([sys.executable, "-m", "okid_ros.cli", "batch", str(bag), "--params", str(params),
                                "--out", str(out), "--workers", "1", "--no-progress"], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / "bags").is_dir() or not any((out / "bags").glob(".tmp-*")):
        assert process.poll() is None and time.monotonic() < deadline, "batch ended before it processed the bag"
        time.sleep(0.01)
    return process
