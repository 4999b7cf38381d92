"""`okid-ros track`: JSON lines per window update, equal to the batch pipeline on each window."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.cli import main as okid_ros_main
from okid_ros.core.arx import fit_arx
from okid_ros.core.pipeline import identify_from_arx
from okid_ros.core.realization_window import realization_window
from okid_ros.records import save_record
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation

DT = 0.008


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    truth = paper_model()
    u = white_input(2600, 2, seed=3)
    y, _ = simulate_innovation(truth, u, seed=4)
    path = tmp_path_factory.mktemp("track") / "paper.npz"
    save_record(path, u, y, DT)
    return path, u, y


def test_track_writes_one_line_per_update_matching_batch(record, tmp_path, capsys):
    path, u, y = record
    out = tmp_path / "track.jsonl"
    q, window, every = 20, 1500, 400
    status = okid_ros_main([
        "track", str(path), "--order", str(q), "--window", str(window), "--every", str(every),
        "--states", "6", "--jsonl", str(out), "--no-progress",
    ])
    assert status == 0
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    first = window + q - 1
    assert [entry["sample_index"] for entry in lines] == list(range(first, 2600, every))
    for entry in lines:
        assert entry["rows"] == window
        assert entry["window_first_index"] == entry["sample_index"] - window - q + 1
        assert entry["n_states"] == 6 and entry["modes"]
        for mode in entry["modes"]:
            assert {"frequency_rad_s", "frequency_hz", "damping_ratio"} <= set(mode)
            assert mode["frequency_hz"] == pytest.approx(mode["frequency_rad_s"] / (2 * np.pi))
    # The last update equals the batch chain on the same samples.
    k = lines[-1]["sample_index"]
    u_w, y_w = u[k - window - q + 1 : k + 1], y[k - window - q + 1 : k + 1]
    batch = identify_from_arx(fit_arx(u_w, y_w, q, "ridge", "gcv"), u_w, y_w, DT, n_states=6)
    got = sorted(mode["frequency_rad_s"] for mode in lines[-1]["modes"])
    want = sorted(mode.frequency_rad_s for mode in batch.modes)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert "updates" in capsys.readouterr().out


def test_track_too_few_samples_is_one_line_error(record, tmp_path, capsys):
    path, _, _ = record
    status = okid_ros_main(["track", str(path), "--order", "20", "--window", "3000",
                            "--jsonl", str(tmp_path / "x.jsonl")])
    assert status == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "at least 3020 needed" in err


def test_every_sample_an_update_is_said_with_its_cost(record, tmp_path, capsys):
    # --every 1 ran a realization per sample (3000 samples: 265 s) in silence; process warns of its equivalent.
    path, _, _ = record
    args = ["track", str(path), "--order", "20", "--window", "2560", "--states", "4", "--no-progress"]
    assert okid_ros_main([*args, "--every", "1", "--jsonl", str(tmp_path / "a.jsonl")]) == 0
    assert "--every 1 identifies a model at every sample: 21 identifications" in capsys.readouterr().err
    assert okid_ros_main([*args, "--every", "2", "--jsonl", str(tmp_path / "b.jsonl")]) == 0
    assert "--every" not in capsys.readouterr().err


@pytest.mark.parametrize("offset, order", [(1e12, "auto"), (5.0, "20")])
def test_a_dead_output_is_the_records_error_in_its_own_units(record, tmp_path, capsys, offset, order):
    # A channel that does not vary: refused as identify refuses it, with its value as recorded
    # (the windows saw it divided by a power of two, and --order auto blamed --order).
    _, u, y = record
    y = y.copy()
    y[:, 1] = offset if order != "auto" else y[:, 1] + offset
    path = tmp_path / "dead.npz"
    save_record(path, u, y, DT)
    status = okid_ros_main(["track", str(path), "--order", order, "--window", "1500",
                            "--jsonl", str(tmp_path / "x.jsonl"), "--no-progress"])
    assert status == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"output channel 1 carries no response (constant {offset:g}" in err, err
    assert ("subtract the offset" in err) == (order == "auto"), err  # a signal on the offset: named
    assert not (tmp_path / "x.jsonl").exists()


@pytest.mark.parametrize("input_factor", [1.0, 1e-25])
def test_a_channel_dead_in_some_windows_is_named_in_its_own_units(record, tmp_path, capsys, input_factor):
    # Stuck at 5.0 from the middle on: the record passes, the windows after it fail, and their
    # lines said "constant 0.15625" (the value divided by the power of two the windows saw); the
    # outputs keep their units when only the inputs need dividing (1e-25). The windows are node 1's to refuse
    # (its solve names the dead output, as it refuses such a window live).
    _, u, y = record
    u, y = u * input_factor, y.copy()
    y[900:, 1] = 5.0
    path = tmp_path / "stuck.npz"
    save_record(path, u, y, DT)
    lines = _track(path, tmp_path / "x.jsonl", "--order", "20", "--window", "1000", "--no-change-detection")
    errors = [line["error"] for line in lines if line.get("error")]
    assert errors, lines
    assert all(error.startswith("unexcited window: condition number inf > arx.max_condition_number")
               and "output channel 1 carries no response (constant 5, " in error for error in errors), errors


@pytest.mark.parametrize("level", [1e-3, 1.0])
def test_a_constant_input_is_tracked_as_an_input_of_zeros(record, tmp_path, level):
    # Before: every window "identified" with an ARX penalty near 1e263 (GCV on the rounding residue
    # of the constant column once centred, blown up by the column scaling) and no modes, silently.
    _, u, y = record
    lines = {}
    for name, value in (("zeros", 0.0), ("constant", level)):
        stuck = u.copy()
        stuck[:, 1] = value
        save_record(tmp_path / f"{name}.npz", stuck, y, DT)
        lines[name] = _track(tmp_path / f"{name}.npz", tmp_path / f"{name}.jsonl", "--order", "20", "--window",
                             "1000", "--no-change-detection")
    assert all(line["modes"] and line["arx_penalty"] < 1e3 for line in lines["constant"]), lines["constant"][0]
    assert [line["modes"] for line in lines["constant"]] == [line["modes"] for line in lines["zeros"]]
    assert all(any(f"no excitation on input 1 (constant {level:g})" in w for w in line["warnings"])
               for line in lines["constant"])


@pytest.mark.parametrize("order, window", [(20, 1), (500, 800)])
def test_a_window_too_short_for_any_realization_is_refused_up_front(record, tmp_path, capsys, order, window):
    # Before: every update failed on a gap the record does not have, numpy warnings on stderr, status 0.
    path = record[0]
    code = okid_ros_main(["track", str(path), "--jsonl", str(tmp_path / "x.jsonl"), "--order", str(order),
                          "--window", str(window), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert f"--window {window} rows with {order} lags" in err and f"a window of at least {3 * order} rows" in err
    assert not (tmp_path / "x.jsonl").exists()


def test_outputs_near_the_float64_limits_are_still_divided_and_tracked(record, tmp_path):
    # Their powers of two average out (1e152 and 1e-140: about 2^22), but the channels do not:
    # undivided, the 1e152 channel is beyond the window's 1e150 limit and every sample missing.
    _, u, y = record
    path = tmp_path / "extreme.npz"
    save_record(path, u, y * np.array([1e152, 1e-140]), DT)
    lines = _track(path, tmp_path / "x.jsonl", "--order", "20", "--window", "1000", "--no-change-detection")
    assert lines and all(not line.get("error") and line["modes"] for line in lines), lines


def _track(path, out, *args) -> list[dict]:
    status = okid_ros_main(["track", str(path), "--jsonl", str(out), "--no-progress", *args])
    assert status == 0
    return [json.loads(line) for line in out.read_text().splitlines()]


def test_samples_with_nan_are_missing_samples_and_the_update_equals_the_batch_chain(record, tmp_path, capsys):
    # A dropout of 40 samples (longer than the nodes' bridge of 10), then a dropped reading of 3.
    _, u, y = record
    u, y = u.copy(), y.copy()
    u[1540:1580] = np.inf
    y[1700:1703, 0] = np.nan
    path = tmp_path / "gaps.npz"
    save_record(path, u, y, DT)
    q, window = 20, 1500
    lines = _track(path, tmp_path / "gaps.jsonl", "--order", str(q), "--window", str(window), "--every", "100",
                   "--states", "6")
    captured = capsys.readouterr()
    assert "43 of the 2600 samples hold NaN/Inf (the first at sample 1540)" in captured.err
    assert "(43 missing: NaN/Inf or beyond 1e150)" in captured.out
    assert not any(line["change_detected"] for line in lines)  # a gap is not a structural change
    at = {line["sample_index"]: line for line in lines}
    assert at[1519]["window_first_index"] == 0 and len(at[1519]["modes"]) == 3
    # After the dropout the realization starts after it (node 2's rule): too few samples at first.
    assert "follow its last gap longer than 10 samples" in at[1619]["error"]
    # The window's rows leave out those that reach a missing sample (each gap and q after it).
    k = 2519
    first = at[k]["window_first_index"]
    assert first == k - window - (40 + q) - (3 + q) - q + 1 and len(at[k]["modes"]) == 3
    # The update is the batch chain on the same samples: the ARX fit without the rows that reach
    # a missing sample, the realization on the samples after the dropout, the 3 missing filled.
    u_w, y_w = u[first : k + 1], y[first : k + 1]
    finite = np.isfinite(u_w).all(axis=1) & np.isfinite(y_w).all(axis=1)
    fit = fit_arx(np.where(finite[:, None], u_w, 0), np.where(finite[:, None], y_w, 0), q, "ridge", "gcv",
                  valid=finite, center=True)
    skipped = np.diff(np.flatnonzero(finite), prepend=-1) - 1  # missing samples before each
    samples = realization_window(u_w[finite], y_w[finite], skipped, fit, max_gap=10, need=window + q)
    assert samples.filled == 3 and samples.u.shape[0] == k + 1 - 1580
    batch = identify_from_arx(fit, samples.u, samples.y, DT, n_states=6, valid=samples.valid)
    got = sorted(mode["frequency_rad_s"] for mode in at[k]["modes"])
    np.testing.assert_allclose(got, sorted(mode.frequency_rad_s for mode in batch.modes), rtol=1e-6)


def test_order_auto_is_chosen_on_samples_without_nan(record, tmp_path, capsys):
    _, u, y = record
    y = y.copy()
    y[::200, 1] = np.nan  # no run of window + 200 samples without NaN
    path = tmp_path / "holes.npz"
    save_record(path, u, y, DT)
    status = okid_ros_main(["track", str(path), "--window", "1000", "--jsonl", str(tmp_path / "o.jsonl"),
                            "--no-progress"])
    assert status == 2
    assert "--order auto chooses the ARX order on 1200 samples without NaN/Inf" in capsys.readouterr().err


def test_updates_that_all_wait_for_rows_fail_the_run_in_one_line(record, tmp_path, capsys):
    # The first 2300 samples without outputs: no window ever holds the rows a model needs. The run
    # fails, saying why the first update waited (was: "3 updates (0 failed)" and nothing on stderr but
    # the NaN count; then exit 0 with a warning and lines without a model).
    _, u, y = record
    y = y.copy()
    y[:2300] = np.nan
    path = tmp_path / "late.npz"
    save_record(path, u, y, DT)
    code, _, err = run_cli(capsys, "track", path, "--jsonl", tmp_path / "late.jsonl", "--no-progress", "--order",
                           "20", "--window", "1500", "--every", "400")
    warning, error = err.strip().split("\n")  # the NaN count, then why the run failed
    assert "2300 of the 2600 samples hold NaN/Inf" in warning
    assert_one_line_error(code, error, "none of the 3 updates gave a model (0 failed, 3 waiting for rows); the first: "
                          "the window holds 0 of the 750 rows needed")  # node 1's arx.min_window_fill 0.5
    # The reason names what was rejected, and nothing that was not (no "0 samples rejected for values beyond").
    assert "for NaN/Inf" in error and "1e150" not in error, error
    assert sorted(p.name for p in tmp_path.iterdir()) == ["late.npz"]


def test_a_run_where_no_update_gives_a_model_fails_and_writes_nothing(record, tmp_path, capsys):
    # --states 100, beyond every window's rank: each update failed, and track exited 0 with a warning and
    # lines of errors only. A run without a model is a failure; an old OUT stays as it was.
    path, _, _ = record
    out = tmp_path / "t.jsonl"
    out.write_text("old lines\n")
    code, stdout, err = run_cli(capsys, "track", path, "--jsonl", out, "--window", "1000", "--every", "1000",
                                "--order", "20", "--states", "100", "--no-progress", "--force")
    assert_one_line_error(code, err, "none of the 2 updates gave a model (2 failed, 0 waiting for rows); the first: "
                          "100 states are not supported")
    assert stdout == "" and out.read_text() == "old lines\n" and list(tmp_path.iterdir()) == [out]


def test_updates_after_the_data_stop_say_so_instead_of_repeating_the_last_window(record, tmp_path, capsys):
    # NaN from the middle to the end: every later update realized the window that ended where the
    # data stopped again, and its line read as a new model (rows full, no warning, no waiting).
    _, u, y = record
    y = y.copy()
    y[2000:] = np.nan
    path = tmp_path / "stops.npz"
    save_record(path, u, y, DT)
    out = tmp_path / "stops.jsonl"
    assert okid_ros_main(["track", str(path), "--order", "20", "--window", "1000", "--every", "250",
                          "--jsonl", str(out), "--no-progress"]) == 0
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    realized = [line for line in lines if line["modes"]]
    assert realized and max(line["sample_index"] for line in realized) < 2250
    after = [line for line in lines if line["sample_index"] >= 2250]
    assert after and all(not line["modes"] and line["waiting"].startswith("no sample since sample 1999")
                         for line in after), after[:2]
    assert f"{len(after)} waiting for rows" in capsys.readouterr().out


def test_the_help_says_the_exit_statuses(capsys):
    # `track` exits 2 when no update gives a model; neither its help nor the docs said its statuses.
    with pytest.raises(SystemExit):
        okid_ros_main(["track", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "Exit status: 0 when an update gave a model, 2 for a usage or data error, none of the updates giving a " \
           "model among them (OUT.jsonl left as it was), 130 when interrupted" in text, text
