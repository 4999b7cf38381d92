"""Two "hosts" on one machine: two Linux network namespaces joined by a veth pair.

The nodes
run in one, a probe in the other publishes IoSample and receives the modal states back, over
UDP across the veth pair (Fast DDS's shared-memory transport is switched off, so nothing
takes a shortcut through /dev/shm).

Needs root (creating network namespaces); skipped with the reason otherwise. The addresses
(10.213.0.1/24, 10.213.0.2/24) exist only inside the two namespaces the test creates, which
have no other interface than their loopback and their end of the pair: no traffic leaves them.
Discovery is ROS 2 Jazzy's default (ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET, multicast on the
veth link), and static peers (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST with ROS_STATIC_PEERS
naming the other side, no multicast) as docs/deployment.md describes.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest
from ros_helpers import REPO_ROOT, RosProcess

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process

SMALL = """
/**/okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: 2.0
    arx: {order: 40, window_length: 2000}
/**/okid_modal_estimator:
  ros__parameters:
    realization: {n_states: 6}
"""
ADDRESSES = {"a": "10.213.0.1", "b": "10.213.0.2"}


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(args, capture_output=True, text=True)


@pytest.fixture
def two_hosts():
    """Namespaces okid<pid>a / okid<pid>b joined by a veth pair; removed at teardown."""
    if os.geteuid() != 0:
        pytest.skip("creating network namespaces needs root (run the suite as root to include this test)")
    if shutil.which("ip") is None:
        pytest.skip("the ip command (iproute2) is not installed")
    tag = f"okid{os.getpid() % 100000}"
    names = {side: f"{tag}{side}" for side in "ab"}
    made = _run("ip", "netns", "add", names["a"])
    if made.returncode != 0:
        pytest.skip(f"cannot create a network namespace: {made.stderr.strip()}")
    try:
        steps = [
            ("ip", "netns", "add", names["b"]),
            ("ip", "link", "add", f"{tag}va", "netns", names["a"], "type", "veth", "peer", "name", f"{tag}vb",
             "netns", names["b"]),
        ]
        for side in "ab":
            ns = ("ip", "netns", "exec", names[side])
            steps += [
                (*ns, "ip", "link", "set", "lo", "up"),
                (*ns, "ip", "addr", "add", f"{ADDRESSES[side]}/24", "dev", f"{tag}v{side}"),
                (*ns, "ip", "link", "set", f"{tag}v{side}", "up", "multicast", "on"),
                # DDS discovery multicast (239.255.0.1) goes out over the veth link.
                (*ns, "ip", "route", "add", "224.0.0.0/4", "dev", f"{tag}v{side}"),
            ]
        for step in steps:
            result = _run(*step)
            if result.returncode != 0:
                pytest.skip(f"cannot set up the namespaces ({' '.join(step)}): {result.stderr.strip()}")
        yield names
    finally:
        for side in "ab":
            _run("ip", "netns", "del", names[side])  # deletes the veth pair with it


def host_env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    for var in ("ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        env.pop(var, None)
    env.update(ROS_DOMAIN_ID="42", FASTDDS_BUILTIN_TRANSPORTS="UDPv4", PYTHONUNBUFFERED="1", **extra)
    return env


@pytest.mark.parametrize("discovery", ["multicast", "static_peers"])
def test_nodes_on_one_host_serve_a_probe_on_another(two_hosts, tmp_path, discovery):
    params = tmp_path / "small.yaml"
    params.write_text(SMALL)
    if discovery == "multicast":
        env_b, env_a = host_env(), host_env()
    else:
        # No multicast: each side discovers its own host and the other's address only
        # (OFF would switch static peers off as well).
        env_b = host_env(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_STATIC_PEERS=ADDRESSES["a"])
        env_a = host_env(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_STATIC_PEERS=ADDRESSES["b"])
    nodes = RosProcess(["ip", "netns", "exec", two_hosts["b"], sys.executable, "-m", "okid_ros.cli", "up",
                        "--params", str(REPO_ROOT / "config" / "okid.yaml"), "--params", str(params)], env_b)
    probe = None
    try:
        # The probe starts with the nodes: it publishes only once both nodes' subscriptions have matched.
        probe = subprocess.Popen(["ip", "netns", "exec", two_hosts["a"], sys.executable,
                                  str(REPO_ROOT / "test" / "nodes" / "netns_probe.py"), "4000", "500", "90"],
                                 env=env_a, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        nodes.wait_for_output(r"\[okid_modal_estimator\]: ready", 60)
        nodes.wait_for_output(r"\[okid_arx_identifier\]: ready", 60)
        stdout, stderr = probe.communicate(timeout=180)
        lines = [line for line in stdout.splitlines() if line.startswith("{")]
        assert lines, (stdout, stderr, nodes.output())
        summary = json.loads(lines[-1])
        assert summary["subscribers"] == 2, summary  # both nodes found across the link
        assert summary["modal_states"] > 500, (summary, nodes.output())
        assert len(summary["modes_rad_s"]) >= 2, summary
    finally:
        if probe is not None and probe.poll() is None:
            probe.kill()
            probe.communicate()
        nodes.stop()
