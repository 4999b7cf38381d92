"""Hostile options and spoilt files for `plot`, `batch`, `simulate` and `identify --reference`.

Each case was an internal error (exit 70) or a silently wrong output in a sweep of the CLI; the
expected outcome is one line ``okid-ros COMMAND: error: ...`` with status 2 and nothing left
behind, or for a spoilt result of an earlier `batch` run, a warning and the bag processed again.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from batch_helpers import batch, read_summary, table_rows, write_good_bag, write_params

from okid_ros.cli import main
from okid_ros.errors import OutputError, ParameterError

LONG_NAME = "y" * 300  # beyond NAME_MAX (255): "File name too long"


def _usage_error(capsys, argv: list[str], fragment: str) -> None:
    """The parser refuses ``argv``: status 2 and ``fragment`` in its one error line."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err


def _one_line_error(capsys, argv: list[str], fragment: str) -> str:
    """``argv`` exits with status 2 and one error line holding ``fragment``; returns the line."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and ": error: " in err and fragment in err, err
    return err


# --- simulate ---------------------------------------------------------------------------------

@pytest.mark.parametrize("option, fragment", [
    (["--seed", "-1"], "argument --seed: expected an integer >= 0, got -1"),
    (["--noise", "inf"], "argument --noise: expected a positive finite number, got inf"),
    (["--start-time", "nan"], "argument --start-time: expected seconds since the epoch from 0 to 2147483647"),
    (["--start-time", "1e12"], "got 1000000000000.0"),
    (["--start-time", "-1"], "got -1.0"),
])
def test_simulate_refuses_options_out_of_range_before_writing(tmp_path, capsys, option, fragment):
    out = tmp_path / "sim"
    _usage_error(capsys, ["simulate", "--out", str(out), "--duration", "1", *option], fragment)
    assert not out.exists()


def test_simulate_refuses_a_record_ending_beyond_a_ros_stamp(tmp_path, capsys):
    out = tmp_path / "sim"
    err = _one_line_error(capsys, ["simulate", "--out", str(out), "--duration", "2", "--start-time",
                                   str(2**31 - 1)], "would end at 2147483648 s")
    assert "int32" in err and not out.exists()


@pytest.mark.parametrize("option, fragment", [
    # outputs beyond 1e150, refused sample by sample by `process` (was: a bag written)
    (["--noise", "1e300"], "--noise 1e+300 is more than 1e+280"),
    # was: out of memory without naming the option, and an internal error for 1e-300
    (["--cutoff", "1e-12"], "--cutoff 1e-12 Hz: the input cut-off must be from 0.001"),
    (["--cutoff", "1e-300"], "filter's start-up"),
    # was: a --start-time error, an option not given
    (["--duration", "1e10"], "--duration 1e+10 s is more than the 2147483647 s a ROS 2 stamp can hold"),
])
def test_simulate_refuses_options_that_cannot_give_samples_the_nodes_take(tmp_path, capsys, option, fragment):
    out = tmp_path / "sim"
    _one_line_error(capsys, ["simulate", "--out", str(out), "--duration", "1", *option], fragment)
    assert not out.exists()


def test_simulate_refuses_a_duration_beyond_the_available_memory(tmp_path, capsys, monkeypatch):
    from okid_ros.service import sample_buffer

    monkeypatch.setattr(sample_buffer, "available_memory_bytes", lambda: 2**20, raising=False)  # 1 MiB
    out = tmp_path / "sim"
    err = _one_line_error(capsys, ["simulate", "--out", str(out), "--duration", "100"],
                          "--duration 100 s: simulating its 12500 samples needs about")
    assert "only 0.000977 GiB available" in err and not out.exists()


def test_simulate_experiment_checks_seed_and_noise_itself():
    from okid_ros.tools.simulate_bag import simulate_experiment

    with pytest.raises(ParameterError, match="--seed"):
        simulate_experiment(1.0, seed=-1)
    with pytest.raises(ParameterError, match="finite"):
        simulate_experiment(1.0, innovation_variance=float("inf"))


def test_a_bag_failing_half_way_is_removed_and_an_existing_output_kept(tmp_path):
    from okid_ros.tools.errors import BagWriteError, OutputExistsError
    from okid_ros.tools.simulate_bag import simulate_experiment, write_experiment_bag

    experiment = simulate_experiment(0.1, start_ns=0)
    experiment.start_ns = -1_000_000_000  # past the checks: the bag's unsigned log time fails on close
    out = tmp_path / "sim"
    with pytest.raises(BagWriteError, match="cannot finish the bag"):
        write_experiment_bag(out, experiment)
    assert not out.exists()  # was: a 43-byte .mcap that --force then refused to replace
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(OutputExistsError):
        write_experiment_bag(mine, experiment)
    assert (mine / "notes.txt").read_text() == "keep"


# --- plot ---------------------------------------------------------------------------------------

def test_plot_terms_is_bounded(capsys):
    from okid_ros.commands.plot import MAX_TERMS
    from okid_ros.tools import plots

    assert MAX_TERMS == plots.MAX_TERMS
    _usage_error(capsys, ["plot", "x", "--terms", "9223372036854775807"], "expected an integer from 1 to 10000")
    _usage_error(capsys, ["plot", "x", "--terms", "0"], "expected an integer from 1 to 10000, got 0")


@pytest.fixture
def output_bag(tmp_path) -> Path:
    """A bag with the output topic /okid/modal_states and no message (nothing to draw)."""
    from okid_ros.tools.bagio import BagWriter

    path = tmp_path / "out"
    with BagWriter(path) as bag:
        bag.add_topic("/okid/modal_states", "okid_msgs/msg/ModalStates")
    return path


@pytest.mark.parametrize("where, fragment", [
    ("file", "is a file, not a folder"),
    ("/proc/okid_figs", "cannot create the folder of the figures"),
    ("long", "File name too long"),
])
def test_plot_out_dir_that_cannot_be_a_folder_is_one_line(output_bag, tmp_path, capsys, where, fragment):
    out_dir = {"file": tmp_path / "rand.npz", "long": tmp_path / LONG_NAME}.get(where, Path(where))
    if where == "file":
        out_dir.write_bytes(b"mine")
    _one_line_error(capsys, ["plot", str(output_bag), "--out-dir", str(out_dir)], fragment)
    assert where != "file" or out_dir.read_bytes() == b"mine"


def test_a_file_at_the_default_figure_folder_is_refused_as_out_dir_is(output_bag, small_campaign, tmp_path, capsys):
    # Without --out-dir a file at OUT_figures (or a campaign's DIR/figures) said "exists and is not a
    # folder", the one folder check's wording aside.
    default = tmp_path / "out_figures"
    default.write_bytes(b"mine")
    _one_line_error(capsys, ["plot", str(output_bag)], f"--out-dir (by default) {default}: is a file, not a folder")
    campaign = tmp_path / "camp"
    shutil.copytree(small_campaign["out"], campaign)
    (campaign / "figures").write_bytes(b"mine")
    _one_line_error(capsys, ["plot", str(campaign)], f"--out-dir (by default) {campaign / 'figures'}: is a file, not "
                    "a folder")
    assert default.read_bytes() == (campaign / "figures").read_bytes() == b"mine"


def test_a_figure_failing_to_save_leaves_no_file(tmp_path, monkeypatch):
    from okid_ros.tools.plots import pyplot, save_figure

    plt = pyplot()
    fig = plt.figure()

    def fail(stream, **_):
        stream.write(b"\x89PNG half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(fig, "savefig", fail)
    with pytest.raises(OutputError, match="No space left"):
        save_figure(plt, fig, tmp_path / "a.png")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("content, fragment", [
    (b"", "Parquet file size is 0 bytes"),
    (bytes(range(256)) * 4, "magic bytes"),
    (None, "no column mode_id"),
])
def test_plot_of_a_campaign_with_a_spoilt_modes_table_is_one_line(tmp_path, capsys, content, fragment):
    campaign = tmp_path / "camp"
    campaign.mkdir()
    (campaign / "manifest.jsonl").write_text("")
    if content is None:  # a Parquet file, not the campaign's table
        import pyarrow as pa
        import pyarrow.parquet as pq

        pq.write_table(pa.table({"x": [1.0]}), campaign / "modes.parquet")
    else:
        (campaign / "modes.parquet").write_bytes(content)
    err = _one_line_error(capsys, ["plot", str(campaign)], fragment)
    assert f"{campaign / 'modes.parquet'}: not a" in err and not (campaign / "figures").exists()


@pytest.mark.parametrize("column, value", [("frequency_hz", math.nan), ("frequency_hz", math.inf),
                                           ("damping_ratio", math.nan), ("stamp_s", 1e300), ("stamp_s", None)])
def test_plot_of_a_campaign_leaves_out_rows_it_cannot_draw(tmp_path, capsys, column, value):
    """Rows of NaN or Inf were drawn as nothing, and a stamp of 1e300 as a time axis of 1e295 days, in silence."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    campaign = tmp_path / "camp"
    campaign.mkdir()
    (campaign / "manifest.jsonl").write_text("")
    rows = {"mode_id": [1, 1, 2], "stamp_s": [1e9, 1e9 + 10, 1e9 + 10], "frequency_hz": [5.9, 5.91, 48.4],
            "frequency_hz_std": [0.01, 0.01, None], "damping_ratio": [0.003, 0.003, 0.004],
            "damping_ratio_std": [0.001, 0.001, None], "bag_index": [0, 0, 0]}
    rows[column][1] = value
    pq.write_table(pa.table(rows), campaign / "modes.parquet")
    assert main(["plot", str(campaign)]) == 0
    err = capsys.readouterr().err
    assert f"{campaign / 'modes.parquet'}: 1 of the 3 rows left out, not drawn: " in err and "the first: row 1" in err
    rows[column] = [value] * 3
    pq.write_table(pa.table(rows), campaign / "modes.parquet")
    _one_line_error(capsys, ["plot", str(campaign), "--out-dir", str(tmp_path / "f2")],
                    f"{campaign / 'modes.parquet'}: none of its 3 rows can be drawn: a stamp_s beyond any ROS 2 time")


