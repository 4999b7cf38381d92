"""`okid-ros record --force`: an old bag is replaced only by a complete new recording.

rclpy's node and executor and the recorder are stood in for (no DDS): each spin writes one message
to the bag and the recording then ends as a test says, by Ctrl-C (SIGTERM arrives as the same
KeyboardInterrupt), by ``--duration`` or by a failure. test/tools/test_tools_record.py records over DDS.
"""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import pytest
import rclpy
import rclpy.executors
from cli_helpers import assert_one_line_error, run_cli

import okid_ros.tools.recorder
from okid_ros.tools.bagio import BagWriter, open_bag
from okid_ros.tools.errors import BagWriteError


def _diagnostics(writer: BagWriter):
    header = writer.msg_class("std_msgs/msg/Header")(
        stamp=writer.msg_class("builtin_interfaces/msg/Time")(sec=1, nanosec=0), frame_id="")
    return writer.msg_class("diagnostic_msgs/msg/DiagnosticArray")(header=header, status=[])


class _Rig:
    """Stands in for rclpy and the LiveRecorder: each spin writes a /diagnostics message, the fourth ends as ``end``.

    ``end``: an exception the fourth spin raises, or None (spins until ``--duration`` ends the recording).
    """

    def __init__(self, monkeypatch, end: BaseException | None) -> None:
        self.end, self.spins, self.writer = end, 0, None
        monkeypatch.setattr(rclpy, "init", lambda **_: None)
        monkeypatch.setattr(rclpy, "try_shutdown", lambda **_: None)
        monkeypatch.setattr(rclpy, "create_node", lambda *_, **__: SimpleNamespace(destroy_node=lambda: None))
        monkeypatch.setattr(rclpy.executors, "SingleThreadedExecutor", lambda **_: SimpleNamespace(
            add_node=lambda node: None, spin_once=self.spin_once, shutdown=lambda: None))
        monkeypatch.setattr(okid_ros.tools.recorder, "LiveRecorder", self.recorder)

    def recorder(self, node, writer: BagWriter, topics: dict[str, str]) -> SimpleNamespace:
        for topic, msgtype in topics.items():
            writer.add_topic(topic, msgtype)
        self.writer = writer
        return SimpleNamespace(counts=writer.counts)

    def spin_once(self, timeout_sec: float) -> None:
        self.spins += 1
        if self.spins == 4 and self.end is not None:
            raise self.end
        self.writer.write("/diagnostics", self.spins, _diagnostics(self.writer))
        time.sleep(0.01)


def _old_bag(path: Path) -> None:
    with BagWriter(path) as bag:
        bag.add_topic("/old", "diagnostic_msgs/msg/DiagnosticArray")
        bag.write("/old", 1, _diagnostics(bag))


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name)


@pytest.mark.parametrize("end", ["interrupt", "duration"])
def test_a_recording_stopped_normally_replaces_the_old_bag(tmp_path, capsys, monkeypatch, end):
    out = tmp_path / "live"
    _old_bag(out)
    _Rig(monkeypatch, KeyboardInterrupt() if end == "interrupt" else None)
    code, stdout, err = run_cli(capsys, "record", out, "--force", *(["--duration", "0.2"] if end == "duration" else []))
    assert code == 0, err
    assert "/diagnostics: " in stdout
    with open_bag(out) as bag:
        assert "/old" not in bag.topics and bag.message_count(["/diagnostics"]) >= 3
    assert _leftovers(tmp_path) == []


def test_a_failed_recording_keeps_the_old_bag(tmp_path, capsys, monkeypatch):
    # Before: --force removed the old bag before recording, and a failure (the disk full) left neither.
    out = tmp_path / "live"
    _old_bag(out)
    _Rig(monkeypatch, BagWriteError(f"{out}: cannot write (No space left on device)"))
    code, _, err = run_cli(capsys, "record", out, "--force")
    assert_one_line_error(code, err, "No space left on device")
    with open_bag(out) as bag:
        assert set(bag.topics) == {"/old"} and bag.message_count() == 1
    assert _leftovers(tmp_path) == []


def test_a_failed_recording_to_a_new_path_keeps_what_it_recorded_and_no_empty_bag(tmp_path, capsys, monkeypatch):
    out = tmp_path / "live"
    _Rig(monkeypatch, BagWriteError("the disk is full"))
    code, _, err = run_cli(capsys, "record", out)
    assert_one_line_error(code, err, "the disk is full")
    with open_bag(out) as bag:  # three messages: kept, closed and readable
        assert bag.message_count(["/diagnostics"]) == 3
    empty = tmp_path / "empty"
    monkeypatch.setattr(okid_ros.tools.recorder, "LiveRecorder", _refusing_recorder)
    code, _, err = run_cli(capsys, "record", empty)
    assert_one_line_error(code, err, "unknown message type")
    assert not empty.exists()  # no recording: a rerun needs no --force


def _refusing_recorder(node, writer, topics):
    raise BagWriteError(f"{writer.path}: unknown message type x/msg/Y for /x")
