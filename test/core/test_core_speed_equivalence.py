"""The faster forms of the realization's steps give what the direct forms give (issue 17).

Each speed-up of the realization replaced a direct computation by a cheaper one with the same
result: these tests compute both on the same data and compare, so a change in either shows.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg

from okid_ros.core.kalman_gain import kalman_gain_from_residuals
from okid_ros.core.modal import mac
from okid_ros.core.options import ModeCriteria
from okid_ros.core.refine import _Objective, _Predictor
from okid_ros.core.refit import refit_predictor
from okid_ros.core.stabilization import StabilizationPole, _match, stabilization_diagram
from okid_ros.core.stable_matrix import MAX_BASIS_CONDITION, _basis_inverse
from okid_ros.core.state_completion import fit_from_states, regress_state_equations
from okid_ros.core.statespace import (
    InnovationModel,
    InnovationPredictor,
    _run_states,
    held_input_response,
    one_step_prediction,
    predictor_states,
)
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation


def _paper_record(n_samples: int = 3000, seed: int = 1):
    truth = paper_model()
    u = white_input(n_samples, 2, seed=seed)
    y, _ = simulate_innovation(truth, u, seed=seed + 1)
    return truth, u, y


def test_fit_from_states_by_the_gram_equals_the_data_regressions():
    """One Gram of [u, x, y, x_next] gives the data pass's A, B, C, D and Riccati gain."""
    truth, u, y = _paper_record()
    states, _ = predictor_states(truth, u, y)
    states = states + 0.01 * np.random.default_rng(4).standard_normal(states.shape)  # not exact states
    model = fit_from_states(states, u, y)
    A, B, C, D, w, v = regress_state_equations(states, u, y)
    L, Re = kalman_gain_from_residuals(A, C, w, v[:-1])
    for got, want in ((model.A, A), (model.B, B), (model.C, C), (model.D, D), (model.predictor_gain, L),
                      (model.innovation_covariance, Re)):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-8 * np.abs(want).max())


@pytest.mark.parametrize("condition", [1e3, 3e8, 3e9, 1e10 / 1.5, 1.5e10, 5e10, 1e13])
def test_basis_inverse_refuses_exactly_the_bases_the_svd_condition_refuses(condition):
    """The Frobenius bracket decides as ``np.linalg.cond`` (2-norm) around the limit 1e10."""
    rng = np.random.default_rng(int(np.log10(condition) * 10))
    n = 6
    left, _ = np.linalg.qr(rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n)))
    right, _ = np.linalg.qr(rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n)))
    V = (left * np.geomspace(1.0, 1.0 / condition, n)) @ right
    inverse = _basis_inverse(V)
    refused = np.linalg.cond(V) > MAX_BASIS_CONDITION
    assert (inverse is None) == refused
    if inverse is not None:
        np.testing.assert_allclose(inverse, linalg.inv(V))


def test_refine_normal_equations_equal_those_of_the_explicit_jacobian():
    rng = np.random.default_rng(5)
    p, m, n_pairs, n_real = 3, 2, 2, 1
    w = p + m
    pairs = [(0.9 * np.exp(1j * rng.uniform(0.2, 2.5)), rng.standard_normal(w) + 1j * rng.standard_normal(w),
              rng.standard_normal(p) + 1j * rng.standard_normal(p)) for _ in range(n_pairs)]
    reals = [(0.5, rng.standard_normal(w), rng.standard_normal(p)) for _ in range(n_real)]
    predictor = _Predictor(n_pairs, n_real, p, m)
    theta = predictor.pack(pairs, reals, rng.standard_normal((p, m)))
    u, y = rng.standard_normal((400, m)), rng.standard_normal((400, p))
    objective = _Objective(predictor, u, y, 20, 350, (10.0, 10.0))
    r = objective.residuals(theta)
    J = -predictor.jacobian(theta, objective.v, u, 20)[: objective.n_fitted]
    H, g = objective.normal(theta, r)
    np.testing.assert_allclose(H, J.T @ J, rtol=0, atol=1e-10 * np.abs(J.T @ J).max())
    np.testing.assert_allclose(g, J.T @ r, rtol=0, atol=1e-10 * np.abs(J.T @ r).max())


