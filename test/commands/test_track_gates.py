"""`okid-ros track` screens the samples of its window as node 1's service does (service/window_gates.py).

Each test feeds one small record to `track` and to node 1's service
(:class:`~okid_ros.service.identification.ArxIdentificationService`, driven without DDS as the
service tests drive it, a snapshot at each of track's updates) and compares what each window held:
the ARX fit's penalty and condition number at every update, and the glitches counted.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from okid_ros.cli import main as okid_ros_main
from okid_ros.records import save_record
from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
from okid_ros.service.params import ARX_NODE, resolve_parameters
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

DT = 0.008
N = 3600
Q, WINDOW, EVERY = 20, 1500, 400


@pytest.fixture(scope="module")
def record():
    u = lowpass_input(N, 2, 15.0, DT, seed=5)
    y, _ = simulate_innovation(paper_model(), u, seed=6)
    return u, y


def _track(tmp_path, u, y) -> tuple[list[dict], str]:
    path, out = tmp_path / "record.npz", tmp_path / "track.jsonl"
    save_record(path, u, y, DT)
    status = okid_ros_main(["track", str(path), "--order", str(Q), "--window", str(WINDOW), "--every", str(EVERY),
                            "--states", "6", "--no-change-detection", "--jsonl", str(out), "--no-progress"])
    assert status == 0
    return [json.loads(line) for line in out.read_text().splitlines()], out


def _node_1(u, y, updates: list[int]) -> tuple[list, dict]:
    """Node 1's service fed the record, a snapshot at each update's sample: the snapshots, its diagnostics."""
    values = {"sample_time_s": DT, "arx.order": Q, "arx.window_length": WINDOW}
    service = ArxIdentificationService(ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, values)))
    snapshots, fed = [], 0
    for k in updates:
        service.push_block(DT * np.arange(fed, k + 1), u[fed : k + 1], y[fed : k + 1])
        snapshots.append(service.snapshot())
        fed = k + 1
    return snapshots, service.diagnostics()


def _same_windows(lines: list[dict], snapshots: list, rtol: float = 1e-9) -> None:
    assert len(lines) == len(snapshots) >= 4
    for line, snapshot in zip(lines, snapshots):
        assert snapshot.valid, snapshot.reason
        np.testing.assert_allclose(line["arx_penalty"], snapshot.fit.penalty, rtol=rtol)
        np.testing.assert_allclose(line["condition_number"], snapshot.condition_number, rtol=rtol)


def test_output_glitches_go_into_tracks_window_as_node_1s_prediction(record, tmp_path, capsys):
    # Five samples of output 0 two of its spreads off after the first update (far beyond the ARX fit's residual,
    # within the realization's spike rule, which would refit node 2's window without them): node 1 puts each in
    # as its last fit's prediction (core/arx_glitches.py); track's window held them as they came (its fits were
    # not node 1's from the third update on).
    u, y = record
    glitched = y.copy()
    glitched[[2100, 2450, 2790, 3120, 3377], 0] += 2.0 * y[:, 0].std()
    lines, _ = _track(tmp_path, u, glitched)
    snapshots, diagnostics = _node_1(u, glitched, [line["sample_index"] for line in lines])
    _same_windows(lines, snapshots)
    assert diagnostics["glitches"] == 5
    assert "node 1's glitch gates: glitches 5" in capsys.readouterr().out


def test_an_output_beyond_1e150_is_refused_by_track_as_by_node_1(record, tmp_path, capsys):
    # One output sample of 1e200 in a record of unit spread (a bit error in its exponent): node 1 refuses it for
    # its size (a gap in its window); track divided the whole record by 2^332 for it (core/channels.py, the
    # peaks' scale) and its windows took it in, its ordinary samples near 1e-100. Now track's units come from the
    # channels' typical sizes (channels.record_units): the record keeps its units and the sample is refused.
    u, y = record
    far = y.copy()
    far[2000, 1] = 1e200
    lines, _ = _track(tmp_path, u, far)
    snapshots, diagnostics = _node_1(u, far, [line["sample_index"] for line in lines])
    _same_windows(lines, snapshots)
    assert diagnostics["rejected_magnitude"] == 1
    assert "(1 missing: NaN/Inf or beyond 1e150)" in capsys.readouterr().out


def test_input_glitches_are_judged_on_the_samples_node_1_accepts(record, tmp_path, capsys):
    # Two inputs 1e12 times input 0's spread, each alone (a bit error): the first, among ordinary samples, goes
    # into node 1's window as its neighbours' mean; the second is followed by a sample whose outputs are NaN,
    # which node 1 refuses: its gate is flushed at the gap and the glitch goes on as it came, uncounted
    # (core/input_glitches.py). track screened its record with every sample of finite inputs (2 replaced).
    u, y = record
    spiked, dropped = u.copy(), y.copy()
    spiked[[2500, 3540], 0] = 1e12 * u[:, 0].std()
    dropped[3541] = np.nan
    lines, _ = _track(tmp_path, spiked, dropped)
    snapshots, diagnostics = _node_1(spiked, dropped, [line["sample_index"] for line in lines])
    _same_windows(lines, snapshots)
    assert diagnostics["input_glitches"] == 1
    said = [line for line in capsys.readouterr().err.splitlines() if "input sample(s) lie alone" in line]
    assert len(said) == 1 and said[0].startswith("okid-ros track: warning: 1 input sample(s) lie alone"), said


def test_a_window_filled_less_than_node_1_asks_gives_no_model(record, tmp_path):
    # The outputs missing over samples 100-1099: at the first update (1519) the window holds 480 of its 1500 rows,
    # a fill of 0.32, below node 1's arx.min_window_fill (0.5; restart_min_fill 0.25 only after a change), so node
    # 1's snapshot is refused; track modelled every window of 0.25 on (now node 1's rule, rows_needed).
    u, y = record
    dropped = y.copy()
    dropped[100:1100] = np.nan
    lines, _ = _track(tmp_path, u, dropped)
    snapshots, _ = _node_1(u, dropped, [line["sample_index"] for line in lines])
    assert not snapshots[0].valid and "below arx.min_window_fill 0.50" in snapshots[0].reason, snapshots[0].reason
    assert lines[0]["modes"] == [] and lines[0]["waiting"] == "the window holds 480 of the 750 rows needed: " \
        "1000 samples rejected for NaN/Inf", lines[0]
    # (A window's sums after a gap are added in another order by node 1's per-sample push: penalties within 1e-5.)
    _same_windows(lines[1:], snapshots[1:], rtol=1e-4)


def test_a_window_node_1_refuses_gives_track_no_model_and_node_1s_reason(record, tmp_path, capsys):
    # Input 1 half of input 0 from sample 1000 on (one command sent to both actuators): the windows from the update
    # at 2719 on hold the two inputs dependent, condition number inf, which node 1's solve refuses (naming the
    # inputs, its fit kept from before). track fitted its own ARX model there and wrote its modes.
    u, _ = record
    dependent = u.copy()
    dependent[1000:, 1] = 0.5 * dependent[1000:, 0]
    y, _ = simulate_innovation(paper_model(), dependent, seed=6)
    lines, _ = _track(tmp_path, dependent, y)
    snapshots, diagnostics = _node_1(dependent, y, [line["sample_index"] for line in lines])
    refused = [snapshot.reason for snapshot in snapshots if not snapshot.valid]
    assert len(refused) == 3 and all("inputs 0, 1 are linearly dependent" in reason for reason in refused), refused
    for line, snapshot in zip(lines, snapshots):
        if snapshot.valid:
            assert line["modes"] and line["arx_penalty"] == pytest.approx(snapshot.fit.penalty, rel=1e-9), line
        else:
            assert line["modes"] == [] and line["error"] == snapshot.reason, line
    out = capsys.readouterr().out
    assert "6 updates (3 failed, 0 waiting for rows)" in out
    assert "node 1's solve: snapshots 6, valid_snapshots 3, silent_input_snapshots 0" in out
    # Counted as node 1 counts them, under its names: each line node 1's counts up to its update, the summary the last.
    counted = ("snapshots", "valid_snapshots", "silent_input_snapshots")
    assert [line["arx_identifier"]["valid_snapshots"] for line in lines] == [1, 2, 3, 3, 3, 3]
    assert {name: lines[-1]["arx_identifier"][name] for name in counted} == {n: diagnostics[n] for n in counted}
    assert (diagnostics["snapshots"], diagnostics["valid_snapshots"]) == (6, 3)
