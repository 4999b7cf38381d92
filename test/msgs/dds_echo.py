"""Echo node for test_msgs_dds.py: republishes every message it receives, in its own process.

    python test/msgs/dds_echo.py okid_msgs/msg/IoSample:io okid_msgs/msg/ArxModel:arx ...

For each argument TYPE:TAG it subscribes /okid_test/TAG/ping and publishes what arrives,
unchanged, on /okid_test/TAG/pong. Prints "ready" once all endpoints exist; stops on SIGINT.
"""

from __future__ import annotations

import importlib
import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def import_type(name: str) -> type:
    """okid_msgs/msg/IoSample -> the class okid_msgs.msg.IoSample."""
    package, kind, type_name = name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), type_name)


def main(specs: list[str]) -> None:
    rclpy.init()
    node = Node("okid_test_echo")
    for spec in specs:
        type_name, tag = spec.split(":")
        msg_type = import_type(type_name)
        publisher = node.create_publisher(msg_type, f"/okid_test/{tag}/pong", QOS)
        node.create_subscription(msg_type, f"/okid_test/{tag}/ping", publisher.publish, QOS)
    print("ready", flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main(sys.argv[1:])
