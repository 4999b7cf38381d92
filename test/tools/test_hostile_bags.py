"""Bags and trees of bags that are odd rather than corrupt: one-line errors or warnings, never exit 70.

A bag whose data file cannot be opened, `plot` given `.` or a metadata document of the wrong
shape, `batch` searching a tree with a folder it may not enter.
"""

from __future__ import annotations

import json
import pathlib
import shutil
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from cli_helpers import assert_one_line_error, run_cli
from ros_helpers import REPO_ROOT

from okid_ros.cli import main
from okid_ros.errors import OkidWarning
from okid_ros.tools.campaign.discovery import find_bags
from okid_ros.tools.plot_metadata import check_plot_metadata

CONFIG = REPO_ROOT / "config" / "okid.yaml"
FAST = ["--param", "publish_rate_hz=0.25", "--param", "realization.max_states=8"]  # as test_bags.py


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> dict[str, Path]:
    """A 22 s simulated bag processed once (one model)."""
    root = tmp_path_factory.mktemp("hostile")
    bag, out = root / "experiment", root / "out"
    assert main(["simulate", "--out", str(bag), "--duration", "22"]) == 0
    assert main(["process", str(bag), "--params", str(CONFIG), "--out", str(out), "--no-progress", *FAST]) == 0
    return {"root": root, "bag": bag, "out": out}


@pytest.mark.parametrize("command", [["export", "--npz", "x.npz"], ["identify", "--json", "x.json"],
                                     ["process", "--out", "x_out"]])
def test_a_bag_whose_data_file_is_a_folder_is_one_line(run, tmp_path, capsys, command):
    bag = tmp_path / "bag"
    shutil.copytree(run["bag"], bag)
    data = next(bag.glob("*.mcap"))
    data.unlink()
    data.mkdir()
    name, *options = command
    code, _, err = run_cli(capsys, name, bag, *[str(tmp_path / o) if o.startswith("x") else o for o in options])
    assert_one_line_error(code, err, f"{bag}: not a readable rosbag2", "Is a directory")


def test_plot_dot_from_inside_the_bag_puts_the_figures_beside_it(run, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    shutil.copytree(run["out"], out)
    monkeypatch.chdir(out)
    code, stdout, err = run_cli(capsys, "plot", ".")
    assert code == 0, err
    assert f"figures to {tmp_path / 'out_figures'}" in stdout
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, "plot", "/")
    assert_one_line_error(code, err, "no folder to put the figures beside", "--out-dir")


def _with_custom_data(source: Path, bag: Path, documents: dict[str, str]) -> None:
    shutil.copytree(source, bag)
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())
    metadata["rosbag2_bagfile_information"]["custom_data"].update(documents)
    (bag / "metadata.yaml").write_text(yaml.safe_dump(metadata))


#: Metadata documents of the wrong shape: (key, JSON text, the reason plot gives when it leaves the document out).
SPOILT_DOCUMENTS = [
    ("okid_ros.truth", "[1, 2]", "not a JSON object"),
    ("okid_ros.truth", '{"modes": [1]}', "modes is not a list of objects"),
    ("okid_ros.truth", '{"modes": [{"frequency_hz": null, "damping_ratio": 0.1}]}', "frequency_hz"),
    ("okid_ros.truth", '{"A": [[1, 0], [0, 1]], "B": [[1]], "C": [[1, 0]], "D": [[0]], "K": [[0], [0]]}',
     "matrix sizes do not fit together (B (1, 1))"),
    ("okid_ros.truth", '{"A": "x", "B": [], "C": [], "D": [], "K": []}', "A is not a matrix of numbers"),
    # JSON integers beyond float64: OverflowError, an internal error (exit 70)
    ("okid_ros.truth", '{"modes": [{"frequency_hz": 1' + "0" * 400 + ', "damping_ratio": 0.1}]}',
     "a mode's frequency_hz is not a finite number"),
    ("okid_ros.truth", '{"A": [[1' + "0" * 400 + ']], "B": [[1]], "C": [[1]], "D": [[0]], "K": [[0]]}',
     "A is not a finite 2-D matrix"),
    ("okid_ros.stabilization", '[{"n_states": "x", "poles": []}]', "n_states is not an integer"),
    ("okid_ros.process", '{"parameters": {"x": 1}}', "its parameters of okid_modal_estimator: no object"),
    # exit 70 before: int(round(1e300 * 1e9)), and a ValueError assembling the input bag's samples
    ("okid_ros.process", '{"first_stamp_s": 1e300}', "its first_stamp_s is not a ROS 2 time"),
    ("okid_ros.process", '{"parameters": {"okid_modal_estimator": {"sample_time_s": "x"}}}',
     "parameter sample_time_s must be a number, got 'x'; the input bag read with --params or the built-in defaults"),
]


