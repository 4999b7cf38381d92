"""Ctrl-C and SIGTERM held back while a bag record is being written, raised right after it.

A command ends on Ctrl-C or SIGTERM by ``KeyboardInterrupt`` and closes its outputs. Raised in the
middle of a bag writer's record (its header written, its bytes not), it left a truncated record
that made the whole bag unreadable (``Truncated record at offset ...``). The command line's handler
(:func:`interrupt`) holds the interrupt while :func:`deferred` is entered in the main thread and
raises it when it is left. Python's signal handlers run in the main thread only.
"""

from __future__ import annotations

import contextlib
import threading
from typing import Iterator

__all__ = ["deferred", "interrupt"]

_depth = 0  # deferred() entered in the main thread, how deep
_pending = False  # an interrupt came meanwhile


def interrupt(signum, frame) -> None:
    """Signal handler: ``KeyboardInterrupt`` now, or when the section that holds interrupts ends."""
    global _pending
    if _depth:
        _pending = True
        return
    raise KeyboardInterrupt


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """A section an interrupt does not cut (main thread; elsewhere no signal handler runs anyway)."""
    global _depth, _pending
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0 and _pending:
            _pending = False
            raise KeyboardInterrupt
