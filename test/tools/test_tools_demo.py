"""`okid-ros demo`, the job behind `make demo`, end to end on a short experiment.

Simulate, both nodes live, replay, recording, monitor tables, figures, identified against true
modes.
"""

from __future__ import annotations

import sys

import pytest
from ros_helpers import REPO_ROOT, RosProcess, subprocess_env
from rosbags.highlevel import AnyReader

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process

# A window of 1000 rows is valid from about 5 s of data; models twice a second.
FAST_PARAMS = """
okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: 2.0
    arx:
      window_length: 1000
"""


def test_demo_runs_end_to_end_and_finds_the_paper_modes(ros_domain_id, tmp_path):
    fast = tmp_path / "fast.yaml"
    fast.write_text(FAST_PARAMS)
    out_dir = tmp_path / "demo"
    proc = RosProcess([sys.executable, "-m", "okid_ros.cli", "demo", "--out-dir", str(out_dir), "--duration", "16",
                       "--rate", "2", "--params", str(REPO_ROOT / "config" / "okid.yaml"), "--params", str(fast),
                       "--no-ansi"], subprocess_env(ros_domain_id), REPO_ROOT)
    code = proc.proc.wait(timeout=240)
    out = proc.output()
    assert code == 0, out
    assert f"ROS_DOMAIN_ID={ros_domain_id}" in out  # the session's domain, never another one
    assert "okid-ros demo (live)" in out and "\x1b[H" not in out  # monitor tables on a pipe, no redraw
    table = out[out.index("[5/5]"):].splitlines()
    rows = {line.split()[0]: line.split() for line in table[2:5]}
    for k, true_hz in (("1", 5.9042), ("2", 7.3422)):
        assert rows[k][1] == f"{true_hz:.4f}" and rows[k][3] != "-", table
        assert abs(float(rows[k][4]) / true_hz - 1) < 0.02, table
    run = out_dir / "latest"
    assert run.is_symlink() and (run / "nodes.log").is_file()
    assert sorted(p.name for p in (run / "figures").iterdir()) == [
        "fig2_system_markov.png", "fig3_stochastic_markov.png", "fig4_modal_states.png",
        "fig5_output_estimate.png", "modes_over_time.png"]
    with AnyReader([run / "live"]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        states = [c for c in reader.connections if c.topic == "/okid/modal_states"]
        _, _, raw = next(reader.messages(connections=states))
        msg = reader.deserialize(raw, "okid_msgs/msg/ModalStates")  # bytes from the wire read back
    assert counts["/okid/modal_states"] > 500 and counts["/okid/state_space_model"] >= 2
    assert len(msg.modal_coordinates) == 2 * len(msg.modes)
    assert "okid_arx_identifier" in (run / "nodes.log").read_text()
