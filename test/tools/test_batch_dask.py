"""`okid-ros batch --scheduler`: the campaign of test_batch.py on real Dask clusters.

A LocalCluster of worker processes, and a scheduler and workers started as separate programs
(`dask scheduler`, `dask worker`, bound to 127.0.0.1 on free ports, stopped at teardown);
both must give the serial run's table bit for bit.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from batch_helpers import batch, build_campaign, read_summary, table_rows
from ros_helpers import REPO_ROOT


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> dict:
    """The campaign of batch_helpers.build_campaign, run serially once for the module."""
    campaign = build_campaign(tmp_path_factory.mktemp("campaign_dask"))
    assert campaign["status"] == 1
    return campaign


def _assert_same_as_serial(out: Path, campaign: dict) -> None:
    assert (out / "modes.parquet").read_bytes() == (campaign["serial"] / "modes.parquet").read_bytes()
    assert table_rows(out) == table_rows(campaign["serial"])
    summary = read_summary(out)
    assert summary["run_001_cut"]["status"] == "failed" and "run_001_cut" in summary["run_001_cut"]["reason"]
    assert [summary[f"run_{i:03d}"]["status"] for i in range(3)] == ["ok", "ok", "ok"]


def test_local_cluster_of_worker_processes_gives_the_serial_table(campaign, tmp_path):
    import distributed  # the okid_ros[dask] extra; imported here, not by every pytest session's collection

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        out = tmp_path / "dask"
        assert batch(campaign["bags"], "--params", campaign["params"], "--out", out,
                     "--scheduler", cluster.scheduler_address) == 1
        _assert_same_as_serial(out, campaign)
        # and a rerun on the cluster has nothing to send
        assert batch(campaign["bags"], "--params", campaign["params"], "--out", out,
                     "--scheduler", cluster.scheduler_address) == 1
        assert all(row["reused"] == "True" for row in read_summary(out).values())
        _max_failures_on(cluster.scheduler_address, campaign, tmp_path)


def _max_failures_on(address: str, campaign: dict, tmp_path: Path) -> None:
    """--max-failures with every bag already sent: bags not started are cancelled and reported skipped."""
    bags = tmp_path / "bags"
    bags.mkdir()
    for name in ("a_garbage.mcap", "b_garbage.mcap"):
        (bags / name).write_bytes(b"not a bag")
    for i in range(3):
        shutil.copytree(campaign["bags"] / f"run_{i:03d}", bags / f"c_run_{i}")
    out = tmp_path / "stopped"
    assert batch(bags, "--params", campaign["params"], "--out", out, "--scheduler", address, "--max-failures", 1) == 1
    summary = read_summary(out)
    assert {row["status"] for row in summary.values()} <= {"ok", "failed", "skipped"}
    assert sum(row["status"] == "failed" for row in summary.values()) >= 1
    journaled = (out / "manifest.jsonl").read_text().count("\n")
    assert journaled == sum(row["status"] != "skipped" for row in summary.values())
    assert batch(bags, "--params", campaign["params"], "--out", out, "--scheduler", address) == 1
    summary = read_summary(out)
    assert [summary[f"c_run_{i}"]["status"] for i in range(3)] == ["ok", "ok", "ok"]
    assert summary["b_garbage.mcap"]["status"] == "failed"


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _dask_program(*args: str, log: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT), "OPENBLAS_NUM_THREADS": "1"}
    dask = Path(sys.executable).with_name("dask")
    with open(log, "w") as stream:
        return subprocess.Popen([str(dask), *args], env=env, stdout=stream, stderr=subprocess.STDOUT,
                                start_new_session=True)


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=5)


@pytest.fixture
def dask_programs(tmp_path):
    """`dask scheduler` and `dask worker` (2 processes) as separate programs; yields the address."""
    import distributed  # the okid_ros[dask] extra; imported here, not by every pytest session's collection

    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    scheduler = _dask_program("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard",
                              log=tmp_path / "scheduler.log")
    worker = _dask_program("worker", address, "--host", "127.0.0.1", "--nworkers", "2", "--nthreads", "1",
                           "--no-dashboard", "--local-directory", str(tmp_path / "dask-worker"),
                           log=tmp_path / "worker.log")
    try:
        deadline = time.monotonic() + 90
        while True:
            try:
                with distributed.Client(address, timeout="5s") as client:
                    client.wait_for_workers(2, timeout=max(1.0, deadline - time.monotonic()))
                break
            except (OSError, TimeoutError):
                if time.monotonic() > deadline or scheduler.poll() is not None:
                    raise AssertionError("dask scheduler/worker did not start:\n"
                                         + (tmp_path / "scheduler.log").read_text()
                                         + (tmp_path / "worker.log").read_text()) from None
                time.sleep(0.5)
        yield address
    finally:
        _stop(worker)
        _stop(scheduler)


def test_scheduler_and_workers_as_separate_programs_give_the_serial_table(campaign, dask_programs, tmp_path):
    out = tmp_path / "dask"
    assert batch(campaign["bags"], "--params", campaign["params"], "--out", out, "--scheduler", dask_programs) == 1
    _assert_same_as_serial(out, campaign)


def test_an_unreachable_scheduler_is_a_usage_error(campaign, tmp_path, capsys):
    address = f"tcp://127.0.0.1:{_free_port()}"
    assert batch(campaign["bags"] / "run_000", "--params", campaign["params"], "--out", tmp_path / "x",
                 "--scheduler", address, "--scheduler-timeout", "1") == 2
    assert "cannot connect within 1 s" in capsys.readouterr().err
