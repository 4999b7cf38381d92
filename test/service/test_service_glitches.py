"""Glitches (one output sample far off) kept out of node 1's window and node 2's realization windows."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from okid_bench.live_chain import chain_modes
from okid_ros.core.arx import fit_arx
from okid_ros.core.realization_window import realization_window
from okid_ros.service.estimation import ModalEstimationService
from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
from okid_ros.service.options import ModalEstimationParams
from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, resolve_parameters
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

Q, W = 30, 2000
GLITCHES = [3100, 3650, 4210, 4777, 5302]


@pytest.fixture(scope="module")
def record():
    model = paper_model()
    u = lowpass_input(6000, 2, 15.0, model.sample_time_s, seed=5)
    y, _ = simulate_innovation(model, u, seed=6)
    return model, u, y


def _glitched(y: np.ndarray, samples, size: float = 30.0, output: int = 0) -> np.ndarray:
    out = y.copy()
    out[samples, output] += size * y[:, output].std()
    return out


def _service(dt: float) -> ArxIdentificationService:
    values = {"sample_time_s": dt, "arx.order": Q, "arx.window_length": W}
    return ArxIdentificationService(ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, values)))


def _window_after(dt: float, u: np.ndarray, y: np.ndarray) -> ArxIdentificationService:
    """Node 1 fed the record, with a model from its first 2500 samples."""
    service = _service(dt)
    service.push_block(dt * np.arange(2500), u[:2500], y[:2500])
    assert service.snapshot().valid
    service.push_block(dt * np.arange(2500, u.shape[0]), u[2500:], y[2500:])
    return service


@pytest.mark.parametrize("size", [30.0, 1e20])
def test_a_glitch_goes_into_node_1s_window_as_its_prediction(record, size):
    # Five samples of output 0 thirty spreads off: the window's fit was 1.5 times its own size
    # away from the clean record's (the glitches' squares outweigh the whole window's). At 1e20
    # spreads the prediction taken as the sample less its error was 0, and the next glitches
    # went in as they came.
    model, u, y = record
    dt = model.sample_time_s
    clean = _window_after(dt, u, y).snapshot().fit.theta
    service = _window_after(dt, u, _glitched(y, GLITCHES, size))
    theta = service.snapshot().fit.theta
    assert service.diagnostics()["glitches"] == len(GLITCHES)
    assert np.linalg.norm(theta - clean) < 0.1 * np.linalg.norm(clean)
    # What went in at a glitch is the last model's prediction: close to the clean sample.
    _, y_window, _ = service.window_samples()
    at = np.array(GLITCHES) - (u.shape[0] - y_window.shape[0])
    assert np.all(np.abs(y_window[at, 0] - y[GLITCHES, 0]) < 4 * y[:, 0].std())


def test_an_impact_on_every_output_and_a_lasting_step_are_no_glitch(record):
    model, u, y = record
    dt = model.sample_time_s
    impact = _glitched(_glitched(y, [4000], output=0), [4000], output=1)
    step = y.copy()
    step[4500:, 1] += 30 * y[:, 1].std()  # a sensor re-zeroed: the next samples stay off
    for record_y in (impact, step):
        service = _window_after(dt, u, record_y)
        u_window, y_window, _ = service.window_samples()
        assert service.diagnostics()["glitches"] == 0
        np.testing.assert_array_equal(y_window, record_y[-y_window.shape[0]:])
        np.testing.assert_array_equal(u_window, u[-u_window.shape[0]:])


def test_a_realization_window_leaves_a_large_spike_out_of_its_samples_and_its_fit(record):
    # Node 2's window of node 1's fit holding the glitch: the samples and the fit to realize are
    # both without it (the fit refitted without the rows that reach it), as `identify` does.
    model, u, y = record
    spiked = _glitched(y[:3000], [1500])
    fit = fit_arx(u[:3000], spiked, Q, center=True)
    window = realization_window(u[:3000], spiked, np.zeros(3000, np.int64), fit, max_gap=10, need=3000)
    assert window.filled == 1 and np.flatnonzero(~window.valid).tolist() == [1500]
    assert abs(window.y[1500, 0] - y[1500, 0]) < 4 * y[:, 0].std()
    np.testing.assert_array_equal(np.delete(window.y, 1500, axis=0), np.delete(y[:3000], 1500, axis=0))
    clean_fit = fit_arx(u[:3000], y[:3000], Q, center=True)
    residual = np.linalg.norm(window.fit.theta - clean_fit.theta)
    assert residual < 0.2 * np.linalg.norm(fit.theta - clean_fit.theta)
    clean = realization_window(u[:3000], y[:3000], np.zeros(3000, np.int64), clean_fit, max_gap=10, need=3000)
    assert clean.valid is None and clean.filled == 0 and clean.fit is clean_fit


def test_a_spike_at_a_windows_last_sample_is_judged_by_the_next_one(record):
    # `track`'s windows end at the update's sample, which no gate holds back (node 1 holds a glitch
    # candidate for the next sample, so node 2's windows end before it): a glitch there stayed in the
    # samples and the fit, and ten of them at update samples of the paper record cost 13 of 83 modes.
    model, u, y = record
    spiked = _glitched(y[:3001], [2999])
    fit = fit_arx(u[:3000], spiked[:3000], Q, center=True)
    zeros = np.zeros(3000, np.int64)
    kept = realization_window(u[:3000], spiked[:3000], zeros, fit, max_gap=10, need=3000)
    assert kept.u.shape[0] == 3000 and kept.fit is fit  # no next sample: not judged
    window = realization_window(u[:3000], spiked[:3000], zeros, fit, max_gap=10, need=3000,
                                next_sample=(u[3000], spiked[3000]))
    assert window.u.shape[0] == 2999 and window.valid is None
    np.testing.assert_array_equal(window.y, y[:2999])
    clean_fit = fit_arx(u[:2999], y[:2999], Q, center=True)
    residual = np.linalg.norm(window.fit.theta - clean_fit.theta)
    assert residual < 0.2 * np.linalg.norm(fit.theta - clean_fit.theta)
    clean = realization_window(u[:3000], y[:3000], zeros, fit, max_gap=10, need=3000, next_sample=(u[3000], y[3000]))
    assert clean.u.shape[0] == 3000 and clean.fit is fit


def test_glitches_cost_the_live_chain_no_mode(record):
    # The chain of both nodes (as `process` and the live nodes run it) on the record with the
    # five glitches: the models of the windows holding them lost modes and listed spurious ones.
    model, u, y = record
    clean = chain_modes(model, u, y, order=Q, window=W, every=500)
    glitched = chain_modes(model, u, _glitched(y, GLITCHES), order=Q, window=W, every=500)
    assert glitched.updates == clean.updates and glitched.found >= clean.found - 1
    assert glitched.spurious <= clean.spurious + 1 and glitched.arx_glitches == len(GLITCHES)


def test_a_window_fitted_exactly_judges_no_glitch_and_lets_numpy_say_nothing():
    # Order 8, p = 3, m = 2 and a window of 60: its first fit has 42 rows for 42 coefficients per
    # output, a residual covariance of rounding (one variance 0 or below). 8644b37: numpy's "divide by
    # zero" at each of the 42 samples the gate then judged (core/glitches.py).
    rng = np.random.default_rng(3)
    n, dt = 400, 0.01
    values = {"sample_time_s": dt, "arx.order": 8, "arx.window_length": 60, "n_outputs": 3, "n_inputs": 2,
              "offsets": "none"}
    service = ArxIdentificationService(ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, values)))
    u, y = rng.standard_normal((n, 2)), np.zeros((n, 3))
    for k in range(1, n):
        y[k] = 0.5 * y[k - 1] + u[k - 1].sum() + 0.1 * rng.standard_normal(3)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for k in range(n):
            assert service.push(k * dt, u[k], y[k])
            if k % 50 == 49:
                assert service.snapshot().valid
    assert service.diagnostics()["glitches"] == 0
    np.testing.assert_array_equal(service.window_samples()[1], y[n - service.window_samples()[1].shape[0]:])


def _switch_after_a_realization(model, u: np.ndarray, y: np.ndarray) -> dict:
    """Each published sample's (model id, modal coordinates) of node 2 with two models.

    A model of samples 0-1999, then one of the window 1000-2999 realized while 400 more samples
    come (live at tens of outputs a realization takes seconds), its warm start following them
    before the switch at sample 3400.
    """
    dt = model.sample_time_s
    service = ModalEstimationService(ModalEstimationParams.from_parameters(resolve_parameters(
        ESTIMATOR_NODE, {"sample_time_s": dt, "n_inputs": 2, "n_outputs": 2})))
    states, outcome = {}, None
    for k in range(y.shape[0]):
        result = service.step(k * dt, u[k], y[k])
        if result is not None:
            states[k] = (result.model_id, result.coordinates.ravel())
        if k in (1999, 2999):
            service.submit_arx(fit_arx(u[k - 1999:k + 1], y[k - 1999:k + 1], Q, center=True), k * dt, k)
            outcome = service.run_job(service.take_job(), follow=False)
            if k == 1999:
                service.deliver(outcome)
        if k == 3399:
            service.deliver(service.follow(outcome))
    return states


@pytest.mark.parametrize("glitch_at", [3350, 3390])
def test_a_warm_start_follows_a_glitch_as_the_estimator_left_it_out(record, glitch_at):
    # A glitch while a model is being realized: the estimator in use leaves it out, but the new
    # model's warm start followed node 2's buffered samples, which held it as it came, and the
    # switch carried it (modal coordinates 2.2 % and 5.6 % off the clean run's over the 200 samples
    # after it, some withheld as diverged). The buffer now keeps the estimator's prediction.
    model, u, y = record
    clean = _switch_after_a_realization(model, u, y)
    states = _switch_after_a_realization(model, u, _glitched(y, [glitch_at]))
    errors = [np.linalg.norm(states[k][1] - clean[k][1]) / np.linalg.norm(clean[k][1])
              for k in range(3401, 3601) if k in states and states[k][0] == clean[k][0]]
    assert len(errors) == 200 and np.sqrt(np.mean(np.square(errors))) < 0.005


@pytest.mark.parametrize("n_inputs", [0, 2])
def test_a_block_of_samples_goes_through_node_1s_gates_as_one_sample_at_a_time(record, n_inputs):
    # screened_block passes runs of ordinary samples at once (their predictions by one product, whose rounding
    # differs from one sample's sum in the last bits): the samples out, the glitches and the gates' state must be
    # those of each sample offered alone, for output and input glitches, refused samples, and errors at the limit.
    from okid_ros.core.arx import fit_from_normal_equations
    from okid_ros.core.recursive import SlidingWindowArx
    from okid_ros.service.window_gates import WindowGates, screened_block

    _, u, y = record
    u, y = u[:, :n_inputs].copy(), _glitched(y, GLITCHES[:3], size=8.0)
    u[[3300, 4500], :n_inputs] += 1e12
    accepted = np.ones(len(y), bool)
    accepted[[2500, 3900, 3901]] = False
    window = SlidingWindowArx(5, 2, n_inputs, window=W)
    window.update(u[:2000], y[:2000])
    fit = fit_from_normal_equations(window.normal_equations(), 5, 2, n_inputs, "ridge", "gcv")
    one, block = WindowGates(5, 2, n_inputs), WindowGates(5, 2, n_inputs)
    alone, at_once = (u.copy(), y.copy()), (u.copy(), y.copy())
    for lo, hi in [(0, 2000), (2000, 4200), (4200, 6000)]:
        if lo == 2000:
            one.set_model(fit), block.set_model(fit)
        for k in range(lo, hi):  # each sample alone, as screened_block took them on main
            for u_due, y_due, j in one.offer(alone[0][k], alone[1][k], k) if accepted[k] else one.gap():
                alone[0][j], alone[1][j] = u_due, y_due
            if k in (4100, 4150):  # an error at the limit to the last bits: each is judged alone
                gate = one.outputs
                limit = gate._limit[1] * (1.0 + (k - 4100) * 1e-16)
                alone[1][k + 1, 1] = at_once[1][k + 1, 1] = gate._prediction(alone[0][k + 1])[1] + limit
        screened_block(block, at_once, accepted, lo, hi)
    assert block.glitches == one.glitches >= 3 and block.input_glitches == one.input_glitches == 2 * bool(n_inputs)
    assert all(np.array_equal(a, b) for a, b in zip(alone, at_once))
    assert np.array_equal(block.outputs._history, one.outputs._history)
    assert (block.outputs._pos, block.outputs._run) == (one.outputs._pos, one.outputs._run)