def test_plot_of_a_campaign_names_the_options_of_a_bag_s_figures(tmp_path, capsys):
    """--input, --window, --frf-pairs ... draw an output bag's figures (were passed over in silence)."""
    campaign = tmp_path / "camp"
    campaign.mkdir()
    (campaign / "manifest.jsonl").write_text("")
    (campaign / "modes.parquet").write_bytes(b"")  # the warning comes before the table is read
    main(["plot", str(campaign), "--frf-pairs", "1:1", "--window", "3", "--input", str(tmp_path / "bag")])
    assert (f"okid-ros plot: warning: --input, --window, --frf-pairs: options of an output bag's figures; ignored for "
            f"the campaign folder {campaign} (campaign_modes.png)") in capsys.readouterr().err
    main(["plot", str(campaign), "--window", "5"])  # the default, given
    assert "warning" not in capsys.readouterr().err


# --- identify --reference -------------------------------------------------------------------------

GOOD_MODE = {"id": 0, "frequency_hz": 5.9, "shape_real": [0.88, 0.47], "shape_imag": [0.0, 0.03]}
BAD_REFERENCES = {
    "len3": ({"shape_real": [1, 2, 3], "shape_imag": [0, 0, 0]}, "its shape has 3 entries, the record 2 outputs"),
    "null": ({"shape_real": None}, "shape_real is not a non-empty list of finite numbers"),
    "nested": ({"shape_real": [[1, 2], [3, 4]]}, "shape_real is not a non-empty list"),
    "strings": ({"shape_real": ["a", "b"]}, "shape_real is not a non-empty list"),
    "nan": ({"shape_real": [float("nan"), 1.0]}, "finite numbers"),
    "empty_shape": ({"shape_real": [], "shape_imag": []}, "non-empty"),
    "imag_short": ({"shape_imag": [0.0]}, "shape_imag is not a list of 2 finite numbers"),
    "zero": ({"shape_real": [0, 0], "shape_imag": [0, 0]}, "its shape is all zero"),
    "freq_text": ({"frequency_hz": "fast"}, "frequency_hz is 'fast', not a finite number"),
    "freq_negative": ({"frequency_hz": -5}, "frequency_hz is -5, not a frequency above 0 Hz and at most 500000 Hz"),
    "freq_zero": ({"frequency_hz": 0.0}, "frequency_hz is 0.0, not a frequency above 0 Hz"),
    "freq_huge": ({"frequency_hz": 1e308}, "frequency_hz is 1e+308, not a frequency above 0 Hz"),
    # JSON integers beyond 64 bits: numpy's isfinite raised TypeError, an internal error (exit 70)
    "freq_int": ({"frequency_hz": 10**30}, f"frequency_hz is {10**30}, not a frequency above 0 Hz"),
    "shape_int": ({"shape_real": [10**400, 1]}, "shape_real is not a non-empty list of finite numbers"),
}


