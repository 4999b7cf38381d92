"""A bag's Imu messages that declare no data (REP 145: element 0 of a covariance at -1) in `export` and `process`.

Such a message is rejected, counted and named with its covariance once per topic, never read as data; a
covariance of zeros ("unknown") or of variances leaves the values as they were.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_cli
from ros_helpers import rosbags_typestore

from okid_ros.records import load_record

IMU_TYPE = "sensor_msgs/msg/Imu"
TOPICS = ("/imu/a", "/imu/b")
START_NS = 1_700_000_000 * 1_000_000_000
DT = 0.008
N = 600
SOURCES = ["--param", "n_inputs=0", "--param", "n_outputs=2", "--source", f"imu {TOPICS[0]} linear_acceleration.x=y0",
           "--source", f"imu {TOPICS[1]} linear_acceleration.x=y1"]
REASON = ("linear_acceleration_covariance[0] is -1, which REP 145 reserves for a field the sensor does not measure "
          "(no data)")


def write_imu_bag(path: Path, declared_b: np.ndarray, seed: int = 0) -> tuple[Path, np.ndarray]:
    """Two Imu topics on a 125 Hz grid; ``declared_b[k]``: /imu/b's message k declares no acceleration data.

    /imu/a's covariance is all zeros (unknown), /imu/b's otherwise a variance; both declare no orientation and
    no angular velocity (as an accelerometer does). Returns the bag and the accelerations written (N, 2).
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = rosbags_typestore()
    t = store.types
    acc = np.random.default_rng(seed).standard_normal((N, 2))
    none, unknown, variance = np.zeros(9), np.zeros(9), np.diag([0.04] * 3).ravel()
    none[0] = -1.0
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = [writer.add_connection(topic, IMU_TYPE, typestore=store) for topic in TOPICS]
        for k in range(N):
            ns = START_NS + round(k * DT * 1e9)
            header = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=ns // 10**9,
                                                                                     nanosec=ns % 10**9), frame_id="")
            for j, connection in enumerate(connections):
                covariance = unknown if j == 0 else none if declared_b[k] else variance
                msg = t[IMU_TYPE](header=header, orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0,
                                                                                              w=1.0),
                                  orientation_covariance=none, angular_velocity=t["geometry_msgs/msg/Vector3"](
                                      x=0.0, y=0.0, z=0.0), angular_velocity_covariance=none,
                                  linear_acceleration=t["geometry_msgs/msg/Vector3"](x=acc[k, j], y=0.0, z=0.0),
                                  linear_acceleration_covariance=covariance)
                writer.write(connection, ns, store.serialize_cdr(msg, IMU_TYPE))
    return path, acc


@pytest.mark.parametrize("command", [["export", "--npz", "x.npz"], ["process", "--out", "out", "--no-progress"]])
def test_a_topic_declaring_no_data_is_refused_naming_its_covariance(tmp_path, capsys, command):
    # Was: its accelerations read as data (a dead channel where they are zeros, nothing said of the covariance).
    bag, _ = write_imu_bag(tmp_path / "bag", np.ones(N, dtype=bool))
    command = [command[0], bag, *[tmp_path / c if c in ("x.npz", "out") else c for c in command[1:]]]
    code, _, err = run_cli(capsys, *command, *SOURCES)
    assert code == 2, err
    assert f"{N} no data" in err.replace("_", " "), err
    assert err.count(f"{TOPICS[1]}: {N} of its {N} messages rejected, never used as data: {REASON}") == 1, err
    assert TOPICS[0] + ":" not in err, err


def test_messages_declaring_no_data_are_left_out_and_the_rest_read_as_written(tmp_path, capsys):
    declared = np.arange(N) >= 2 * N // 3  # the sensor lost its acceleration for the last third
    bag, acc = write_imu_bag(tmp_path / "bag", declared)
    code, out, err = run_cli(capsys, "export", bag, "--npz", tmp_path / "x.npz", *SOURCES)
    assert code == 0, err
    assert f"{TOPICS[1]}: {N // 3} of its {N} messages rejected, never used as data: {REASON}" in err, err
    record = load_record(tmp_path / "x.npz")
    np.testing.assert_array_equal(record.y, acc[~declared])  # zeros and variances: the values, bit for bit
