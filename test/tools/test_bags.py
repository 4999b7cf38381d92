"""Bags without DDS.

Simulate -> process -> modes against the truth, the output bag read back by rosbags alone, a bag
written by rosbags alone processed, the figures, and the one-line errors (existing outputs
refused, missing topic, wrong type, corrupt file).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli
from ros_helpers import REPO_ROOT, rosbags_typestore
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from okid_ros.cli import main
from okid_ros.sim import lowpass_input, paper_model, paper_modes, simulate_innovation
from okid_ros.tools.bagio import TRUTH_KEY, open_bag
from okid_ros.tools.campaign.worker import BagJob, run_bag_job
from okid_ros.tools.plots import add_measured_outputs, fit_percent, output_estimates, read_plot_data
from okid_ros.tools.process import load_node_parameters
from okid_ros.tools.simulate_bag import IMU_TOPICS, IO_SAMPLE_TOPIC, THRUSTER_TOPICS

CONFIG = REPO_ROOT / "config" / "okid.yaml"
START_S = 1_700_000_000
# ArxModel every 4 s of data: with the default window (4000 rows, valid from half full, about
# 17 s) a 25 s record gives two models (at 20 s and 24 s), which keeps the test short; the
# truth has 6 states, so orders up to 8 are enough for the automatic order selection.
FAST = ["--param", "publish_rate_hz=0.25", "--param", "realization.max_states=8"]
TRUTH = paper_modes()


def assert_modes_match_truth(modes: list[dict]) -> None:
    """Every true mode has an identified one within 1 % in frequency and 1 point in damping."""
    for true in TRUTH:
        near = [m for m in modes if abs(m["frequency_rad_s"] / true["frequency_rad_s"] - 1) < 0.01]
        assert near, f"no mode near {true['frequency_rad_s']:.3f} rad/s in {modes}"
        best = min(near, key=lambda m: abs(m["frequency_rad_s"] - true["frequency_rad_s"]))
        assert abs(best["damping_ratio"] - true["damping_ratio"]) < 0.01, (best, true)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A 25 s simulated bag (MCAP) processed once with the nodes' default parameters."""
    root = tmp_path_factory.mktemp("bags")
    bag, out, jsonl = root / "experiment", root / "out", root / "models.jsonl"
    assert main(["simulate", "--out", str(bag), "--duration", "25", "--start-time", str(START_S)]) == 0
    assert main(["process", str(bag), "--params", str(CONFIG), "--out", str(out), "--jsonl", str(jsonl),
                 "--no-progress", *FAST]) == 0
    return {"root": root, "bag": bag, "out": out, "jsonl": jsonl}


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory) -> Path:
    """3 s, sqlite3: enough for the error paths (no model is identified from it)."""
    bag = tmp_path_factory.mktemp("small") / "small"
    assert main(["simulate", "--out", str(bag), "--duration", "3", "--storage", "sqlite3",
                 "--start-time", str(START_S)]) == 0
    return bag


def test_simulated_bag_has_the_topics_on_the_grid_and_the_truth_in_its_metadata(run):
    with open_bag(run["bag"]) as bag:
        assert bag.topics == {
            **{t: "geometry_msgs/msg/WrenchStamped" for t in THRUSTER_TOPICS},
            **{t: "sensor_msgs/msg/Imu" for t in IMU_TOPICS},
            IO_SAMPLE_TOPIC: "okid_msgs/msg/IoSample",
        }
        assert bag.message_count() == 5 * 3125
        truth = bag.custom_json(TRUTH_KEY)
        stamps, io, imu = [], [], []
        for topic, log_ns, msg in bag.messages([IO_SAMPLE_TOPIC, IMU_TOPICS[1], THRUSTER_TOPICS[0]]):
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            assert stamp_ns == log_ns
            if topic == IO_SAMPLE_TOPIC:
                stamps.append(stamp_ns)
                io.append((msg.u[0], msg.y[1]))
            elif topic == IMU_TOPICS[1]:
                imu.append(msg.linear_acceleration.x)
                assert msg.orientation_covariance[0] == -1.0
            else:
                assert msg.wrench.force.y == 0.0
    assert np.all(np.diff(stamps) == 8_000_000) and stamps[0] == START_S * 1_000_000_000
    assert np.array_equal([y for _, y in io], imu)  # the Imu carries output 2 of the IoSample
    assert [m["frequency_rad_s"] for m in truth["modes"]] == pytest.approx([m["frequency_rad_s"] for m in TRUTH])
    assert np.allclose(truth["A"], paper_model().A)
    # the metadata.yaml is what other tools read: custom_data is there in plain text
    assert TRUTH_KEY in (run["bag"] / "metadata.yaml").read_text()