def test_refit_innovations_are_the_refitted_predictor_s_one_step_errors():
    """The shortened FFT convolution leaves no wrap-around.

    The refit's innovations are the one-step prediction errors of the model it returns, from its
    fitted initial state.
    """
    truth, u, y = _paper_record(2500, seed=7)
    Abar = truth.A - truth.predictor_gain @ truth.C
    fit = refit_predictor(Abar, truth.C, u, y)
    _, innovations = one_step_prediction(fit.model, u, y, x0=fit.x0)
    np.testing.assert_allclose(fit.innovations, innovations, rtol=0, atol=1e-9 * np.abs(y).max())


def test_predictor_run_by_gemv_equals_the_plain_recursion():
    rng = np.random.default_rng(8)
    n, r = 7, 3
    F = 0.3 * rng.standard_normal((n, n))
    G, w, x0 = rng.standard_normal((n, r)), rng.standard_normal((200, r)), rng.standard_normal(n)
    want = np.empty((200, n))
    x = x0.copy()
    for k in range(200):
        want[k] = x
        x = F @ x + G @ w[k]
    np.testing.assert_allclose(_run_states(F, G, w, x0), want, rtol=1e-12, atol=1e-12)
    assert _run_states(F, G, w[:0], x0).shape == (0, n)


def test_a_bridge_and_an_innovation_alone_make_no_predictor_matrices(monkeypatch):
    """Node 2 bridges each gap and takes a switch's innovation on its sample path: A, B, C, D, not F, G_u, G_y.

    The predictor's matrices were made with every InnovationPredictor (30 us at 28 outputs and 104 states,
    most of a bridged sample's time); now at their first use, the same as before.
    """
    truth = paper_model()
    made = []
    predictor = InnovationModel.predictor
    monkeypatch.setattr(InnovationModel, "predictor", lambda model: made.append(model) or predictor(model))
    rng = np.random.default_rng(9)
    x0, u, y = rng.standard_normal(truth.n_states), rng.standard_normal(2), rng.standard_normal(2)
    bridged = InnovationPredictor(truth, x0)
    assert bridged.bridge(u, 3, 5)
    x = x0
    for _ in range(3):
        x = truth.A @ x + truth.B @ u
    np.testing.assert_array_equal(bridged.x, x)
    assert made == []
    alone = InnovationPredictor(truth, x0)
    np.testing.assert_array_equal(alone.step(u, y, advance=False), y - truth.D @ u - truth.C @ x0)
    np.testing.assert_array_equal(alone.x, x0)
    assert made == []
    e = alone.step(u, y)  # the step needs F, G_u, G_y: made once, as model.predictor() makes them
    F, Gu, Gy = predictor(truth)
    np.testing.assert_array_equal(e, y - truth.D @ u - truth.C @ x0)
    np.testing.assert_array_equal(alone.x, F @ x0 + Gu @ u + Gy @ y)
    alone.step(u, y)
    assert made == [truth] and alone.F is alone.F


def test_diagram_marks_equal_the_pairwise_test_of_every_pole():
    """The diagram's frequency prefilter keeps every pole pair the pairwise test accepts."""
    truth = paper_model()
    rng = np.random.default_rng(9)
    models = {}
    for n_extra, order in enumerate((6, 8, 10)):
        A = linalg.block_diag(truth.A, 0.5 * np.eye(order - truth.A.shape[0]))
        A = A + 1e-4 * (n_extra + 1) * rng.standard_normal(A.shape)
        C = np.hstack([truth.C, rng.standard_normal((truth.C.shape[0], order - truth.A.shape[0]))])
        models[order] = InnovationModel(A, np.zeros((order, 2)), C, np.zeros((2, 2)), np.zeros((order, 2)),
                                        np.eye(2))
    criteria = ModeCriteria()
    diagram = stabilization_diagram(models, truth.sample_time_s, criteria)
    for previous, current in zip(diagram, diagram[1:]):
        for pole in current.poles:
            want = _match(pole, previous.poles, criteria)
            assert (pole.stable_frequency, pole.stable_damping, pole.stable_shape) == want
    assert any(pole.stable_shape for pole in diagram[-1].poles)
    assert mac(diagram[-1].poles[0].shape, diagram[-1].poles[0].shape) == pytest.approx(1.0)
    assert isinstance(diagram[0].poles[0], StabilizationPole)


