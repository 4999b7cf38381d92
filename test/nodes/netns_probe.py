"""The "other host" of test_nodes_two_hosts.py.

Publishes simulated IoSample and counts the
ModalStates that come back, then prints one JSON line and exits (0: modal states received).

    python test/nodes/netns_probe.py SAMPLES RATE_HZ TIMEOUT_S
"""

from __future__ import annotations

import json
import sys
import threading
import time

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from okid_msgs.msg import IoSample, ModalStates
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation


def main(samples: int, rate_hz: float, timeout_s: float) -> int:
    rclpy.init()
    node = Node("okid_netns_probe")
    states: list[ModalStates] = []
    lock = threading.Lock()

    def on_states(msg: ModalStates) -> None:
        with lock:
            states.append(msg)

    publisher = node.create_publisher(IoSample, "/okid/io_sample",
                                      QoSProfile(depth=500, reliability=ReliabilityPolicy.BEST_EFFORT))
    node.create_subscription(ModalStates, "/okid/modal_states", on_states,
                             QoSProfile(depth=2000, reliability=ReliabilityPolicy.RELIABLE))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    thread = threading.Thread(target=lambda: _spin(executor), daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout_s
    while publisher.get_subscription_count() < 2 and time.monotonic() < deadline:
        time.sleep(0.1)
    subscribers = publisher.get_subscription_count()
    u = lowpass_input(samples, 2, 50.0, 0.008, seed=1)
    y, _ = simulate_innovation(paper_model(), u, seed=2)
    start = time.monotonic()
    for k in range(samples):
        msg = IoSample()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round((1000.0 + k * 0.008) * 1e9)), 1_000_000_000)
        msg.u = [float(v) for v in u[k]]
        msg.y = [float(v) for v in y[k]]
        publisher.publish(msg)
        wait = start + (k + 1) / rate_hz - time.monotonic()
        if wait > 0:
            time.sleep(wait)
    while time.monotonic() < deadline:
        with lock:
            if states and states[-1].header.stamp.sec >= 1000 + int((samples - 1) * 0.008) - 1:
                break
        time.sleep(0.1)
    with lock:
        modes = [round(m.frequency_rad_s, 2) for m in states[-1].modes] if states else []
        summary = {"subscribers": subscribers, "modal_states": len(states), "modes_rad_s": modes}
    print(json.dumps(summary), flush=True)
    rclpy.try_shutdown()
    thread.join(timeout=5)
    return 0 if states else 1


def _spin(executor) -> None:
    try:
        executor.spin()
    except ExternalShutdownException:
        pass


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])))
