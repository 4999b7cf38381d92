"""`okid-ros process`, `batch` and `track` output-only (n_inputs 0), through the command line.

An ambient experiment (:mod:`okid_ros.tools.simulate_ambient`: four modes at 3.2, 7.5, 12.8
and 21 Hz, 1 % damping, 200 Hz, two 3-axis Imu topics, no measured input) as a bag for
`process` and `batch` with ``config/okid_output_only.yaml``, and as a y-only record (and a
record with an unrelated u and ``--output-only``) for `track`.
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest
from ros_helpers import REPO_ROOT

from okid_ros.cli import main as okid_ros_main
from okid_ros.tools.simulate_ambient import AMBIENT_FREQUENCIES_HZ, simulate_ambient, write_ambient_bag

PARAMS = ["--params", str(REPO_ROOT / "config" / "okid.yaml"),
          "--params", str(REPO_ROOT / "config" / "okid_output_only.yaml"),
          "--param", "arx.window_length=8000", "--param", "publish_rate_hz=0.25"]


@pytest.fixture(scope="module")
def experiment():
    return simulate_ambient(60.0, seed=2, start_ns=1_000 * 1_000_000_000)


@pytest.fixture(scope="module")
def bag(experiment, tmp_path_factory):
    path = tmp_path_factory.mktemp("ambient") / "ambient"
    write_ambient_bag(path, experiment)
    return path


def assert_true_modes_found(updates: list[list[dict]], rtol: float = 0.02) -> None:
    """Each true mode within ``rtol`` in frequency in at least half of the updates.

    In every update at most one listed mode is no true one. (A 40 s window holds 128 periods
    of the slowest mode, which the output-only selection does not always keep.)
    """
    hits = np.zeros(len(AMBIENT_FREQUENCIES_HZ))
    for modes in updates:
        found = np.array([m["frequency_hz"] for m in modes])
        assert found.size, "an update without modes"
        hits += [np.min(np.abs(found / f - 1)) < rtol for f in AMBIENT_FREQUENCIES_HZ]
        spurious = [g for g in found if min(abs(g / f - 1) for f in AMBIENT_FREQUENCIES_HZ) >= rtol]
        assert len(spurious) <= 1, found
    assert np.all(hits >= 0.5 * len(updates)), dict(zip(AMBIENT_FREQUENCIES_HZ, hits))


@pytest.fixture(scope="module")
def processed(bag, tmp_path_factory) -> dict:
    """`okid-ros process` of the bag once for the module (--jsonl only adds its file): status, paths, stdout."""
    folder = tmp_path_factory.mktemp("process_output_only")
    out, jsonl = folder / "out", folder / "updates.jsonl"
    with contextlib.redirect_stdout(io.StringIO()) as stdout:
        status = okid_ros_main(["process", str(bag), *PARAMS, "--out", str(out), "--jsonl", str(jsonl)])
    print(stdout.getvalue())
    return {"status": status, "out": out, "jsonl": jsonl, "stdout": stdout.getvalue()}


def test_process_runs_the_nodes_logic_output_only(processed):
    assert processed["status"] == 0
    lines = [json.loads(line) for line in processed["jsonl"].read_text().splitlines()]
    assert len(lines) >= 5
    assert all(line["n_inputs"] == 0 and line["modes"] for line in lines)
    assert_true_modes_found([line["modes"] for line in lines])
    ids = {mode["id"] for line in lines for mode in line["modes"]}
    assert len(ids) <= len(AMBIENT_FREQUENCIES_HZ) + 2  # ids kept across the windows
    text = processed["stdout"]
    assert "StateSpaceModel" in text and "ModalStates" in text


def test_process_bag_holds_state_space_models_without_inputs(processed):
    from okid_ros.tools.bagio import open_bag

    assert processed["status"] == 0
    out = processed["out"]
    with open_bag(out) as reader:
        models = [msg for topic, _, msg in reader.messages(["/okid/state_space_model"])]
        n_states_msgs = reader.message_count(["/okid/modal_states"])
        arx = [msg for topic, _, msg in reader.messages(["/okid/arx_model"])]
    assert models and all(m.n_inputs == 0 and len(m.b) == 0 and len(m.d) == 0 for m in models)
    assert arx and all(m.n_inputs == 0 for m in arx)
    first_model_s = models[0].header.stamp.sec + models[0].header.stamp.nanosec * 1e-9
    samples_after = 60.0 - (first_model_s - 1_000.0)
    assert n_states_msgs >= 0.98 * samples_after / 0.005  # modal states on (nearly) every sample
    assert okid_ros_main(["plot", str(out)]) == 0  # the source bag recorded by process; no input: no FRF
    figures = sorted(p.name for p in (out.parent / "out_figures").iterdir())
    assert "modes_over_time.png" in figures and "stabilization.png" in figures
    assert "frf.png" not in figures and "fig2_system_markov.png" not in figures


def test_batch_takes_the_output_only_parameters(bag, tmp_path):
    import pandas as pd  # imported here, not by every pytest session's collection

    out = tmp_path / "campaign"
    assert okid_ros_main(["batch", str(bag), *PARAMS, "--out", str(out), "--workers", "1"]) == 0
    table = pd.read_parquet(out / "modes.parquet")
    assert_true_modes_found([group.to_dict("records") for _, group in table.groupby("stamp_s")])


@pytest.mark.parametrize("output_only_flag", [False, True])
def test_track_streams_output_only_updates(experiment, tmp_path, output_only_flag):
    path = tmp_path / "record.npz"
    if output_only_flag:  # a record with an unrelated u: --output-only ignores it
        u = np.random.default_rng(0).standard_normal((experiment.y.shape[0], 1))
        np.savez(path, u=u, y=experiment.y, sample_time_s=experiment.sample_time_s)
    else:
        np.savez(path, y=experiment.y, sample_time_s=experiment.sample_time_s)
    out = tmp_path / "track.jsonl"
    args = ["track", str(path), "--window", "8000", "--every", "1000", "--jsonl", str(out), "--no-progress"]
    assert okid_ros_main(args + (["--output-only"] if output_only_flag else [])) == 0
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(lines) == len(range(8000 + 10 - 1, experiment.y.shape[0], 1000))
    for line in lines:
        assert line["n_inputs"] == 0 and line["arx_order"] == 10 and line["rows"] == 8000
        assert {"sample_index", "window_first_index", "time_s", "n_states", "modes", "change_detected"} <= set(line)
    assert_true_modes_found([line["modes"] for line in lines])
