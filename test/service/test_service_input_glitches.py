"""Input glitches (one input sample absurdly far off) kept out of node 1's window; real blows kept."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from okid_bench.live_chain import chain_modes, run_pipeline
from okid_ros.core.arx import fit_from_normal_equations
from okid_ros.core.input_glitches import INPUT_GLITCH_SPREADS, without_input_glitches
from okid_ros.core.recursive import SlidingWindowArx
from okid_ros.service.estimation import ModalEstimationService
from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
from okid_ros.service.options import ModalEstimationParams
from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, resolve_parameters
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

# The live fault rig's node 1 (test/fault_rig.py): models within seconds, a solve twice a second.
LIVE = {"arx.order": 20, "arx.window_length": 800, "arx.min_window_fill": 0.25, "publish_rate_hz": 2.0}
SPIKES_FROM, SPIKE_EVERY = 1500, 62  # half a second at 125 Hz


@pytest.fixture(scope="module")
def record():
    model = paper_model()
    u = lowpass_input(5000, 2, 50.0, model.sample_time_s, seed=1)
    y, _ = simulate_innovation(model, u, seed=2)
    return model.sample_time_s, u, y


def _models(dt: float, u: np.ndarray, y: np.ndarray, **overrides) -> tuple[list, ArxIdentificationService]:
    """Node 1 fed the record, a snapshot whenever one is due: [(sample, snapshot)], the service."""
    params = ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, {"sample_time_s": dt, **LIVE,
                                                                                   **overrides}))
    service, models = ArxIdentificationService(params), []
    for k in range(u.shape[0]):
        assert service.push(k * dt, u[k], y[k])
        if service.due(k * dt):
            models.append((k, service.snapshot()))
    return models, service


@pytest.mark.parametrize("inputs", [[0], [0, 1]])
def test_input_spikes_of_1e149_every_half_second_leave_node_1s_models_coming(record, inputs):
    # The live fuzz's spikes (under the window's bound of 1e150): in one input every model after them
    # was 0.7 of its size off the clean record's (the spikes' squares decide that input's
    # coefficients), in both no model was valid (`unexcited window: condition number inf`) for 47 s.
    dt, u, y = record
    spiked = u.copy()
    spiked[SPIKES_FROM::SPIKE_EVERY, inputs] = 1e149
    clean, _ = _models(dt, u, y)
    models, service = _models(dt, spiked, y)
    after = [(c.fit.theta, s) for (k, c), (_, s) in zip(clean, models) if k > SPIKES_FROM]
    assert len(after) > 10 and all(s.valid for _, s in after)
    errors = [np.linalg.norm(s.fit.theta - theta) / np.linalg.norm(theta) for theta, s in after]
    assert max(errors) < 0.3
    assert service.diagnostics()["input_glitches"] == len(range(SPIKES_FROM, u.shape[0] - 1, SPIKE_EVERY))
    u_window = service.window_samples()[0]
    assert np.abs(u_window).max() <= np.abs(u).max()  # what went in: its neighbours' mean


def test_a_record_without_spikes_gives_the_models_of_its_window_bit_for_bit(record):
    # No gate touched a sample: each model is the solve of a bare window fed the record as it came.
    dt, u, y = record
    models, service = _models(dt, u, y)
    prm = service.params
    window = SlidingWindowArx(prm.order, prm.n_outputs, prm.n_inputs, window=prm.window_length)
    fed = 0
    for k, snapshot in models:
        for j in range(fed, k + 1):
            window.push(u[j], y[j])
        fed = k + 1
        normal = window.normal_equations()  # at each snapshot, as the service's capture reads them
        if snapshot.valid:
            bare = fit_from_normal_equations(normal, prm.order, prm.n_outputs, prm.n_inputs, prm.regularization,
                                             "gcv", decay="gcv", center=True)
            np.testing.assert_array_equal(snapshot.fit.theta, bare.theta)
    assert service.diagnostics()["input_glitches"] == service.diagnostics()["glitches"] == 0


@pytest.mark.parametrize("blow", [50.0, 1e6])
@pytest.mark.parametrize("quiet", [0.01, 0.0])
def test_an_impact_hammers_blows_go_in_as_they_came(blow, quiet):
    # A quiet force (0.01, or exactly 0 between blows: no spread to judge by) struck by blows of
    # 5e3 or 1e8 of its spreads, single samples: far beyond any output glitch's rule, within the
    # input's (INPUT_GLITCH_SPREADS).
    model, dt = paper_model(), paper_model().sample_time_s
    rng = np.random.default_rng(4)
    u = quiet * rng.standard_normal((4000, 2))
    u[rng.choice(np.arange(300, 3900), 12, replace=False), rng.integers(0, 2, 12)] += blow
    assert blow / max(quiet, 1e-300) < INPUT_GLITCH_SPREADS or quiet == 0.0
    y, _ = simulate_innovation(model, u, seed=5)
    models, service = _models(dt, u, y)
    assert service.diagnostics()["input_glitches"] == 0
    u_window = service.window_samples()[0]
    np.testing.assert_array_equal(u_window, u[-u_window.shape[0]:])


def test_a_first_blow_over_a_silent_input_at_the_windows_newest_sample_is_an_unexcited_window(record):
    # The force exactly 0 (or float noise) for longer than the window, then a blow solved while it is
    # the newest sample: its square was only in the feedthrough column, the prior scaled it by the
    # tiny float, and the solve failed, 'array must not contain infs or NaNs', with numpy's
    # 'overflow encountered in multiply' (core/least_squares.py). The window is unexcited: said so.
    dt, u, y = record
    silent = u.copy()
    silent[:2000] = 0.0
    silent[1500, 0] = 50.0
    node_1 = ArxIdentificationService(ArxIdentificationParams.from_parameters(
        resolve_parameters(ARX_NODE, {"sample_time_s": dt, **LIVE})))
    node_1.push_block(np.arange(1501) * dt, silent[:1501], y[:1501])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        snapshot = node_1.snapshot()
    assert not snapshot.valid and snapshot.reason.startswith("unexcited window: condition number inf"), snapshot.reason


def test_an_excitation_switched_on_over_a_rounding_floor_goes_in_as_it_came(record):
    # A force of 1e-12 (rounding) and then the excitation: each of its samples lies 1e12 of the
    # floor's spreads off, but not alone: none is a glitch, and the window holds the record.
    dt, u, y = record
    switched = u.copy()
    switched[:2000] = 1e-12 * np.random.default_rng(6).standard_normal((2000, 2))
    _, service = _models(dt, switched, y)
    assert service.diagnostics()["input_glitches"] == 0
    u_window = service.window_samples()[0]
    np.testing.assert_array_equal(u_window, switched[-u_window.shape[0]:])


@pytest.mark.parametrize("floor", ["held", "subnormal"])
def test_a_floor_of_float_noise_gives_no_spread_to_judge_a_real_sample_by(record, floor):
    # An input held at 0.3 with its rounding jitter (one step, 5.6e-17), or a filter's subnormal tail
    # at 0 (1e-310), then a blow of 50 and the excitation switched on: node 2 refused the blow and the
    # excitation's first sample as glitches (2 counted, each a sample bridged), node 1 and track
    # replaced the blow by its neighbours' mean (1e9 spreads of rounding are no measure of a force).
    dt, u, y = record
    rng = np.random.default_rng(6)
    switched = u.copy()
    switched[:2000] = (0.3 * (1 + 2.2e-16 * rng.standard_normal((2000, 2))) if floor == "held"
                       else 1e-310 * rng.standard_normal((2000, 2)))
    switched[1500, 0] += 50.0
    assert 0 < np.median(np.abs(switched[:2000] - np.median(switched[:2000], axis=0)))  # a spread, not 0
    params = ModalEstimationParams.from_parameters(resolve_parameters(ESTIMATOR_NODE, {"sample_time_s": dt}))
    service = ModalEstimationService(params)
    for k in range(u.shape[0]):
        service.step(k * dt, switched[k], y[k])
    assert service.diagnostics()["input_glitches"] == service.diagnostics()["rejected_samples"] == 0
    node_1 = ArxIdentificationService(ArxIdentificationParams.from_parameters(
        resolve_parameters(ARX_NODE, {"sample_time_s": dt, **LIVE})))  # no solve: the window as it is taken
    assert node_1.push_block(np.arange(1600) * dt, switched[:1600], y[:1600]) == 1600
    assert node_1.diagnostics()["input_glitches"] == 0
    np.testing.assert_array_equal(node_1.window_samples()[0], switched[1600 - node_1.window_samples()[0].shape[0]:1600])
    assert without_input_glitches(switched)[1].size == 0  # track's and identify's


def test_input_spikes_of_1e149_cost_the_live_chain_no_mode():
    # Both nodes (as `process` and the live nodes run them): node 2's estimator stepped the spikes as
    # they came, its states driven to 1e149 (numpy's overflow warnings, a change declared); the chain
    # found 36 of the clean record's 55 modes with node 1's models off, 9 with node 1's alone right.
    # Node 2 refuses such a sample as one beyond 1e150 (a gap of one, bridged by the model).
    model = paper_model()
    u = lowpass_input(12000, 2, 15.0, model.sample_time_s, seed=5)
    y, _ = simulate_innovation(model, u, seed=6)
    spiked = u.copy()
    spiked[3000::SPIKE_EVERY, 0] = 1e149
    clean = chain_modes(model, u, y, order=30, window=2000, every=500)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        chain = chain_modes(model, spiked, y, order=30, window=2000, every=500)
    assert chain.changes == clean.changes == 0 and chain.updates >= clean.updates - 1
    assert chain.found >= clean.found - 1 and chain.spurious <= clean.spurious + 1


def test_node_2_refuses_an_input_glitch_and_counts_it_and_takes_a_hammers_blows(record):
    dt, u, y = record
    params = ModalEstimationParams.from_parameters(resolve_parameters(ESTIMATOR_NODE, {"sample_time_s": dt}))
    spiked = u.copy()
    spiked[SPIKES_FROM::SPIKE_EVERY, 1] = -1e149
    blows = u.copy()
    blows[SPIKES_FROM::SPIKE_EVERY, 1] = 5e3 * np.median(np.abs(u[:, 1] - np.median(u[:, 1])))
    for inputs, glitches in ((spiked, len(range(SPIKES_FROM, u.shape[0], SPIKE_EVERY))), (blows, 0), (u, 0)):
        service = ModalEstimationService(params)
        for k in range(u.shape[0]):
            service.step(k * dt, inputs[k], y[k])
        diagnostics = service.diagnostics()
        assert diagnostics["input_glitches"] == diagnostics["rejected_samples"] == glitches


def test_a_hammers_blows_on_an_input_a_models_window_held_quiet_are_no_structural_change():
    # The paper's structure, unchanged, struck by 12 blows of 1e6 over a quiet force of 0.01. A model
    # whose window held an input at its quiet force only diverged at that input's next blow, and again
    # after the restart from the buffer (its error grows with the blow): declared a structural change,
    # 4 in this record, each restarting node 1's window so that the next model held no blow either.
    model, dt = paper_model(), paper_model().sample_time_s
    rng = np.random.default_rng(4)
    u = 0.01 * rng.standard_normal((4000, 2))
    u[rng.choice(np.arange(300, 3900), 12, replace=False), rng.integers(0, 2, 12)] += 1e6
    y, _ = simulate_innovation(model, u, seed=5)
    pipeline, _ = run_pipeline(u, y, dt, LIVE)
    diagnostics = pipeline.est.diagnostics()
    assert diagnostics["changes_detected"] == 0 and pipeline.changes == []
    assert diagnostics["divergences_beyond_window"] >= 1 and diagnostics["divergence_restarts"] >= 1
    assert diagnostics["models_accepted"] >= 5