@pytest.mark.parametrize(("key", "value", "reason"), SPOILT_DOCUMENTS)
def test_a_metadata_document_of_the_wrong_shape_is_left_out_with_its_reason(key, value, reason):
    """Each document as plot reads it from metadata.yaml (``custom_json``: JSON text), judged by plot's check."""
    documents = {"okid_ros.truth": "truth", "okid_ros.stabilization": "stabilization",
                 "okid_ros.process": "process_info"}
    data = SimpleNamespace(truth=None, stabilization=None, process_info=None)
    setattr(data, documents[key], json.loads(value))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_plot_metadata("out", data)
    said = [str(w.message) for w in caught if issubclass(w.category, OkidWarning)]
    assert len(said) == 1 and f"{key} is not what plot can draw (" in said[0] and reason in said[0], said
    assert "left out" in said[0]


def test_plot_leaves_out_the_metadata_documents_of_the_wrong_shape_and_draws(run, tmp_path, capsys):
    """One plot of a bag with a spoilt document under each key (each left out, the process record's bad parts)."""
    bag = tmp_path / "out"
    spoilt = {"okid_ros.truth": '{"modes": [1]}', "okid_ros.stabilization": '[{"n_states": "x", "poles": []}]',
              "okid_ros.process": '{"first_stamp_s": 1e300, "parameters": {"okid_modal_estimator": '
                                  '{"sample_time_s": "x"}}}'}
    _with_custom_data(run["out"], bag, spoilt)
    code, stdout, err = run_cli(capsys, "plot", bag, "--out-dir", tmp_path / "figures")
    assert code == 0, err
    for key, reason in (("okid_ros.truth", "modes is not a list of objects"),
                        ("okid_ros.stabilization", "n_states is not an integer"),
                        ("okid_ros.process", "its first_stamp_s is not a ROS 2 time"),
                        ("okid_ros.process", "its parameters of okid_modal_estimator")):
        assert f"{key} is not what plot can draw (" in err and reason in err, (key, reason, err)
    assert "wrote" in stdout and (tmp_path / "figures" / "modes_over_time.png").is_file()


def test_plot_refuses_a_figure_folder_inside_its_input_bag(run, tmp_path, capsys):
    bag = tmp_path / "experiment"
    shutil.copytree(run["bag"], bag)
    code, _, err = run_cli(capsys, "plot", run["out"], "--input", bag, "--out-dir", bag / "figures")
    assert_one_line_error(code, err, "input bag")
    assert not (bag / "figures").exists()


@pytest.mark.parametrize("spoilt", ["empty.mcap", "empty_folder"])
def test_an_unreadable_input_bag_is_refused_as_the_option(run, tmp_path, capsys, spoilt):
    """Was ``OUT: INPUT: not a readable rosbag2 ...``: prefixed with the plotted bag, as if it were at fault."""
    bag = tmp_path / spoilt
    bag.mkdir() if spoilt == "empty_folder" else bag.write_bytes(b"")
    code, _, err = run_cli(capsys, "plot", run["out"], "--input", bag, "--out-dir", tmp_path / "figures")
    assert_one_line_error(code, err, f"plot: error: --input {bag}: not a readable rosbag2 or ROS 1 bag")
    assert str(run["out"]) not in err and not (tmp_path / "figures").exists()


def test_a_folder_batch_may_not_enter_is_left_out_with_a_warning(run, tmp_path, monkeypatch):
    tree = tmp_path / "tree"
    shutil.copytree(run["bag"], tree / "ok")
    (tree / "locked").mkdir()
    is_file = pathlib.Path.is_file

    def refused(self: Path) -> bool:  # as for a user without permission (the tests run as root)
        if self.parent.name == "locked":
            raise PermissionError(13, "Permission denied", str(self))
        return is_file(self)

    monkeypatch.setattr(pathlib.Path, "is_file", refused)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert find_bags([tree]) == [tree / "ok"]
    assert any(issubclass(w.category, OkidWarning) and "left out 1 folder(s)" in str(w.message)
               and str(tree / "locked") in str(w.message) for w in caught)


def test_a_bag_directory_and_its_own_storage_file_are_one_recording(run, tmp_path):
    # `batch BAG BAG/BAG.mcap` (or a link to the file) processed one recording twice: its modes
    # counted twice in the campaign's table.
    storage = next(run["bag"].glob("*.mcap"))
    link = tmp_path / "link.mcap"
    link.symlink_to(storage)
    with pytest.warns(OkidWarning, match="the storage file of a bag directory given or found too"):
        assert find_bags([run["bag"], storage, link]) == [run["bag"]]
    assert find_bags([storage]) == [storage]  # alone, the file is the bag


