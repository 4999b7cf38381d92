"""Shared fixtures: an isolated ROS 2 domain per test run, and ROS subprocesses.

Every test session takes a ROS_DOMAIN_ID (1..100) that no other pytest session on this
machine holds (an flock per id), and sets it with LOCALHOST discovery in os.environ, so
in-process rclpy and the subprocesses started through `ros_env` / `spawn_ros` share a
domain of their own:

    def test_node(spawn_ros):
        node = spawn_ros("-m", "okid_ros.nodes.arx_identifier_node", "--ros-args", ...)
        node.wait_for_output("ready", timeout_s=20)
        ...                       # stopped with SIGINT (then SIGTERM, SIGKILL) at teardown

For module-scoped processes use `ros_helpers.RosProcess` with
`ros_helpers.subprocess_env(ros_domain_id)` directly.
"""

from __future__ import annotations

import os

# One BLAS thread, as the CLI and the nodes use: set before any test module imports numpy
# (multi-threaded BLAS made the core 5-20x slower on the shared 2-core machines).
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import fcntl  # noqa: E402
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO

import pytest
from ros_helpers import REPO_ROOT, ROS_VARS_REMOVED, RosProcess, subprocess_env

# 0 is everyone's default; ids above 101 can collide with ephemeral ports on Linux.
_DOMAIN_IDS = range(1, 101)


def _claim_domain_id() -> tuple[int, IO[str]]:
    """Lock and return a domain id no other test session holds, starting from a pid hash."""
    lock_dir = Path(tempfile.gettempdir()) / "okid_ros_domain_locks"
    lock_dir.mkdir(exist_ok=True)
    start = os.getpid() % len(_DOMAIN_IDS)
    for i in range(len(_DOMAIN_IDS)):
        domain_id = _DOMAIN_IDS[(start + i) % len(_DOMAIN_IDS)]
        handle = open(lock_dir / f"{domain_id}.lock", "w")  # held until the session ends
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return domain_id, handle
    raise RuntimeError(f"all ROS domain ids {_DOMAIN_IDS} are held by other test sessions")


@pytest.fixture(scope="session", autouse=True)
def ros_domain_id() -> Iterator[int]:
    """The ROS_DOMAIN_ID of this session, also set in os.environ so in-process rclpy uses it."""
    domain_id, lock = _claim_domain_id()
    saved = {k: os.environ.get(k)
             for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", *ROS_VARS_REMOVED)}
    os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # never leave this machine
    for var in ROS_VARS_REMOVED:
        os.environ.pop(var, None)
    try:
        yield domain_id
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        lock.close()


@pytest.fixture
def ros_env(ros_domain_id: int) -> dict[str, str]:
    """A fresh environment dict for a ROS subprocess in this session's domain."""
    return subprocess_env(ros_domain_id)


@pytest.fixture
def spawn_ros(ros_env: dict[str, str]) -> Iterator[Callable[..., RosProcess]]:
    """Factory: spawn_ros(*python_args, env=None) starts `python *python_args` in this domain.

    The interpreter is the one running pytest (the venv's on the pip route), the working
    directory the repository root. Every process still running is stopped at teardown.
    """
    started: list[RosProcess] = []

    def spawn(*python_args: str, env: dict[str, str] | None = None) -> RosProcess:
        process = RosProcess([sys.executable, *python_args], env or ros_env, REPO_ROOT)
        started.append(process)
        return process

    yield spawn
    for process in reversed(started):
        process.stop()


# The fixtures that start ROS processes: a test that takes one talks over DDS.
_DDS_FIXTURES = frozenset({"ros_env", "spawn_ros"})


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark ``dds`` every test that takes a ROS process fixture.

    Modules that start nodes or rclpy otherwise say so: ``pytestmark = pytest.mark.dds``.
    `make test` runs the ``dds`` tests after the others and in one process: their fixed-rate
    streams lose samples to a second test worker's load. A test that only starts nodes and checks
    how they start, refuse or exit is marked ``dds_startup`` too and runs with the others, in
    parallel: each test worker is a session with a domain of its own.
    """
    for item in items:
        if _DDS_FIXTURES & set(getattr(item, "fixturenames", ())) and item.get_closest_marker("dds") is None:
            item.add_marker(pytest.mark.dds)
