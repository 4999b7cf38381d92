"""Output-only records as a user might hand them over: layouts, dtypes, CSV locales (docs/robustness.md).

Each case was seen to fail in a confusing way before (the forty-fifth session's sweep, "Hostile
output-only records"); the ones already right are in the table of that section, not here.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli

SAMPLE_TIME_S = 0.005


def _ambient(n_samples: int = 6000, n_outputs: int = 3, seed: int = 1) -> np.ndarray:
    """Outputs of three lightly damped modes (3, 7, 12 Hz at 200 Hz) driven by white noise, with sensor noise."""
    from okid_ros.sim.models import modal_structure
    from okid_ros.sim.simulators import simulate_noisy

    system = modal_structure([3.0, 7.0, 12.0], 0.02, 1, n_outputs, SAMPLE_TIME_S, seed=seed, output="acceleration",
                             disturbance_std=1.0)
    return simulate_noisy(system, np.zeros((n_samples, 1)), seed=seed)


def _frequencies(document: dict) -> list[float]:
    return sorted(mode["frequency_hz"] for mode in document["modes"])


def test_an_empty_u_is_a_record_without_inputs(tmp_path: Path, capsys) -> None:
    """Was "length mismatch: u has 0 samples, y has 6000" for u saved as np.zeros(0)."""
    y = _ambient()
    np.savez(tmp_path / "plain.npz", y=y, sample_time_s=SAMPLE_TIME_S)
    code, _, err = run_cli(capsys, "identify", tmp_path / "plain.npz", "--json", tmp_path / "plain.json")
    assert code == 0, err
    plain = json.loads((tmp_path / "plain.json").read_text())
    for name, u in (("flat", np.zeros(0)), ("no_rows", np.zeros((0, 0))), ("other_rows", np.zeros((5000, 0)))):
        np.savez(tmp_path / f"{name}.npz", y=y, u=u, sample_time_s=SAMPLE_TIME_S)
        code, _, err = run_cli(capsys, "identify", tmp_path / f"{name}.npz", "--json", tmp_path / f"{name}.json")
        assert code == 0, err
        document = json.loads((tmp_path / f"{name}.json").read_text())
        assert document["n_inputs"] == 0 and _frequencies(document) == _frequencies(plain)


def test_inputs_of_another_length_say_what_to_do(tmp_path: Path, capsys) -> None:
    record = tmp_path / "short_u.npz"
    np.savez(record, y=_ambient(600), u=np.ones((500, 1)), sample_time_s=SAMPLE_TIME_S)
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json", "--output-only")
    assert_one_line_error(code, err, "short_u.npz: length mismatch: u has 500 samples, y has 600",
                          "both must hold the same samples", "store no u")


@pytest.mark.parametrize("key, stored", [("y", "channels"), ("sample_time_s", "dict")])
def test_a_member_pickled_as_objects_is_named_with_what_to_store(tmp_path: Path, capsys, key, stored) -> None:
    """Was "not a readable .npz file (ValueError: Object arrays cannot be loaded when allow_pickle=False)"."""
    y = _ambient(600)
    arrays = {"y": y, "sample_time_s": SAMPLE_TIME_S}
    arrays[key] = (np.array([y[:, 0], y[:-1, 1]], dtype=object) if stored == "channels"
                   else np.array({"dt": SAMPLE_TIME_S}, dtype=object))
    record = tmp_path / "objects.npz"
    np.savez(record, **arrays)
    for command, output in (("identify", "--json"), ("track", "--jsonl")):
        code, _, err = run_cli(capsys, command, record, output, tmp_path / "out")
        assert_one_line_error(code, err, "objects.npz: not a readable .npz file",
                              f"({key} is stored as Python objects", f"store {key} as one numeric array")
        assert "allow_pickle" not in err


def test_fewer_samples_than_channels_names_both_readings(tmp_path: Path, capsys) -> None:
    """100 samples of 120 channels: transposed, or as stored far too short; both are said."""
    record = tmp_path / "wide.npz"
    np.savez(record, y=np.tile(_ambient(100), (1, 40)), sample_time_s=SAMPLE_TIME_S)
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json")
    assert_one_line_error(code, err, "y holds 100 samples of 120 channels", "stored transposed?",
                          "read as it is stored, 100 samples are too few to identify 120 channels from")


def _csv(path: Path, header: str, rows: np.ndarray, *, separator: str = ",", decimal: str = ".",
         comment: str = "# sample_time_s=0.005\n") -> Path:
    lines = [separator.join(f"{value:.6f}".replace(".", decimal) for value in row) for row in rows]
    path.write_text(comment + header + "\n" + "\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("separator, header, fragment", [
    (",", "y1,y2,y3", "data row 1 has 6 values, the header 3 (numbers written with decimal commas?"),
    (";", "y1;y2;y3", "(values separated by semicolons, numbers with decimal commas?"),
])
def test_a_csv_with_decimal_commas_is_refused_naming_them(tmp_path: Path, capsys, separator, header,
                                                          fragment) -> None:
    """Was "data row 1 has 6 values, the header 3" with nothing more, or the semicolons alone."""
    record = _csv(tmp_path / "locale.csv", header, _ambient(300), separator=separator, decimal=",")
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json")
    assert_one_line_error(code, err, "locale.csv: ", fragment, "decimal points")


@pytest.mark.parametrize("name", ["t", "time", "Time [s]"])
def test_a_time_column_by_another_name_is_pointed_at(tmp_path: Path, capsys, name) -> None:
    """Was "no '# sample_time_s=...' line and no time_s column" with the column standing beside it."""
    y = _ambient(300)
    rows = np.column_stack([SAMPLE_TIME_S * np.arange(y.shape[0]), y])
    record = _csv(tmp_path / "timed.csv", f"{name},y1,y2,y3", rows, comment="")
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json")
    assert_one_line_error(code, err, "timed.csv: no '# sample_time_s=...' line and no time_s column",
                          f"the column {name!r} is not read as the time: name it time_s")


def test_a_record_shorter_than_a_window_is_refused_without_its_faults(tmp_path: Path, capsys) -> None:
    """`track` of 5 samples warned of two "drifting" outputs before refusing the record as too short."""
    record = tmp_path / "five.npz"
    np.savez(record, y=_ambient()[:5], sample_time_s=SAMPLE_TIME_S)
    code, _, err = run_cli(capsys, "track", record, "--jsonl", tmp_path / "t.jsonl")
    assert_one_line_error(code, err, "five.npz: too few samples for one window: 5 given")


def test_output_only_gaps_are_said_filled_by_the_autoregression_that_fills_them(tmp_path: Path, capsys) -> None:
    """The warning said "filled by the ARX prediction"; output-only, a vector autoregression fills them."""
    y = _ambient()
    y[2000:2005] = np.inf
    record = tmp_path / "gaps.npz"
    np.savez(record, y=y, sample_time_s=SAMPLE_TIME_S)
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json")
    assert code == 0, err
    assert "its 5 missing samples filled by a vector autoregression's prediction (as node 2 fills its window)" in err
    assert "ARX" not in err
    assert "vector autoregression" in json.loads((tmp_path / "m.json").read_text())["source"]


@pytest.mark.parametrize("units, advice", [((1e-200, 1e-200, 1e-200), "multiplied by 1e100"),
                                           ((1e200, 1.0, 1.0), "divided by 1e100"),
                                           ((1e200, 1e-200, 1.0), "the large ones divided and the small ones "
                                                                  "multiplied by 1e100")])
def test_outputs_beyond_float64s_range_are_told_the_way_back(tmp_path: Path, capsys, units, advice) -> None:
    """Spreads of 1e-200 were told "express the outputs in other units, e.g. divided by 1e100": further out."""
    record = tmp_path / "units.npz"
    np.savez(record, y=_ambient(600) * np.array(units), sample_time_s=SAMPLE_TIME_S)
    for command, output in (("identify", "--json"), ("track", "--jsonl")):
        code, _, err = run_cli(capsys, command, record, output, tmp_path / "out")
        assert_one_line_error(code, err, "units.npz: the innovation covariance in the record's units is beyond the "
                              "float64 range", f"express the outputs in other units, e.g. {advice}")


def test_an_irregular_time_column_is_refused_saying_what_to_do(tmp_path: Path, capsys) -> None:
    """Was refused naming the row only: the way on (resample, or cut at the change) was not said."""
    y = _ambient(300)
    times = SAMPLE_TIME_S * np.arange(y.shape[0]) + np.random.default_rng(3).uniform(-1e-3, 1e-3, y.shape[0])
    record = _csv(tmp_path / "jitter.csv", "time_s,y1,y2,y3", np.column_stack([np.sort(times), y]), comment="")
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "m.json")
    assert_one_line_error(code, err, "jitter.csv: time_s is not uniformly increasing (data row",
                          "resample the record onto one, or cut it where the step changes")