def test_process_refuses_a_bag_of_one_sample(tmp_path, capsys):
    # Exit 0 with an empty output bag. (`export` writes such a record with a warning on the sample
    # time, test_bag_records.py: the likely cause, which a refusal would hide.)
    from real_helpers import write_record_bag

    rng = np.random.default_rng(0)
    write_record_bag(tmp_path / "one", rng.standard_normal((1, 2)), rng.standard_normal((1, 2)), 0.008)
    code, _, err = run_cli(capsys, "process", tmp_path / "one", "--out", tmp_path / "o", "--no-progress")
    assert code == 2 and "one complete sample only" in err and not (tmp_path / "o").exists(), err


def test_a_window_beyond_the_address_space_limit_is_refused_naming_the_parameter(tmp_path):
    """Under ``ulimit -v 4000000`` a window of 1e8 rows was "out of memory", the parameter unnamed."""
    import resource
    import subprocess
    import sys

    bag = tmp_path / "sim"
    assert main(["simulate", "--out", str(bag), "--duration", "3"]) == 0

    def limit_address_space() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (4_000_000 * 1024, 4_000_000 * 1024))

    result = subprocess.run(
        [sys.executable, "-m", "okid_ros.cli", "process", str(bag), "--out", str(tmp_path / "out"), "--no-progress",
         "--param", "arx.window_length=100000000"],
        capture_output=True, text=True, timeout=120, preexec_fn=limit_address_space, cwd=REPO_ROOT)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1, result.stderr
    assert "arx.window_length 100000000: buffering the window's samples needs about 15.3 GiB" in result.stderr
    assert not (tmp_path / "out").exists()


def _spoil_state_space(msg) -> None:
    msg.a = msg.a[:-1]


def _spoil_sample_time(msg) -> None:
    msg.sample_time_s = 0.0


def _spoil_stability(msg) -> None:
    msg.a = np.asarray(msg.a) * 3


def _spoil_values(msg) -> None:
    msg.k = np.full(len(msg.k), np.nan)


def _spoil_shape(msg) -> None:
    msg.modes[0].shape_real = np.zeros(7)


def _spoil_markov(msg) -> None:
    msg.markov_parameters = msg.markov_parameters[:-3]


@pytest.mark.parametrize(("topic", "spoil", "reason"), [
    ("/okid/state_space_model", _spoil_state_space, "a has 63 values, its sizes give 8 x 8"),
    ("/okid/state_space_model", _spoil_sample_time, "sample_time_s 0.0 is not a positive number of seconds"),
    ("/okid/state_space_model", _spoil_stability, "A is unstable (spectral radius 2.99"),
    ("/okid/state_space_model", _spoil_values, "k holds values that are not finite"),
    ("/okid/state_space_model", _spoil_shape, "its shape has 7 real and 2 imaginary values, the model 2 outputs"),
    ("/okid/arx_model", _spoil_markov, "markov_parameters has 401 values, its sizes give 101 x 4"),
])
def test_plot_leaves_out_a_model_message_it_cannot_draw(run, tmp_path, topic, spoil, reason):
    """A recording takes any publisher's models: one of the wrong sizes, not finite, of no sample time or unstable.

    Was exit 70 (a reshape's ValueError, scipy's "array must not contain infs or NaNs", a ZeroDivisionError in the
    FRF), or the unstable model's figures drawn in silence.
    """
    import copy

    from okid_ros.tools.bagio import BagWriter, open_bag
    from okid_ros.tools.plots import read_plot_data

    with open_bag(run["out"]) as bag:
        msgs = [(log_ns, msg) for _, log_ns, msg in bag.messages([topic])]
        msgtype = bag.topics[topic]
    log_ns, good = next((log_ns, msg) for log_ns, msg in reversed(msgs)
                        if topic != "/okid/arx_model" or (msg.valid and msg.markov_parameters_count))
    spoilt = copy.deepcopy(good)
    spoilt.model_id += 1
    spoil(spoilt)
    msgs.append((log_ns + 1, spoilt))
    with BagWriter(tmp_path / "spoilt") as out:
        out.add_topic(topic, msgtype)
        for log_ns, msg in msgs:
            out.write(topic, log_ns, msg)
    with pytest.warns(OkidWarning) as caught:
        data = read_plot_data(tmp_path / "spoilt")
    assert any(f"1 of the {len(msgs)} messages on {topic} left out, not drawn (the last: model "
               f"{spoilt.model_id}: " in str(w.message) and reason in str(w.message) for w in caught), \
        [str(w.message) for w in caught]
    kept = data.state_space["model_id"] if topic == "/okid/state_space_model" else data.arx_model_id
    assert kept == good.model_id