@pytest.fixture
def record_file(tmp_path) -> Path:
    rng = np.random.default_rng(1)
    path = tmp_path / "rec.npz"
    np.savez(path, u=rng.standard_normal((400, 1)), y=rng.standard_normal((400, 2)), sample_time_s=0.01)
    return path


@pytest.mark.parametrize("case", sorted(BAD_REFERENCES) + ["no_modes", "modes_dict"])
def test_a_malformed_reference_is_one_line_naming_it(record_file, tmp_path, capsys, case):
    if case in BAD_REFERENCES:
        change, fragment = BAD_REFERENCES[case]
        document = {"modes": [{**GOOD_MODE, **change}]}
    else:
        document = {"modes": [] if case == "no_modes" else {"a": 1}}
        fragment = "no mode to compare with"
    reference = tmp_path / "ref.json"
    reference.write_text(json.dumps(document))
    out, figures = tmp_path / "x.json", tmp_path / "figs"
    err = _one_line_error(capsys, ["identify", str(record_file), "--json", str(out), "--plot-dir", str(figures),
                                   "--reference", str(reference)], fragment)
    assert err.startswith(f"okid-ros identify: error: --reference {reference}: ")  # not the record's name
    # The options are checked before the outputs: not even the figure folder is made.
    assert not out.exists() and not figures.exists()