@pytest.mark.parametrize(("radius", "length"), [(0.94, 3000), (0.999, 2000), (0.5, 40), (0.9, 5), (0.0, 30)])
def test_impulse_rows_by_blocks_equal_the_lag_by_lag_recursion(radius, length):
    """``C Abar^k`` by blocks of lags: the same rows and the same decay point as one lag at a time."""
    from okid_ros.core.refit import _impulse_rows

    rng = np.random.default_rng(int(radius * 1000) + length)
    n = 6
    Q = np.linalg.qr(rng.standard_normal((n, n)))[0]
    Abar = Q @ np.diag(radius * np.cos(rng.uniform(0, 3, n))) @ Q.T
    C = rng.standard_normal((2, n))
    want = np.zeros((length, 2, n))
    row, filled = C.copy(), length
    for k in range(length):
        want[k] = row
        row = row @ Abar
        if np.abs(row).max() < 1e-13 * np.abs(C).max():
            filled = k + 1
            break
    got, got_filled = _impulse_rows(Abar, C, length)
    assert got_filled == filled
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14 * np.abs(C).max())


@pytest.mark.parametrize("fit_initial_state", [True, False])
def test_refit_by_modal_filters_equals_the_refit_by_convolutions(fit_initial_state, monkeypatch):
    """The refit's normal equations from each pole's filtered data equal the convolved regressors'.

    A predictor with pole pairs and real poles (the paper model's 4 states and 2 real ones), 3
    outputs; the same fit to rounding, and the convolution route where the basis is too
    ill-conditioned.
    """
    import okid_ros.core.refit as refit

    truth, u, y = _paper_record(2500, seed=3)
    rng = np.random.default_rng(7)
    n = truth.n_states + 2
    Abar = linalg.block_diag(truth.predictor()[0], np.diag([0.6, -0.3]))
    C = np.hstack([truth.C, rng.standard_normal((2, 2))])
    C = np.vstack([C, rng.standard_normal((1, n))])
    y3 = np.column_stack([y, y @ rng.standard_normal(2) + 0.1 * rng.standard_normal(y.shape[0])])
    modal = refit_predictor(Abar, C, u, y3, fit_initial_state)
    assert refit._modal_normal_equations(Abar, C, u, y3, [np.zeros((len(u), 0))] * 3, 10) is not None
    monkeypatch.setattr(refit, "_modal_normal_equations", lambda *args: None)
    convolved = refit_predictor(Abar, C, u, y3, fit_initial_state)
    for mine, theirs in ((modal.model.B, convolved.model.B), (modal.model.K, convolved.model.K),
                         (modal.model.D, convolved.model.D), (modal.innovations, convolved.innovations),
                         (modal.x0, convolved.x0)):
        np.testing.assert_allclose(mine, theirs, rtol=1e-8, atol=1e-10 * max(np.abs(theirs).max(), 1e-300))


def test_refit_of_a_defective_predictor_takes_the_convolution_route():
    import okid_ros.core.refit as refit

    truth, u, y = _paper_record(1500, seed=5)
    Abar = np.array([[0.8, 1.0], [0.0, 0.8]])  # a Jordan block: no eigenvector basis
    C = np.array([[1.0, 0.0], [0.0, 1.0]])
    assert refit._modal_normal_equations(Abar, C, u, y, [np.zeros((len(u), 0))] * 2, 10) is None
    fit = refit_predictor(Abar, C, u, y)
    assert np.all(np.isfinite(fit.innovations)) and fit.model.B.shape == (2, 2)


@pytest.mark.parametrize("n, steps", [(6, 3), (6, 10), (6, 3000), (40, 100_000)])
def test_a_long_bridge_by_the_augmented_matrix_power_is_the_steps_state(n, steps):
    """A gap of up to ``estimator.max_gap_samples`` (1e6) was stepped one product a sample on node 2's path.

    Beyond the steps' cost it is the augmented matrix's power; the state is the steps' to rounding
    (short gaps, the default's 10, are stepped as before: to the last bit).
    """
    rng = np.random.default_rng(n + steps)
    A = rng.standard_normal((n, n))
    A *= 0.999 / max(abs(np.linalg.eigvals(A)))  # a lightly damped pole: the gap's response rings long
    x0, forcing = rng.standard_normal(n), rng.standard_normal(n)
    x = x0
    for _ in range(steps):
        x = A @ x + forcing
    got = held_input_response(A, x0, forcing, steps)
    if steps <= 10:
        np.testing.assert_array_equal(got, x)
    else:
        np.testing.assert_allclose(got, x, rtol=1e-9, atol=1e-9 * np.abs(x).max())
