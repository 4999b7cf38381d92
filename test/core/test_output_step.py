"""An output's level step read from a predictor's innovations (core/output_step.py)."""

from __future__ import annotations

import numpy as np

from okid_ros.core.change_detection import whitening_matrix
from okid_ros.core.output_step import output_step, step_response
from okid_ros.core.state_jump import StateJumpTest
from okid_ros.core.statespace import InnovationPredictor
from okid_ros.sim import paper_model


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