def _strict_loads(text: str):
    """json.loads that refuses NaN and Infinity (strict JSON, as JavaScript's JSON.parse)."""
    def refuse(token: str):
        raise ValueError(f"non-standard JSON token {token}")

    return json.loads(text, parse_constant=refuse)


def test_process_identifies_the_true_modes_and_writes_json_lines(run):
    lines = [_strict_loads(line) for line in run["jsonl"].read_text().splitlines()]
    with open_bag(run["out"]) as bag:
        _strict_loads(bag.custom_data["okid_ros.process"])
        _strict_loads(bag.custom_data[TRUTH_KEY])
    assert len(lines) >= 2
    for line in lines:
        assert isinstance(line["stamp_s"], float) and line["stamp_s"] > START_S
        for mode in line["modes"]:
            assert {"frequency_rad_s", "frequency_hz", "damping_ratio"} <= set(mode)
            assert mode["frequency_hz"] == pytest.approx(mode["frequency_rad_s"] / (2 * np.pi))
    assert [line["stamp_s"] for line in lines] == sorted(line["stamp_s"] for line in lines)
    assert_modes_match_truth(lines[-1]["modes"])
    for line in lines:  # fits on the model's window: the prediction beats the free-run simulation
        assert len(line["fit_one_step_pct"]) == len(line["fit_simulation_pct"]) == 2
        assert all(80 < pred < 100 and sim < pred for pred, sim in zip(line["fit_one_step_pct"],
                                                                        line["fit_simulation_pct"]))
        assert all(mode["frequency_hz_std"] > 0 and mode["damping_ratio_std"] > 0 for mode in line["modes"])