def test_a_reference_shape_of_huge_numbers_is_drawn_without_a_warning(record_file, tmp_path, capsys):
    reference = tmp_path / "ref.json"
    reference.write_text(json.dumps({"modes": [{**GOOD_MODE, "shape_real": [1e308, 1e308], "shape_imag": [0, 0]},
                                               {**GOOD_MODE, "shape_real": [1e308, -1e308]}]}))
    figures = tmp_path / "figs"
    assert main(["identify", str(record_file), "--json", str(tmp_path / "m.json"), "--plot-dir", str(figures),
                 "--reference", str(reference)]) == 0
    said = capsys.readouterr().err.splitlines()  # the record is noise: only that is said (no overflow, no NaN)
    assert [line for line in said if "warning" in line and "no dynamics identified" not in line] == []
    assert (figures / "mac.png").exists()


def test_a_reference_without_imaginary_parts_or_of_huge_numbers_is_compared():
    from okid_ros.tools.validation_plots import ModelView, mac_data, reference_modes

    modes = reference_modes([{"frequency_hz": 5.9, "shape_real": [0.88, 0.47]},
                             {"frequency_hz": 7.3, "shape_real": [1e308, -1e308], "shape_imag": [1e308, 0]}], "ref")
    view = ModelView(np.eye(2), np.ones((2, 1)), np.eye(2), np.zeros((2, 1)), 0.01,
                     modes=[{"frequency_hz": 5.9, "damping_ratio": 0.01, "shape": np.array([0.88, 0.47]), "id": 0}])
    data = mac_data(view, modes)
    assert data["reference"].shape == (1, 2) and np.all(np.isfinite(data["reference"]))
    assert data["reference"][0, 0] == pytest.approx(1.0)


