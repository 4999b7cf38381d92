"""Replay over real DDS.

Every message with its recorded stamps and spacing on (remapped) topics, started once the
subscriptions asked for have matched; a looped replay (stamps
jump back) through both live nodes, which keep running and keep publishing modal states.
ROS_DOMAIN_ID is this session's (conftest.py).
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import REPO_ROOT, RosProcess, subprocess_env
from sensor_msgs.msg import Imu

from okid_msgs.msg import IoSample, ModalStates
from okid_ros.tools.simulate_bag import IMU_TOPICS, IO_SAMPLE_TOPIC, simulate_experiment, write_experiment_bag

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process

START_NS = 1_700_000_000 * 1_000_000_000
DT_NS = 8_000_000
# Fast enough for a short test: a window of 1000 rows is valid from 500 rows (about 5 s of
# data), and the window is solved twice a second.
FAST_PARAMS = """
okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: 2.0
    arx:
      window_length: 1000
"""


class Listener:
    """In-process subscriptions that keep (receive time, message) per topic."""

    def __init__(self, topics: dict[str, type]) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context, args=[])
        self.node = rclpy.create_node("okid_test_listener", context=self.context)
        self.received: dict[str, list] = {topic: [] for topic in topics}
        qos = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
        for topic, cls in topics.items():
            self.node.create_subscription(cls, topic, self._keep(topic), qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _keep(self, topic: str):
        def callback(msg) -> None:
            self.received[topic].append((time.monotonic(), msg))
        return callback

    def _spin(self) -> None:
        while not self._stop and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def wait_for_publishers(self, topics, timeout_s: float = 20.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not all(self.node.count_publishers(t) for t in topics):
            assert time.monotonic() < deadline, f"no publisher on {topics}"
            time.sleep(0.05)

    def close(self) -> None:
        self._stop = True
        self.thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()  # its subscriptions end here, not when the process does
        self.context.try_shutdown()


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def replay(ros_domain_id: int, *args: str) -> RosProcess:
    return RosProcess([sys.executable, "-m", "okid_ros.cli", "replay", *args], subprocess_env(ros_domain_id), REPO_ROOT)


def wait_exit(proc: RosProcess, timeout_s: float) -> int:
    try:
        return proc.proc.wait(timeout=timeout_s)
    except Exception:
        proc.stop()
        pytest.fail(f"{proc.args} did not finish within {timeout_s} s; output:\n{proc.output()}")


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory) -> Path:
    bag = tmp_path_factory.mktemp("replay") / "short"
    write_experiment_bag(bag, simulate_experiment(2.0, start_ns=START_NS), storage="sqlite3")
    return bag


def test_replay_publishes_every_message_with_its_stamps_and_timing(ros_domain_id, short_bag):
    listener = Listener({"/test/io": IoSample, IMU_TOPICS[0]: Imu, IO_SAMPLE_TOPIC: IoSample})
    try:
        proc = replay(ros_domain_id, str(short_bag), "--rate", "2", "--topics", IO_SAMPLE_TOPIC, IMU_TOPICS[0],
                      "--remap", f"{IO_SAMPLE_TOPIC}:=/test/io", "--wait-for-subscribers", "--delay", "0.3")
        assert wait_exit(proc, 60) == 0, proc.output()
        deadline = time.monotonic() + 5
        while min(len(listener.received["/test/io"]), len(listener.received[IMU_TOPICS[0]])) < 250:
            assert time.monotonic() < deadline, {t: len(v) for t, v in listener.received.items()}
            time.sleep(0.05)
        io = listener.received["/test/io"]
        assert len(io) == 250 and not listener.received[IO_SAMPLE_TOPIC]  # remapped, not on the original
        assert [stamp_ns(m) for _, m in io] == [START_NS + k * DT_NS for k in range(250)]
        arrival = np.array([t for t, _ in io])
        # the bag spans 1.992 s; at rate 2 it plays in about 1 s, spaced as recorded
        assert 0.85 < arrival[-1] - arrival[0] < 1.4, arrival[-1] - arrival[0]
        assert np.median(np.diff(arrival)) == pytest.approx(0.004, abs=0.002)
        assert "replayed 500 messages on 2 topics" in proc.output()
        assert "/test/io: 250" in proc.output()
    finally:
        listener.close()


def test_replay_sends_each_message_as_recorded_whatever_its_cdr_encoding(ros_domain_id, tmp_path):
    """Little-endian CDR goes out as stored, big-endian through rclpy's message object: the same fields."""
    from okid_ros.tools.bagio import BagWriter

    bag, topic = tmp_path / "endian", "/test/endian"
    with BagWriter(bag, storage="sqlite3") as writer:
        writer.add_topic(topic, "sensor_msgs/msg/Imu")
        imu, header, stamp, vector = (writer.msg_class(f"{kind}") for kind in (
            "sensor_msgs/msg/Imu", "std_msgs/msg/Header", "builtin_interfaces/msg/Time", "geometry_msgs/msg/Vector3"))
        quaternion = writer.msg_class("geometry_msgs/msg/Quaternion")
        for k in range(40):
            msg = imu(header=header(stamp=stamp(sec=1000 + k, nanosec=k), frame_id="x" * (k % 9)),
                      orientation=quaternion(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
                      angular_velocity=vector(x=k * 0.5, y=-1.0, z=2.0), angular_velocity_covariance=np.zeros(9),
                      linear_acceleration=vector(x=k * 1.25, y=3.0, z=-4.0),
                      linear_acceleration_covariance=np.full(9, 0.1))
            data = writer.typestore.serialize_cdr(msg, "sensor_msgs/msg/Imu", little_endian=bool(k % 2))
            writer.write_raw(topic, START_NS + k * DT_NS, bytes(data))
    listener = Listener({topic: Imu})
    try:
        proc = replay(ros_domain_id, str(bag), "--wait-for-subscribers", "--delay", "0.3", "--rate", "4")
        assert wait_exit(proc, 60) == 0, proc.output()
        deadline = time.monotonic() + 5
        while len(listener.received[topic]) < 40:
            assert time.monotonic() < deadline, len(listener.received[topic])
            time.sleep(0.05)
        got = [m for _, m in listener.received[topic]]
        assert [(m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id) for m in got] == \
            [(1000 + k, k, "x" * (k % 9)) for k in range(40)]
        assert [(m.linear_acceleration.x, m.angular_velocity.x, m.linear_acceleration_covariance[8]) for m in got] == \
            [(k * 1.25, k * 0.5, 0.1) for k in range(40)]
    finally:
        listener.close()


def test_replay_waits_for_the_number_of_subscriptions_asked(ros_domain_id, short_bag):
    # One subscription matched is not enough with N = 2: a fast probe must not start the replay
    # before a slower node has matched (a looped-bag test once lost its first samples so). A
    # topic of its own: no other test's subscription can count.
    first = Listener({"/test/wait": IoSample})
    second = None
    try:
        proc = replay(ros_domain_id, str(short_bag), "--topics", IO_SAMPLE_TOPIC, "--remap",
                      f"{IO_SAMPLE_TOPIC}:=/test/wait", "--subscribers", "2", "--delay", "0.3")
        proc.wait_for_output(r"waiting for 2 subscriptions on /test/wait \([01] matched\)", 30)
        time.sleep(3.0)  # the first subscription matches well within it
        assert proc.proc.poll() is None and not first.received["/test/wait"], proc.output()
        second = Listener({"/test/wait": IoSample})
        assert wait_exit(proc, 60) == 0, proc.output()
        deadline = time.monotonic() + 5
        while min(len(first.received["/test/wait"]), len(second.received["/test/wait"])) < 250:
            assert time.monotonic() < deadline, (len(first.received["/test/wait"]),
                                                 len(second.received["/test/wait"]))
            time.sleep(0.05)
    finally:
        first.close()
        if second is not None:
            second.close()


def test_the_wait_flag_takes_no_value():
    # `--wait-for-subscribers BAG` reads BAG as the bag (a flag with an optional count swallowed it).
    from okid_ros.cli import build_parser

    args = build_parser().parse_args(["replay", "--wait-for-subscribers", "run"])
    assert args.bag == "run" and args.wait_for_subscribers and args.subscribers is None
    assert build_parser().parse_args(["replay", "run", "--subscribers", "3"]).subscribers == 3


@pytest.mark.dds_startup
def test_replay_errors_are_one_line(ros_domain_id, short_bag, tmp_path):
    cases = (
        ([str(short_bag), "--topics", "/nope"], "no topic /nope"),
        ([str(short_bag), "--remap", "/okid/io_sample"], "must be FROM:=TO"),
        ([str(short_bag), "--rate", "0"], "--rate"),
        ([str(tmp_path / "missing")], "no such bag"),
    )
    procs = [replay(ros_domain_id, *args) for args, _ in cases]  # at once: each one only starts and exits
    for proc, (_, fragment) in zip(procs, cases):
        assert wait_exit(proc, 60) == 2
        # Fast DDS may add colored log lines of its own (e.g. a shared-memory port held elsewhere)
        lines = [line for line in proc.output().splitlines() if line.strip() and not line.startswith("\x1b")]
        assert len(lines) == 1 and lines[0].startswith("okid-ros replay: error: ") and fragment in lines[0], lines


# Pass 1 (6 s at rate 2) brings the first models (a window of 1000 rows is valid from 4 s of data); pass 2
# runs 3 s (750 samples, of which the test asks 200 ModalStates).
LOOP_BAG_S = 12.0


def _states_after_a_jump(received: list) -> int:
    """ModalStates received after the first jump back of their stamps (0 before it)."""
    stamps = np.array([stamp_ns(m) for _, m in list(received)], dtype=np.int64)
    jumps = np.flatnonzero(np.diff(stamps) < -1_000_000_000)
    return len(stamps) - int(jumps[0]) - 1 if len(jumps) else 0


def test_a_looped_replay_jumps_back_in_time_and_the_nodes_keep_running(ros_domain_id, tmp_path):
    """Pass 1 brings the first models; the loop sends the stamps LOOP_BAG_S back.

    With reset_on_time_jump false the nodes go on with their models (the default restart at a
    jump: test_nodes_time_jump.py).
    """
    fast = tmp_path / "fast.yaml"
    fast.write_text(FAST_PARAMS + "/**:\n  ros__parameters:\n    reset_on_time_jump: false\n")
    env = subprocess_env(ros_domain_id)
    nodes = {
        module: RosProcess([sys.executable, "-m", f"okid_ros.nodes.{module}", "--ros-args", "--params-file",
                            str(REPO_ROOT / "config" / "okid.yaml"), "--params-file", str(fast)], env, REPO_ROOT)
        for module in ("arx_identifier_node", "modal_estimator_node")
    }
    listener = Listener({"/okid/modal_states": ModalStates})
    try:
        bag = tmp_path / "loop"  # written while the nodes start
        write_experiment_bag(bag, simulate_experiment(LOOP_BAG_S, start_ns=START_NS))
        for proc in nodes.values():
            proc.wait_for_output(r"ready:", timeout_s=60)
        listener.wait_for_publishers(["/okid/modal_states"])
        player = replay(ros_domain_id, str(bag), "--rate", "2", "--loop", "--duration", f"{LOOP_BAG_S / 2 + 3:g}",
                        "--topics", IO_SAMPLE_TOPIC, "--subscribers", "2", "--delay", "0.5")
        assert wait_exit(player, 90) == 0, player.output()
        assert "pass 2 (stamps jump back" in player.output()
        deadline = time.monotonic() + 1.0  # the states of pass 2 still on their way, if any (was: 1 s always)
        while _states_after_a_jump(listener.received["/okid/modal_states"]) <= 200 and time.monotonic() < deadline:
            time.sleep(0.05)
        states = [m for _, m in listener.received["/okid/modal_states"]]
        stamps = np.array([stamp_ns(m) for m in states])
        jumps = np.flatnonzero(np.diff(stamps) < -1_000_000_000)
        assert len(jumps) == 1, (len(states), stamps[:3], stamps[-3:])
        before, after = states[: jumps[0] + 1], states[jumps[0] + 1:]
        assert stamp_ns(before[-1]) > START_NS + (LOOP_BAG_S - 2) * 1e9  # pass 1 ran to its end
        assert stamp_ns(after[0]) < START_NS + 2 * 1_000_000_000     # pass 2 from the start again
        assert len(after) > 200, len(after)  # and the estimates went on through the jump
        assert all(np.diff([stamp_ns(m) for m in after]) > 0)
        ids = [m.model_id for m in states]
        assert ids == sorted(ids) and ids[0] >= 1  # models are never lost or renumbered
        assert all(len(m.modes) >= 2 for m in after)
        for proc in nodes.values():
            assert proc.proc.poll() is None, proc.output()  # both nodes survived the jump
        assert "Traceback" not in "".join(p.output() for p in nodes.values())
    finally:
        listener.close()
        for proc in nodes.values():
            proc.stop()
