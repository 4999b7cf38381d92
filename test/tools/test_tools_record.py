"""`okid-ros record`: a rig's topics over DDS into a bag.

An existing bag is never replaced without --force.
"""

from __future__ import annotations

import sys
import time

import pytest
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import REPO_ROOT, RosProcess, subprocess_env

from okid_msgs.msg import ModalStates
from okid_ros.tools.bagio import open_bag

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process


def test_record_writes_the_rigs_topics_and_refuses_to_overwrite(ros_domain_id, tmp_path):
    out = tmp_path / "live"
    env = subprocess_env(ros_domain_id)
    rec = RosProcess([sys.executable, "-m", "okid_ros.cli", "record", str(out), "--namespace", "/rec1",
                      "--duration", "6"], env, REPO_ROOT)
    rec.wait_for_output(r"recording /rec1/arx_model, /rec1/state_space_model, /rec1/modal_states, "
                        r"/rec1/structural_change, /diagnostics", 30)
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("okid_record_probe", context=context)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        rig = node.create_publisher(ModalStates, "/rec1/modal_states", qos)
        other = node.create_publisher(ModalStates, "/okid/modal_states", qos)  # another rig: not recorded
        deadline = time.monotonic() + 20
        while rig.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert rig.get_subscription_count() >= 1
        for k in range(20):
            msg = ModalStates()
            msg.model_id = k
            msg.header.frame_id = "rig1"
            rig.publish(msg)
            other.publish(msg)
            time.sleep(0.01)
        assert rec.proc.wait(timeout=30) == 0, rec.output()
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    rec.wait_for_output(r"wrote .*/rec1/modal_states: 20", 5)
    with open_bag(out) as bag:
        assert "/okid/modal_states" not in bag.topics
        ids = [int(msg.model_id) for _t, _ns, msg in bag.messages(["/rec1/modal_states"])]
    assert ids == list(range(20))
    again = RosProcess([sys.executable, "-m", "okid_ros.cli", "record", str(out), "--duration", "1"], env, REPO_ROOT)
    assert again.proc.wait(timeout=30) == 2
    again.wait_for_output(r"exists already, not overwriting \(use --force", 5)
    forced = RosProcess([sys.executable, "-m", "okid_ros.cli", "record", str(out), "--duration", "1", "--force"],
                        env, REPO_ROOT)
    assert forced.proc.wait(timeout=30) == 0, forced.output()
