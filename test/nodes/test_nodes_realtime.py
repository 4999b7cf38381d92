"""Node 2's ``realtime_priority``: its own threads at SCHED_FIFO, the realization worker not.

The helper runs in a child interpreter (the test process itself must not become real-time);
the node runs as a process over real DDS. Where the machine refuses SCHED_FIFO (no
CAP_SYS_NICE, ``ulimit -r`` 0), the helper must say so and change nothing.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest
from ros_helpers import REPO_ROOT, RosProcess, subprocess_env

PROBE = r"""
import json, os, threading, time
from okid_ros.nodes.common import realtime_threads

def policies():
    out = {}
    for tid in os.listdir("/proc/self/task"):
        with open(f"/proc/self/task/{tid}/comm") as f:
            out[f.read().strip()] = os.sched_getscheduler(int(tid)) & ~os.SCHED_RESET_ON_FORK
    return out

stop = threading.Event()
before = threading.Thread(target=stop.wait, name="before")
before.start()
refused = realtime_threads(7)
result = {"refused": refused, "after_call": policies()}
later = threading.Thread(target=lambda: result.update(later=os.sched_getscheduler(0)), name="later")
later.start(); later.join()
child = os.fork()
if child == 0:
    os._exit(os.sched_getscheduler(0))
result["child"] = os.waitstatus_to_exitcode(os.waitpid(child, 0)[1])
stop.set(); before.join()
print(json.dumps(result))
"""


def _fifo_allowed() -> bool:
    """Whether this machine lets a process of ours use SCHED_FIFO at all (asked in a child)."""
    probe = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True).returncode == 0


def test_every_running_thread_becomes_fifo_and_nothing_started_later_does():
    run = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=60,
                         cwd=REPO_ROOT)
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout)
    if not _fifo_allowed():
        assert "refused" in result["refused"]
        assert set(result["after_call"].values()) == {os.SCHED_OTHER}  # all or none
        return
    assert result["refused"] == ""
    assert set(result["after_call"].values()) == {os.SCHED_FIFO}, result["after_call"]  # "before" too
    assert result["later"] == os.SCHED_OTHER  # a thread started afterwards (reset on fork)
    assert result["child"] == os.SCHED_OTHER  # a process started afterwards


BLAS_PROBE = r"""
import json, os, threading
from okid_ros.nodes.common import realtime_threads

main = threading.get_native_id()
pool = [int(t) for t in os.listdir("/proc/self/task") if int(t) != main]
refused = realtime_threads(7)
policy = lambda tid: os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK
print(json.dumps({"refused": refused, "main": policy(main), "pool": [policy(t) for t in pool]}))
"""


def test_a_blas_pool_stays_ordinary():
    # With OPENBLAS_NUM_THREADS > 1 OpenBLAS runs worker threads from the moment numpy loads; at
    # SCHED_FIFO they would run any thread's BLAS call real-time (and they spin for work).
    if not _fifo_allowed():
        pytest.skip("this machine refuses SCHED_FIFO (no CAP_SYS_NICE, ulimit -r 0)")
    results = {}
    for blas_threads in ("1", "2"):
        env = dict(os.environ, OPENBLAS_NUM_THREADS=blas_threads)
        run = subprocess.run([sys.executable, "-c", BLAS_PROBE], capture_output=True, text=True, timeout=60,
                             cwd=REPO_ROOT, env=env)
        assert run.returncode == 0, run.stderr
        results[blas_threads] = json.loads(run.stdout)
    assert all(r["refused"] == "" and r["main"] == os.SCHED_FIFO for r in results.values()), results
    # More threads with two BLAS threads: OpenBLAS's workers (numpy's and scipy's libraries have
    # one each), among those that stay ordinary.
    assert len(results["2"]["pool"]) > len(results["1"]["pool"]), results
    assert set(results["2"]["pool"]) == {os.SCHED_OTHER}, results


def _thread_policies(pid: int) -> dict[str, tuple[int, int]]:
    """Policy and nice of each named thread of a process."""
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{tid}/comm") as f:
            name = f.read().strip()
        policy = os.sched_getscheduler(int(tid)) & ~os.SCHED_RESET_ON_FORK
        out[name] = (policy, os.getpriority(os.PRIO_PROCESS, int(tid)))
    return out


def _worker(pid: int) -> int | None:
    """The realization worker process of node 2 (a child named okid_realize, started by any thread)."""
    for tid in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{tid}/children") as f:
            for child in map(int, f.read().split()):
                with open(f"/proc/{child}/comm") as comm:
                    if comm.read().strip() == "okid_realize":
                        return child
    return None


@pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process (the helper's tests with the rest)
def test_node_2_serves_its_samples_at_fifo_and_realizes_at_ordinary_priority(ros_domain_id, tmp_path):
    params = tmp_path / "rt.yaml"
    params.write_text("/**/okid_modal_estimator:\n  ros__parameters:\n    realtime_priority: 10\n")
    proc = RosProcess([sys.executable, "-m", "okid_ros.nodes.modal_estimator_node", "--ros-args",
                       "--params-file", str(REPO_ROOT / "config" / "okid.yaml"), "--params-file", str(params)],
                      subprocess_env(ros_domain_id), REPO_ROOT)
    try:
        proc.wait_for_output(r"ready:", timeout_s=30)
        pid = proc.proc.pid
        deadline = time.monotonic() + 20
        while ("okid_samples" not in _thread_policies(pid) or _worker(pid) is None) and time.monotonic() < deadline:
            time.sleep(0.1)
        threads = _thread_policies(pid)
        if not _fifo_allowed():
            assert "realtime_priority not applied" in proc.output()
            assert threads["okid_samples"][0] == os.SCHED_OTHER
            return
        assert "realtime_priority not applied" not in proc.output()
        assert threads["okid_samples"][0] == os.SCHED_FIFO
        assert os.sched_getparam(pid).sched_priority == 10  # the executor's thread
        if "okid_side" in threads:  # started on the first diagnostics, from a real-time thread
            assert threads["okid_side"][0] == os.SCHED_OTHER
        worker = _worker(pid)
        assert worker is not None, "no realization worker process"
        for name, (policy, nice) in _thread_policies(worker).items():
            assert policy == os.SCHED_OTHER, name
            assert nice >= 10, name
    finally:
        proc.stop()
