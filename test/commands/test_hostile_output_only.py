"""Hostile records on the output-only paths (`identify` without `u`, node 2's window with n_inputs 0)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.core.identified_model import IdentificationError
from okid_ros.service.realization import identify_window

SAMPLE_TIME_S = 0.005


def _sinusoids(n_samples: int = 12000, seed: int = 4, noise: float = 1e-3) -> np.ndarray:
    """Three outputs of two sinusoids (11 and 23 Hz, over 600 cycles each) and a little white noise: no mode."""
    t = np.arange(n_samples) * SAMPLE_TIME_S
    rng = np.random.default_rng(seed)
    y = np.stack([np.sin(2 * np.pi * 11 * t + k) + 0.5 * np.sin(2 * np.pi * 23 * t + 2 * k) for k in range(3)], 1)
    return y + noise * rng.standard_normal(y.shape)


def test_a_record_of_sinusoids_alone_is_refused_naming_its_lines(tmp_path: Path, capsys) -> None:
    """Was: "no stable mode found across model orders: is the record long and excited enough?" only."""
    record = tmp_path / "sines.npz"
    np.savez(record, y=_sinusoids(), sample_time_s=SAMPLE_TIME_S)
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "model.json")
    assert_one_line_error(code, err, "sines.npz: ", "harmonic lines at 11 Hz, 23 Hz", "broadband")
    assert not (tmp_path / "model.json").exists()


def test_node_2s_output_only_window_of_sinusoids_says_why_it_gives_no_model() -> None:
    y = _sinusoids()
    try:
        identify_window(None, np.zeros((y.shape[0], 0)), y, SAMPLE_TIME_S, options=None)
    except IdentificationError as exc:
        reason = str(exc)
    else:
        raise AssertionError("a window of sinusoids gave a model")
    assert "harmonic lines at 11 Hz, 23 Hz" in reason and "broadband" in reason, reason


def test_a_broadband_record_that_fails_gets_no_harmonic_note(tmp_path: Path, capsys) -> None:
    record = tmp_path / "white.npz"
    np.savez(record, y=np.random.default_rng(2).standard_normal((6000, 3)), sample_time_s=SAMPLE_TIME_S)
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "model.json")
    assert_one_line_error(code, err, "white.npz: ")
    assert "harmonic" not in err


def test_outputs_stored_transposed_are_refused_as_such(tmp_path: Path, capsys) -> None:
    """Was "too few samples for output-only identification: 3 < 200" (identify), "3 samples of 6000 outputs" (track)."""
    record = tmp_path / "transposed.npz"
    np.savez(record, y=_sinusoids(n_samples=600).T, sample_time_s=SAMPLE_TIME_S)
    for command, output in (("identify", "--json"), ("track", "--jsonl")):
        code, _, err = run_cli(capsys, command, record, output, tmp_path / "out")
        assert_one_line_error(code, err, "transposed.npz: y holds 3 samples of 600 channels", "stored transposed?")
    assert not (tmp_path / "out").exists()


def test_node_1s_output_only_window_of_noise_free_sinusoids_names_the_cause() -> None:
    """Was "unexcited window: condition number inf > arx.max_condition_number 1e+12" alone."""
    from okid_bench.live_chain import run_pipeline

    y = _sinusoids(n_samples=4000, noise=0.0)
    pipe, _ = run_pipeline(np.zeros((y.shape[0], 0)), y, SAMPLE_TIME_S,
                           {"arx.order": 10, "arx.window_length": 3000, "publish_rate_hz": 1 / (1000 * SAMPLE_TIME_S)})
    snapshot = pipe.arx.snapshot()
    assert not snapshot.valid and not pipe.updates
    assert "unexcited window" in snapshot.reason and "own past predicts them" in snapshot.reason, snapshot.reason
    assert "broadband" in snapshot.reason


@pytest.mark.parametrize("frequencies_hz, warned", [((85.0, 90.0, 95.0), True), ((3.0, 7.0, 12.0), False)])
def test_modes_near_the_nyquist_frequency_are_warned_of(tmp_path: Path, capsys, frequencies_hz, warned) -> None:
    """Modes at 85, 90 and 95 Hz sampled at 200 Hz: two listed (95 Hz beyond the selection's band), nothing said."""
    from okid_ros.sim.models import modal_structure
    from okid_ros.sim.simulators import simulate_noisy

    system = modal_structure(list(frequencies_hz), 0.02, 1, 3, SAMPLE_TIME_S, seed=1, output="acceleration",
                             disturbance_std=1.0)
    record = tmp_path / "fast.npz"
    np.savez(record, y=simulate_noisy(system, np.zeros((6000, 1)), seed=1), sample_time_s=SAMPLE_TIME_S)
    code, _, err = run_cli(capsys, "identify", record, "--json", tmp_path / "model.json")
    assert code == 0, err
    document = json.loads((tmp_path / "model.json").read_text())
    said = [w for w in document["warnings"] if "of the sampling rate (200 Hz)" in w]
    assert len(said) == int(warned), document["warnings"]
    assert ("okid-ros identify: warning: mode(s) at 85" in err) == warned, err
    if warned:
        assert "may be missed" in said[0] and "aliasing" in said[0]
