"""`okid-ros batch --workers N`: at most one local worker per core (and per bag), and the summary says how many ran.

Hostile sweep of session 31: `--workers 99999999999` was taken and printed as "99999999999 local
worker(s)"; with as many bags it would have started as many processes.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from cli_helpers import run_cli

from okid_ros.cli import main
from okid_ros.commands.batch import local_workers


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("workers") / "bags"
    for seed in (1, 2, 3):
        assert main(["simulate", "--out", str(root / f"run_{seed}"), "--duration", "3", "--seed", str(seed)]) == 0
    return root


def test_more_workers_than_cores_are_capped_with_a_warning_and_the_summary_counts_those_that_ran(
        bags, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    code, out, err = run_cli(capsys, "batch", bags, "--out", tmp_path / "c", "--workers", "99999999999",
                             "--no-progress")
    assert code == 0, err
    assert err == ("okid-ros batch: warning: --workers 99999999999 is more than the 2 cores of this machine: 2 used "
                   "(processing a bag is CPU-bound: more processes add memory, not speed)\n")
    assert "3 processed now (2 local worker(s))" in out  # was: (99999999999 local worker(s))
    code, out, err = run_cli(capsys, "batch", bags / "run_1", "--out", tmp_path / "one", "--workers", "2",
                             "--no-progress")
    assert (code, err) == (0, "") and "1 processed now (serial)" in out  # one bag: no pool started
    assert local_workers(None) == 2 and local_workers(1) == 1 and local_workers(2) == 2
