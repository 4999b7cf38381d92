"""`okid-ros record OUT [--namespace NS] [--inputs] [--duration S]`: the nodes' topics to a bag.

Like ``ros2 bag record`` for one rig: subscribes the nodes' outputs (``arx_model``,
``state_space_model``, ``modal_states``, ``structural_change`` in the rig namespace) and ``/diagnostics`` (and with
``--inputs`` the rig's ``io_sample``) and writes every message as it arrived (serialized bytes,
receive time as log time) to a new rosbag2 until Ctrl-C or ``--duration``. An existing output is
never replaced without ``--force``, and with it only by a complete recording: the new bag is written
beside the old one and renamed over it when the recording ends by Ctrl-C, SIGTERM or ``--duration``;
a recording that fails leaves the old bag as it was.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from okid_ros.commands._args import namespace, path_text
from okid_ros.errors import shown_path
from okid_ros.tools.ros_domain import check_ros_environment, ros_context

if TYPE_CHECKING:
    from okid_ros.tools.bagio import BagWriter


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `record`."""
    parser = subparsers.add_parser(
        "record",
        help="record the nodes' topics (models, modal states, diagnostics) to a new bag until Ctrl-C",
        description="Subscribe the output topics of both nodes of one rig (NS/arx_model, NS/state_space_model, "
        "NS/modal_states, NS/structural_change; NS is /okid by default) and /diagnostics, and write every message "
        "to a new rosbag2 "
        "as received, like `ros2 bag record`. Stops on Ctrl-C or after --duration seconds. Never replaces an "
        "existing output without --force.",
    )
    parser.add_argument("out", type=path_text, help="output bag directory to create")
    parser.add_argument("--namespace", type=namespace, default=None, metavar="NS",
                        help="the rig's namespace (nodes started with --namespace NS; default: topics under /okid)")
    parser.add_argument("--inputs", action="store_true", help="also record the rig's io_sample input topic")
    parser.add_argument("--no-diagnostics", action="store_true", help="leave /diagnostics out")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S seconds (default: until Ctrl-C)")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                        help="storage plugin of the bag (default: %(default)s)")
    parser.add_argument("--force", action="store_true", help="replace an existing bag")
    parser.set_defaults(func=run)
    return parser


def record_topics(namespace: str | None, *, inputs: bool, diagnostics: bool) -> dict[str, str]:
    """Topic -> message type recorded for a rig in ``namespace`` (None: /okid)."""
    from okid_ros.service.topics import IO_SAMPLE, output_topics, resolve_topic

    topics = output_topics(namespace)
    if inputs:
        topics[resolve_topic(IO_SAMPLE, namespace)] = "okid_msgs/msg/IoSample"
    if diagnostics:
        topics["/diagnostics"] = "diagnostic_msgs/msg/DiagnosticArray"
    return topics


def run(args: argparse.Namespace) -> int:
    from okid_ros.errors import OkidError
    from okid_ros.tools.bagio import BagWriter
    from okid_ros.tools.output_paths import StagedOutput

    check_ros_environment()  # before rclpy loads
    if args.duration is not None and not args.duration > 0:
        raise OkidError(f"--duration must be a positive number of seconds, got {args.duration}")
    topics = record_topics(args.namespace, inputs=args.inputs, diagnostics=not args.no_diagnostics)
    # --force replaces an old bag only by a complete new recording: one that fails keeps the old bag.
    staged = StagedOutput(args.out, force=args.force)
    writer = None
    try:
        writer = BagWriter(staged.staged, storage=args.storage)
        with writer:
            counts = _record_live(writer, topics, duration=args.duration, out=args.out)
    except BaseException:
        if staged.staged != staged.path or writer is None or not any(writer.counts.values()):
            staged.discard()  # the old bag stays; a new one that holds no message is no recording
        raise  # a new bag with messages stays, closed and readable
    staged.commit()
    written = ", ".join(f"{shown_path(topic)}: {count}" for topic, count in counts.items())
    print(f"okid-ros record: wrote {shown_path(args.out)}: {written}", flush=True)
    return 0


def _record_live(writer: BagWriter, topics: dict[str, str], *, duration: float | None, out: str) -> dict[str, int]:
    """Record ``topics`` into the open ``writer`` until Ctrl-C, SIGTERM or ``duration`` s; messages per topic.

    Those ends are the normal ones (the recording is complete); any other exception is a failure.
    """
    import time

    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    from okid_ros.tools.recorder import LiveRecorder

    context = ros_context()
    try:
        node = rclpy.create_node("okid_record", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        recorder = LiveRecorder(node, writer, topics)
        print(f"okid-ros record: recording {', '.join(map(shown_path, topics))} -> {shown_path(out)} (Ctrl-C stops)",
              flush=True)
        end = None if duration is None else time.monotonic() + duration
        try:
            while end is None or time.monotonic() < end:
                executor.spin_once(timeout_sec=0.1)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    return recorder.counts
