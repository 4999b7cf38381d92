"""Threads for the independent decompositions of an identification (the same results for any number).

The stabilization diagram decomposes the state matrix of every model order, and the jackknife
realizes the record once per left-out segment: independent LAPACK calls that release the GIL,
so threads run them side by side on the cores a process has. Each task is the call the serial
code makes, on the same arrays, so the results are bit for bit those of one thread
(``test/core/test_output_only_threads.py``). With one worker nothing is threaded (the live
nodes' realizations keep one, beside their sample path).

The standard library's :class:`concurrent.futures.ThreadPoolExecutor` does the threading; this
class only gives the serial case the same interface without a pool.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

__all__ = ["SERIAL", "WorkerThreads"]


class WorkerThreads:
    """``workers`` threads (none for 1), a context manager that joins them on exit.

    Parameters
    ----------
    workers : threads for the tasks (1: each task runs in the calling thread when submitted).
    """

    def __init__(self, workers: int = 1) -> None:
        self.workers = int(workers)
        self._pool = (ThreadPoolExecutor(self.workers, thread_name_prefix="okid_worker")
                      if self.workers > 1 else None)

    def map(self, function: Callable[[Any], Any], items: Iterable[Any]) -> list:
        """``[function(item) for item in items]``, the items shared among the threads."""
        if self._pool is None:
            return [function(item) for item in items]
        return list(self._pool.map(function, items))

    def submit(self, function: Callable[..., Any], *args: Any) -> Future:
        """A future of ``function(*args)`` (with one worker already done: an error raises here)."""
        if self._pool is not None:
            return self._pool.submit(function, *args)
        future: Future = Future()
        future.set_result(function(*args))
        return future

    def __enter__(self) -> WorkerThreads:
        return self

    def __exit__(self, *exc_info) -> None:
        if self._pool is not None:  # a task still queued after an error is not started
            self._pool.shutdown(wait=True, cancel_futures=True)


#: No threads: what the functions that take ``threads`` use by default.
SERIAL = WorkerThreads(1)