def test_output_bag_reads_back_with_rosbags_alone(run):
    lines = [json.loads(line) for line in run["jsonl"].read_text().splitlines()]
    counts: dict[str, int] = {}
    with AnyReader([run["out"]]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == {
            "/okid/arx_model": "okid_msgs/msg/ArxModel",
            "/okid/state_space_model": "okid_msgs/msg/StateSpaceModel",
            "/okid/modal_states": "okid_msgs/msg/ModalStates",
            "/okid/structural_change": "okid_msgs/msg/StructuralChange",
        }
        last_model = last_states = None
        for connection, log_ns, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
            if connection.topic == "/okid/state_space_model":
                last_model = msg
            elif connection.topic == "/okid/modal_states":
                last_states = msg
                assert log_ns == msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        custom = reader.readers[0].storage.metadata.custom
    assert counts["/okid/arx_model"] == 6  # one per 4 s of the 25 s record
    assert counts["/okid/state_space_model"] == len(lines)
    assert counts["/okid/modal_states"] == 624  # from the first model (ArxModel at 20 s) on
    assert counts.get("/okid/structural_change", 0) == 0  # a stationary structure
    assert not any(line["change_detected"] for line in lines)
    n = last_model.n_states
    assert len(last_model.a) == n * n and len(last_model.k) == n * 2
    assert [m.id for m in last_states.modes] == [m["id"] for m in lines[-1]["modes"]]
    assert len(last_states.modal_coordinates) == 2 * len(last_states.modes)
    assert len(last_states.y_estimated) == len(last_states.innovation) == 2
    assert json.loads(custom[TRUTH_KEY])["modes"][0]["frequency_rad_s"] == pytest.approx(TRUTH[0]["frequency_rad_s"])
    assert json.loads(custom["okid_ros.process"])["source"] == str(run["bag"])


def test_fig5_measured_output_is_the_input_bags_output_at_the_same_stamp(run):
    data = read_plot_data(run["out"], window_s=2.0)
    assert len(data.modal_stamp_ns) == 250
    assert add_measured_outputs(data, run["bag"], load_node_parameters()[1]) == 250
    with open_bag(run["bag"]) as bag:
        y = {log_ns: msg.y for _, log_ns, msg in bag.messages([IO_SAMPLE_TOPIC])}
    for stamp_ns, measured in zip(data.modal_stamp_ns, data.measured):
        assert np.array_equal(measured, y[stamp_ns])
    assert data.truth is not None and data.process_info["source"] == str(run["bag"])
    # Fig. 5 shows the one-step prediction y - innovation; without the input bag the same curve
    # comes from the message alone (y_estimated - C K innovation)
    with_input = output_estimates(data, 0)
    np.testing.assert_allclose(with_input["one_step"],
                               [m[0] - e[0] for m, e in zip(data.measured, data.innovation)])
    alone = output_estimates(read_plot_data(run["out"], window_s=2.0), 0)
    np.testing.assert_allclose(alone["one_step"], with_input["one_step"], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(alone["measured"], with_input["measured"], rtol=1e-9, atol=1e-9)
    assert fit_percent(with_input["measured"], with_input["one_step"]) < fit_percent(
        with_input["measured"], with_input["filtered"]) < 100
    # time from the start of the experiment: the last 2 s of a 25 s record
    t = np.asarray(data.modal_t) + data.time_shift_s()
    assert t[0] == pytest.approx(23.0, abs=0.01) and t[-1] == pytest.approx(24.992, abs=0.01)
    # the modes over time carry standard deviations
    for rows in data.mode_history.values():
        assert all(0 < row[3] < 0.05 * row[1] and 0 < row[4] < 0.05 for row in rows)


def test_sensor_topics_give_the_same_models_as_io_sample(run, capsys):
    """config/okid_imu_wrench.yaml assembles the same samples from 2 Wrench + 2 Imu topics."""
    out, jsonl = run["root"] / "out_sensors", run["root"] / "sensors.jsonl"
    code, stdout, err = run_cli(capsys, "process", run["bag"], "--params", CONFIG, "--params",
                                REPO_ROOT / "config" / "okid_imu_wrench.yaml", "--out", out, "--jsonl", jsonl,
                                "--no-progress", *FAST)
    assert code == 0, err
    assert "12500 messages, 3125 samples" in stdout
    sensors = [json.loads(line) for line in jsonl.read_text().splitlines()]
    io = [json.loads(line) for line in run["jsonl"].read_text().splitlines()]
    assert len(sensors) == len(io)
    for a, b in zip(sensors, io):
        frequencies_b = [m["frequency_rad_s"] for m in b["modes"]]
        assert [m["frequency_rad_s"] for m in a["modes"]] == pytest.approx(frequencies_b, rel=1e-9)


@pytest.mark.parametrize("extra", [None, "okid_imu_wrench.yaml"])
def test_a_bags_samples_read_from_the_bytes_equal_those_of_the_decoded_messages(run, monkeypatch, extra):
    """The offline readers take the stamp and channels from the stored bytes; rosbags' objects agree."""
    from okid_ros.nodes import raw_inputs
    from okid_ros.tools.bag_record import record_from_bag
    from okid_ros.tools.offline import NodeInputs

    files = [CONFIG] + ([REPO_ROOT / "config" / extra] if extra else [])
    values = load_node_parameters(files)[1]
    def readers() -> list:
        inputs = NodeInputs(values)
        return [inputs._reader(i) for i in range(len(inputs.specs))]

    assert all(r is not None for r in readers())  # the bytes are read
    from_bytes = record_from_bag(run["bag"], values)
    monkeypatch.setattr(raw_inputs, "raw_reader", lambda *args, **kwargs: None)
    assert all(r is None for r in readers())
    decoded = record_from_bag(run["bag"], values)
    assert from_bytes.record.u.shape[0] == decoded.record.u.shape[0] > 3000
    np.testing.assert_array_equal(from_bytes.record.u, decoded.record.u)
    np.testing.assert_array_equal(from_bytes.record.y, decoded.record.y)
    np.testing.assert_array_equal(from_bytes.stamp_s, decoded.stamp_s)


def test_a_bag_written_by_the_rosbags_writer_alone_is_processed(tmp_path, capsys):
    """A bag as other writers make it.

    sqlite3, format version 8, other topic names, receive-time log stamps with jitter, and an
    unrelated topic.
    """
    store = rosbags_typestore()
    model = paper_model()
    n = int(25 / model.sample_time_s)
    u = lowpass_input(n, 2, 15.0, model.sample_time_s, seed=7)
    y, _ = simulate_innovation(model, u, seed=8)
    Time, Header = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Header"]
    IoSample, String = store.types["okid_msgs/msg/IoSample"], store.types["std_msgs/msg/String"]
    rng = np.random.default_rng(3)
    bag = tmp_path / "foreign"
    with Writer(bag, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        io = writer.add_connection("/rig/io", "okid_msgs/msg/IoSample", typestore=store)
        chatter = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        for k in range(n):
            stamp_ns = 1_600_000_000 * 10**9 + k * 8_000_000
            msg = IoSample(header=Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id="rig"),
                           u=u[k].copy(), y=y[k].copy())
            received_ns = stamp_ns + int(rng.uniform(0.2e6, 3e6))
            writer.write(io, received_ns, store.serialize_cdr(msg, "okid_msgs/msg/IoSample"))
            if k % 125 == 0:
                writer.write(chatter, stamp_ns, store.serialize_cdr(String(data="hello"), "std_msgs/msg/String"))
    out, jsonl = tmp_path / "out", tmp_path / "models.jsonl"
    code, stdout, err = run_cli(capsys, "process", bag, "--params", CONFIG, "--source", "io_sample /rig/io",
                                "--out", out, "--jsonl", jsonl, "--no-progress", *FAST)
    assert code == 0, err
    lines = [json.loads(line) for line in jsonl.read_text().splitlines()]
    assert lines, stdout
    assert_modes_match_truth(lines[-1]["modes"])
    with AnyReader([out]) as reader:
        assert sum(c.msgcount for c in reader.connections if c.topic == "/okid/modal_states") == 624


def test_figures_are_written_and_not_overwritten(run, capsys):
    figures = run["root"] / "figures"
    code, stdout, err = run_cli(capsys, "plot", run["out"], "--out-dir", figures)
    assert code == 0, err
    # the source that process recorded; all 624 ModalStates (from 20.008 s on) are in the last 5 s
    assert f"measured outputs from {run['bag']} (624 samples)" in stdout
    names = sorted(p.name for p in figures.iterdir())
    assert names == sorted(["fig2_system_markov.png", "fig3_stochastic_markov.png", "fig4_modal_states.png",
                            "fig5_output_estimate.png", "modes_over_time.png", "frf.png", "mac.png",
                            "stabilization.png"])
    assert "FRF from 3125 samples" in stdout
    for path in figures.iterdir():
        data = path.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    before = (figures / "fig2_system_markov.png").stat().st_mtime_ns
    code, _, err = run_cli(capsys, "plot", run["out"], "--out-dir", figures)
    assert_one_line_error(code, err, "exist already", "--force")
    assert all(name in err for name in names), err  # every figure in the way named (was: the last three)
    assert (figures / "fig2_system_markov.png").stat().st_mtime_ns == before
    assert run_cli(capsys, "plot", run["out"], "--out-dir", figures, "--force")[0] == 0
    # an input bag is not an output bag
    code, _, err = run_cli(capsys, "plot", run["bag"], "--out-dir", run["root"] / "nofig")
    assert_one_line_error(code, err, "/okid/modal_states")


def test_an_existing_output_is_refused_and_left_untouched(small_bag, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("precious")
    code, _, err = run_cli(capsys, "process", small_bag, "--out", out, "--no-progress")
    assert_one_line_error(code, err, str(out), "exists already", "--force")
    # --force replaces bags only, never another folder
    code, _, err = run_cli(capsys, "process", small_bag, "--out", out, "--force", "--no-progress")
    assert_one_line_error(code, err, "not a rosbag2 directory")
    assert (out / "notes.txt").read_text() == "precious"

    bag_out, jsonl = tmp_path / "bag_out", tmp_path / "m.jsonl"
    assert run_cli(capsys, "process", small_bag, "--out", bag_out, "--no-progress")[0] == 0
    stamp = (bag_out / "metadata.yaml").stat().st_mtime_ns
    jsonl.write_text("keep\n")
    for argv in (["--out", bag_out], ["--out", tmp_path / "new", "--jsonl", jsonl]):
        code, _, err = run_cli(capsys, "process", small_bag, *argv, "--no-progress")
        assert_one_line_error(code, err, "exists already")
    assert (bag_out / "metadata.yaml").stat().st_mtime_ns == stamp
    assert jsonl.read_text() == "keep\n" and not (tmp_path / "new").exists()
    assert run_cli(capsys, "process", small_bag, "--out", bag_out, "--jsonl", jsonl, "--force", "--no-progress")[0] == 0
    assert (bag_out / "metadata.yaml").stat().st_mtime_ns != stamp and jsonl.read_text() == ""
    # simulate refuses too, and the output may not be the input
    code, _, err = run_cli(capsys, "simulate", "--out", small_bag, "--duration", "1")
    assert_one_line_error(code, err, "exists already")
    code, _, err = run_cli(capsys, "process", small_bag, "--out", small_bag, "--force", "--no-progress")
    assert_one_line_error(code, err, "cannot be the input")
    assert (small_bag / "metadata.yaml").is_file()


def test_no_command_writes_into_a_bag(small_bag, tmp_path, capsys):
    # plot, export and batch did (the bag then no longer counts as a rosbag2 directory).
    before = sorted(p.name for p in small_bag.iterdir())
    for argv, kind in ((["plot", small_bag, "--out-dir", small_bag / "figures"], "figure folder"),
                       (["export", small_bag, "--npz", small_bag / "x.npz"], "record"),
                       (["batch", small_bag, "--out", small_bag / "campaign", "--workers", "1"], "campaign folder")):
        code, _, err = run_cli(capsys, *argv)
        assert_one_line_error(code, err, f"the {kind} cannot be inside", str(small_bag))
    assert sorted(p.name for p in small_bag.iterdir()) == before
    # plot's default folder for a storage file of a bag directory is beside the directory, not in
    # it (refused as above before the bag is read): here it goes on to say the bag has no outputs.
    storage = next(p for p in small_bag.iterdir() if p.suffix == ".db3")
    code, _, err = run_cli(capsys, "plot", storage)
    assert_one_line_error(code, err, "none of /okid/arx_model")


@pytest.mark.parametrize("source, fragments", [
    ("io_sample /okid/nothing", ["no topic /okid/nothing", "/okid/io_sample (okid_msgs/msg/IoSample)"]),
    ("io_sample /accel/tip1/imu", ["/accel/tip1/imu has type sensor_msgs/msg/Imu", "expected okid_msgs/msg/IoSample"]),
])
def test_a_missing_topic_or_a_wrong_type_is_one_line(small_bag, tmp_path, capsys, source, fragments):
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "process", small_bag, "--source", source, "--out", out, "--no-progress")
    assert_one_line_error(code, err, str(small_bag), *fragments)
    assert not out.exists()


def _truncate_storage(bag: Path) -> None:
    storage = next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) // 3])


def _garbage_storage(bag: Path) -> None:
    storage = next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    storage.write_bytes(b"\x00garbage" * 1000)


def _garbage_metadata(bag: Path) -> None:
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")


# A 2 s MCAP bag is one chunk: cut at a third, nothing before the cut is whole. A closed MCAP
# file under a broken metadata.yaml is read alone (test_an_mcap_file_under_a_broken_metadata...).
@pytest.mark.parametrize("storage, damage", [
    ("sqlite3", _truncate_storage), ("sqlite3", _garbage_storage), ("sqlite3", _garbage_metadata),
    ("mcap", _truncate_storage), ("mcap", _garbage_storage)])
def test_a_corrupt_bag_is_one_line(tmp_path, capsys, storage, damage):
    bag = tmp_path / "bag"
    assert run_cli(capsys, "simulate", "--out", bag, "--duration", "2", "--storage", storage)[0] == 0
    damage(bag)
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "process", bag, "--out", out, "--no-progress")
    assert_one_line_error(code, err, str(bag))
    assert not out.exists()


