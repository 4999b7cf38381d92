"""`okid-ros replay BAG [--rate X] [--loop] [--topics T ...] [--remap FROM:=TO ...]`.

Publishes a bag's messages on live topics with their original timing (like `ros2 bag play`).
"""

from __future__ import annotations

import argparse

from okid_ros.commands._args import float_between, int_between, path_text
from okid_ros.errors import shown_path


def _delay_s(text: str) -> float:
    """Seconds from 0 to MAX_DELAY_S (NaN and inf once made the player wait forever)."""
    from okid_ros.tools.replay import MAX_DELAY_S

    return float_between(0.0, MAX_DELAY_S, "seconds from {low:g} to {high:g}")(text)


def _clock_hz(text: str) -> float:
    """A /clock rate in CLOCK_HZ_RANGE (0 is refused: it once became 100 Hz in silence)."""
    from okid_ros.tools.replay import CLOCK_HZ_RANGE

    return float_between(*CLOCK_HZ_RANGE, "a rate from {low:g} to {high:g} Hz")(text)


def _queue_depth(text: str) -> int:
    """A history depth from 1 to MAX_QUEUE_DEPTH (rclpy raised a TypeError beyond 64 bits)."""
    from okid_ros.tools.replay import MAX_QUEUE_DEPTH

    return int_between(1, MAX_QUEUE_DEPTH)(text)


def _subscriptions(text: str) -> int:
    """A number of subscriptions from 1 to MAX_SUBSCRIBERS."""
    from okid_ros.tools.replay import MAX_SUBSCRIBERS

    return int_between(1, MAX_SUBSCRIBERS)(text)


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `replay`."""
    parser = subparsers.add_parser(
        "replay",
        help="publish a bag on live topics with its original timing (like ros2 bag play)",
        description="Publish the messages of a rosbag2 (sqlite3 or MCAP) or ROS 1 bag on live ROS 2 "
        "topics, spaced as recorded (log time), with the header stamps as recorded. With --loop the "
        "bag starts again at its end; the stamps then jump back to the start of the bag.",
    )
    parser.add_argument("bag", type=path_text, help="bag directory, .mcap or .db3 file")
    parser.add_argument("--rate", type=float, default=1.0, metavar="X",
                        help="playback speed factor (default: %(default)s)")
    parser.add_argument("--loop", action="store_true", help="start again at the end of the bag, until Ctrl-C")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC", help="play only these topics (default: all)")
    parser.add_argument("--remap", nargs="+", action="append", default=[], metavar="FROM:=TO",
                        help="publish bag topic FROM on TO (repeatable)")
    parser.add_argument("--namespace", default=None, metavar="NS",
                        help="publish the bag's topics of the default rig namespace /okid in NS instead "
                        "(/okid/io_sample -> NS/io_sample), for nodes started with --namespace NS")
    parser.add_argument("--delay", type=_delay_s, default=0.5, metavar="S",
                        help="wait after creating the publishers so subscribers discover them "
                        "(default: %(default)s s)")
    parser.add_argument("--wait-for-subscribers", action="store_true",
                        help="before playing, wait until every replayed topic has a subscriber (then --delay)")
    parser.add_argument("--subscribers", type=_subscriptions, default=None, metavar="N",
                        help="with --wait-for-subscribers (implied): wait for N matched subscriptions on every "
                        "replayed topic, e.g. 2 for both nodes (default: 1)")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S seconds of playback (default: the whole bag, or forever with --loop)")
    parser.add_argument("--clock", nargs="?", type=_clock_hz, const=100.0, default=None, metavar="HZ",
                        help="also publish the bag time on /clock at HZ (default 100) for use_sim_time nodes")
    parser.add_argument("--queue-depth", type=_queue_depth, default=1000, metavar="N",
                        help="history depth of each publisher (default: %(default)s)")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from okid_ros.tools.ros_domain import check_ros_environment

    check_ros_environment()  # before rclpy loads
    from okid_ros.tools.replay import BagPlayer, parse_remaps

    remaps = parse_remaps([item for group in args.remap for item in group])
    player = BagPlayer(
        args.bag, rate=args.rate, loop=args.loop, topics=args.topics, remaps=remaps, delay_s=args.delay,
        duration_s=args.duration, queue_depth=args.queue_depth, clock=args.clock is not None,
        clock_hz=100.0 if args.clock is None else args.clock,
        wait_for_subscribers=args.subscribers or int(args.wait_for_subscribers), namespace=args.namespace,
    )
    stats = player.run()
    print(f"replayed {stats.total} messages on {len(stats.published)} topics in {stats.wall_time_s:.1f} s "
          f"({stats.passes} pass{'es' if stats.passes != 1 else ''}; largest lag {1e3 * stats.max_lag_s:.1f} ms)")
    for topic, count in sorted(stats.published.items()):
        print(f"  {shown_path(topic)}: {count}")
    return 0
