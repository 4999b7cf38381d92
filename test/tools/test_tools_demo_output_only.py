"""`okid-ros demo --output-only` end to end: ambient experiment, both nodes with n_inputs 0, Imu topics."""

from __future__ import annotations

import sys

import pytest
from ros_helpers import REPO_ROOT, RosProcess, subprocess_env
from rosbags.highlevel import AnyReader

from okid_ros.tools.simulate_ambient import AMBIENT_FREQUENCIES_HZ

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process


def test_output_only_demo_identifies_the_ambient_modes_live(ros_domain_id, tmp_path):
    # 90 s, so that the last live model is of a full window (12000 samples). It is the model of
    # node 1's last window, which ends at the last sample: node 2 applies the models due after the
    # last sample once its input is idle, and the demo waits for them (asserted below). Before,
    # which ArxModel was realized last was a race with the end of the replay; on 60 s the
    # candidates were growing windows, and the one of ~50 s (ArxModel 17) lost the 12.8 Hz mode in
    # the output-only selection (CI, 2026-11-28: twice in a row; an open fragility of issue 18).
    out_dir = tmp_path / "demo"
    proc = RosProcess([sys.executable, "-m", "okid_ros.cli", "demo", "--output-only", "--out-dir", str(out_dir),
                       "--duration", "90", "--rate", "4", "--no-ansi"], subprocess_env(ros_domain_id), REPO_ROOT)
    code = proc.proc.wait(timeout=240)
    out = proc.output()
    assert code == 0, out
    assert "ambient vibration" in out and "/okid/imu_top" in out
    table = out[out.index("[5/5]"):].splitlines()
    rows = {line.split()[0]: line.split() for line in table[2:2 + len(AMBIENT_FREQUENCIES_HZ)]}
    for k, true_hz in enumerate(AMBIENT_FREQUENCIES_HZ, start=1):
        assert rows[str(k)][3] != "-", table  # every true mode identified live
        assert abs(float(rows[str(k)][4]) / true_hz - 1) < 0.02, table
    run = out_dir / "latest"
    assert (run / "output_only_demo.yaml").is_file()
    figures = sorted(p.name for p in (run / "figures").iterdir())
    assert "fig4_modal_states.png" in figures and "fig2_system_markov.png" not in figures  # no input: no Fig. 2
    with AnyReader([run / "live"]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        models = [reader.deserialize(raw, "okid_msgs/msg/StateSpaceModel") for _, _, raw in reader.messages(
            connections=[c for c in reader.connections if c.topic == "/okid/state_space_model"])]
        arx = [reader.deserialize(raw, "okid_msgs/msg/ArxModel") for _, _, raw in reader.messages(
            connections=[c for c in reader.connections if c.topic == "/okid/arx_model"])]
    msg = models[0]
    assert msg.n_inputs == 0 and len(msg.b) == 0 and len(msg.d) == 0

    def stamp(m) -> tuple[int, int]:
        return m.header.stamp.sec, m.header.stamp.nanosec

    # The last model is of node 1's last window (republished unchanged after the replay: its first
    # id). Its stamp may be a sample or two earlier: the last samples may not reach node 2 (sensor QoS).
    last_window = [m.model_id for m in arx if stamp(m) == stamp(arx[-1])]
    assert models[-1].arx_model_id == last_window[0], (
        [(m.model_id, stamp(m)) for m in arx[-5:]], [(m.arx_model_id, stamp(m)) for m in models[-3:]])
    # ModalStates flow from the first model on: 4700-5300 of the 12000 samples in runs alone, 2870
    # once in a full run whose load delayed the first model (the window's half-fill is at 30 s).
    assert counts["/okid/state_space_model"] >= 2 and counts["/okid/modal_states"] > 1500
