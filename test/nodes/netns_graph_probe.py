"""What one process sees of the ROS graph: run in another network namespace by test_nodes_security.py.

Waits until a node named NODE is discovered or TIMEOUT_S pass, then prints one JSON line:
the node names seen and whether NODE was among them.

    python test/nodes/netns_graph_probe.py NODE TIMEOUT_S
"""

from __future__ import annotations

import json
import sys
import time

import rclpy
from rclpy.node import Node


def main(wanted: str, timeout_s: float) -> int:
    rclpy.init()
    node = Node("okid_netns_graph_probe")
    deadline = time.monotonic() + timeout_s
    names: list[str] = []
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
        names = sorted(n for n in node.get_node_names() if n != node.get_name())
        if wanted in names:
            break
    print(json.dumps({"seen": wanted in names, "nodes": names}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], float(sys.argv[2])))
