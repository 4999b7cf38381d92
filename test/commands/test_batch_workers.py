"""`okid-ros batch --workers N`: at most one local worker per core (and per bag), and the summary says how many ran.

Hostile sweep of session 31: `--workers 99999999999` was taken and printed as "99999999999 local
worker(s)"; with as many bags it would have started as many processes.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from batch_helpers import write_good_bag, write_params
from cli_helpers import run_cli
from ros_helpers import REPO_ROOT

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
    root, own = tmp_path / "cgroup", tmp_path / "self_cgroup"
    root.mkdir()
    own.write_text("0::/\n")

    def cores() -> int:
        return usable_cores(cgroup_root=root, own_cgroups=own)

    (root / "cpu.max").write_text("max 100000\n")
    assert cores() == 8
    (root / "cpu.max").write_text("250000 100000\n")  # --cpus 2.5: two processes keep within it
    assert cores() == 2
    (root / "cpu.max").write_text("50000 100000\n")  # half a core: still one worker
    assert cores() == 1
    (root / "cpu.max").write_text("garbage\n")
    assert cores() == 8
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3})
    assert usable_cores(cgroup_root=tmp_path / "absent", own_cgroups=tmp_path / "absent") == 1


def test_the_quotas_of_cgroup_v1_and_of_the_cgroups_above_bind_too(tmp_path, monkeypatch):
    # Only /sys/fs/cgroup/cpu.max was read: a cgroup v1 host's quota (docker on an older host) and a
    # limit set on a parent cgroup (a slice, a pod) were not seen, and batch started a process per
    # host core.
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(16)))
    root, own = tmp_path / "cgroup", tmp_path / "self_cgroup"
    v1 = root / "cpu,cpuacct" / "docker" / "abc"
    v1.mkdir(parents=True)
    (v1 / "cpu.cfs_quota_us").write_text("300000\n")
    (v1 / "cpu.cfs_period_us").write_text("100000\n")
    own.write_text("4:memory:/docker/abc\n3:cpu,cpuacct:/docker/abc\n0::/\n")
    assert usable_cores(cgroup_root=root, own_cgroups=own) == 3
    (v1 / "cpu.cfs_quota_us").write_text("-1\n")  # no limit
    assert usable_cores(cgroup_root=root, own_cgroups=own) == 16
    slice_, leaf = root / "pods.slice", root / "pods.slice" / "pod1" / "ctr"
    leaf.mkdir(parents=True)
    (slice_ / "cpu.max").write_text("200000 100000\n")  # the parent's limit
    (leaf / "cpu.max").write_text("max 100000\n")
    own.write_text("0::/pods.slice/pod1/ctr\n")
    assert usable_cores(cgroup_root=root, own_cgroups=own) == 2


# `okid-ros batch --workers 2` in a process of its own, its cores set to 2 whatever this machine has.
_BATCH_2 = ("import sys; from okid_ros.commands import batch; batch.usable_cores = lambda: 2; "
            "from okid_ros.cli import main; sys.exit(main(sys.argv[1:]))")


def _stat(pid: int) -> tuple[str, int] | None:
    """(state, parent pid) of a process from /proc (Linux), None when it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return fields[0], int(fields[1])


def _forked_children(parent: int) -> list[int]:
    """The pool's workers: children running the parent's own command line (forked, not exec'd)."""
    def cmdline(pid: int) -> bytes:
        try:
            return Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            return b""

    pids = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit()]
    return [pid for pid in pids if (_stat(pid) or ("", 0))[1] == parent and cmdline(pid) == cmdline(parent)]


def _gone(pid: int) -> bool:
    stat = _stat(pid)
    return stat is None or stat[0] in "ZX"  # a zombie is dead, not yet reaped by its new parent


def test_the_pool_workers_die_with_a_killed_batch(tmp_path):
    # Was: SIGKILL (the OOM killer, kill -9) left both workers running the queued bags, then blocked
    # forever on a pipe, ~140 MB each.
    for index in range(6):
        write_good_bag(tmp_path / "bags" / f"b{index}", index)
    command = [sys.executable, "-c", _BATCH_2, "batch", str(tmp_path / "bags"), "--params",
               str(write_params(tmp_path / "p.yaml")), "--out", str(tmp_path / "c"), "--workers", "2", "--no-progress"]
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT), "OPENBLAS_NUM_THREADS": "1"}
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 60
        while len(workers) < 2:
            assert process.poll() is None and time.monotonic() < deadline, "batch ended before its pool started"
            time.sleep(0.05)
            workers = _forked_children(process.pid)
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=10)
        deadline = time.monotonic() + 5
        while not all(map(_gone, workers)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert [pid for pid in workers if not _gone(pid)] == []
    finally:
        process.kill()
        for pid in workers:
            if not _gone(pid):
                os.kill(pid, signal.SIGKILL)  # the old code's orphans: not left on the machine
