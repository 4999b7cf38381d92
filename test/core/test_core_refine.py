"""Tests of the prediction-error refinement (okid_ros.core.refine).

The analytic Jacobian of the predictor is checked against central finite differences, and the
refinement, started from a perturbed model, must lower the prediction-error cost and move the
model towards the truth.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.refine import _Predictor, refine_prediction_error, refinement_size
from okid_ros.core.statespace import InnovationModel, one_step_prediction
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation


def random_predictor(n_pairs: int, n_real: int, p: int, m: int, seed: int) -> tuple[_Predictor, np.ndarray]:
    rng = np.random.default_rng(seed)
    w = p + m
    pairs = [
        (0.9 * np.exp(1j * rng.uniform(0.2, 2.5)), rng.standard_normal(w) + 1j * rng.standard_normal(w),
         rng.standard_normal(p) + 1j * rng.standard_normal(p))
        for _ in range(n_pairs)
    ]
    reals = [(rng.uniform(-0.8, 0.8), rng.standard_normal(w), rng.standard_normal(p)) for _ in range(n_real)]
    model = _Predictor(n_pairs, n_real, p, m)
    return model, model.pack(pairs, reals, rng.standard_normal((p, m)))


def test_pack_and_unpack_are_inverse():
    model, theta = random_predictor(2, 1, 2, 1, seed=1)
    w, p, m = 3, 2, 1
    # A pair: pole (2), complex g (2 w), complex c (2 p); a real pole: 1 + w + p; then D.
    assert theta.size == 2 * (2 + 2 * w + 2 * p) + (1 + w + p) + p * m <= refinement_size(5, p, m)
    np.testing.assert_array_equal(model.pack(*model.unpack(theta)), theta)


def test_analytic_jacobian_equals_finite_differences():
    p, m, burn_in = 2, 1, 20
    model, theta = random_predictor(2, 1, p, m, seed=2)
    rng = np.random.default_rng(3)
    u = rng.standard_normal((300, m))
    v = np.hstack([rng.standard_normal((300, p)), u])
    jac = model.jacobian(theta, v, u, burn_in)
    assert jac.shape == ((300 - burn_in) * p, theta.size)
    step = 1e-6
    fd = np.empty_like(jac)
    for i in range(theta.size):
        up, down = theta.copy(), theta.copy()
        up[i] += step
        down[i] -= step
        diff = model.predict(up, v, u) - model.predict(down, v, u)
        fd[:, i] = (diff[burn_in:] / (2 * step)).ravel()
    scale = np.abs(fd).max(axis=0)
    assert np.all(scale > 0)  # every parameter moves the prediction
    np.testing.assert_allclose(jac, fd, rtol=0, atol=1e-6 * scale.max())
    # Column by column, relative to each column's own size.
    assert np.max(np.abs(jac - fd).max(axis=0) / scale) < 1e-5


def cost(model, u, y, burn_in):
    _, e = one_step_prediction(model[:5], u, y)
    return float(np.sum(e[burn_in:] ** 2))


def test_refinement_lowers_the_cost_and_approaches_the_truth():
    truth = paper_model()
    u = white_input(4000, 2, seed=4)
    y, _ = simulate_innovation(truth, u, seed=5, x0=None)
    rng = np.random.default_rng(6)
    # A start off the truth: B, C, D and K perturbed by 10 %, A's poles moved slightly.
    perturbed = (x * (1 + 0.1 * rng.standard_normal(x.shape)) for x in (truth.B, truth.C, truth.D, truth.K))
    start = [truth.A * (1 - 0.002), *perturbed]
    burn_in = 100
    fit = refine_prediction_error(InnovationModel(*start, truth.innovation_covariance), u, y,
                                  burn_in=burn_in, max_evaluations=40)
    assert fit is not None
    refined = fit.model
    after = (refined.A, refined.B, refined.C, refined.D, refined.K)
    before_cost, after_cost = cost(start, u, y, burn_in), cost(after, u, y, burn_in)
    truth_cost = cost((truth.A, truth.B, truth.C, truth.D, truth.K), u, y, burn_in)
    assert after_cost < before_cost
    # It reaches the truth's cost (a little below: it fits this record's noise).
    assert after_cost < 1.01 * truth_cost < before_cost
    np.testing.assert_allclose(np.sort(np.abs(np.linalg.eigvals(refined.A))),
                               np.sort(np.abs(np.linalg.eigvals(truth.A))), atol=2e-3)
    # Its innovations are those of the returned model after the burn-in.
    _, e = one_step_prediction(after, u, y)
    n_used = fit.innovations.shape[0]
    assert n_used == y.shape[0] - burn_in
    np.testing.assert_allclose(fit.innovations, e[-n_used:], atol=1e-9)
    # A and the predictor stay stable.
    assert refined.stability_problem() == ""


def test_refinement_declines_an_unstable_predictor():
    truth = paper_model()
    u = white_input(500, 2, seed=7)
    y, _ = simulate_innovation(truth, u, seed=8)
    start = InnovationModel(1.2 * truth.A, truth.B, truth.C, truth.D, 0 * truth.K, truth.innovation_covariance)
    assert refine_prediction_error(start, u, y) is None
