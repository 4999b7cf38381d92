"""`process` stopped by SIGTERM (``timeout``, ``docker stop``) or Ctrl-C leaves a readable bag marked as cut short.

Before: SIGTERM left a 0-byte ``.mcap`` without ``metadata.yaml`` (unreadable), Ctrl-C a closed bag
that nothing marked, which `plot` then drew as a finished run; neither said anything on stderr.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from ros_helpers import REPO_ROOT

from okid_ros.cli import main
from okid_ros.tools.bagio import open_bag


def test_a_terminated_process_leaves_its_bag_readable_and_marked(tmp_path):
    bag, out, lines = tmp_path / "in", tmp_path / "out", tmp_path / "out.jsonl"
    assert main(["simulate", "--out", str(bag), "--duration", "120", "--seed", "3"]) == 0
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    process = subprocess.Popen([sys.executable, "-m", "okid_ros.cli", "process", str(bag), "--out", str(out),
                                "--jsonl", str(lines), "--no-progress"],
                               env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (lines.exists() and lines.read_text().count("\n") >= 1):  # a model is out: well under way
        assert process.poll() is None and time.monotonic() < deadline, "process ended before its first model"
        time.sleep(0.02)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130 and err.strip().splitlines() == ["okid-ros process: interrupted"], err
    with open_bag(out) as written:
        record = written.custom_json("okid_ros.process")
        assert record["interrupted"] is True and 0 < record["samples"] < 15000
        assert sum(1 for _ in written.messages()) > 0
