"""`okid-ros simulate --out BAG [--duration S] [--storage mcap|sqlite3]`.

Records a simulated experiment like the paper's (two thrusters, two tip accelerometers,
125 Hz) as a rosbag2, with the true modes in the bag metadata.
"""

from __future__ import annotations

import argparse

from okid_ros.commands._args import float_between, int_between, positive_finite_float
from okid_ros.errors import shown_path


def _start_time(text: str) -> float:
    """Seconds since the epoch that a ROS 2 stamp can hold (not negative: a bag's log time is unsigned)."""
    from okid_ros.tools.simulate_bag import MAX_STAMP_S

    return float_between(0.0, MAX_STAMP_S, "seconds since the epoch from {low:.0f} to {high:.0f} (a ROS 2 "
                         "stamp's sec is an int32)")(text)


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `simulate`."""
    parser = subparsers.add_parser(
        "simulate",
        help="record a simulated paper-like experiment as a rosbag2 (truth in its metadata)",
        description="Simulate the structure published by Chen, Huang & Juang (1991) (3 modes, 2 thrusters, "
        "2 tip accelerometers, 125 Hz) and write a rosbag2 with /thruster{1,2}/wrench "
        "(geometry_msgs/WrenchStamped, force.x), /accel/tip{1,2}/imu (sensor_msgs/Imu, "
        "linear_acceleration.x) and /okid/io_sample (okid_msgs/IoSample). The true modes and matrices "
        "are stored in metadata.yaml, custom_data key okid_ros.truth (JSON).",
    )
    parser.add_argument("--out", required=True, metavar="BAG", help="bag directory to create (must not exist)")
    parser.add_argument("--duration", type=float, default=60.0, metavar="S",
                        help="length of the record (default: %(default)s s)")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                        help="rosbag2 storage plugin (default: %(default)s)")
    parser.add_argument("--seed", type=int_between(0), default=1,
                        help="seed of input and noise, an integer >= 0 (default: %(default)s)")
    parser.add_argument("--cutoff", type=float, default=15.0, metavar="HZ",
                        help="low-pass cut-off of the thruster signals, from 0.001 to below 62.5 Hz "
                        "(default: %(default)s Hz)")
    parser.add_argument("--noise", type=positive_finite_float, default=1.0, metavar="R",
                        help="innovation variance r > 0, Re = r I, at most 1e280 (default: %(default)s)")
    parser.add_argument("--start-time", type=_start_time, default=None, metavar="SEC",
                        help="stamp of the first sample in seconds since the epoch, from 0 to 2**31 - 1 with "
                        "the whole record (a ROS 2 stamp's sec is an int32; default: now)")
    parser.add_argument("--force", action="store_true", help="replace an existing bag at --out")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from okid_ros.tools.simulate_bag import simulate_experiment, write_experiment_bag

    start_ns = None if args.start_time is None else int(round(args.start_time * 1e9))
    experiment = simulate_experiment(args.duration, seed=args.seed, cutoff_hz=args.cutoff,
                                     innovation_variance=args.noise, start_ns=start_ns)
    counts = write_experiment_bag(args.out, experiment, storage=args.storage, force=args.force)
    print(f"wrote {shown_path(args.out)} ({args.storage}): {experiment.n_samples} samples at "
          f"{1 / experiment.sample_time_s:g} Hz, {experiment.n_samples * experiment.sample_time_s:g} s, "
          f"{sum(counts.values())} messages")
    for topic, count in counts.items():
        print(f"  {topic}: {count}")
    print("true modes (metadata custom_data okid_ros.truth):")
    for mode in experiment.truth["modes"]:
        note = "" if mode["in_paper_table"] else "  (published A, not in the paper's table)"
        print(f"  {mode['frequency_rad_s']:9.4f} rad/s {mode['frequency_hz']:8.4f} Hz  "
              f"damping {100 * mode['damping_ratio']:6.3f} %{note}")
    return 0
