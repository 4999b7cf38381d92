"""Helpers for tests that run ROS 2 processes; the fixtures in conftest.py wrap them.

Importable from test modules as `import ros_helpers` (pytest puts test/ on sys.path).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
# Jazzy replaced these by ROS_AUTOMATIC_DISCOVERY_RANGE; a stray value would override it.
ROS_VARS_REMOVED = ("ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS")


def subprocess_env(domain_id: int, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """A copy of `base` (default os.environ) for a ROS process isolated in `domain_id`."""
    env = dict(os.environ if base is None else base)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # discovery never leaves this machine
    for var in ROS_VARS_REMOVED:
        env.pop(var, None)
    env["PYTHONUNBUFFERED"] = "1"  # output arrives line by line for wait_for_output
    return env


class RosProcess:
    """A subprocess whose combined stdout/stderr is collected by a reader thread."""

    def __init__(self, args: list[str], env: Mapping[str, str], cwd: Path = REPO_ROOT) -> None:
        self.args = args
        self.proc = subprocess.Popen(
            args, env=env, cwd=cwd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, bufsize=1,
            start_new_session=True,  # signals reach the process group, not pytest
        )
        self._lines: list[str] = []
        self._changed = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._changed:
                self._lines.append(line)
                self._changed.notify_all()
        with self._changed:
            self._changed.notify_all()

    def output(self) -> str:
        """Everything the process printed so far."""
        with self._changed:
            return "".join(self._lines)

    def wait_for_output(self, pattern: str, timeout_s: float = 30.0) -> re.Match[str]:
        """Wait until a printed line matches the regex `pattern`; fail on timeout or exit."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        seen = 0
        with self._changed:
            while True:
                for line in self._lines[seen:]:
                    if match := regex.search(line):
                        return match
                seen = len(self._lines)
                if self.proc.poll() is not None and not self._reader.is_alive():
                    pytest.fail(f"{self.args} exited with {self.proc.returncode} before "
                                f"printing /{pattern}/; output:\n{self.output()}")
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    pytest.fail(f"{self.args} did not print /{pattern}/ within {timeout_s} s; "
                                f"output:\n{''.join(self._lines)}")
                self._changed.wait(timeout=min(remaining, 0.5))

    def stop(self, timeout_s: float = 10.0) -> int:
        """Stop like Ctrl-C (SIGINT), escalating to SIGTERM and SIGKILL; return the exit code."""
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if self.proc.poll() is not None:
                break
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                break
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                continue
        self.proc.wait()
        self._reader.join(timeout=timeout_s)
        return self.proc.returncode


def start_nodes(ros_args: list[str], env: Mapping[str, str]) -> dict[str, RosProcess]:
    """Both nodes as processes with the same ``--ros-args`` arguments: ``{"arx": ..., "est": ...}``."""
    modules = {"arx": "arx_identifier_node", "est": "modal_estimator_node"}
    return {name: RosProcess([sys.executable, "-m", f"okid_ros.nodes.{module}", "--ros-args", *ros_args], env)
            for name, module in modules.items()}


def wait_ready(procs: Mapping[str, RosProcess], timeout_s: float = 30.0) -> None:
    """Until every node has logged that it is ready."""
    for proc in procs.values():
        proc.wait_for_output(r"ready:", timeout_s=timeout_s)


@contextmanager
def io_sample_rig(probe_factory: Callable[[], ProbeNode], params_text: str, params_dir: Path,
                  env: Mapping[str, str]) -> Iterator[tuple[dict[str, RosProcess], ProbeNode]]:
    """Both nodes on config/okid.yaml and ``params_text``, ready, and a probe whose ``io`` both subscribe.

    Yields ``(procs, probe)``; the probe is closed and the nodes stopped at exit.
    """
    params = params_dir / "params.yaml"
    params.write_text(params_text)
    procs = start_nodes(["--params-file", str(REPO_ROOT / "config" / "okid.yaml"), "--params-file", str(params)], env)
    probe = None
    try:
        probe = probe_factory()
        wait_ready(procs)
        probe.wait_until("the nodes to subscribe the inputs", lambda: probe.io.get_subscription_count() >= 2, 20)
        yield procs, probe
    finally:
        if probe is not None:
            probe.close()
        for proc in procs.values():
            proc.stop()