# --- batch ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("where, fragment", [
    ("file", "is a file, not a folder"),
    ("/proc/okid_campaign", "cannot create the campaign directory"),
    ("long", "File name too long"),
])
def test_batch_out_that_cannot_be_a_directory_is_one_line(tmp_path, capsys, where, fragment):
    bag = tmp_path / "a.mcap"
    bag.write_bytes(b"found by its name; never read: --out is refused first")
    out = {"file": tmp_path / "rand.npz", "long": tmp_path / LONG_NAME}.get(where, Path(where))
    if where == "file":
        out.write_bytes(b"mine")
    _one_line_error(capsys, ["batch", str(bag), "--out", str(out), "--workers", "1", "--no-progress"], fragment)
    assert where != "file" or out.read_bytes() == b"mine"


@pytest.fixture(scope="module")
def small_campaign(tmp_path_factory) -> dict:
    """One simulated 8 s bag run by `batch` once for the module (a few model updates)."""
    root = tmp_path_factory.mktemp("small_campaign")
    bags = root / "bags"
    bags.mkdir()
    write_good_bag(bags / "run_000", 0)
    params = write_params(root / "params.yaml")
    out = root / "camp"
    assert batch(bags, "--params", params, "--out", out, "--workers", 1) == 0
    (label,) = [p.name for p in (out / "bags").iterdir()]
    return {"bags": bags, "params": params, "out": out, "label": label}


def _rerun(small_campaign, tmp_path, capsys, spoil) -> tuple[Path, str]:
    """Copy the campaign, ``spoil(copy)``, run `batch` on it again; returns the copy and stderr."""
    out = tmp_path / "camp"
    shutil.copytree(small_campaign["out"], out)
    spoil(out)
    capsys.readouterr()
    assert batch(small_campaign["bags"], "--params", small_campaign["params"], "--out", out, "--workers", 1) == 0
    return out, capsys.readouterr().err


def _manifest_entry(out: Path, **change) -> None:
    (entry,) = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    (out / "manifest.jsonl").write_text(json.dumps({**entry, **change}) + "\n")


SPOILT_RESULTS = {
    "list": (b"[]", "not a JSON object but list"),
    "empty_object": (b"{}", "its status is None"),
    "random": (bytes(range(128, 256)), "unreadable"),
    "modes_text": (b'{"status": "ok", "label": "x", "updates": [{"stamp_s": 1.0, "model_id": 1, "modes": "abc"}]}',
                   "no list of modes"),
    # JSON integers beyond float64: OverflowError, an internal error (exit 70), or one in the tables' floats
    "huge_stamp": (b'{"status": "ok", "label": "x", "updates": [{"stamp_s": 1' + b"0" * 400 + b', "model_id": 1, '
                   b'"modes": []}]}', "lacks its stamp_s"),
    "huge_frequency": (b'{"status": "ok", "label": "x", "updates": [{"stamp_s": 1.0, "model_id": 1, "modes": '
                       b'[{"id": 0, "frequency_rad_s": 1' + b"0" * 400 + b', "frequency_hz": 1.0, '
                       b'"damping_ratio": 0.01}]}]}',
                       "a mode's frequency_rad_s is 1000"),
}


