"""Hostile options of the ROS commands `info`, `replay`, `monitor`, `up` and `demo`: one line, exit 2, no hang.

Each case once ended in a traceback (exit 70) or a wait without end: a count, depth or window
beyond 64 bits (rclpy's QoS and ``deque(maxlen=...)`` refuse them with TypeError and
OverflowError), a NaN or infinite ``--delay`` (``nan < 0`` is False, so the wait never ended),
``--clock 0`` (silently 100 Hz), a remap onto a topic of another message type (rcl's RCLError),
an invalid ``--topic``. ROS_DOMAIN_ID is this session's (conftest.py).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from okid_ros import cli
from okid_ros.tools.errors import ToolParameterError
from okid_ros.tools.monitor import MAX_WINDOW_SAMPLES, ModalStatesView
from okid_ros.tools.replay import BagPlayer
from okid_ros.tools.ros_domain import installed_rmw_implementations, rmw_implementation
from okid_ros.tools.simulate_bag import IMU_TOPICS, IO_SAMPLE_TOPIC, simulate_experiment, write_experiment_bag

HUGE = "99999999999999999999"  # beyond 64 bits
REPO_ROOT = Path(__file__).resolve().parents[2]


def usage_error(capsys, argv: list[str]) -> str:
    """The error line of an argparse refusal of ``argv`` (exit status 2)."""
    with pytest.raises(SystemExit) as stopped:
        cli.main(argv)
    assert stopped.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith(f"okid-ros {argv[0]}: error: argument "), lines
    return lines[-1]


def one_line_error(capsys, argv: list[str]) -> str:
    """The one line a command prints when it refuses ``argv`` (exit status 2)."""
    assert cli.main(argv) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip() and not line.startswith("\x1b")]
    assert len(lines) == 1 and lines[0].startswith(f"okid-ros {argv[0]}: error: "), lines
    return lines[0]


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory) -> Path:
    bag = tmp_path_factory.mktemp("hostile_replay") / "short"
    write_experiment_bag(bag, simulate_experiment(0.5), storage="sqlite3")
    return bag


@pytest.mark.parametrize("argv, option", [
    (["info", "--selftest", "--count", HUGE], "--count"),
    (["info", "--selftest", "--count", "0"], "--count"),
    (["info", "--selftest", "--timeout", "nan"], "--timeout"),  # was "received 0 of 200 messages within nan s"
    (["info", "--selftest", "--timeout", "-1"], "--timeout"),
    (["replay", "bag", "--queue-depth", HUGE], "--queue-depth"),
    (["replay", "bag", "--delay", "nan"], "--delay"),
    (["replay", "bag", "--delay", "inf"], "--delay"),
    (["replay", "bag", "--delay", "-1"], "--delay"),
    (["replay", "bag", "--clock", "0"], "--clock"),
    (["replay", "bag", "--clock", "1e-300"], "--clock"),  # the clock step in ns overflowed
    (["monitor", "--window", HUGE], "--window"),
    (["up", "--params", "p.yaml", "--grace", "nan"], "--grace"),  # was taken: nan > 0 is False, and nan <= 0 too
])
def test_out_of_range_options_are_usage_errors(capsys, argv, option):
    assert option in usage_error(capsys, argv)


@pytest.mark.parametrize("command", [["process", "bag", "--out", "o"], ["plot", "bag"], ["record", "o"], ["monitor"],
                                     ["up"], ["batch", "bags", "--out", "o"]])
def test_every_namespace_option_refuses_an_invalid_name_before_anything_runs(capsys, tmp_path, monkeypatch, command):
    monkeypatch.chdir(tmp_path)
    line = usage_error(capsys, [*command, "--namespace", "rig 1!"])
    assert "--namespace" in line and "'rig 1!' is not valid" in line
    assert not any(tmp_path.iterdir())  # nothing was started or written


@pytest.mark.parametrize("options", [
    {"delay_s": math.nan}, {"delay_s": math.inf}, {"rate": 1e-300}, {"queue_depth": 10**20},
    {"clock_hz": 0.0}, {"clock_hz": math.inf},
])
def test_the_player_refuses_what_would_never_end_or_overflow(options):
    # checked before the bag is opened: no bag needed
    with pytest.raises(ToolParameterError):
        BagPlayer("no_such_bag", **options)


def test_the_monitor_view_refuses_a_window_beyond_its_limit():
    with pytest.raises(ToolParameterError, match="--window"):
        ModalStatesView(window_samples=MAX_WINDOW_SAMPLES + 1)
    assert ModalStatesView(window_samples=MAX_WINDOW_SAMPLES).innovation_sq.maxlen == MAX_WINDOW_SAMPLES


def test_a_remap_onto_a_topic_of_another_type_names_both(capsys, short_bag):
    line = one_line_error(capsys, ["replay", "--delay", "0", str(short_bag), "--remap",
                                   f"{IO_SAMPLE_TOPIC}:={IMU_TOPICS[0]}"])
    assert f"{IO_SAMPLE_TOPIC} (okid_msgs/msg/IoSample) on {IMU_TOPICS[0]}" in line, line
    assert f"{IMU_TOPICS[0]} (sensor_msgs/msg/Imu)" in line, line


def test_a_topic_remapped_twice_is_refused(capsys, short_bag):
    """Was: the later target taken in silence, the first remap lost."""
    line = one_line_error(capsys, ["replay", "--delay", "0", str(short_bag), "--remap", f"{IO_SAMPLE_TOPIC}:=/a",
                                   f"{IO_SAMPLE_TOPIC}:=/b"])
    assert f"--remap {IO_SAMPLE_TOPIC} is given twice, to /a and to /b" in line, line


def test_a_topic_listed_twice_is_replayed_as_one(short_bag):
    """Was: "2500 messages on 2 topics" for --topics /okid/io_sample /okid/io_sample."""
    player = BagPlayer(short_bag, topics=[IO_SAMPLE_TOPIC, IO_SAMPLE_TOPIC], log=lambda line: None)
    assert player.topics == [IO_SAMPLE_TOPIC]


@pytest.mark.parametrize("spoilt", [-90000, 0])
def test_the_replay_plan_counts_the_stored_messages_and_names_a_spoilt_metadata_count(tmp_path, short_bag, spoilt):
    """Was: "replay BAG: -90000 messages on 1 topics" while every stored message was played.

    A count of 0 also warned "no message to replay" before playing them.
    """
    import shutil
    import warnings

    import yaml

    from okid_ros.tools.bagio import open_bag

    bag = tmp_path / "spoilt"
    shutil.copytree(short_bag, bag)
    with open_bag(bag) as opened:
        stored = sum(1 for _ in opened.raw_messages([IO_SAMPLE_TOPIC]))
    meta = bag / "metadata.yaml"
    info = yaml.safe_load(meta.read_text())
    for entry in info["rosbag2_bagfile_information"]["topics_with_message_count"]:
        if entry["topic_metadata"]["name"] == IO_SAMPLE_TOPIC:
            entry["message_count"] = spoilt
    meta.write_text(yaml.safe_dump(info))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        player = BagPlayer(bag, topics=[IO_SAMPLE_TOPIC], log=lambda line: None)
    assert stored > 0 and player.message_count == stored
    assert player.plan().startswith(f"replay {bag}: {stored} messages (metadata.yaml says {spoilt}) on 1 topics")
    assert "metadata.yaml" not in BagPlayer(short_bag, topics=[IO_SAMPLE_TOPIC], log=lambda line: None).plan()


@pytest.mark.dds  # a node and its publisher, nothing published
def test_a_bag_without_messages_on_its_topics_is_said(capsys, tmp_path, short_bag):
    """Was: "replayed 0 messages on 1 topics", exit 0, and not a word more."""
    import warnings

    from okid_ros.tools.bagio import BagWriter

    empty = tmp_path / "empty"
    with BagWriter(empty) as writer:
        writer.add_topic(IO_SAMPLE_TOPIC, "okid_msgs/msg/IoSample")
    assert cli.main(["replay", "--delay", "0", str(empty)]) == 0
    err = capsys.readouterr().err
    assert f"okid-ros replay: warning: {empty}: no message to replay on {IO_SAMPLE_TOPIC}: nothing is published" \
        in err, err
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        BagPlayer(short_bag, log=lambda line: None)  # messages to replay: nothing said


def test_two_topics_of_one_type_remapped_onto_one_are_named():
    """Two accelerometers on one topic: their messages interleave (was: said by nothing)."""
    from okid_ros.errors import OkidWarning
    from okid_ros.tools.replay import _check_one_type_per_topic

    class Node:
        def resolve_topic_name(self, name: str) -> str:
            return name

    imu = "sensor_msgs/msg/Imu"
    with pytest.warns(OkidWarning, match=f"{IMU_TOPICS[0]} and {IMU_TOPICS[1]} are both published on /x: their "
                      "messages interleave there"):
        _check_one_type_per_topic(Node(), [(IMU_TOPICS[0], "/x", imu), (IMU_TOPICS[1], "/x", imu)])


def test_a_remap_onto_clock_with_clock_is_refused(capsys, short_bag):
    line = one_line_error(capsys, ["replay", "--delay", "0", "--clock", "50", str(short_bag), "--remap",
                                   f"{IO_SAMPLE_TOPIC}:=clock"])  # relative: resolves to /clock
    assert "rosgraph_msgs/msg/Clock" in line and "okid_msgs/msg/IoSample" in line, line


@pytest.mark.parametrize("topic", ["bad topic!!", "", "{nope}/x"])
def test_monitor_refuses_an_invalid_topic_in_one_line(capsys, topic):
    started = time.monotonic()
    line = one_line_error(capsys, ["monitor", "--no-ansi", "--duration", "20", "--topic", topic])
    assert f"--topic {topic!r}" in line and time.monotonic() - started < 10, line


@pytest.mark.dds_startup
def test_selftest_stops_publishing_at_its_timeout(ros_env):
    """100000 messages against a 0.5 s timeout: it once published on for minutes, ever slower."""
    started = time.monotonic()
    result = subprocess.run([sys.executable, "-m", "okid_ros.cli", "info", "--selftest", "--count", "100000",
                             "--timeout", "0.5"], env=ros_env, capture_output=True, text=True, timeout=14)
    assert result.returncode == 2 and "self-test:" in result.stderr, result.stderr
    assert time.monotonic() - started < 14


def _status(argv: list[str]) -> int:
    """``okid-ros ARGV``'s exit status, argparse's refusals (SystemExit) included."""
    try:
        return cli.main(argv)
    except SystemExit as stopped:
        return stopped.code


@pytest.mark.parametrize("options, option", [
    (["--seed", "-1"], "--seed"),  # was: refused after the run folder was made, left empty
    (["--output-only", "--seed", "-1"], "--seed"),  # was: numpy's ValueError, internal error (exit 70)
    (["--output-only", "--duration", "1e300"], "--duration"),  # was: "Maximum allowed dimension exceeded", 70
    (["--duration", "1e300"], "--duration"),  # was: refused after the run folder was made
])
def test_demo_refuses_an_option_out_of_range_before_making_a_run_folder(capsys, tmp_path, options, option):
    runs = tmp_path / "runs"
    assert _status(["demo", "--no-ansi", "--out-dir", str(runs), *options]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith("okid-ros demo: error: ") and option in lines[-1], lines
    assert "Traceback" not in "".join(lines) and not runs.exists()


@pytest.mark.parametrize("options, said", [
    # Was: the replay, then 30 s of waiting, then "node 1 published no valid ArxModel".
    (["--duration", "0.1"], "--duration 0.1 s is shorter than node 1's first window, 16.8 s (2100 samples of 0.008 s: "
     "arx.min_window_fill 0.5 of arx.window_length 4000 rows, plus arx.order 100): no model would come; give at "
     "least 17 s, or a shorter window"),
    (["--output-only", "--duration", "10"], "--duration 10 s is shorter than node 1's first window, 30.05 s (6010 "
     "samples of 0.005 s: arx.min_window_fill 0.5 of arx.window_length 12000 rows, plus arx.order 10)"),
    # Was: the whole experiment replayed at once, the nodes' queues overrun.
    (["--rate", "1e300"], "--rate must be from 0.1 to 5 (times real time: the nodes take the samples live), "
     "got 1e+300"),
    (["--rate", "0.001"], "--rate must be from 0.1 to 5"),
    (["--rate", "5.0000001"], "(times real time: the nodes take the samples live), got 5.0000001"),  # was: got 5
    (["--rate", "nan"], "--rate must be from 0.1 to 5"),
])
def test_demo_refuses_an_experiment_without_a_model_and_a_rate_the_nodes_cannot_take(capsys, tmp_path, options, said):
    runs = tmp_path / "runs"
    started = time.monotonic()
    line = one_line_error(capsys, ["demo", "--no-ansi", "--out-dir", str(runs), *options])
    assert said in line, line
    assert not runs.exists() and time.monotonic() - started < 10


def test_demo_names_an_out_dir_it_cannot_make_in_one_line(capsys, tmp_path):
    """A file as --out-dir: named as one, exit 2.

    Was: NotADirectoryError, internal error, exit 70; then the run folder's "cannot create the parent folder (File
    exists)".
    """
    (tmp_path / "a_file").write_text("")
    line = one_line_error(capsys, ["demo", "--no-ansi", "--duration", "20", "--out-dir", str(tmp_path / "a_file")])
    assert line.endswith(f"--out-dir {tmp_path / 'a_file'}: is a file, not a folder"), line
    assert (tmp_path / "a_file").is_file() and list(tmp_path.iterdir()) == [tmp_path / "a_file"]


@pytest.mark.parametrize("command", ["up", "demo"])
@pytest.mark.parametrize("case, reason", [("folder", "Is a directory"), ("record", "not UTF-8 text"),
                                          ("device", "not a regular file (a device)")])
def test_a_params_file_the_nodes_cannot_read_is_refused_before_anything_starts(capsys, tmp_path, command, case,
                                                                                reason):
    """Read as `process` reads one, before a node starts or the demo simulates.

    Was: "does not exist" for a folder or /dev/null; rcl's parse error from each node for a record
    (`demo`: after its simulation, in a run folder).
    """
    (tmp_path / "record.npz").write_bytes(bytes(range(256)))
    params = {"folder": tmp_path, "record": tmp_path / "record.npz", "device": "/dev/null"}[case]
    started = time.monotonic()
    line = one_line_error(capsys, [command, "--params", str(params), *(["--out-dir", str(tmp_path / "runs")]
                                                                        if command == "demo" else [])])
    assert str(params) in line and reason in line, line
    assert not (tmp_path / "runs").exists() and time.monotonic() - started < 10


MODAL_STATES = "okid_msgs/msg/ModalStates"


class _Graph:
    """The ROS graph as a node sees it: topic -> (types, publishers)."""

    def __init__(self, topics: dict[str, tuple[list[str], int]]) -> None:
        self.topics = topics

    def resolve_topic_name(self, topic: str) -> str:
        return topic if topic.startswith("/") else f"/{topic}"

    def get_topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        return [(name, types) for name, (types, _) in self.topics.items()]

    def count_publishers(self, topic: str) -> int:
        return self.topics.get(topic, ([], 0))[1]


@pytest.mark.parametrize("topics, topic, said", [
    # --topic of another type: rclpy matches no publisher, and the monitor said only "no ModalStates"
    ({"/okid/io_sample": (["okid_msgs/msg/IoSample", MODAL_STATES], 1)}, "/okid/io_sample",
     ": /okid/io_sample carries okid_msgs/msg/IoSample (the wrong --topic?)"),
    # the nodes in another namespace
    ({"/okid/modal_states": ([MODAL_STATES], 0), "/rig/modal_states": ([MODAL_STATES], 1)}, "/okid/modal_states",
     "; ModalStates are published on /rig/modal_states (another --topic or --namespace?)"),
    ({"/okid/modal_states": ([MODAL_STATES], 0)}, "/okid/modal_states", ""),  # nothing to add
])
def test_monitor_says_why_no_modal_states_came(topics, topic, said):
    from okid_ros.tools.monitor import _silence_reason

    assert _silence_reason(_Graph(topics), topic) == said


def test_info_names_selftest_options_given_without_selftest(capsys):
    """Was: passed over in silence (no DDS self-test ran)."""
    assert cli.main(["info", "--count", "5"]) == 0
    assert ("okid-ros info: warning: --count: options of the DDS self-test, which only --selftest runs; ignored"
            in capsys.readouterr().err)
    assert cli.main(["info"]) == 0 and "warning" not in capsys.readouterr().err


@pytest.mark.parametrize("argv, watched", [
    (["--namespace", "/rig", "--topic", "modal_states"], "/rig/modal_states"),  # was /modal_states, --namespace lost
    (["--topic", "modal_states"], "/okid/modal_states"),  # was /modal_states: not the default's rig namespace
    (["--namespace", "/rig", "--topic", "/x/modal_states"], "/x/modal_states"),  # absolute: as given
])
def test_a_relative_monitor_topic_is_in_the_rig_namespace(capsys, argv, watched):
    line = one_line_error(capsys, ["monitor", "--no-ansi", "--once", "--duration", "0.3", *argv])
    assert f"no okid_msgs/ModalStates on {watched} within 0.3 s" in line, line


def test_the_demo_says_node_1_published_nothing_rather_than_blame_node_2():
    """`demo --duration 0.1`: no valid ArxModel came; the note said "node 2 was still busy 30 s after the replay"."""
    from okid_ros.tools.demo import _unsettled_note

    assert _unsettled_note(0, 0.1) == ("node 1 published no valid ArxModel: is the experiment (0.1 s) shorter than "
                                       "its first window (arx.window_length)? see nodes.log")
    assert _unsettled_note(3, 60.0).startswith("node 2 was still busy 30 s after the replay")


@pytest.mark.parametrize("domain_id, said", [("abc", "ROS_DOMAIN_ID='abc' is not an integer"),
                                             ("300", "ROS_DOMAIN_ID=300 is beyond 232")])
@pytest.mark.parametrize("argv", [["monitor", "--no-ansi", "--once", "--duration", "0.3"],
                                  ["info", "--selftest", "--timeout", "0.3"],
                                  ["up", "--params", str(Path(__file__).parents[2] / "config" / "okid.yaml")],
                                  ["demo", "--duration", "20", "--out-dir", "{tmp}/runs"]])
def test_a_ros_domain_id_ros_cannot_use_is_one_line_before_anything_starts(capsys, tmp_path, monkeypatch, domain_id,
                                                                            said, argv):
    """Checked before rclpy, a node or the demo's run folder (`tools/ros_domain.py`).

    Was: rcl's RCLError (`monitor`, `info`, `replay`, `record`) or `demo`'s ValueError, internal errors, exit 70;
    beyond 232 `monitor` and `up` ended with status 1 after Fast DDS's "Calculated port number is too high".
    """
    monkeypatch.setenv("ROS_DOMAIN_ID", domain_id)
    line = one_line_error(capsys, [a.format(tmp=tmp_path) for a in argv])
    assert said in line, line
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("argv", [["monitor", "--no-ansi", "--once", "--duration", "0.3"],
                                  ["info", "--selftest", "--timeout", "0.3"],
                                  ["up", "--params", str(REPO_ROOT / "config" / "okid.yaml")],
                                  ["demo", "--duration", "20", "--out-dir", "{tmp}/runs"],
                                  ["replay", "{tmp}/bag"],
                                  ["record", "{tmp}/out", "--duration", "0.3"]])
def test_an_rmw_implementation_not_installed_is_one_line_before_rclpy_loads(tmp_path, argv):
    """Checked before rclpy loads, whose rcl ended the process at once (`tools/ros_domain.py`).

    Was: rcl's "Expected RMW implementation identifier of 'rmw_bogus' but instead found 'rmw_fastrtps_cpp',
    exiting with 102." and status 102 (a process of its own here: it would end pytest's).
    """
    env = {**os.environ, "RMW_IMPLEMENTATION": "rmw_bogus"}
    done = subprocess.run([sys.executable, "-m", "okid_ros.cli", *[a.format(tmp=tmp_path) for a in argv]], env=env,
                          cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and len(lines) == 1, (done.returncode, done.stderr)
    installed, _ = installed_rmw_implementations()
    assert lines[0] == (f"okid-ros {argv[0]}: error: RMW_IMPLEMENTATION='rmw_bogus' is not installed (installed: "
                        f"{', '.join(installed)}): set one of those, or unset it for the default"), lines
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no run folder, no bag


def test_an_rmw_implementation_is_known_by_the_ament_index_or_its_library(tmp_path):
    installed, _ = installed_rmw_implementations()
    assert installed and "rmw_implementation" not in installed  # the dispatcher is none
    assert rmw_implementation({"RMW_IMPLEMENTATION": installed[0]}) == installed[0]
    assert rmw_implementation({"RMW_IMPLEMENTATION": ""}) is None and rmw_implementation({}) is None
    (tmp_path / "librmw_elsewhere.so").write_bytes(b"")  # installed outside the index (LD_LIBRARY_PATH)
    env = {"RMW_IMPLEMENTATION": "rmw_elsewhere", "LD_LIBRARY_PATH": str(tmp_path)}
    assert rmw_implementation(env) == "rmw_elsewhere"
    with pytest.raises(ToolParameterError, match="RMW_IMPLEMENTATION='rmw_elsewhere' is not installed"):
        rmw_implementation({"RMW_IMPLEMENTATION": "rmw_elsewhere"})
