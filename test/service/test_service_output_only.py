"""Output-only (n_inputs 0) through both services: Imu-like sources, the sample grid, the window.

A simulated structure with known discrete modes (3, 7 and 12 Hz at 1 % damping, 50 Hz, four
accelerometers, :func:`okid_ros.sim.models.modal_structure`) is driven by forces nobody
measures; its outputs come in as two Imu topics of two axes each (parameters as the nodes read
them), are assembled on the sample grid (u of shape (0,)) and go through
:class:`okid_ros.service.windowed.WindowedPipeline`: node 1's window is a vector autoregression,
node 2 realizes each window output-only, checks it, keeps mode ids, estimates modal states on
every sample and watches the innovations for a change.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from okid_ros.errors import ParameterError
from okid_ros.service.inputs import sources_and_grid
from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams
from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, resolve_parameters
from okid_ros.service.windowed import WindowedPipeline
from okid_ros.sim.models import modal_structure
from okid_ros.sim.simulators import initial_state, propagate_states, simulate_noisy, sqrt_psd

DT = 1.0 / 50.0
FREQS_HZ = (3.0, 7.0, 12.0)
N = 14_000
T0 = 20.0
SOURCES = ["imu /rig/imu_a linear_acceleration.x=y0 linear_acceleration.y=y1",
           "imu /rig/imu_b linear_acceleration.x=y2 linear_acceleration.z=y3"]
VALUES = {"sample_time_s": DT, "n_inputs": 0, "n_outputs": 4, "inputs.sources": SOURCES}


def structure():
    return modal_structure(FREQS_HZ, 0.01, 1, 4, DT, seed=3, output="acceleration", disturbance_std=1.0,
                           measurement_noise_ratio=0.05)


def true_modes(system) -> list[tuple[float, float]]:
    """(frequency_hz, damping_ratio) of the simulated discrete poles."""
    s = np.log(np.linalg.eigvals(system.A)) / DT
    s = s[s.imag > 0]
    return sorted((abs(v) / (2 * np.pi), -v.real / abs(v)) for v in s)


def pipeline(method: str = "ssi-cov", **estimator_values) -> WindowedPipeline:
    arx = resolve_parameters(ARX_NODE, {**VALUES, "arx.order": 10, "arx.window_length": 5000,
                                        "publish_rate_hz": 1.0 / 40.0})
    est = resolve_parameters(ESTIMATOR_NODE, {**VALUES, "realization.output_only_method": method,
                                              **estimator_values})
    return WindowedPipeline(ArxIdentificationParams.from_parameters(arx), ModalEstimationParams.from_parameters(est))


def run(y: np.ndarray, method: str = "ssi-cov", **estimator_values):
    """Each sample as two Imu messages through the grid, then both nodes; (pipeline, samples, results)."""
    _, grid = sources_and_grid({**resolve_parameters(ARX_NODE, VALUES)})
    pipe = pipeline(method, **estimator_values)
    samples, results = [], []
    for k in range(y.shape[0]):
        stamp = T0 + k * DT
        emitted = grid.add(0, stamp, y[k, :2]) + grid.add(1, stamp, y[k, 2:])
        for sample in emitted:
            samples.append(sample)
            results.append(pipe.estimate(sample))
            snapshot = pipe.identify(sample)
            if snapshot is not None and snapshot.valid:
                pipe.realize_now(snapshot.fit, snapshot.stamp_s, snapshot.model_id, snapshot.window_rows)
    return pipe, samples, results


@pytest.fixture(scope="module")
def stationary():
    system = structure()
    y = simulate_noisy(system, np.zeros((N, 1)), seed=1)
    return (system, *run(y))


def test_parameter_table_takes_zero_inputs_and_refuses_negative():
    assert resolve_parameters(ARX_NODE, {"n_inputs": 0})["n_inputs"] == 0
    with pytest.raises(ParameterError, match=r"n_inputs = -1 is out of range; valid range \[0, 64\]"):
        resolve_parameters(ESTIMATOR_NODE, {"n_inputs": -1})
    with pytest.raises(ParameterError, match="realization.output_only_method"):
        resolve_parameters(ESTIMATOR_NODE, {"realization.output_only_method": "fdd"})


def test_outputs_only_sources_make_samples_without_inputs(stationary):
    _, pipe, samples, _ = stationary
    assert len(samples) >= N - 10
    assert all(s.u.shape == (0,) and s.y.shape == (4,) for s in samples)
    assert pipe.arx.snapshot().fit.n_inputs == 0  # node 1's window: a vector autoregression


def test_models_have_no_input_matrices_and_pass_the_checks(stationary):
    _, pipe, _, _ = stationary
    model = pipe.est.current_model
    assert model.n_inputs == 0 and model.B.shape == (model.n_states, 0) and model.D.shape == (4, 0)
    assert model.stability_problem() == ""
    assert model.spectral_radius() < 1 and model.predictor_spectral_radius() < 1
    assert len(pipe.updates) >= 5
    assert all(line["n_inputs"] == 0 for line in pipe.updates)


def _listed(line: dict, f_true: float) -> dict | None:
    """The mode of a model update within 2 % of ``f_true`` (None: not listed)."""
    near = [m for m in line["modes"] if abs(m["frequency_hz"] / f_true - 1) < 0.02]
    return near[0] if near else None


def test_modes_are_found_within_a_few_percent_of_truth(stationary):
    """Each true mode in all windows but at most one, nothing else listed.

    A 100 s window's jackknife has 7 degrees of freedom: a true mode's scatter reads 0.6-0.9 of
    the noise limit here and may cross it in one window (the 7 Hz mode at 140 s on one machine's
    rounding, not on another's).
    """
    system, pipe, _, _ = stationary
    truth = true_modes(system)
    for line in pipe.updates:
        assert all(min(abs(m["frequency_hz"] / f - 1) for f, _ in truth) < 0.02 for m in line["modes"]), line
    for f_true, z_true in truth:
        listed = [mode for line in pipe.updates if (mode := _listed(line, f_true)) is not None]
        assert len(listed) >= len(pipe.updates) - 1, (f_true, len(listed))
        for mode in listed:
            assert abs(mode["damping_ratio"] / z_true - 1) < 0.6, mode  # a 100 s window: damping to tens of %


def test_mode_ids_persist_across_windows(stationary):
    _, pipe, _, _ = stationary
    by_id: dict[int, list[float]] = {}
    for line in pipe.updates:
        for mode in line["modes"]:
            by_id.setdefault(mode["id"], []).append(mode["frequency_hz"])
    # One id per mode, kept in every window that lists it (all but at most one, the test above).
    assert len(by_id) == len(FREQS_HZ), by_id
    for freqs in by_id.values():
        assert len(freqs) >= len(pipe.updates) - 1 and np.ptp(freqs) / np.mean(freqs) < 0.03


def test_modal_states_on_every_sample_after_the_first_model(stationary):
    _, pipe, samples, results = stationary
    first = next(i for i, r in enumerate(results) if r is not None)
    after = results[first:]
    assert all(r is not None for r in after), sum(r is None for r in after)
    assert len(after) > 0.5 * len(samples)
    last = after[-1]
    assert last.coordinates.shape == (len(last.modes), 2) and np.all(np.isfinite(last.coordinates))
    d = pipe.est.diagnostics()
    assert d["diverged_samples"] == 0 and d["rejected_samples"] == 0


def test_the_change_test_watches_the_innovations(stationary):
    _, pipe, _, _ = stationary
    d = pipe.est.diagnostics()
    assert d["change_monitor"] == "monitoring" and d["change_threshold"] > 0
    assert d["changes_detected"] == 0  # a stationary structure


def test_a_stiffness_loss_is_declared_from_the_outputs_alone():
    """All frequencies 6 % lower from sample 9000 on: declared, node 1's window restarts there."""
    before = structure()
    after = dataclasses.replace(before, A=_scaled_frequencies(before.A, 0.94))
    change = 9000
    y = np.vstack([simulate_noisy(before, np.zeros((change, 1)), seed=5),
                   simulate_noisy(after, np.zeros((N - change, 1)), seed=6)])
    pipe, _, _ = run(y)
    assert len(pipe.changes) >= 1
    declared = pipe.changes[0]
    assert abs(declared["change_stamp_s"] - (T0 + change * DT)) < 300 * DT
    assert pipe.arx.diagnostics()["window_restarts"] >= 1


def test_louder_ambient_excitation_is_no_structural_change():
    """The unmeasured forces twice as strong from sample 9000 on, the sensors as before.

    The optimal gain changes with that ratio and the first model's innovations become
    predictable: this was declared a change at 180 s. The noise-change test refits the
    reference's gain and goes on (core/noise_change.py).
    """
    system = structure()
    rng = np.random.default_rng(5)
    noise = rng.standard_normal((N, system.n_states + system.n_outputs)) @ sqrt_psd(system.joint_noise_covariance()).T
    w, v = noise[:, :system.n_states], noise[:, system.n_states:]
    w[9000:] *= 2.0
    x = propagate_states(system.A, w, initial_state(system.A, system.process_noise_covariance, "stationary", rng))
    y = x @ system.C.T + v
    pipe, _, _ = run(y)
    d = pipe.est.diagnostics()
    assert pipe.changes == [] and d["changes_detected"] == 0, pipe.changes
    assert d["change_alarms_noise"] >= 1 and d["change_monitor"] == "monitoring"
    # The test can fail: declared without it (and without the modes' confirmation, which explains it too).
    pipe, _, _ = run(y, **{"change.noise_test": False, "change.mode_confirmation": False})
    assert pipe.changes and pipe.est.diagnostics()["change_alarms_noise"] == 0


def _scaled_frequencies(A: np.ndarray, factor: float) -> np.ndarray:
    """The discrete ``A`` with every pole's continuous frequency and decay scaled by ``factor``."""
    z, V = np.linalg.eig(A)
    return np.real(V @ np.diag(np.exp(factor * np.log(z))) @ np.linalg.inv(V))


def test_the_var_route_gives_an_output_only_model_too():
    system = structure()
    y = simulate_noisy(system, np.zeros((7000, 1)), seed=2)
    # The change test off: it declares a (false) change on this record (the next test).
    pipe, _, results = run(y, method="var", **{"change.enabled": False})
    assert pipe.updates and all(line["n_inputs"] == 0 for line in pipe.updates)
    f_true = [f for f, _ in true_modes(system)]
    found = [m["frequency_hz"] for m in pipe.updates[-1]["modes"]]
    # The route's known weakness (its models' warning): screened as the SSI routes' are, its scattered
    # poles are dropped, true modes among them (3 and 7 Hz here); what it lists is within 2 % of a true mode.
    assert found and all(min(abs(f / t - 1) for t in f_true) < 0.02 for f in found), found
    assert results[-1] is not None


def test_the_var_route_declares_no_change_on_a_stationary_record():
    # The VAR route's first model of this record misses the 3 Hz mode and lists a spurious 10.8 Hz
    # one; with it as the reference the innovations' power wanders over ~250 samples (the 3 Hz
    # mode's decay time) and a change was declared at 132-135 s. The noise-change test explains
    # that excursion by the reference's gain refitted (core/noise_change.py) and re-arms.
    system = structure()
    y = simulate_noisy(system, np.zeros((7000, 1)), seed=2)
    pipe, _, _ = run(y, method="var")
    assert not pipe.changes


def test_node_2_realizes_with_the_canonical_variate_route_when_asked():
    system = structure()
    y = simulate_noisy(system, np.zeros((7000, 1)), seed=2)
    pipe, _, results = run(y, method="ssi-cva", **{"change.enabled": False})
    assert pipe.updates and all(line["n_inputs"] == 0 for line in pipe.updates)
    assert pipe.est.current_model.method == "ssi-cva"
    f_true = [f for f, _ in true_modes(system)]
    found = [m["frequency_hz"] for m in pipe.updates[-1]["modes"]]
    assert len(found) == len(f_true) and all(min(abs(f / t - 1) for f in found) < 0.005 for t in f_true), found
    assert results[-1] is not None
