#!/usr/bin/env python3
"""CPU per ModalStates published: the message object against the serialized template.

Run:  .venv/bin/python bench/modal_states_publish.py [--messages 3000] [--rounds 3]

Node 2 publishes a ModalStates for every sample. Two ways are timed side by side, alternated
round after round, in one process with a real publisher and a subscriber in another process
(so that DDS delivers every message, as to the benchmark's receiver in bench/live_pace.py):

- ``message``: the message object refilled in place (:func:`okid_ros.nodes.conversions.fill_modal_states`),
  which rclpy converts to C and serializes at every publish (the node's way until the
  twenty-ninth session);
- ``bytes``: the sample's fields written into a template serialized once per model
  (:class:`okid_ros.nodes.serialized_states.ModalStatesBytes`), published raw.

Two sizes: the paper model (p = 2, 3 modes) and the steel subframe (p = 28, 15 modes). The
CPU is this process's (``time.process_time``: the publishing thread and Fast DDS's threads),
per message, median over the rounds; a 1 ms sleep every 8 messages keeps the rate near the
nodes' 1 kHz. Prints a markdown table (docs/benchmarks-nodes.md).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from array import array
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
TOPIC = "/bench/modal_states"
SIZES = {"paper model (p = 2, 3 modes)": (2, 3), "steel subframe (p = 28, 15 modes)": (28, 15)}


def _subscriber() -> None:
    import rclpy

    from okid_msgs.msg import ModalStates

    rclpy.init()
    node = rclpy.create_node("modal_states_sink")
    node.create_subscription(ModalStates, TOPIC, lambda msg: None, 100)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, Exception):  # noqa: BLE001 - terminated by the parent
        pass


def _cpu_per_message(publish, messages: int) -> float:
    start = time.process_time()
    for k in range(messages):
        publish(k)
        if k % 8 == 7:
            time.sleep(0.001)
    return (time.process_time() - start) / messages


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=3000, help="messages per timing (default 3000)")
    parser.add_argument("--rounds", type=int, default=3, help="alternated rounds (default 3)")
    parser.add_argument("--role", default="main", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "subscriber":
        _subscriber()
        return
    os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))
    import rclpy

    from okid_msgs.msg import ModalStates, Mode
    from okid_ros.nodes.conversions import fill_modal_states
    from okid_ros.nodes.serialized_states import ModalStatesBytes
    from okid_ros.service.results import ModalStatesResult

    sink = subprocess.Popen([sys.executable, __file__, "--role", "subscriber"], env=os.environ.copy())
    rclpy.init()
    node = rclpy.create_node("modal_states_source")
    publisher = node.create_publisher(ModalStates, TOPIC, 100)
    try:
        deadline = time.monotonic() + 30.0
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        if publisher.get_subscription_count() == 0:
            raise SystemExit("the subscriber process was not discovered within 30 s")
        rng = np.random.default_rng(0)
        rows = []
        for label, (p, n_modes) in SIZES.items():
            modes = [Mode(id=i, frequency_hz=float(i + 1), damping_ratio=0.01, mac_previous=float("nan"),
                          shape_real=array("d", rng.standard_normal(p)), shape_imag=array("d", rng.standard_normal(p)))
                     for i in range(n_modes)]
            result = ModalStatesResult(stamp_s=1.0, model_id=1, modes=[], coordinates=rng.standard_normal((n_modes, 2)),
                                       y_estimated=rng.standard_normal(p), innovation=rng.standard_normal(p))
            msg, writer = ModalStates(), ModalStatesBytes(ModalStates)
            msg.header.frame_id = "okid"
            ways = {
                "message": lambda k: publisher.publish(fill_modal_states(msg, result, modes)),
                "bytes": lambda k: publisher.publish(writer.message(result, modes, "okid")),
            }
            cpu: dict[str, list[float]] = {name: [] for name in ways}
            for _ in range(args.rounds):
                for name, publish in ways.items():
                    cpu[name].append(_cpu_per_message(publish, args.messages))
            size = len(writer.message(result, modes, "okid"))
            old, new = statistics.median(cpu["message"]), statistics.median(cpu["bytes"])
            rows.append(f"| {label} | {size} | {old * 1e6:.0f} | {new * 1e6:.0f} | {old / new:.1f}x |")
    finally:
        sink.terminate()
        sink.wait(timeout=10)
        node.destroy_node()
        rclpy.shutdown()
    load = os.getloadavg()[0]
    print(f"bench/modal_states_publish.py: {args.messages} messages x {args.rounds} rounds, "
          f"load average (1 min) {load:.2f}\n")
    print("| message | bytes | CPU per message, message object [us] | serialized template [us] | ratio |")
    print("|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
