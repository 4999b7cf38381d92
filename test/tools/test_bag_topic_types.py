"""A bag whose topic carries two message types is read as a node subscribed with one type reads it."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from okid_ros.errors import OkidWarning
from okid_ros.tools.bagio import okid_typestore, open_bag
from okid_ros.tools.campaign.discovery import plan_bag
from okid_ros.tools.errors import BagReadError

IMU, ACCEL = "sensor_msgs/msg/Imu", "geometry_msgs/msg/AccelStamped"
COUNTS = {IMU: 40, ACCEL: 7}


@pytest.fixture(scope="module")
def two_types_bag(tmp_path_factory):
    """``/imu`` stored with 40 Imu and 7 AccelStamped messages (two connections, as MCAP allows)."""
    store, path = okid_typestore(), tmp_path_factory.mktemp("bags") / "two_types"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for msgtype, count in COUNTS.items():
            connection = writer.add_connection("/imu", msgtype, typestore=store)
            for k in range(count):
                raw = _accel(store) if msgtype == ACCEL else _imu(store)
                writer.write(connection, 1_000_000_000 + 8_000_000 * k, raw)
    return path


def _imu(store):
    T = store.types
    stamp = T["builtin_interfaces/msg/Time"](sec=1, nanosec=0)
    vector, covariance = T["geometry_msgs/msg/Vector3"](x=1.0, y=2.0, z=3.0), np.zeros(9)
    msg = T[IMU](header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="imu"),
                 orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                 orientation_covariance=covariance, angular_velocity=vector, angular_velocity_covariance=covariance,
                 linear_acceleration=vector, linear_acceleration_covariance=covariance)
    return store.serialize_cdr(msg, IMU)


def _accel(store):
    T = store.types
    vector = T["geometry_msgs/msg/Vector3"](x=1.0, y=2.0, z=3.0)
    msg = T[ACCEL](header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=0),
                                                  frame_id="a"), accel=T["geometry_msgs/msg/Accel"](linear=vector,
                                                                                                   angular=vector))
    return store.serialize_cdr(msg, ACCEL)


@pytest.mark.parametrize("wanted", [IMU, ACCEL])
def test_a_topic_of_two_types_is_read_in_the_type_asked(two_types_bag, wanted):
    """Both types were read as the first one (an internal error in `process`), or the second refused."""
    with open_bag(two_types_bag) as bag:
        with pytest.warns(OkidWarning, match="those passed over, as a node subscribed with"):
            assert bag.require_topic("/imu", [wanted]) == wanted
        kinds = {type(msg).__name__.split("__")[-1] for _, _, msg in bag.messages(["/imu"])}
        assert kinds == {wanted.rsplit("/", 1)[-1]}
        assert bag.message_count(["/imu"]) == COUNTS[wanted]


def test_a_topic_of_neither_type_names_both(two_types_bag):
    said = "has type sensor_msgs/msg/Imu and geometry_msgs/msg/AccelStamped, expected"
    with open_bag(two_types_bag) as bag, pytest.raises(BagReadError, match=said):
        bag.require_topic("/imu", ["std_msgs/msg/Float64MultiArray"])


def test_a_campaign_plan_names_both_types_of_a_topic(two_types_bag):
    """`batch --plan` (metadata only) showed the topic as of its last type alone, with both types' messages."""
    plan = plan_bag(two_types_bag)
    assert plan.topics == {"/imu": f"{IMU} and {ACCEL}"}
    assert plan.counts == {"/imu": sum(COUNTS.values())}
