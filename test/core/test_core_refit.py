"""Tests of the least-squares completion of a realization (okid_ros.core.refit).

``refit_predictor`` is given the true predictor poles ``Abar = A - A K C`` and ``C`` of a known
innovation model and must return its matrices. (The completion from a state sequence has its
own module and tests: ``core/state_completion.py``, ``test/core/test_core_state_completion.py``.)
"""

from __future__ import annotations

import numpy as np
import pytest

from okid_ros.core.refit import gain_from_predictor, refit_predictor
from okid_ros.core.statespace import InnovationModel, one_step_prediction
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import propagate_states


def record(model: InnovationModel, n_samples: int, seed: int):
    """Inputs, outputs, innovations and states of the model from rest (x_0 = 0)."""
    rng = np.random.default_rng([seed, 1])  # a stream of its own, not that of the inputs
    u = white_input(n_samples, model.n_inputs, seed=seed)
    e = rng.standard_normal((n_samples, model.n_outputs)) @ np.linalg.cholesky(model.innovation_covariance).T
    states = propagate_states(model.A, u @ model.B.T + e @ model.predictor_gain.T)
    y = states @ model.C.T + u @ model.D.T + e
    return u, y, e, states


def rel(a, b) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_refit_predictor_recovers_the_true_model_from_its_predictor_poles():
    truth = paper_model()
    u, y, e, states = record(truth, 20000, seed=1)
    Abar = truth.predictor()[0]
    fit = refit_predictor(Abar, truth.C, u, y)
    model = fit.model
    # Estimation error ~ 1/sqrt(N) = 0.7 %: a few percent on the fitted matrices.
    # Measured: D 0.005 absolute (|D| ~ 0.02), A 0.3 %, B 1.2 %, L 0.6 %, Re 0.014.
    assert np.abs(model.D - truth.D).max() < 0.02
    assert rel(model.A, truth.A) < 0.01
    assert rel(model.B, truth.B) < 0.04
    assert rel(model.A @ model.K, truth.predictor_gain) < 0.02
    np.testing.assert_allclose(model.innovation_covariance, truth.innovation_covariance, atol=0.05)
    # Its innovations are the one-step prediction errors of the fitted model (x0 = 0 here).
    _, errors = one_step_prediction(model, u, y, x0=fit.x0)
    np.testing.assert_allclose(fit.innovations, errors, atol=1e-8 * np.abs(y).max())
    assert rel(fit.innovations, e) < 0.06
    # The record starts at rest: the fitted initial state is small against the typical state.
    assert np.linalg.norm(fit.x0) < 0.2 * np.sqrt(np.mean(np.sum(states**2, axis=1)))
    n, p, m = truth.n_states, truth.n_outputs, truth.n_inputs
    assert fit.n_parameters == n * (2 * p + m) + p * m + n
    assert np.isfinite(fit.bic())


def test_refit_predictor_refuses_an_unstable_predictor_and_too_short_records():
    truth = paper_model()
    u, y, _, _ = record(truth, 400, seed=2)
    with pytest.raises(ValueError, match="unstable"):
        refit_predictor(1.01 * np.eye(truth.n_states), truth.C, u, y)
    with pytest.raises(ValueError, match="too few"):
        refit_predictor(truth.predictor()[0], truth.C, u[:10], y[:10])


def test_gain_from_predictor_inverts_the_paper_convention():
    truth = paper_model()
    np.testing.assert_allclose(gain_from_predictor(truth.A, truth.predictor_gain), truth.K, rtol=1e-10, atol=1e-12)


def test_identify_with_the_state_sequence_completion_finds_the_true_modes():
    """completion="states" (fit_from_states on the predictor-based states) through identify."""
    from okid_ros.core.pipeline import identify
    from okid_ros.sim.paper_model import paper_modes
    from okid_ros.sim.simulators import simulate_innovation

    truth = paper_model()
    u = white_input(6000, 2, seed=9)
    y, _ = simulate_innovation(truth, u, seed=10)
    model = identify(u, y, truth.sample_time_s, order=40, n_states=6, completion="states", refine=False)
    assert model.completion == "states" and model.n_states == 6
    assert model.order_scores and np.isfinite(model.order_scores[6])
    found = sorted((mode.frequency_rad_s, mode.damping_ratio) for mode in model.modes)
    expected = sorted((mode["frequency_rad_s"], mode["damping_ratio"]) for mode in paper_modes())
    assert len(found) == len(expected) == 3
    for (f, z), (f_true, z_true) in zip(found, expected):
        assert abs(f - f_true) < 0.02 * f_true  # measured: 0.7 % at most
        assert abs(z - z_true) < 0.02  # measured: 0.015 at most (the 2.9 % mode)
