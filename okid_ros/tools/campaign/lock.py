"""One `okid-ros batch` at a time in a campaign directory, and what a killed one left there.

Two runs on one ``DIR`` would append to one journal, process the same bags into the same folders
and write the tables over each other; and the folders a killed run leaves under ``DIR/bags``
(``.tmp-*``: a bag being processed, :mod:`~okid_ros.tools.campaign.worker`; ``.old-*``: a bag's
previous folder being replaced, :func:`~okid_ros.tools.campaign.manifest.replace_directory`) may
be removed only when no run is writing there. So a run holds an exclusive ``flock`` on
``DIR/.batch.lock`` from before it reads the journal until it has written the tables. The kernel
drops the lock when the process ends, however it ends (SIGKILL too): a killed run never leaves a
campaign locked. A second run is refused, naming the first (its pid, host and start, which the
holder writes into the file). Under the lock the leftovers are removed (:func:`remove_leftovers`).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import shutil
import socket
import time
import warnings
from collections.abc import Iterator
from pathlib import Path

from okid_ros.errors import OkidWarning, OutputError, one_line, shown_path
from okid_ros.tools.campaign.manifest import OLD_PREFIX
from okid_ros.tools.campaign.worker import TMP_PREFIX

__all__ = ["LEFTOVER_PREFIXES", "LOCK_NAME", "campaign_lock", "remove_leftovers"]

LOCK_NAME = ".batch.lock"
#: Names of the folders under ``DIR/bags`` that only a run under way may hold.
LEFTOVER_PREFIXES = (TMP_PREFIX, OLD_PREFIX)


@contextlib.contextmanager
def campaign_lock(out_dir: Path) -> Iterator[bool]:
    """Hold ``out_dir``'s batch lock for the ``with`` block; yields whether it is held.

    False (with a warning) on a file system that has no locks: the run goes on as before, unguarded,
    and removes no leftovers.

    Raises
    ------
    OutputError
        another process holds the lock (another batch on this campaign), or the lock file cannot be made.
    """
    path = out_dir / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise OutputError(f"--out {shown_path(out_dir)}: cannot create its lock file {LOCK_NAME} "
                          f"({one_line(exc.strerror or exc)})") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                why = one_line(exc.strerror or exc)
                warnings.warn(f"--out {shown_path(out_dir)}: cannot lock the campaign ({why}): a second batch on it "
                              "would not be noticed, and no folder a killed run left under bags/ is removed",
                              OkidWarning, stacklevel=3)
                yield False
                return
            holder = os.pread(fd, 4096, 0).decode("utf-8", "replace").strip() or "its pid not written yet"
            raise OutputError(f"--out {shown_path(out_dir)}: another okid-ros batch is running on this campaign "
                              f"({holder}); wait for it to end, or give another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()}, started "
                      f"{time.strftime('%Y-%m-%d %H:%M:%S %Z')}\n".encode(), 0)
        yield True
    finally:
        os.close(fd)  # the lock goes with the last descriptor of the file open


def remove_leftovers(out_dir: Path) -> int:
    """Remove the folders under ``out_dir/bags`` that a killed run left; returns how many.

    Call only under :func:`campaign_lock`: a run under way writes such folders.
    """
    try:
        folders = [entry for entry in (out_dir / "bags").iterdir()
                   if entry.name.startswith(LEFTOVER_PREFIXES) and entry.is_dir() and not entry.is_symlink()]
    except OSError:  # no bags/ yet; one that cannot be read is said by the run that reads it
        return 0
    for folder in folders:
        shutil.rmtree(folder, ignore_errors=True)
    return len(folders)
