"""The cores this process may use, and the threads an identification takes from them."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["IDENTIFY_MAX_WORKERS", "identify_workers", "usable_cores"]

#: The cgroup v2 CPU limit of this process's container (``"max 100000"`` or ``"QUOTA PERIOD"``).
CGROUP_CPU_MAX = Path("/sys/fs/cgroup/cpu.max")


def usable_cores(*, cpu_max_path: Path = CGROUP_CPU_MAX) -> int:
    """The cores this process may run on: its CPU affinity, within its container's CPU quota.

    ``os.cpu_count()`` counts the host's cores, not those of a ``taskset``, a cpuset or a
    container's ``--cpus`` limit. The quota is read here by hand: the libraries that read it
    (dask.system, loky) are not dependencies of the command (dask is an optional extra).
    """
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        cores = os.cpu_count() or 1
    try:
        quota, period = cpu_max_path.read_text().split()[:2]
        if quota != "max":
            cores = min(cores, max(1, int(int(quota) / int(period))))
    except (OSError, ValueError, ZeroDivisionError):  # no cgroup v2, or a line not understood
        pass
    return max(1, cores)


#: Most threads an ``okid-ros identify`` of outputs alone takes (:mod:`okid_ros.core.worker_threads`):
#: about half its time is serial (the record's checks, the clustering, the gain), so cores beyond
#: four would add little. Measured with two (docs/benchmarks-output-only.md).
IDENTIFY_MAX_WORKERS = 4


def identify_workers() -> int:
    """Threads for an ``okid-ros identify`` of outputs alone: the usable cores, at most four (above)."""
    return min(usable_cores(), IDENTIFY_MAX_WORKERS)
