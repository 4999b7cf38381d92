"""An output's level step read from a predictor's innovations (core/output_step.py)."""

from __future__ import annotations

import numpy as np

from okid_ros.core.change_detection import whitening_matrix
from okid_ros.core.output_step import output_step, step_response
from okid_ros.core.state_jump import StateJumpTest
from okid_ros.core.statespace import InnovationPredictor
from okid_ros.sim import paper_model
from okid_ros.sim.models import modal_structure


def _innovations(model, y: np.ndarray, x0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The model's predictor over outputs ``y`` (N, p) with zero input: innovations (N, p), last state."""
    predictor = InnovationPredictor(model, x0)
    e = predictor.run(np.zeros((y.shape[0], model.B.shape[1])), y)
    return e, predictor.x


def test_a_step_of_the_outputs_is_read_back_from_the_innovations_it_leaves():
    # Noise-free: the innovations of a step are the constant and the free response that the
    # state-jump fit's regressors span, so the step comes back to rounding.
    model = paper_model()
    F, _, G_y = model.predictor()
    whiten = whitening_matrix(model.innovation_covariance)
    d = np.array([3.0, -1.25]) * 10.0 * np.sqrt(np.diag(model.innovation_covariance))
    y = np.zeros((120, 2))
    y[20:] = d
    e, _ = _innovations(model, y)
    test = StateJumpTest(F, whiten @ model.C)
    jump = test.judge(e @ whiten.T, 0)
    assert jump.explained and jump.loud_index == 20
    np.testing.assert_allclose(output_step(jump, F, G_y, model.C, whiten), d, rtol=1e-8)


def test_step_response_is_what_the_predictors_state_took():
    model = paper_model()
    F, _, G_y = model.predictor()
    d = np.array([0.7, 2.0])
    _, x = _innovations(model, np.tile(d, (37, 1)))
    np.testing.assert_allclose(step_response(F, G_y, d, 37), x, rtol=1e-10, atol=1e-12)
    _, x_far = _innovations(model, np.tile(d, (4000, 1)))
    np.testing.assert_allclose(step_response(F, G_y, d), x_far, rtol=1e-8, atol=1e-12)


def test_a_jump_of_the_state_alone_is_no_step():
    # An impact: the predictor's state off, the outputs' level unchanged, white innovations
    # beside it. The fitted constant is noise: no step.
    model = paper_model()
    F, _, G_y = model.predictor()
    whiten = whitening_matrix(model.innovation_covariance)
    rng = np.random.default_rng(4)
    noise = rng.standard_normal((200, 2)) @ np.linalg.cholesky(model.innovation_covariance).T
    e = noise.copy()
    row, jump_state = model.C.copy(), 50.0 * rng.standard_normal(model.A.shape[0])
    for k in range(30, 200):
        e[k] += row @ jump_state
        row = row @ F
    jump = StateJumpTest(F, whiten @ model.C).judge(e @ whiten.T, 0)
    assert jump.explained
    assert output_step(jump, F, G_y, model.C, whiten) is None


def test_a_step_in_one_of_many_outputs_is_taken_in_that_output_alone():
    # Sixteen accelerometers: the constant of a 33-sample fit carries its noise through G_inf^-1 into
    # every channel (on the steel subframe, up to 0.2 spreads where nothing stepped, which taken
    # off made a new excursion). Only the channel beyond its noise is taken.
    model = modal_structure([3.0, 7.5, 12.0, 21.0, 33.0], 0.02, 2, 16, 0.01, seed=3).to_innovation_form()
    F, _, G_y = model.predictor()
    whiten = whitening_matrix(model.innovation_covariance)
    std = np.sqrt(np.diag(model.innovation_covariance))
    rng = np.random.default_rng(5)
    for _ in range(20):
        e = rng.standard_normal((60, 16)) @ np.linalg.cholesky(model.innovation_covariance).T
        y = np.zeros((60, 16))
        y[20:, 11] = 40.0 * std[11]
        e += _innovations(model, y)[0]
        jump = StateJumpTest(F, whiten @ model.C, min_samples=16).judge(e @ whiten.T, 0)
        assert jump.explained
        step = output_step(jump, F, G_y, model.C, whiten)
        assert np.flatnonzero(step).tolist() == [11]
        assert abs(step[11] / (40.0 * std[11]) - 1.0) < 0.05
