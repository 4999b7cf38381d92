"""Child processes that end with their parent, however the parent ends (Linux).

A parent killed by SIGKILL (the OOM killer, ``kill -9``, a CI timeout's hard kill) runs no
cleanup: the processes it started lived on, orphaned. Three kinds of child use this one helper:
node 2's realization worker, `okid-ros up`'s two node processes and `okid-ros batch`'s pool
workers (which went on with the queued bags, then blocked forever on a pipe, ~140 MB each).
No rclpy here: the nodes and the tools both import it.
"""

from __future__ import annotations

import os
import signal

__all__ = ["die_with_parent"]

_PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int | None = None, signum: int = signal.SIGTERM) -> None:
    """In a child process: receive ``signum`` when the parent dies; exit at once if it has died already.

    Linux's ``prctl(PR_SET_PDEATHSIG)``; elsewhere nothing. The signal comes when the *thread*
    that started the child ends: start such children from a thread that lives as long as the
    process (the main thread). Safe in a ``preexec_fn``.

    Parameters
    ----------
    parent_pid : the parent's pid, as the parent saw it before it started the child; when the
        child's parent is already another process (the parent died before the prctl took
        effect), the child exits now. None: not checked.
    signum : the signal (SIGTERM; SIGKILL where the child inherits a handler that would catch it).
    """
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signum), 0, 0, 0)
    except (OSError, AttributeError):  # no glibc (not Linux)
        pass
    if parent_pid is not None and os.getppid() != parent_pid:
        os._exit(0)
