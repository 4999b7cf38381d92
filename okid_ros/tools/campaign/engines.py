"""Where the bags of a campaign run: in this process, a local process pool, or a Dask cluster.

Every engine calls the same :func:`~okid_ros.tools.campaign.worker.run_bag_job` once per bag and
hands each result to ``on_result`` as it finishes (in completion order; the caller orders the
table afterwards, so the engine does not change a bit of it). ``on_result`` returns True to
stop early (``--max-failures``): bags not started are cancelled and returned as not run; bags
already running finish and are delivered, so nothing done is lost.

The local pool forks this process (Linux), so a worker starts with the modules the command has
already imported: the per-bag overhead is the bag itself; its workers end with it, even when it
is killed (:func:`okid_ros.tools.parent_death.die_with_parent`). Dask is an optional extra
(``okid_ros[dask]``) imported only for ``--scheduler``.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import uuid
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from okid_ros.errors import OkidError
from okid_ros.tools.campaign import SCHEDULER_TIMEOUT_S
from okid_ros.tools.campaign.worker import BagJob, failed_result, run_bag_job
from okid_ros.tools.parent_death import die_with_parent

__all__ = ["run_jobs"]

OnResult = Callable[[BagJob, dict], bool]


def run_jobs(jobs: list[BagJob], on_result: OnResult, *, workers: int = 1,
             scheduler: str | None = None, scheduler_timeout_s: float = SCHEDULER_TIMEOUT_S) -> list[BagJob]:
    """Run ``jobs``; returns the jobs not run because ``on_result`` asked to stop.

    Parameters
    ----------
    jobs : one per bag, in the order to submit them.
    on_result : called in this process with each job and its result; True stops early.
    workers : local processes (1: in this process); ignored with ``scheduler``.
    scheduler : address of a running Dask distributed scheduler (``tcp://host:8786``).
    scheduler_timeout_s : how long to try to connect to ``scheduler``.
    """
    if not jobs:
        return []
    if scheduler is not None:
        return _run_dask(jobs, on_result, scheduler, timeout_s=scheduler_timeout_s)
    if workers <= 1 or len(jobs) == 1:
        return _run_serial(jobs, on_result)
    return _run_pool(jobs, on_result, min(workers, len(jobs)))


def _run_serial(jobs: list[BagJob], on_result: OnResult) -> list[BagJob]:
    for i, job in enumerate(jobs):
        if on_result(job, run_bag_job(job)):
            return jobs[i + 1:]
    return []


def _pool_context() -> multiprocessing.context.BaseContext:
    """Fork where there is one (children inherit the imports), else the platform's default."""
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("fork" if "fork" in methods else None)


def _pool_worker_init(parent_pid: int) -> None:
    """A pool worker ends with the command, however the command ends.

    Killed (SIGKILL, the OOM killer), the command cannot stop its pool: the workers went on with
    the bags queued, then waited forever on a pipe (~140 MB each). SIGKILL, not SIGTERM: a worker
    forked from the command inherits its SIGTERM handler, which raises KeyboardInterrupt in the
    bag under way: the worker sends it back as the bag's error and waits for the next bag, forever.
    What a worker killed so leaves is a ``bags/.tmp-*`` folder, never a table or a journal line; the
    next run on the campaign removes it (campaign/lock.py).
    """
    die_with_parent(parent_pid, signal.SIGKILL)


def _run_pool(jobs: list[BagJob], on_result: OnResult, workers: int) -> list[BagJob]:
    # A few bags in flight per worker, not all of them: cancelling the rest at a stop is then exact
    # and the pool's queues stay small for thousands of bags.
    pending = list(reversed(range(len(jobs))))
    running: dict[Future, int] = {}
    with ProcessPoolExecutor(max_workers=workers, mp_context=_pool_context(), initializer=_pool_worker_init,
                             initargs=(os.getpid(),)) as pool:
        try:
            _drain(pool, jobs, pending, running, on_result, workers)
        except KeyboardInterrupt:
            pool.shutdown(wait=False, cancel_futures=True)  # what finished is journaled already
            raise
    return [jobs[i] for i in reversed(pending)]


def _drain(pool: ProcessPoolExecutor, jobs: list[BagJob], pending: list[int], running: dict[Future, int],
           on_result: OnResult, workers: int) -> None:
    """Submit and collect until every job ran, or ``on_result`` stopped (``pending`` then holds the rest)."""
    stopped = False
    while pending or running:
        while pending and not stopped and len(running) < 2 * workers:
            try:
                running[pool.submit(run_bag_job, jobs[pending[-1]])] = pending[-1]
            except BrokenProcessPool:  # a worker died (killed, out of memory): the rest cannot run here
                for index in reversed(pending):
                    on_result(jobs[index], failed_result(jobs[index], f"{jobs[index].display}: not run, a worker "
                                                         "process of the pool died", transient=True))
                pending.clear()
                break
            pending.pop()
        done, _ = wait(running, return_when=FIRST_COMPLETED)
        for future in sorted(done, key=running.__getitem__):
            job = jobs[running.pop(future)]
            try:
                result = future.result()
            except Exception as exc:  # noqa: BLE001 - a worker process died (killed, out of memory)
                result = failed_result(job, f"{job.display}: worker failed ({type(exc).__name__}: {exc})",
                                       transient=True)
            stopped = on_result(job, result) or stopped
        if stopped and not running:
            return


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise OkidError("--scheduler needs Dask distributed: pip install 'okid_ros[dask]' "
                        "(or dask[distributed])") from None
    return distributed


def _run_dask(jobs: list[BagJob], on_result: OnResult, address: str, *, timeout_s: float) -> list[BagJob]:
    distributed = _import_distributed()
    try:
        client = distributed.Client(address, timeout=f"{timeout_s}s", set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise OkidError(f"--scheduler {address}: cannot connect within {timeout_s:g} s "
                        f"({type(exc).__name__}: {exc})") from None
    try:
        # pure=False: a rerun with --force must run again; the key names the bag in the dashboard.
        run = uuid.uuid4().hex[:8]  # two campaigns on one cluster never share a key
        futures = {client.submit(run_bag_job, job, pure=False, key=f"okid-batch-{job.label}-{run}-{i}"): job
                   for i, job in enumerate(jobs)}
        finished: set = set()
        stopped = False
        for future in distributed.as_completed(list(futures), loop=client.loop):
            job = futures[future]
            finished.add(future)
            if future.cancelled():
                continue
            try:
                result = future.result()
            except Exception as exc:  # noqa: BLE001 - the task itself failed (a worker died, a missing module)
                result = failed_result(job, f"{job.display}: Dask task failed ({type(exc).__name__}: {exc})",
                                           transient=True)
            if on_result(job, result) and not stopped:
                stopped = True
                waiting = [f for f in futures if f not in finished and f.status == "pending"]
                client.cancel(waiting)
        return [futures[f] for f in futures if f.cancelled()]
    finally:
        client.close()