def test_a_missing_bag_and_bad_options_are_one_line(tmp_path, capsys):
    code, _, err = run_cli(capsys, "process", tmp_path / "nope", "--out", tmp_path / "out")
    assert_one_line_error(code, err, "no such bag")
    code, _, err = run_cli(capsys, "process", tmp_path / "nope", "--out", tmp_path / "out", "--param", "arx.order=0")
    assert_one_line_error(code, err, "arx.order")
    code, _, err = run_cli(capsys, "process", tmp_path / "nope", "--out", tmp_path / "out", "--param", "bogus=1")
    assert_one_line_error(code, err, "bogus")
    code, _, err = run_cli(capsys, "simulate", "--out", tmp_path / "s", "--duration", "-1")
    assert_one_line_error(code, err, "--duration")


def test_a_forgetting_factor_no_window_could_be_realized_with_is_refused_at_the_start(small_bag, tmp_path, capsys):
    # Was: every ArxModel refused (node 1: unexcited at 0.5; node 2: shorter than a realization needs at 0.99),
    # `process` exit 0, `batch` one failure per bag.
    forgetting = ("--param", "arx.window_length=0", "--param", "arx.forgetting_factor=0.99")
    said = "arx.forgetting_factor 0.99 with arx.window_length 0 and arx.order 100: the window's effective memory"
    code, _, err = run_cli(capsys, "process", small_bag, "--out", tmp_path / "out", "--no-progress", *forgetting)
    assert_one_line_error(code, err, said)
    code, _, err = run_cli(capsys, "batch", small_bag, "--out", tmp_path / "campaign", "--no-progress", *forgetting)
    assert_one_line_error(code, err, said)
    assert not (tmp_path / "out").exists() and not (tmp_path / "campaign").exists()


