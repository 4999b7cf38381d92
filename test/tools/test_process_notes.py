"""What `process` says about a bag whose stamps or values are odd (second hostile sweep, session s31).

Stamps that go back and rise again, a gap of hours, every other message NaN, a sample time that
does not fit the stamps, a publish rate above the sampling rate: each gives an honest line or a
warning, never a figure that reads wrong.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_cli
from ros_helpers import rosbags_typestore

IO_TOPIC, IO_TYPE = "/okid/io_sample", "okid_msgs/msg/IoSample"
START_NS = 1_700_000_000 * 1_000_000_000
DT = 0.008
N = 600


def write_io_bag(path: Path, stamps_ns: np.ndarray, y: np.ndarray | None = None, seed: int = 0) -> Path:
    """A bag of ``IoSample`` on /okid/io_sample with the given header stamps; 2 inputs, 2 outputs.

    The log times are those of a regular recording (:func:`grid_ns`), so the messages are read in
    the order given whatever their stamps.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    rng = np.random.default_rng(seed)
    n = len(stamps_ns)
    u = rng.standard_normal((n, 2))
    y = rng.standard_normal((n, 2)) if y is None else y
    store = rosbags_typestore()
    time_cls, header_cls = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Header"]
    io_cls = store.types[IO_TYPE]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(IO_TOPIC, IO_TYPE, typestore=store)
        for k, (ns, log_ns) in enumerate(zip(np.asarray(stamps_ns).tolist(), grid_ns(n).tolist())):
            header = header_cls(stamp=time_cls(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id="")
            msg = io_cls(header=header, u=u[k].astype(np.float64), y=np.asarray(y[k], dtype=np.float64))
            writer.write(connection, log_ns, store.serialize_cdr(msg, IO_TYPE))
    return path


def grid_ns(n: int = N) -> np.ndarray:
    return START_NS + np.rint(np.arange(n) * DT * 1e9).astype(np.int64)


def process(capsys, bag: Path, tmp_path: Path, *options: str) -> tuple[int, str, str]:
    return run_cli(capsys, "process", bag, "--out", tmp_path / "out", "--no-progress", *options)


def test_stamps_that_go_back_and_rise_again_give_the_data_they_hold(tmp_path, capsys):
    # Stamps descending to mid-bag, then rising again: was "254 samples (0.0 s of data)" (sweep: 1136
    # samples of 2500), the first sample, taken before the stamps went back, and the last having one stamp.
    grid = grid_ns()
    vee = np.where(np.arange(N) <= N // 2, grid[::-1], grid)
    code, out, err = process(capsys, write_io_bag(tmp_path / "vee", vee), tmp_path)
    assert code == 0, err
    line = next(x for x in out.splitlines() if x.startswith("processed "))
    assert "(0.0 s of data" not in line and "2.0 s of data in 2 stretches" in line, line
    assert "the stamps went back in time once" in line, line


def test_a_gap_of_hours_is_said_to_be_a_gap(tmp_path, capsys):
    # Was: "0 of the 600 input messages were rejected: 2250000 samples dropped incomplete (missing)".
    stamps = grid_ns() + np.where(np.arange(N) >= N // 2, 5 * 3600 * 10**9, 0)
    code, out, err = process(capsys, write_io_bag(tmp_path / "gap", stamps), tmp_path)
    assert code == 0, err
    assert "0 of the" not in err and "rejected" not in err, err
    assert "2250000 samples missing: a gap of 18000 s with no messages after the stamp 1700000002.392 s" in err, err
    line = next(x for x in out.splitlines() if x.startswith("processed "))
    assert "(4.8 s of data, and 18000.0 s of gaps without samples)" in line, line


@pytest.mark.parametrize("sample_time_s, hint", [
    ("0.016", "300 off_grid; most fell between sample times: is sample_time_s 0.016 s right?"),
    ("0.004", "most of the 600 samples stand alone between empty sample times: is sample_time_s 0.004 s right?"),
])
def test_process_gives_the_sample_time_hint_export_gives(tmp_path, capsys, sample_time_s, hint):
    # Was: "1250 off_grid" or "2499 samples dropped incomplete (missing)" and no word on the sample time.
    bag = write_io_bag(tmp_path / "bag", grid_ns())
    code, _, err = process(capsys, bag, tmp_path, "--param", f"sample_time_s={sample_time_s}")
    assert code == 0 and hint in err, err
    code, _, err = run_cli(capsys, "export", bag, "--npz", tmp_path / "r.npz", "--param",
                           f"sample_time_s={sample_time_s}")
    # one rule for both; at 0.004 s each sample stands alone: no record of two samples, export refuses it
    assert code == (2 if sample_time_s == "0.004" else 0) and hint.split("; ")[-1] in err, err


@pytest.mark.parametrize("command", ["process", "export"])
def test_every_other_message_nan_is_blamed_on_the_values_not_the_sample_time(tmp_path, capsys, command):
    # Was: "most of the 300 samples stand alone between empty sample times: is sample_time_s 0.008 s right?"
    y = np.random.default_rng(1).standard_normal((N, 2))
    y[1::2] = np.nan
    bag = write_io_bag(tmp_path / "halfnan", grid_ns(), y=y)
    target = ["--out", tmp_path / "out"] if command == "process" else ["--npz", tmp_path / "r.npz"]
    code, _, err = run_cli(capsys, command, bag, *target, *(["--no-progress"] if command == "process" else []))
    assert code == (0 if command == "process" else 2), err  # export: no two samples in a row, no record
    assert ("most of the 300 samples stand alone between sample times whose messages were rejected "
            "(300 with NaN or Inf values): the values, not sample_time_s, left them empty") in err, err
    assert "is sample_time_s" not in err, err


@pytest.mark.parametrize("time_jump_s", ["1.0", "60.0"])
def test_a_slow_grid_takes_every_sample_whatever_the_time_jump(tmp_path, capsys, time_jump_s):
    # A structure sampled at 0.2 Hz: the default inputs.time_jump_s of 1 s made every step a jump and the
    # hint asked whether sample_time_s was right (it was); the grid's threshold is now at least
    # latency + 2 sample times, so every sample is taken and nothing needs saying.
    bag = write_io_bag(tmp_path / "slow", START_NS + np.arange(40) * 5 * 10**9)
    options = ["--param", "sample_time_s=5.0", "--param", f"inputs.time_jump_s={time_jump_s}"]
    code, _, err = run_cli(capsys, "export", bag, "--npz", tmp_path / "r.npz", *options)
    assert code == 0 and not err, err
    assert np.load(tmp_path / "r.npz")["y"].shape[0] == 40


@pytest.mark.parametrize("every, code, said", [
    (15, 0, "warning: BAG: the record written is the longest of its 100 contiguous runs, 14 of the 1400 samples "
            "(1 %); 99 sample times dropped incomplete"),
    (14, 2, "error: BAG: the longest of its 108 contiguous runs, 13 of the 1393 samples (0.93 %), is shorter than any "
            "command identifies from (14 samples with 2 inputs and 2 outputs): 107 sample times dropped incomplete"),
])
def test_export_of_a_bag_with_many_gaps_says_the_share_kept_or_refuses_a_run_too_short(tmp_path, capsys, every,
                                                                                         code, said):
    # Every 15th message lost: 14 of the 1400 samples exported, exit 0, the warning naming only the lost
    # sample times. 14 is the fewest identify takes with 2 inputs and 2 outputs (ARX order 2 and 2 states;
    # arx_order.fewest_samples_to_identify): runs of 13 (every 14th lost) were exported before, then refused.
    stamps = grid_ns(1500)
    bag = write_io_bag(tmp_path / "gaps", stamps[np.arange(1500) % every != every - 1])
    out = tmp_path / "r.npz"
    got, _, err = run_cli(capsys, "export", bag, "--npz", out)
    assert got == code and err.startswith(f"okid-ros export: {said}".replace("BAG", str(bag))), err
    assert out.exists() == (code == 0) and (code or np.load(out)["y"].shape[0] == 14)


def test_a_publish_rate_above_the_sampling_rate_is_said_up_front(tmp_path, capsys):
    # 1000 Hz on a 125 Hz bag took 90 times as long as the default, with nothing said when stderr is
    # not a terminal (no progress bar).
    bag = write_io_bag(tmp_path / "bag", grid_ns(300))
    code, _, err = process(capsys, bag, tmp_path, "--param", "publish_rate_hz=1000.0")
    assert code == 0, err
    assert err.startswith("okid-ros process: warning: publish_rate_hz 1000 is above the sampling rate 125 Hz: a model "
                          "at every sample, about 300 ArxModel solved and each valid one realized, against about 2 at "
                          "the default 1 Hz: process may take up to 125 times as long"), err


@pytest.mark.parametrize("sample_time_s", [0.008, 1.0, 5.0])
def test_the_default_publish_rate_is_not_warned_about_on_any_grid(tmp_path, capsys, sample_time_s):
    # An earlier refusal of a rate at or above the sampling rate refused the default 1 Hz on slow grids.
    bag = write_io_bag(tmp_path / "bag", START_NS + np.rint(np.arange(40) * sample_time_s * 1e9).astype(np.int64))
    options = ["--param", f"sample_time_s={sample_time_s}", "--param", "inputs.time_jump_s=60.0"]
    code, _, err = process(capsys, bag, tmp_path, *options)
    assert code == 0 and "publish_rate_hz" not in err, err
    if sample_time_s >= 1.0:  # the default is a model at every sample there already: any rate costs the same
        code, _, err = run_cli(capsys, "process", bag, "--out", tmp_path / "o2", "--no-progress", *options,
                               "--param", "publish_rate_hz=1000.0")
        assert code == 0 and "publish_rate_hz" not in err, err


def test_a_stray_duplicate_is_no_sign_of_a_wrong_sample_time(tmp_path, capsys):
    # "most fell in a sample time already taken" counted the refusals only: one duplicate in 600 asked
    # whether sample_time_s was right, and process says its hints also when models came.
    stamps = grid_ns()
    stamps[300] = stamps[299]
    code, _, err = run_cli(capsys, "export", write_io_bag(tmp_path / "bag", stamps), "--npz", tmp_path / "r.npz")
    assert code == 0 and "1 duplicate" in err and "sample_time_s" not in err, err


def test_arx_models_node_2_refuses_after_a_forward_jump_of_hours_are_said(tmp_path, capsys):
    # A jump of 5 h half-way: node 2 refused 17 of node 1's ArxModels (windows across the gap,
    # `arx_models_refused` in its diagnostics) and `process` said nothing of it.
    from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

    n = 7500
    u = lowpass_input(n, 2, 15.0, DT, seed=1)
    y, _ = simulate_innovation(paper_model(), u, seed=2)
    stamps = grid_ns(n) + np.where(np.arange(n) >= n // 2, 5 * 3600 * 10**9, 0)
    bag = write_io_bag(tmp_path / "jump", stamps, y=y)
    code, _, err = process(capsys, bag, tmp_path)
    assert code == 0, err
    said = [line for line in err.splitlines() if "ArxModels" in line]
    assert len(said) == 1, err
    assert said[0].startswith("okid-ros process: warning: node 2 refused 17 of the 43 ArxModels of node 1: 17 with too "
                              "few samples after a gap (or a time jump) in their window (the last: "), said
    assert "follow its last gap longer than 10 samples; the realization needs at least" in said[0]


@pytest.mark.parametrize("factor", [2.0, 1 + 1e-6])
def test_node_2_and_process_ignore_an_arx_model_of_another_sample_time_alike(factor):
    # `process` read node 1's ArxModel without node 2's sample time: a model of another grid was realized.
    from types import SimpleNamespace as NS

    from okid_ros.nodes.modal_estimator_node import ModalEstimatorNode
    from okid_ros.service.options import ModalEstimationParams
    from okid_ros.tools.offline import OfflineNodes
    from okid_ros.tools.process import load_node_parameters

    arx_values, est_values = load_node_parameters([], [], [])
    dt = float(est_values["sample_time_s"])
    msg = NS(model_id=7, valid=True, sample_time_s=factor * dt, n_inputs=2, n_outputs=2, order=10)
    logged: list[str] = []
    node = NS(active=True, _arx_invalid=0, _arx_malformed=0, get_logger=lambda: NS(warning=logged.append),
              service=NS(params=ModalEstimationParams.from_parameters(est_values)))
    ModalEstimatorNode._on_arx_model(node, msg)  # node 2's callback, its DDS left out
    offline = OfflineNodes(arx_values, est_values)
    why = offline.take_arx_model(msg)
    assert logged == [why] and node._arx_malformed == offline.summary.arx_malformed == 1
    assert why == (f"ArxModel 7 ignored: ArxModel of sample time {factor * dt!r} s; this node's sample_time_s is "
                   f"{dt!r} s")
    told = re.search(r"sample time (\S+) s; this node's sample_time_s is (\S+) s", why)
    assert told and told[1] != told[2]  # the two times told apart, however close (:g said 0.008 and 0.008)
    offline.summary.valid_arx_models = 1
    assert offline.summary.arx_refused_note() == (f"node 2 ignored 1 of the 1 valid ArxModels of node 1, the first: "
                                                  f"{why}")