@pytest.mark.parametrize("case", sorted(SPOILT_RESULTS))
def test_a_spoilt_stored_result_is_processed_again_with_a_warning(small_campaign, tmp_path, capsys, case):
    content, fragment = SPOILT_RESULTS[case]
    result = Path("bags") / small_campaign["label"] / "result.json"
    out, err = _rerun(small_campaign, tmp_path, capsys, lambda out: (out / result).write_bytes(content))
    assert "okid-ros batch: warning: " in err and fragment in err and "processing" in err
    assert read_summary(out)["run_000"]["reused"] == "False"
    assert json.loads((out / result).read_text())["status"] == "ok"  # a good result again
    assert table_rows(out) == table_rows(small_campaign["out"])


def _first_mode_changed(result: dict, name: str, value) -> dict:
    mode = next(mode for update in result["updates"] for mode in update["modes"])
    mode[name] = value if not name.startswith("shape") else [value, *mode[name][1:]]
    return result


NONFINITE_RESULTS = {  # a stored result's numbers NaN/Inf where node 2 never writes them so
    "nan_frequency": (lambda r: _first_mode_changed(r, "frequency_hz", math.nan),
                      "a mode's frequency_hz is nan, not finite"),
    "inf_damping": (lambda r: _first_mode_changed(r, "damping_ratio", math.inf),
                    "a mode's damping_ratio is inf, not finite"),
    "nan_shape": (lambda r: _first_mode_changed(r, "shape_real", math.nan),
                  "a mode's shape_real is not a list of finite numbers"),
    "nan_samples": (lambda r: {**r, "samples": math.nan}, "its samples is nan, not finite"),
}


@pytest.mark.parametrize("case", sorted(NONFINITE_RESULTS))
def test_a_stored_result_of_nan_or_inf_is_spoilt_and_processed_again(small_campaign, tmp_path, capsys, case):
    # NaN/Inf frequencies, damping ratios, shapes or counts in a result.json were taken as a good result.
    from okid_ros.tools.campaign.stored import result_problem

    spoil, fragment = NONFINITE_RESULTS[case]
    result = Path("bags") / small_campaign["label"] / "result.json"

    def write_spoilt(out: Path) -> None:
        (out / result).write_text(json.dumps(spoil(json.loads((out / result).read_text())), allow_nan=True))

    out, err = _rerun(small_campaign, tmp_path, capsys, write_spoilt)
    assert f"okid-ros batch: warning: {out / result}: {fragment}; processing" in err
    assert read_summary(out)["run_000"]["reused"] == "False"
    assert result_problem(json.loads((out / result).read_text()), "ok") == ""  # a good result again
    assert table_rows(out) == table_rows(small_campaign["out"])


@pytest.mark.parametrize("change, fragment", [
    ({"label": ["x"]}, "its label is ['x'], not a folder name"),
    ({"label": "../../elsewhere"}, "not a plain folder name"),
    ({"status": "weird", "summary": {"bag": 1}}, "the status 'weird'"),
    ({"status": "failed", "summary": "x"}, "not a JSON object but str"),
])
def test_a_spoilt_manifest_entry_is_processed_again_keeping_the_good_result(small_campaign, tmp_path, capsys,
                                                                           change, fragment):
    out, err = _rerun(small_campaign, tmp_path, capsys, lambda out: _manifest_entry(out, **change))
    assert "okid-ros batch: warning: " in err and fragment in err
    assert read_summary(out)["run_000"]["status"] == "ok"
    stored = json.loads((out / "bags" / small_campaign["label"] / "result.json").read_text())
    assert stored["status"] == "ok" and stored["updates"]
    assert table_rows(out) == table_rows(small_campaign["out"])


def test_a_manifest_of_random_bytes_is_ignored_with_a_warning(small_campaign, tmp_path, capsys):
    out, err = _rerun(small_campaign, tmp_path, capsys,
                      lambda out: (out / "manifest.jsonl").write_bytes((bytes(range(128, 256)) + b"\n") * 3))
    assert "manifest.jsonl: 3 unreadable line(s) ignored" in err
    assert read_summary(out)["run_000"]["reused"] == "False"
    assert table_rows(out) == table_rows(small_campaign["out"])
    assert json.loads((out / "manifest.jsonl").read_text())["status"] == "ok"  # rewritten, readable


