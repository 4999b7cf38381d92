"""Node 2's realization pool stopped at shutdown: worker ended, manager thread joined (no ROS needed).

Python 3.11's exit handler races a pool manager thread still closing its wake-up pipe and printed
"OSError: Bad file descriptor" after Ctrl-C (test_nodes_shutdown.py saw it now and then); the
thread must have ended when close() returns.
"""

from __future__ import annotations

import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor

from okid_ros.nodes.modal_estimator_node import stop_process_pool


def test_a_busy_pool_is_stopped_with_its_manager_thread_ended():
    pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))
    job = pool.submit(time.sleep, 60.0)  # a realization under way
    deadline = time.monotonic() + 30.0
    while not job.running() and time.monotonic() < deadline:
        time.sleep(0.01)
    manager = pool._executor_manager_thread
    workers = list(pool._processes.values())
    started = time.monotonic()
    stop_process_pool(pool, timeout_s=10.0)
    assert time.monotonic() - started < 10.0  # not the 60 s job
    assert not manager.is_alive()
    assert all(not worker.is_alive() for worker in workers)
