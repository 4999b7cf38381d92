"""`okid-ros track` switches models by node 2's rule (service/model_switch.ModelSelection).

The added-mass structure (okid_bench.switching: 1.8, 4.2, 7.9 Hz drop by 6 %) changes 100 samples
after the first update, while the change test still calibrates on the first model's innovations, so
no change is declared. Windows of 1500 rows, an update every 1500 samples: the next windows' models
hold the new modes only, so each lost the modes in use. Node 2 refuses such a model
(``tracking.min_matched_fraction``) and keeps the model in use, up to
``tracking.max_consecutive_rejections`` (3) in a row, then takes the next (the structure changed),
its modes under new persistent ids; `track` took every model.
"""

from __future__ import annotations

import json

import pytest

from okid_bench.switching import added_mass_case
from okid_ros.cli import main as okid_ros_main
from okid_ros.records import save_record
from okid_ros.service.params import ESTIMATOR_NODE, resolve_parameters

WINDOW = EVERY = 1500
UPDATES = 6
CHANGE_AFTER_FIRST_UPDATE = 100


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    case = added_mass_case()
    first = WINDOW + case.arx_order - 1
    u, y = case.simulate(first + (UPDATES - 1) * EVERY + 1, first + CHANGE_AFTER_FIRST_UPDATE, seed=0)
    path = tmp_path_factory.mktemp("track_modes") / "added_mass.npz"
    save_record(path, u, y, case.sample_time_s)
    return path, case.arx_order


@pytest.mark.parametrize("change_detection", [True, False], ids=["watch", "no-change-detection"])
def test_a_model_that_lost_the_modes_in_use_is_refused_as_node_2_refuses_it(record, change_detection):
    path, q = record
    out = path.with_name(f"modes_{change_detection}.jsonl")
    args = ["track", str(path), "--order", str(q), "--window", str(WINDOW), "--every", str(EVERY),
            "--jsonl", str(out), "--no-progress"]
    assert okid_ros_main(args + ([] if change_detection else ["--no-change-detection"])) == 0
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(lines) == UPDATES and not any(line["change_detected"] for line in lines)
    rejections = resolve_parameters(ESTIMATOR_NODE)["tracking.max_consecutive_rejections"]
    refused, taken = lines[1 : 1 + rejections], lines[1 + rejections :]
    for line in refused:  # node 2's reason; the window's own modes kept in "modes" (each with its "id")
        assert line["watch_refused"].startswith("modes lost: "), line
        assert "mode_ids" not in line and len(line["modes"]) >= 3
        assert [mode["id"] for mode in line["modes"]] == list(range(len(line["modes"])))
    assert "watch_refused" not in lines[0] and all("watch_refused" not in line for line in taken)
    # Node 2's persistent ids: the first model's, then, after the forced switch, new ones kept across windows.
    assert lines[0]["mode_ids"] == [0, 1, 2]
    new_ids = taken[0]["mode_ids"]
    assert len(new_ids) == 3 and not set(new_ids) & {0, 1, 2}
    assert all(line["mode_ids"] == new_ids for line in taken)
    if change_detection:  # counted, under node 2's diagnostics' names (a line's: before its own model)
        counts = lines[-1]["watch"]
        assert (counts["models_accepted"], counts["models_rejected"], counts["forced_accepts"]) == (
            len(lines) - rejections - 1, rejections, 1)
        assert [line["watch"]["models_rejected"] for line in refused] == list(range(rejections))
        assert all(line["watch"]["models_accepted"] == 1 for line in refused)
    else:
        assert all("watch" not in line for line in lines)