def test_an_intact_campaign_is_reused_without_a_warning(small_campaign, tmp_path, capsys):
    from okid_ros.tools.campaign.stored import result_problem

    stored = json.loads((small_campaign["out"] / "bags" / small_campaign["label"] / "result.json").read_text())
    assert result_problem(stored, "ok") == ""
    out, err = _rerun(small_campaign, tmp_path, capsys, lambda out: None)
    assert "warning" not in err and read_summary(out)["run_000"]["reused"] == "True"


@pytest.mark.parametrize("plan", [False, True])
def test_batch_names_a_folder_without_bags_as_it_is_spelt(tmp_path, capsys, plan):
    """A tab in the folder's name was shown as a blank: "no bags found in empty dir", a folder not there."""
    folder = tmp_path / "empty\tdir"
    folder.mkdir()
    argv = ["batch", str(folder), *(["--plan"] if plan else ["--out", str(tmp_path / "campaign")])]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"no bags found in {str(folder)!r}" in err, err


@pytest.mark.parametrize("options, named", [
    (["--workers", "2", "--max-failures", "1", "--retry-failed"], "--workers, --max-failures, --retry-failed"),
    (["--force", "--csv", "--storage", "sqlite3"], "--force, --csv, --storage"),
])
def test_batch_plan_names_the_options_of_processing_it_passes_over(tmp_path, capsys, options, named):
    """Were passed over in silence: `--plan --force` read as if the bags were to be processed again."""
    bag = write_good_bag(tmp_path / "run_000", 0, duration_s=1.0)
    assert main(["batch", str(bag), "--plan", *options]) == 0
    captured = capsys.readouterr()
    assert f"okid-ros batch: warning: {named}: options of processing bags; ignored with --plan (it lists the bags " \
           "and processes none)" in captured.err, captured.err
    assert "run_000" in captured.out and not (tmp_path / "campaign").exists()


def _metadata(start_ns: object = 1_700_000_000_000_000_000, duration_ns: object = 20_000_000_000,
              count: object = 2500) -> dict:
    """A rosbag2 metadata.yaml's information, one topic."""
    topic = {"name": "/okid/io_sample", "type": "okid_msgs/msg/IoSample"}
    return {"rosbag2_bagfile_information": {
        "starting_time": {"nanoseconds_since_epoch": start_ns}, "duration": {"nanoseconds": duration_ns},
        "topics_with_message_count": [{"message_count": count, "topic_metadata": topic}]}}


@pytest.mark.parametrize("spoilt, error", [
    ({"start_ns": 10**30}, "starting_time is 1000000000000000000000000000000, not an integer from 0 to 2**63 - 1"),
    ({"start_ns": -10**23}, "starting_time is -100000000000000000000000, not an integer"),
    ({"duration_ns": -20_000_000_000}, "duration is -20000000000, not an integer"),
    ({"count": -100000}, "the message_count of /okid/io_sample is -100000, not an integer"),
    ({"count": 2500.7}, "the message_count of /okid/io_sample is 2500.7, not an integer"),
])
def test_batch_plan_flags_metadata_of_times_and_counts_rosbag2_never_writes(tmp_path, capsys, spoilt, error):
    """Were exit 70 (a start beyond datetime's years), or negative counts and durations planned in silence.

    A count of 2500.7 was planned as 2500.
    """
    import yaml

    bag = tmp_path / "run"
    bag.mkdir()
    (bag / "metadata.yaml").write_text(yaml.safe_dump(_metadata(**spoilt)))
    assert main(["batch", str(bag), "--plan"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith(str(bag)))
    assert f"{bag}: metadata.yaml: {error}" in row and "1 would fail" in out, out
    (bag / "metadata.yaml").write_text(yaml.safe_dump(_metadata()))
    assert main(["batch", str(bag), "--plan"]) == 0
    assert "0 would fail" in capsys.readouterr().out
