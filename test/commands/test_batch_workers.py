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
from okid_ros.commands import batch
from okid_ros.commands.batch import local_workers, usable_cores


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("workers") / "bags"
    for seed in (1, 2, 3):
        assert main(["simulate", "--out", str(root / f"run_{seed}"), "--duration", "3", "--seed", str(seed)]) == 0
    return root


def test_more_workers_than_cores_are_capped_with_a_warning_and_the_summary_counts_those_that_ran(
        bags, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(batch, "usable_cores", lambda: 2)
    code, out, err = run_cli(capsys, "batch", bags, "--out", tmp_path / "c", "--workers", "99999999999",
                             "--no-progress")
    assert code == 0, err
    assert err == ("okid-ros batch: warning: --workers 99999999999 is more than the 2 cores this process may use: "
                   "2 used (processing a bag is CPU-bound: more processes add memory, not speed)\n")
    assert "3 processed now (2 local worker(s))" in out  # was: (99999999999 local worker(s))
    code, out, err = run_cli(capsys, "batch", bags / "run_1", "--out", tmp_path / "one", "--workers", "2",
                             "--no-progress")
    assert (code, err) == (0, "") and "1 processed now (serial)" in out  # one bag: no pool started
    assert local_workers(None) == 2 and local_workers(1) == 1 and local_workers(2) == 2


def test_the_cores_are_those_of_the_affinity_and_the_container_quota(tmp_path, monkeypatch):
    # Was os.cpu_count(): the host's cores, whatever taskset, a cpuset or `docker --cpus` allowed.
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3, 4, 5, 6, 7})
    cpu_max = tmp_path / "cpu.max"
    cpu_max.write_text("max 100000\n")
    assert usable_cores(cpu_max_path=cpu_max) == 8
    cpu_max.write_text("250000 100000\n")  # --cpus 2.5: two processes keep within it
    assert usable_cores(cpu_max_path=cpu_max) == 2
    cpu_max.write_text("50000 100000\n")  # half a core: still one worker
    assert usable_cores(cpu_max_path=cpu_max) == 1
    cpu_max.write_text("garbage\n")
    assert usable_cores(cpu_max_path=cpu_max) == 8
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3})
    assert usable_cores(cpu_max_path=tmp_path / "absent") == 1
