"""`okid-ros process` logic (OfflineNodes) through a structural change.

The StructuralChange
messages, node 1's window restart and `change_detected` in the JSON lines, without DDS.

The 2-mode structure of test_service_change.py (6 and 21 Hz at 250 Hz, -6 % at sample 5000).
"""

from __future__ import annotations

import numpy as np

from okid_bench.switching import added_mass_structure, simulate_switched
from okid_ros.nodes.conversions import io_sample_msg, structural_change_from_msg
from okid_ros.sim.inputs import lowpass_input
from okid_ros.tools.process import OfflineNodes, load_node_parameters

DT, CHANGE, N, T0 = 0.004, 5000, 8000, 100.0
OVERRIDES = ["sample_time_s=0.004", "arx.order=40", "arx.window_length=2000", "arx.restart_min_fill=0.5",
             "realization.n_states=4", "realization.refine=false"]


def test_process_declares_the_change_restarts_the_window_and_flags_the_json_lines():
    before, after = added_mass_structure([6.0, 21.0], [0.01, 0.015], 2, 2, DT, frequency_factor=0.94, seed=1)
    u = lowpass_input(N, 2, 40.0, DT, seed=3)
    y = simulate_switched([before, after], CHANGE, u, seed=4)
    nodes = OfflineNodes(*load_node_parameters(overrides=OVERRIDES))
    out = []
    for k in range(N):
        t = T0 + k * DT
        out += nodes.feed("/okid/io_sample", io_sample_msg(t, u[k], y[k], nodes.types), t)
    out += nodes.finish()
    assert nodes.output_topics["/okid/structural_change"] == "okid_msgs/msg/StructuralChange"
    changes = [structural_change_from_msg(msg) for topic, msg in out if topic == "/okid/structural_change"]
    assert [c["identified"] for c in changes] == [False, True]
    assert abs(changes[0]["change_stamp_s"] - (T0 + CHANGE * DT)) <= 100 * DT
    np.testing.assert_allclose(sorted(m["frequency_hz"] for m in changes[1]["modes_after"]), [5.64, 19.74], rtol=0.01)
    summary = nodes.summary
    assert summary.arx_diagnostics["window_restarts"] == 1
    assert summary.estimator_diagnostics["changes_detected"] == 1
    lines = summary.updates
    assert all("change_detected" in line for line in lines)
    flagged = [line for line in lines if line["change_detected"]]
    assert len(flagged) == 1 and flagged[0]["change_stamp_s"] == changes[0]["change_stamp_s"]
    # The flagged update is the first model of the new structure (windows spanning the change refused).
    assert flagged[0]["stamp_s"] - flagged[0]["window_samples"] * DT >= changes[0]["change_stamp_s"] - 2 * DT
    assert {m["id"] for m in flagged[0]["modes"]}.isdisjoint({m["id"] for m in lines[0]["modes"]})
    assert not any(line["change_detected"] for line in lines if line["stamp_s"] < T0 + CHANGE * DT)