class ProbeNode:
    """A test's own rclpy node, in a context of its own, spun on a daemon thread.

    Subclasses create their publishers and subscriptions on ``self.node`` and then call
    :meth:`start`; callbacks take ``self.lock`` around what the test thread reads.
    """

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.node import Node

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node(name, context=self.context)
        self.lock = threading.Lock()
        self.executor = None
        self.thread: threading.Thread | None = None
        self._clients: dict = {}

    def start(self) -> None:
        """Spin the node on a daemon thread until :meth:`close`."""
        from rclpy.executors import SingleThreadedExecutor

        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def keep(self, store: list):
        """A subscription callback appending each message to ``store`` (under the lock)."""
        def callback(msg) -> None:
            with self.lock:
                store.append(msg)
        return callback

    def call(self, srv_type, name: str, request, *, attempts: int = 4, wait_s: float = 20.0):
        """Answer of one service call; the request is sent again when no answer comes.

        A client's first request can be lost over DDS while the service's reply path is still
        being matched (wait_for_service sees only the request path), so one silent request is
        not a failure of the node; ``attempts`` are (AssertionError).
        """
        if name not in self._clients:
            self._clients[name] = self.node.create_client(srv_type, name)
        client = self._clients[name]
        assert client.wait_for_service(timeout_sec=60), name
        for _ in range(attempts):
            future = client.call_async(request)
            deadline = time.monotonic() + wait_s  # a call on a loaded machine may take seconds
            while not future.done() and time.monotonic() < deadline:
                time.sleep(0.02)
            if future.done():
                return future.result()
            client.remove_pending_request(future)
        raise AssertionError(f"{name}: no answer to {attempts} requests of {wait_s} s each")

    def wait_until(self, what: str, predicate, timeout_s: float = 30.0, *, explain=None) -> None:
        """Wait until ``predicate()`` (called under the lock) holds; fail the test on timeout.

        ``explain``: called (under the lock) on a timeout, its text added to the failure message:
        what the nodes said about why (their diagnostics, their log).
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if predicate():
                    return
            time.sleep(0.05)
        why = ""
        if explain is not None:
            with self.lock:
                why = f"\n{explain()}"
        pytest.fail(f"timed out after {timeout_s} s waiting for {what}{why}")

    def close(self) -> None:
        import rclpy

        rclpy.try_shutdown(context=self.context)  # ends the spin
        if self.thread is not None:
            self.thread.join(timeout=10)
        if self.executor is not None:
            self.executor.shutdown()
        self.node.destroy_node()


def rosbags_typestore():
    """The rosbags Jazzy typestore plus okid_msgs from the repository's .msg files (no project code)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in sorted((REPO_ROOT / "msg_defs" / "msg").glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"okid_msgs/msg/{path.stem}"))
    store.register(types)
    return store


def publish_io_samples(publisher, u, y, *, t0_s: float, sample_time_s: float, rate_hz: float = 1000.0) -> None:
    """Publish ``u``, ``y`` (N, m), (N, p) as IoSample stamped ``t0_s + k sample_time_s``, ``rate_hz`` a second."""
    from okid_msgs.msg import IoSample  # here: the helpers' other users need no message package

    start = time.monotonic()
    for k in range(len(y)):
        msg = IoSample()
        ns = int(round((t0_s + k * sample_time_s) * 1e9))
        msg.header.stamp.sec, msg.header.stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
        msg.u, msg.y = [float(v) for v in u[k]], [float(v) for v in y[k]]
        publisher.publish(msg)
        wait = start + (k + 1) / rate_hz - time.monotonic()
        if wait > 0:
            time.sleep(wait)
