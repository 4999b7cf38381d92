"""`okid-ros track` names a record's sensor faults once, on stderr, and tracks the record as recorded.

The faults are those `identify` names (:mod:`okid_ros.core.sensor_faults`); track used to name
none of them: a drifting, clipped or hum-laden record was tracked with nothing said.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from okid_ros.cli import main as okid_ros_main
from okid_ros.core.arx import fit_arx
from okid_ros.core.pipeline import identify_from_arx
from okid_ros.records import save_record
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation

DT = 0.008
N = 2600
Q, WINDOW, EVERY = 20, 1500, 400
#: The words of every fault's warning (none of them on a clean record).
FAULT_WORDS = ("drifts", "is clipped", "harmonic disturbance", "dropped out", "hold every output", "changes level")


@pytest.fixture(scope="module")
def record():
    u = white_input(N, 2, seed=3)
    y, _ = simulate_innovation(paper_model(), u, seed=4)
    return u, y


def _track(tmp_path, u, y, *args) -> tuple[list[dict], str]:
    path, out = tmp_path / "record.npz", tmp_path / "track.jsonl"
    save_record(path, u, y, DT)
    status = okid_ros_main(["track", str(path), "--order", str(Q), "--window", str(WINDOW), "--every", str(EVERY),
                            "--states", "6", "--jsonl", str(out), "--no-progress", *args])
    assert status == 0
    return [json.loads(line) for line in out.read_text().splitlines()]


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("okid-ros track: warning: ")]


def test_a_clean_record_names_no_fault_and_tracks_as_before(record, tmp_path, capsys):
    # The lines of the code before the faults were named (sample_index, n_states, modes).
    u, y = record
    lines = _track(tmp_path, u, y)
    assert _warnings(capsys.readouterr().err) == []
    assert [(line["sample_index"], line["window_first_index"], line["n_states"]) for line in lines] == [
        (1519, 0, 6), (1919, 400, 6), (2319, 800, 6)]
    np.testing.assert_allclose([[m["frequency_hz"] for m in line["modes"]] for line in lines], [
        [5.901406, 7.325245, 48.459222], [5.912839, 7.319907, 48.46589], [5.912513, 7.314771, 48.459754]], rtol=1e-6)
    np.testing.assert_allclose([[m["damping_ratio"] for m in line["modes"]] for line in lines], [
        [0.001046, 0.026077, 0.00411], [0.000914, 0.025756, 0.004065], [0.00089, 0.031244, 0.003972]], atol=1e-6)
    assert all("fault" not in line and line["warnings"] == [] for line in lines)  # the JSONL contract unchanged


def test_a_drifting_record_is_named_and_tracked_as_recorded(record, tmp_path, capsys):
    # A ramp over the record holding 8 and 19 % of the outputs' variance: named once, before the
    # tracking, and not removed from the windows (the last update is the batch chain on the raw window).
    u, y = record
    drifted = y + np.linspace(0.0, y.std(axis=0).max(), N)[:, None]
    lines = _track(tmp_path, u, drifted)
    warnings = _warnings(capsys.readouterr().err)
    assert [w.split(" drifts")[0] for w in warnings] == ["okid-ros track: warning: output 0",
                                                         "okid-ros track: warning: output 1"]
    assert all("NOT removed: track fits its windows as recorded" in w and "`okid-ros identify` removes it" in w
               for w in warnings), warnings
    k = lines[-1]["sample_index"]
    u_w, y_w = u[k - WINDOW - Q + 1 : k + 1], drifted[k - WINDOW - Q + 1 : k + 1]
    batch = identify_from_arx(fit_arx(u_w, y_w, Q, "ridge", "gcv", center=True), u_w, y_w, DT, n_states=6)
    np.testing.assert_allclose(sorted(m["frequency_rad_s"] for m in lines[-1]["modes"]),
                               sorted(m.frequency_rad_s for m in batch.modes), rtol=1e-6)


def test_a_level_shift_is_named_and_taken_off_where_node_2s_watch_finds_it(record, tmp_path, capsys):
    # Output 1 re-zeroed at sample 1700 by 3 of its spreads: named once, with its sample and time. The
    # windows are fitted as recorded until node 2's watch (service/record_watch.py) finds the step: its
    # watchdog's state-jump fit (the change test still calibrating) gives it, and it is taken off from
    # there, as node 2 does; the last update then lists the clean record's modes (as recorded: one lost).
    u, y = record
    shifted = y.copy()
    shifted[1700:, 1] += 3.0 * y[:, 1].std()
    lines = _track(tmp_path, u, shifted)
    warnings = _warnings(capsys.readouterr().err)
    assert len(warnings) == 1 and warnings[0].startswith(
        "okid-ros track: warning: output 1 changes level at sample 1700 (13.6 s) by +3.0 standard deviations"), warnings
    assert "NOT removed: track fits its windows as recorded" in warnings[0]
    assert [line["watch"]["output_level_steps"] for line in lines] == [0, 1, 1]
    k = lines[-1]["sample_index"]
    u_w, y_w = u[k - WINDOW - Q + 1 : k + 1], y[k - WINDOW - Q + 1 : k + 1]
    clean = identify_from_arx(fit_arx(u_w, y_w, Q, "ridge", "gcv", center=True), u_w, y_w, DT, n_states=6)
    np.testing.assert_allclose(sorted(m["frequency_rad_s"] for m in lines[-1]["modes"]),
                               sorted(m.frequency_rad_s for m in clean.modes), rtol=1e-3)


@pytest.mark.parametrize("units", [1e150, 1e-150])
def test_a_record_in_far_units_has_its_faults_said_in_them(record, tmp_path, capsys, units):
    # The windows see the record divided by a power of two (core/channels.py); the faults are the
    # record's, as identify says them (8644b37: the shift of 1.7e152 below was said to be of +1.612).
    u, y = record
    shifted = y.copy()
    shifted[1700:, 1] += 3.0 * y[:, 1].std()
    _track(tmp_path, u, shifted * units)
    warnings = _warnings(capsys.readouterr().err)
    size = float(warnings[0].split("standard deviations (")[1].split(")")[0])
    assert len(warnings) == 1 and "output 1 changes level at sample 1700" in warnings[0], warnings
    np.testing.assert_allclose(size, 3.0 * y[:, 1].std() * units, rtol=0.05)


def test_a_clipped_record_is_named(record, tmp_path, capsys):
    u, y = record
    level = 0.8 * np.abs(y[:, 0]).max()
    clipped = y.copy()
    clipped[:, 0] = np.clip(y[:, 0], -level, level)
    _track(tmp_path, u, clipped)
    warnings = _warnings(capsys.readouterr().err)
    at_top = np.count_nonzero(clipped[:, 0] == level)
    assert len(warnings) == 1 and warnings[0].startswith(
        f"okid-ros track: warning: output 0 is clipped (a sensor's or recorder's range exceeded?): "
        f"{100 * at_top / N:.1f} % of its samples sit at its largest value"), warnings
    assert warnings[0].endswith("; the windows' models may list spurious modes from it")


@pytest.mark.parametrize("output_only", [False, True])
def test_hum_in_the_outputs_is_named_and_kept_in_the_windows(record, tmp_path, capsys, output_only):
    # A 20 Hz line at half the outputs' spread, which the inputs lack (or which no input is measured for).
    u, y = record
    hum = y + 0.5 * y.std(axis=0) * np.sqrt(2.0) * np.sin(2 * np.pi * 20.0 * np.arange(N) * DT + 0.3)[:, None]
    _track(tmp_path, u, hum, *(["--output-only"] if output_only else []))
    where = "(not a mode)" if output_only else "(not a mode; the inputs hold no such line)"
    # _track's --states 6 is passed over by the output-only windows, and said so (as identify does).
    ignored = ["okid-ros track: warning: --states applies to input-output identification; ignored for this "
               "output-only one"] if output_only else []
    assert _warnings(capsys.readouterr().err) == ignored + [
        f"okid-ros track: warning: harmonic disturbance in the outputs {where}: 20 Hz; kept: track fits its windows "
        "as recorded, as node 1 sees them live (`okid-ros identify` removes it); the windows' models may list it "
        "as a mode"]


def test_missing_samples_leave_the_faults_named_on_the_others(record, tmp_path, capsys):
    # NaN from sample 2000 on (the data stop) with output 1 dropped out before: the gap is no held
    # value (no frozen record), the dropout is named, and the drift is fitted to the samples present.
    u, y = record
    faulty = y + np.linspace(0.0, y.std(axis=0).max(), N)[:, None]
    faulty[1000:1600, 1] = 0.0
    faulty[2000:] = np.nan
    _track(tmp_path, u, faulty, "--every", "250")
    warnings = _warnings(capsys.readouterr().err)
    assert warnings[0].startswith("okid-ros track: warning: 600 of the 2600 samples hold NaN/Inf")
    assert warnings[1].startswith("okid-ros track: warning: output 1 holds the value 0 over samples 1000-1599")
    assert not any("hold every output" in w for w in warnings), warnings
    assert any("output 0 drifts" in w for w in warnings), warnings


@pytest.mark.parametrize("glitch", [1919, 2319])
def test_a_glitch_of_1e200_at_an_updates_sample_is_a_missing_sample(record, tmp_path, capsys, glitch):
    # The change test was fed a block of samples per update (1520-1919, 1920-2319). A glitch of 1e200
    # in one output at a block's last sample, or at the record's last (2319), was tested as it came:
    # numpy's overflow in the model-error check's squares, and no glitch counted. Now node 2's watch
    # steps sample by sample (service/record_watch.py): the next sample judges it, or, at the record's
    # end, it is counted, and the far sample's squares beyond the floats in the gates are not warned of.
    # Since track keeps the record's units (core/channels.record_units: one far sample no longer divides the whole
    # record), the sample lies beyond the windows' 1e150 and is missing, as node 2 refuses it: bridged by the watch.
    u, y = record
    u, y = u[:2320], y[:2320].copy()
    y[glitch, 0] = 1e200
    lines = _track(tmp_path, u, y)
    captured = capsys.readouterr()
    assert not any(line["change_detected"] for line in lines)
    # (The realization of the window that ends at the glitch warns: its own matter.)
    assert not any(name in captured.err for name in ("model_error_check", "change_detection", "change_monitor",
                                                     "estimator.py")), captured.err
    assert "(1 missing: NaN/Inf or beyond 1e150)" in captured.out, captured.out
    assert ("gaps_bridged 1" in captured.out) == (glitch < 2319), captured.out  # the record's last: nothing after it


def test_a_re_zero_the_change_test_finds_is_taken_off_as_node_2_does(tmp_path, capsys):
    # Output 0 re-zeroed by 10 of its spreads at sample 4123: the change test's state-jump fit reads the
    # step, and the record is taken off it from there (node 2's rule, service/watch.py); before, the
    # windows holding it listed spurious modes and lost true ones for a window's length.
    u = white_input(7000, 2, seed=3)
    y, _ = simulate_innovation(paper_model(), u, seed=4)
    stepped = y.copy()
    stepped[4123:, 0] += 10.0 * y[:, 0].std()
    true_hz = np.array([5.894, 7.295, 48.477])

    def scored(lines: list[dict]) -> tuple[int, int, int]:
        hz = [np.array([m["frequency_hz"] for m in line["modes"]]) for line in lines]
        found = sum(int(np.any(np.abs(f - t) < 0.005 * t)) for f in hz for t in true_hz)
        spurious = sum(int(not np.any(np.abs(h - true_hz) < 0.005 * true_hz)) for f in hz for h in f)
        return found, spurious, sum(bool(line["change_detected"]) for line in lines)

    clean = scored(_track(tmp_path, u, y, "--states", "auto", "--force"))
    found, spurious, changes = scored(_track(tmp_path, u, stepped, "--states", "auto", "--force"))
    assert "changes level at sample 4123" in capsys.readouterr().err
    assert changes == 0 and found >= clean[0] - 1 and spurious <= clean[1] + 1, (clean, found, spurious)


def test_input_glitches_of_1e149_are_taken_as_node_1_takes_them(record, tmp_path, capsys):
    # An input of 1e149 every half second (no force: a bit error in its exponent): track named input 0
    # "clipped" and its windows held the spikes as they came: the first update found one of the clean record's
    # three modes, the next the 5.9 Hz mode's damping twice the clean record's. Node 1's rule now replaces each
    # by its neighbours' mean (core/input_glitches.py) and says so.
    u, y = record
    clean = _track(tmp_path, u, y)
    capsys.readouterr()
    spiked = u.copy()
    spiked[400::62, 0] = 1e149
    lines = _track(tmp_path, spiked, y, "--force")
    said = _warnings(capsys.readouterr().err)
    assert len(said) == 1 and said[0].startswith("okid-ros track: warning: 36 input sample(s) lie alone beyond 1e+09")
    assert [len(line["modes"]) for line in lines] == [len(line["modes"]) for line in clean]
    for key, tolerance in (("frequency_hz", 0.002), ("damping_ratio", 0.3)):
        values = [[m[key] for m in line["modes"]] for line in (*clean, *lines)]
        np.testing.assert_allclose(values[len(clean):], values[:len(clean)], rtol=tolerance)


def test_identify_takes_input_glitches_of_1e149_as_track_does(record, tmp_path, capsys):
    # identify named the same spikes "clipped", took their mean off input 0 as an offset of about 1e147, and its
    # free-run fit fell by half; now it replaces them as track and node 1 do, said in one warning.
    u, y = record

    def identify(inputs, name):
        path, out = tmp_path / f"{name}.npz", tmp_path / f"{name}.json"
        save_record(path, inputs, y, DT)
        assert okid_ros_main(["identify", str(path), "--order", str(Q), "--states", "6", "--json", str(out)]) == 0
        err = capsys.readouterr().err.splitlines()
        return json.loads(out.read_text()), [line for line in err if line.startswith("okid-ros identify: warning: ")]

    clean, clean_said = identify(u, "clean")
    spiked = u.copy()
    spiked[400::62, 0] = 1e149
    model, said = identify(spiked, "spiked")
    assert clean_said == [] and len(said) == 1, said
    assert said[0].startswith("okid-ros identify: warning: 36 input sample(s) lie alone beyond 1e+09")
    assert model["fit_simulation_pct"] == pytest.approx(clean["fit_simulation_pct"], abs=3.0)
    found = sorted(m["frequency_hz"] for m in model["modes"])
    np.testing.assert_allclose(found, sorted(m["frequency_hz"] for m in clean["modes"]), rtol=0.01)
