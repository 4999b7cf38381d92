"""Record live topics into a new bag, as ``ros2 bag record`` would (used by the demo).

Each topic gets an rclpy subscription with ``raw=True``: the callback receives the serialized
CDR bytes as they came over the wire, which are written unchanged
(:meth:`okid_ros.tools.bagio.BagWriter.write_raw`) with the receive time on the node clock as
log time. Subscriptions are reliable, keep-last ``queue_depth``, volatile: they match the
nodes' reliable (and transient-local) publishers.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

from okid_ros.tools.bagio import BagWriter
from okid_ros.tools.replay import message_class

__all__ = ["LiveRecorder"]


class LiveRecorder:
    """Subscribes ``topics`` on ``node`` and writes every message to ``writer``.

    Parameters
    ----------
    node : an rclpy node (spun by the caller).
    writer : an open :class:`BagWriter`.
    topics : topic -> message type ``pkg/msg/Name``.
    on_message : optional ``on_message(topic, raw_bytes, receive_ns)`` after each write.
    queue_depth : subscription history depth.
    """

    def __init__(self, node: Any, writer: BagWriter, topics: dict[str, str],
                 on_message: Callable[[str, bytes, int], None] | None = None, queue_depth: int = 1000) -> None:
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        self.node = node
        self.writer = writer
        self.on_message = on_message
        self.counts = {topic: 0 for topic in topics}
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=queue_depth,
                         reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        self.subscriptions = []
        for topic, msgtype in topics.items():
            writer.add_topic(topic, msgtype)
            self.subscriptions.append(node.create_subscription(
                message_class(msgtype), topic, partial(self._on_raw, topic), qos, raw=True))

    def _on_raw(self, topic: str, data: bytes) -> None:
        receive_ns = self.node.get_clock().now().nanoseconds
        self.writer.write_raw(topic, receive_ns, data)
        self.counts[topic] += 1
        if self.on_message is not None:
            self.on_message(topic, data, receive_ns)
