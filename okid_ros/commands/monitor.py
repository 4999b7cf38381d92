"""`okid-ros monitor [--topic T] [--once] [--duration S]`: live terminal view of the modes."""

from __future__ import annotations

import argparse

from okid_ros.commands._args import int_between, namespace


def _window_samples(text: str) -> int:
    """An integer from 1 to MAX_WINDOW_SAMPLES (a deque's maxlen overflowed beyond 64 bits)."""
    from okid_ros.tools.monitor import MAX_WINDOW_SAMPLES

    return int_between(1, MAX_WINDOW_SAMPLES)(text)


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `monitor`."""
    parser = subparsers.add_parser(
        "monitor",
        help="live terminal table of the identified modes from okid_msgs/ModalStates",
        description="Subscribe to okid_msgs/ModalStates and show one row per mode: id, frequency "
        "(Hz, rad/s), damping ratio, trend of the frequency, EMAC, MPC, MSV, MAC, stability and the RMS "
        "amplitude of its modal coordinates over recent samples. On a terminal the table is redrawn in "
        "place; otherwise (pipe, file) a table is printed every --interval seconds.",
    )
    parser.add_argument("--topic", default=None,
                        help="ModalStates topic; a relative name is in the rig namespace, as the nodes' topics are "
                        "(default: modal_states, /okid/modal_states)")
    parser.add_argument("--namespace", type=namespace, default=None, metavar="NS",
                        help="the rig's namespace (nodes started with --namespace NS): shows NS/modal_states")
    parser.add_argument("--once", action="store_true",
                        help="print one table after the first message and exit (waits up to --duration, "
                        "default 30 s; exit status 2 if nothing arrives)")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="exit after S seconds (default: run until Ctrl-C)")
    parser.add_argument("--interval", type=float, default=None, metavar="S",
                        help="seconds between tables (default: 0.25 on a terminal, 2 otherwise)")
    parser.add_argument("--window", type=_window_samples, default=250, metavar="N",
                        help="samples in the RMS amplitude (default: %(default)s)")
    parser.add_argument("--trend-window", type=float, default=10.0, metavar="S",
                        help="look-back of the frequency trend in stamp seconds (default: %(default)s)")
    parser.add_argument("--no-ansi", action="store_true", help="never redraw in place, print tables")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from okid_ros.errors import ParameterError
    from okid_ros.service.topics import MODAL_STATES, resolve_topic
    from okid_ros.tools.errors import ToolParameterError
    from okid_ros.tools.ros_domain import check_ros_environment

    check_ros_environment()  # before rclpy loads
    from okid_ros.tools.monitor import run_monitor

    # A relative --topic is in the rig namespace, as the default and the nodes' topics are (was: under
    # /, and --namespace passed over: `--namespace /rig --topic modal_states` watched /modal_states).
    # `--topic ''` is refused, not taken for the default in silence.
    try:
        topic = resolve_topic(MODAL_STATES if args.topic is None else args.topic, args.namespace)
    except ParameterError as exc:
        raise ToolParameterError(f"--topic {args.topic!r}: cannot subscribe: {exc}") from None
    try:
        run_monitor(topic, once=args.once, duration_s=args.duration, interval_s=args.interval,
                    window_samples=args.window, trend_window_s=args.trend_window,
                    ansi=False if args.no_ansi else None)
    except KeyboardInterrupt:
        return 0
    return 0
