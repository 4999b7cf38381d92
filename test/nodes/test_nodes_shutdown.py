"""Ctrl-C twice, and Ctrl-C while node 2 realizes: each node stops quietly (okid_ros/nodes/runner.py).

A terminal's Ctrl-C reaches the node's whole process group (node 2's realization worker too),
and ``ros2 launch`` passes a second one on while it stops its nodes. The nodes run as
processes in a session of their own, with the shipped config/okid.yaml and diagnostics at
100 Hz (their publishing off the sample path meets the shutdown); the test sends SIGINT to the
group, then again every 20 ms until the process has ended.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest
from ros_helpers import REPO_ROOT

pytestmark = [pytest.mark.dds, pytest.mark.dds_startup]  # start-ups and exits only: `make test` runs it in parallel

MODULES = ("arx_identifier_node", "modal_estimator_node")
FAST_DIAGNOSTICS = "/**:\n  ros__parameters:\n    diagnostics_rate_hz: 100.0\n"


def interrupt_until_gone(proc, every_s: float = 0.02, timeout_s: float = 10.0) -> tuple[int, int]:
    """SIGINT to the process group, again every ``every_s`` until the process ends: (exit status, count)."""
    sent = 0
    deadline = time.monotonic() + timeout_s
    while proc.proc.poll() is None and time.monotonic() < deadline:
        try:
            os.killpg(proc.proc.pid, signal.SIGINT)
        except ProcessLookupError:
            break
        sent += 1
        time.sleep(every_s)
    return proc.proc.wait(timeout=10), sent


def after_ready(proc) -> list[str]:
    """The lines the node printed after its "ready" line."""
    out = proc.output()
    return out[out.index("ready:"):].splitlines()[1:]


@pytest.mark.parametrize("module", MODULES)
@pytest.mark.parametrize("settle_s", [0.3, 3.0])  # node 2's worker still importing the core, then idle
def test_ctrl_c_twice_stops_the_node_quietly(spawn_ros, tmp_path, module, settle_s):
    params = tmp_path / "fast_diagnostics.yaml"
    params.write_text(FAST_DIAGNOSTICS)
    proc = spawn_ros("-m", f"okid_ros.nodes.{module}", "--ros-args", "--params-file",
                     str(REPO_ROOT / "config" / "okid.yaml"), "--params-file", str(params))
    proc.wait_for_output(r"ready:", timeout_s=60)
    time.sleep(settle_s)
    status, sent = interrupt_until_gone(proc)
    # It was: a KeyboardInterrupt traceback from the interpreter's wait for the pool at exit, or
    # from node 2's worker interrupted in its imports, or the process killed by the late one (-2).
    assert status == 0, (status, proc.output()[-3000:])
    assert sent >= 2
    assert after_ready(proc) == [], proc.output()[-3000:]


def test_node_2_ends_a_realization_under_way_when_it_stops(ros_domain_id):
    # The process waited at exit for the realization in its worker (seconds; 10 s measured with
    # a slowed one), and a Ctrl-C meanwhile is ignored now: the worker is ended instead.
    import rclpy

    from okid_ros.nodes.modal_estimator_node import ModalEstimatorNode

    context = rclpy.Context()
    rclpy.init(context=context)
    node = ModalEstimatorNode(context=context)
    try:
        running = node._pool.submit(time.sleep, 20.0)  # a realization that takes long
        deadline = time.monotonic() + 60
        while not running.running() and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = list(node._pool._processes.values())
        assert running.running() and len(workers) == 1
        pid = workers[0].pid
        started = time.monotonic()
        node.close()
        # Asked of the OS: the pool's own thread may reap the worker first, and then
        # Process.is_alive() cannot tell (its waitpid fails and it answers "alive").
        while _running(pid) and time.monotonic() - started < 5:
            time.sleep(0.05)
        assert not _running(pid), f"worker {pid} still running {time.monotonic() - started:.1f} s after close()"
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists and has not ended (a zombie has ended)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        # The process can be reaped between opening its stat file and reading it (ESRCH).
        return False
    return stat.rsplit(")", 1)[-1].split()[0] not in ("Z", "X")
