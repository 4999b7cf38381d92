"""`okid-ros info`: versions and environment; `--selftest` sends okid_msgs over DDS."""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from importlib import metadata

from okid_ros import __version__
from okid_ros.commands._args import int_between, positive_finite_float
from okid_ros.errors import OkidError
from okid_ros.tools.ros_domain import check_ros_environment, ros_context

# Distributions whose versions `info` reports, as named on PyPI (ROS wheels: ros-jazzy-*).
_DISTRIBUTIONS = ("numpy", "scipy", "filterpy", "rosbags", "ros-jazzy-rclpy")
_ROS_ENV_VARS = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOCALHOST_ONLY",
                 "RMW_IMPLEMENTATION", "AMENT_PREFIX_PATH")
#: Most --selftest messages. They go one at a time (about 0.2 ms each) and the count is also the
#: QoS depth, which rclpy refuses beyond 64 bits (a TypeError) and Fast DDS keeps in an int32.
MAX_SELFTEST_COUNT = 100_000
#: --selftest's defaults: messages sent, seconds waited.
SELFTEST_DEFAULTS = {"--count": 200, "--timeout": 10.0}


def _selftest_count(text: str) -> int:
    """An integer from 1 to :data:`MAX_SELFTEST_COUNT`."""
    return int_between(1, MAX_SELFTEST_COUNT)(text)


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `info`."""
    parser = subparsers.add_parser(
        "info",
        help="show versions and the ROS environment; --selftest checks DDS",
        description="Show the versions of okid_ros and its dependencies and the ROS "
        "environment. With --selftest, publish okid_msgs/IoSample messages to a subscription "
        "over DDS (rclpy, Fast DDS) and report delivery and latency.",
    )
    parser.add_argument("--selftest", action="store_true",
                        help="publish and receive okid_msgs/IoSample over DDS")
    parser.add_argument("--count", type=_selftest_count, default=SELFTEST_DEFAULTS["--count"], metavar="N",
                        help="messages sent by --selftest (default: %(default)s)")
    parser.add_argument("--timeout", type=positive_finite_float, default=SELFTEST_DEFAULTS["--timeout"], metavar="S",
                        help="seconds --selftest waits for discovery and delivery "
                        "(default: %(default)s)")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Print the report; run the DDS self-test when asked."""
    given = [option for option, default in SELFTEST_DEFAULTS.items()
             if getattr(args, option.lstrip("-")) != default]
    if given and not args.selftest:  # as identify's --frf-pairs without --plot-dir (was passed over in silence)
        print(f"okid-ros info: warning: {', '.join(given)}: options of the DDS self-test, which only --selftest runs; "
              "ignored", file=sys.stderr)
    print(f"okid_ros {__version__}")
    print(f"python {platform.python_version()} ({sys.executable})")
    for dist in _DISTRIBUTIONS:
        try:
            version = metadata.version(dist)
        except metadata.PackageNotFoundError:
            version = "not installed"
        print(f"{dist} {version}")
    for var in _ROS_ENV_VARS:
        print(f"{var}={os.environ.get(var, '')}")
    if args.selftest:
        _selftest(args.count, args.timeout)
    return 0


def _selftest(count: int, timeout_s: float) -> None:
    """Send `count` IoSample messages between two nodes over DDS; raise OkidError on failure."""
    check_ros_environment()  # before rclpy loads
    try:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from okid_msgs.msg import IoSample
    except ImportError as exc:
        raise OkidError(f"ROS 2 is not available ({exc}); run `make setup` or source ROS") from exc

    context = ros_context()
    try:
        # Two nodes, so the message travels through the middleware from one to the other.
        pub_node = rclpy.create_node("okid_selftest_pub", context=context)
        sub_node = rclpy.create_node("okid_selftest_sub", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(pub_node)
        executor.add_node(sub_node)
        topic = f"/okid/selftest_{os.getpid()}"
        qos = QoSProfile(depth=count, reliability=ReliabilityPolicy.RELIABLE)
        latencies_s: list[float] = []

        def on_sample(msg: IoSample) -> None:
            latencies_s.append(time.monotonic() - msg.y[0])

        sub_node.create_subscription(IoSample, topic, on_sample, qos)
        publisher = pub_node.create_publisher(IoSample, topic, qos)

        deadline = time.monotonic() + timeout_s
        while publisher.get_subscription_count() < 1:
            if time.monotonic() > deadline:
                raise OkidError(f"self-test: no subscription matched within {timeout_s} s")
            executor.spin_once(timeout_sec=0.05)

        # One message in flight at a time, so the latency is the middleware's, not a queue's.
        for i in range(count):
            if time.monotonic() > deadline:
                break  # publishing on without spinning slowed down ever more (80000: 80 s past a 3 s timeout)
            msg = IoSample()
            msg.header.stamp = pub_node.get_clock().now().to_msg()
            msg.u = [float(i), -float(i)]
            msg.y = [time.monotonic(), 0.0]  # send time, for the latency
            publisher.publish(msg)
            while len(latencies_s) <= i and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
        if len(latencies_s) < count:
            raise OkidError(f"self-test: received {len(latencies_s)} of {count} messages "
                            f"within {timeout_s} s")
        latencies_ms = sorted(1e3 * t for t in latencies_s)
        p99 = latencies_ms[min(len(latencies_ms) - 1, int(0.99 * len(latencies_ms)))]
        print(f"selftest: {count}/{count} okid_msgs/IoSample delivered over "
              f"{rclpy.get_rmw_implementation_identifier()} on {topic}; latency "
              f"median {statistics.median(latencies_ms):.3f} ms, p99 {p99:.3f} ms")
        executor.shutdown()
    finally:
        context.try_shutdown()