def _sorted_before(messages: list, stamp_ns: int) -> list:
    return sorted(m for m in messages if m[2] < stamp_ns)


def test_a_cut_off_mcap_recording_is_read_up_to_its_cut(run, tmp_path, capsys, monkeypatch):
    """A recorder killed mid-file: no footer, no metadata.yaml; what is whole is read, with a warning."""
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    with open_bag(run["bag"]) as whole:
        full = list(whole.raw_messages())
    data = next(run["bag"].glob("*.mcap")).read_bytes()
    cut = tmp_path / "killed"
    cut.mkdir()
    (cut / "killed_0.mcap").write_bytes(data[: 2 * len(data) // 3])
    with pytest.warns(UserWarning, match=r"killed_0.mcap was cut off .* read the \d+ messages"):
        with open_bag(cut) as bag:
            got = list(bag.raw_messages())
            assert "cut off" in bag.read_note and len(list(scratch.iterdir())) == 1
    assert not list(scratch.iterdir())  # the closed copy is removed on exit
    assert len(full) // 3 < len(got) < len(full)
    last = max(m[2] for m in got)
    assert _sorted_before(got, last) == _sorted_before(full, last)  # every message before the cut, unchanged
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "process", cut, "--out", out, "--no-progress", *FAST)
    assert code == 0 and out.is_dir(), err
    assert err.count("warning:") == 1 and "cut off" in err and "Traceback" not in err, err
    # A campaign reports the bag ok, and says in its reason that it was read in part.
    arx, est = load_node_parameters(overrides=FAST[1::2])
    with pytest.warns(UserWarning, match="cut off"):
        result = run_bag_job(BagJob(bag=str(cut), display="killed", label="killed",
                                    out_dir=str(tmp_path / "campaign"), arx_values=arx, est_values=est))
    assert result["status"] == "ok" and "cut off" in result["reason"], result["reason"]
    # Cut after its messages (the footer lost): every message is read, and the warning says so.
    (cut / "killed_0.mcap").write_bytes(data[:-37])
    with pytest.warns(UserWarning, match="cut off in its index: read the .* every message whole"):
        with open_bag(cut) as bag:
            assert bag.message_count() == len(full)
    # Cut inside its first chunk: nothing to read, one line, nothing written.
    (cut / "killed_0.mcap").write_bytes(data[:3000])
    code, _, err = run_cli(capsys, "process", cut, "--out", tmp_path / "out2", "--no-progress")
    assert_one_line_error(code, err, "cut off", "no message before the cut")
    assert not (tmp_path / "out2").exists() and not list(scratch.iterdir())


def test_a_split_recording_cut_off_in_its_last_file_is_read_as_one(tmp_path):
    """rosbag2 splits long recordings into files; a killed recorder leaves the last one cut."""
    parts = []
    for k in range(2):
        assert main(["simulate", "--out", str(tmp_path / f"part{k}"), "--duration", "20",
                     "--start-time", str(START_S + 20 * k)]) == 0
        parts.append(next((tmp_path / f"part{k}").glob("*.mcap")).read_bytes())
    split = tmp_path / "split"
    split.mkdir()
    (split / "rec_0.mcap").write_bytes(parts[0])
    (split / "rec_1.mcap").write_bytes(parts[1][: len(parts[1]) * 3 // 4])  # cut after its first chunk
    with open_bag(tmp_path / "part0") as first:
        first_count = first.message_count()
    with pytest.warns(UserWarning, match=r"rec_1.mcap was cut off .* read the \d+ messages"):
        with open_bag(split) as bag:
            stamps = [stamp for _, _, stamp, _ in bag.raw_messages()]
    assert first_count < len(stamps) < 2 * first_count  # the closed file whole, the cut one in part
    assert stamps == sorted(stamps) and stamps[-1] > (START_S + 20) * 1_000_000_000


def test_an_mcap_file_under_a_broken_metadata_yaml_is_read_alone(run, tmp_path):
    bag = tmp_path / "bag"
    shutil.copytree(run["bag"], bag)
    _garbage_metadata(bag)
    with pytest.warns(UserWarning, match="metadata.yaml missing or unreadable"):
        with open_bag(bag) as alone, open_bag(run["bag"]) as whole:
            assert alone.message_count() == whole.message_count() > 0
            assert alone.topics == whole.topics


def test_a_bare_mcap_file_opens_like_its_bag(run):
    mcap = next(run["bag"].glob("*.mcap"))
    with open_bag(mcap) as bare, open_bag(run["bag"]) as whole:
        assert bare.topics == whole.topics
        assert bare.message_count() == whole.message_count()


def test_force_on_a_bag_replaces_it(small_bag, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(small_bag, copy)
    assert main(["simulate", "--out", str(copy), "--duration", "1", "--force"]) == 0
    with open_bag(copy) as bag:
        assert bag.message_count([IO_SAMPLE_TOPIC]) == 125


def test_a_simulate_that_fails_keeps_the_bag_it_was_to_replace(small_bag, tmp_path, monkeypatch, capsys):
    # simulate --force removed the old bag before writing: a failure half-way (here a full disk)
    # left neither. The new bag is written beside and renamed over the old one when complete.
    import okid_ros.tools.simulate_bag as simulate_bag
    from okid_ros.tools.errors import BagWriteError

    copy = tmp_path / "copy"
    shutil.copytree(small_bag, copy)
    before = sorted((p.name, p.stat().st_size) for p in copy.iterdir())
    written = simulate_bag._write_messages

    def failing(bag, *args):
        written(bag, *args)
        raise BagWriteError(f"{bag.path}: cannot write (No space left on device)")

    monkeypatch.setattr(simulate_bag, "_write_messages", failing)
    assert main(["simulate", "--out", str(copy), "--duration", "1", "--force"]) == 2
    assert "No space left on device" in capsys.readouterr().err
    assert sorted((p.name, p.stat().st_size) for p in copy.iterdir()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["copy"]  # nothing left beside it
    assert main(["simulate", "--out", str(tmp_path / "new"), "--duration", "1"]) == 2
    assert not (tmp_path / "new").exists()  # a new path: the partial bag removed, as before


def test_an_ambient_bag_that_fails_keeps_the_bag_it_was_to_replace(tmp_path):
    # write_ambient_bag (demo --output-only's experiment) removed an old bag before writing (BagWriter with
    # force): a failure half-way left a partial bag in its place. Now written beside, as simulate does.
    import dataclasses

    from okid_ros.tools.simulate_ambient import simulate_ambient, write_ambient_bag

    bag = tmp_path / "ambient"
    experiment = simulate_ambient(1.0, seed=2, start_ns=1_000 * 1_000_000_000)
    write_ambient_bag(bag, experiment)
    before = sorted((p.name, p.read_bytes()) for p in bag.iterdir())
    three_outputs = dataclasses.replace(experiment, y=experiment.y[:, :3])  # the second Imu has no values
    with pytest.raises(ValueError):
        write_ambient_bag(bag, three_outputs, force=True)
    assert sorted((p.name, p.read_bytes()) for p in bag.iterdir()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ambient"]  # nothing left beside it
    assert write_ambient_bag(bag, experiment, force=True) == {"/okid/imu_top": 200, "/okid/imu_base": 200}


def test_a_ros1_bag_is_read_and_its_messages_come_out_as_cdr(tmp_path):
    from rosbags.rosbag1 import Writer as Ros1Writer

    store = rosbags_typestore()
    T = store.types
    bag = tmp_path / "old.bag"
    with Ros1Writer(bag) as writer:
        connection = writer.add_connection("/okid/io_sample", "okid_msgs/msg/IoSample", typestore=store)
        for k in range(10):
            msg = T["okid_msgs/msg/IoSample"](
                header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=5, nanosec=k * 8_000_000),
                                                frame_id="rig"),
                u=np.array([k, -k], dtype=float), y=np.array([2.0 * k, 0.5], dtype=float))
            writer.write(connection, 5 * 10**9 + k * 8_000_000, store.serialize_ros1(msg, "okid_msgs/msg/IoSample"))
    with open_bag(bag) as reader:
        assert reader.topics == {"/okid/io_sample": "okid_msgs/msg/IoSample"}
        decoded = [msg for _, _, msg in reader.messages()]
        cdr = [raw for _, _, _, raw in reader.raw_messages()]
    assert [list(m.u) for m in decoded] == [[k, -k] for k in range(10)]
    again = [store.deserialize_cdr(raw, "okid_msgs/msg/IoSample") for raw in cdr]  # what replay publishes
    assert [list(m.y) for m in again] == [[2.0 * k, 0.5] for k in range(10)]
    assert again[3].header.stamp.nanosec == 24_000_000 and again[3].header.frame_id == "rig"


def test_plot_draws_the_stabilization_diagram_that_process_recorded(run, capsys):
    out, figures = run["root"] / "out_stab", run["root"] / "figures_stab"
    assert run_cli(capsys, "process", run["bag"], "--params", CONFIG, "--out", out, "--no-progress", *FAST)[0] == 0
    with open_bag(out) as bag:
        stabilization = bag.custom_json("okid_ros.stabilization")
    # The orders the last realization tried, increasing, each with its marked poles.
    orders = [entry["n_states"] for entry in stabilization]
    assert orders == sorted(orders) and len(orders) >= 3
    assert any(pole["stable_frequency"] for entry in stabilization for pole in entry["poles"])
    # A pair out of range is refused before any figure: five figures were left, refusing the rerun.
    code, _, err = run_cli(capsys, "plot", out, "--out-dir", figures, "--frf-pairs", "3:1")
    assert code == 2 and "--frf-pairs" in err and not figures.exists(), err
    code, stdout, err = run_cli(capsys, "plot", out, "--out-dir", figures, "--frf-pairs", "1:1")
    assert code == 0, err
    assert {"stabilization.png", "frf.png", "mac.png"} <= {p.name for p in figures.iterdir()}
def test_process_in_a_namespace_reads_and_writes_the_rigs_topics(small_bag, tmp_path, capsys):
    """--namespace: relative topics under the rig's namespace, absolute ones as they are.

    A parameter file's unknown names are warnings, or an error with --strict-params.
    """
    out = tmp_path / "rig1"
    code, _, err = run_cli(capsys, "process", small_bag, "--namespace", "/rig1", "--out", out, "--no-progress")
    assert_one_line_error(code, err, "/rig1/io_sample")  # the bag has /okid/io_sample only
    typo = tmp_path / "typo.yaml"
    typo.write_text("/**/okid_modal_estimator:\n  ros__parameters:\n    tracking: {min_mak: 0.8}\n")
    code, _, err = run_cli(capsys, "process", small_bag, "--namespace", "/rig1",
                           "--source", "io_sample /okid/io_sample",
                           "--params", CONFIG, "--params", typo, "--out", out, "--no-progress")
    assert code == 0, err
    assert "warning:" in err and "tracking.min_mak" in err
    with open_bag(out) as bag:
        assert set(bag.topics) == {"/rig1/arx_model", "/rig1/state_space_model", "/rig1/modal_states",
                                    "/rig1/structural_change"}
    code, _, err = run_cli(capsys, "process", small_bag, "--source", "io_sample /okid/io_sample", "--params", typo,
                           "--strict-params", "--out", tmp_path / "strict", "--no-progress")
    assert_one_line_error(code, err, "unknown parameter(s) tracking.min_mak")


def test_plot_reads_a_namespaced_output(run, tmp_path, capsys):
    """The output of `process --namespace /rig1` plots with `plot --namespace /rig1`.

    Such a bag is what `record --namespace /rig1` writes; without it the /okid topics are missing.
    """
    out = tmp_path / "rig1"
    code, _, err = run_cli(capsys, "process", run["bag"], "--namespace", "/rig1",
                           "--source", "io_sample /okid/io_sample",
                           "--params", CONFIG, "--out", out, "--no-progress", *FAST)
    assert code == 0, err
    code, _, err = run_cli(capsys, "plot", out, "--out-dir", tmp_path / "none")
    assert_one_line_error(code, err, "none of /okid/arx_model")
    code, stdout, err = run_cli(capsys, "plot", out, "--namespace", "/rig1", "--out-dir", tmp_path / "figs")
    assert code == 0, err
    assert len(list((tmp_path / "figs").glob("*.png"))) >= 4


def test_plot_of_an_output_without_models_says_there_is_nothing_to_draw(tmp_path, capsys):
    """An output bag whose topics hold no model (every model refused) is refused, not 'wrote 0 figures'."""
    store = rosbags_typestore()
    bag = tmp_path / "refused_all"
    with Writer(bag, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        for topic, kind in (("/okid/arx_model", "ArxModel"), ("/okid/state_space_model", "StateSpaceModel"),
                            ("/okid/modal_states", "ModalStates")):
            writer.add_connection(topic, f"okid_msgs/msg/{kind}", typestore=store)
    code, _, err = run_cli(capsys, "plot", bag, "--out-dir", tmp_path / "figs")
    assert_one_line_error(code, err, "nothing to draw", "0 on /okid/state_space_model")
    assert not (tmp_path / "figs").exists()  # the folder made for the figures is not left behind empty
    (tmp_path / "mine").mkdir()
    code, _, err = run_cli(capsys, "plot", bag, "--out-dir", tmp_path / "mine")
    assert_one_line_error(code, err, "nothing to draw")
    assert (tmp_path / "mine").is_dir()  # a folder that was there stays
