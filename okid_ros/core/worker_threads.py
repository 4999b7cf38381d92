"""Threads for the independent decompositions of an identification (the same results for any number).

The stabilization diagram decomposes the state matrix of every model order, and the jackknife
realizes the record once per left-out segment: independent LAPACK calls that release the GIL,
so threads run them side by side on the cores a process has. Each task is the call the serial
code makes, on the same arrays, so the results are bit for bit those of one thread
(``test/core/test_output_only_threads.py``). With one worker nothing is threaded (the live
nodes' realizations keep one, beside their sample path).

``workers`` counts the calling thread: it never waits idle for the others. In :meth:`map` it takes
items as the others do, and a task it asks the result of that no thread has started yet it runs
itself. So ``workers`` threads are busy at most, and work queued earlier (the jackknife's
replicates, submitted before the diagram) does not hold up work the caller needs now.
The standard library's :class:`concurrent.futures.ThreadPoolExecutor` runs the other threads.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

__all__ = ["SERIAL", "Task", "WorkerThreads"]


class Task:
    """A call submitted to :class:`WorkerThreads`; :meth:`result` runs it in the caller if no thread has begun it."""

    def __init__(self, function: Callable[..., Any], args: tuple, future: Future | None) -> None:
        self._call = (function, args)
        self._future = future
        self._value: Any = None
        self._done = future is None

    def result(self) -> Any:
        """The call's value (its exception raised here)."""
        if not self._done:
            if self._future.cancel():  # not begun: the caller runs it rather than wait for a thread
                function, args = self._call
                self._value = function(*args)
            else:
                self._value = self._future.result()
            self._done, self._future = True, None
        return self._value

    @classmethod
    def ran(cls, function: Callable[..., Any], args: tuple) -> Task:
        """The call run at once, in the calling thread."""
        task = cls(function, args, None)
        task._value = function(*args)
        return task


class WorkerThreads:
    """``workers`` threads counting the caller's (none started for 1); a context manager that joins them.

    Parameters
    ----------
    workers : threads busy at most, the calling thread among them.
    """

    def __init__(self, workers: int = 1) -> None:
        self.workers = int(workers)
        self._pool = (ThreadPoolExecutor(self.workers - 1, thread_name_prefix="okid_worker")
                      if self.workers > 1 else None)

    def map(self, function: Callable[[Any], Any], items: Iterable[Any]) -> list:
        """``[function(item) for item in items]``, the items taken in turn by the caller and the free threads."""
        items = list(items)
        if self._pool is None or len(items) < 2:
            return [function(item) for item in items]
        results: list = [None] * len(items)
        taken = itertools.count()  # its next() is atomic under the GIL: each index is taken once
        stop = []

        def take() -> None:
            while not stop and (i := next(taken)) < len(items):
                results[i] = function(items[i])

        helpers = [self._pool.submit(take) for _ in range(min(self.workers - 1, len(items) - 1))]
        try:
            take()
        finally:
            stop.append(True)  # after an error in the caller the threads take no further item
            for helper in helpers:
                if not helper.cancel():  # one a thread began: wait for its item (its error raised)
                    helper.result()
        return results

    def submit(self, function: Callable[..., Any], *args: Any) -> Task:
        """``function(*args)`` for a free thread (with one worker: run now, an error raised here)."""
        if self._pool is None:
            return Task.ran(function, args)
        return Task(function, args, self._pool.submit(function, *args))

    def __enter__(self) -> WorkerThreads:
        return self

    def __exit__(self, *exc_info) -> None:
        if self._pool is not None:  # a task still queued after an error is not started
            self._pool.shutdown(wait=True, cancel_futures=True)


#: No threads: what the functions that take ``threads`` use by default.
SERIAL = WorkerThreads(1)
