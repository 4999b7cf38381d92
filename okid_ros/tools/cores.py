"""The cores this process may use, and the threads an identification takes from them."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["IDENTIFY_MAX_WORKERS", "identify_workers", "usable_cores"]

#: Where the cgroup hierarchies are mounted, and the file naming this process's cgroups.
CGROUP_ROOT = Path("/sys/fs/cgroup")
PROC_SELF_CGROUP = Path("/proc/self/cgroup")


def usable_cores(*, cgroup_root: Path = CGROUP_ROOT, own_cgroups: Path = PROC_SELF_CGROUP) -> int:
    """The cores this process may run on: its CPU affinity, within its cgroups' CPU quotas.

    ``os.cpu_count()`` counts the host's cores, not those of a ``taskset``, a cpuset or a
    container's ``--cpus`` limit. The quotas are read here by hand (the libraries that read them,
    dask.system and loky, are not dependencies of the command): cgroup v2's ``cpu.max`` and v1's
    ``cpu.cfs_quota_us`` / ``cpu.cfs_period_us``, of this process's cgroup (``/proc/self/cgroup``)
    and every cgroup above it (a parent's limit binds too), the smallest.
    """
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        cores = os.cpu_count() or 1
    for quota in _cpu_quotas(cgroup_root, own_cgroups):
        cores = min(cores, max(1, int(quota)))
    return max(1, cores)


def _cpu_quotas(root: Path, own_cgroups: Path) -> list[float]:
    """The CPU quotas (cores) of this process's cgroups and their ancestors; lines not understood are passed."""
    try:
        lines = own_cgroups.read_text().splitlines()
    except OSError:
        lines = []
    folders = [root]  # a container's own namespace shows its cgroup at the root
    for line in lines:
        _, controllers, path = (line.split(":", 2) + ["", ""])[:3]
        relative = path.strip().lstrip("/")
        if not controllers:  # v2: 0::/path
            base = root
        elif "cpu" in controllers.split(","):  # v1: N:cpu,cpuacct:/path
            base = root / controllers
        else:
            continue
        folder = base / relative
        folders += [folder, *(p for p in folder.parents if p.is_relative_to(base))]
    quotas = []
    for folder in dict.fromkeys(folders):
        try:
            quota, period = (folder / "cpu.max").read_text().split()[:2]
        except (OSError, ValueError):
            try:
                quota, period = ((folder / name).read_text().strip()
                                 for name in ("cpu.cfs_quota_us", "cpu.cfs_period_us"))
            except OSError:
                continue
        try:
            if quota not in ("max", "-1"):
                quotas.append(int(quota) / int(period))
        except (ValueError, ZeroDivisionError):
            continue
    return quotas


#: Most threads an ``okid-ros identify`` of outputs alone takes (:mod:`okid_ros.core.worker_threads`):
#: about half its time is serial (the record's checks, the clustering, the gain), so cores beyond
#: four would add little. Measured with two (docs/benchmarks-output-only.md).
IDENTIFY_MAX_WORKERS = 4


def identify_workers() -> int:
    """Threads for an ``okid-ros identify`` of outputs alone: the usable cores, at most four (above)."""
    return min(usable_cores(), IDENTIFY_MAX_WORKERS)
