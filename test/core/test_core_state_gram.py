"""The fast realization's pieces reproduce the data-pass computations they replace (issue 17).

Every order's state regressions from the window's Gram, the doubling Riccati solver and the
eigendecompositions shared with the stabilization diagram.
"""

import numpy as np
import pytest
from scipy import linalg

from okid_ros.core.arx import fit_from_normal_equations, normal_equations
from okid_ros.core.era import decompose_hankel, default_hankel_size
from okid_ros.core.kalman_gain import noise_covariances, riccati_covariance, riccati_residual
from okid_ros.core.options import ModeCriteria
from okid_ros.core.regressors import arx_regressors
from okid_ros.core.stabilization import stabilization_diagram
from okid_ros.core.state_completion import regress_state_equations
from okid_ros.core.state_gram import StateGram
from okid_ros.core.statespace import InnovationModel
from okid_ros.sim.inputs import white_input
from okid_ros.sim.models import modal_structure
from okid_ros.sim.simulators import simulate


def _record(n_samples=3000, seed=5):
    truth = modal_structure([3.0, 7.5, 12.0], 0.02, n_inputs=2, n_outputs=5, sample_time_s=0.02, seed=seed,
                            output="acceleration", disturbance_std=0.3, measurement_noise_ratio=0.05)
    u = white_input(n_samples, 2, seed=seed + 1)
    y = simulate(truth, u, seed + 2)
    return u - u.mean(0), y - y.mean(0)


@pytest.fixture(scope="module")
def window():
    u, y = _record()
    order = 20
    phi, targets, _ = arx_regressors(u, y, order)
    arx = fit_from_normal_equations(normal_equations(phi, targets), order, y.shape[1], u.shape[1], "ridge")
    rows, cols = default_hankel_size(arx.observer_markov.shape[0] - 1)
    gram = StateGram(u, y, cols)
    dec = decompose_hankel(arx.observer_markov, rows, cols, gram.past_weight())
    top = 30
    gram.set_states((dec.U[:, :top].T @ dec.h0).T / np.sqrt(dec.s[:top]))
    return u, y, gram


def _rel(a, b):
    return np.abs(a - b).max() / max(np.abs(b).max(), 1e-300)


@pytest.mark.parametrize("n", [2, 6, 14, 30])
def test_gram_regressions_equal_the_data_pass(window, n):
    u, y, gram = window
    states = gram.states(n)
    A, B, C, D, w, v = regress_state_equations(states, u[gram.rows], y[gram.rows])
    fit = gram.regress(n, covariances=True)
    for mine, theirs in ((fit.A, A), (fit.B, B), (fit.C, C), (fit.D, D), (fit.output_covariance, v.T @ v / len(v))):
        assert _rel(mine, theirs) < 1e-7
    for mine, theirs in zip(fit.noise_covariances(), noise_covariances(w, v[:-1])):
        assert _rel(mine, theirs) < 1e-7
    # The eigendecomposition handed to the diagram is that of the returned A.
    lam, vectors = fit.eigenvalues, fit.eigenvectors
    assert np.abs(fit.A @ vectors - vectors * lam).max() < 1e-8 * max(1.0, np.abs(fit.A).max())


def test_gram_refuses_orders_beyond_its_states(window):
    _, _, gram = window
    with pytest.raises(ValueError, match="outside"):
        gram.regress(31)


def test_doubling_riccati_matches_scipy_and_its_residual_is_at_rounding(window):
    _, _, gram = window
    fit = gram.regress(14, covariances=True)
    Q, R, S = fit.noise_covariances()
    mine = riccati_covariance(fit.A, fit.C, Q, R, S)
    theirs = linalg.solve_discrete_are(fit.A.T, fit.C.T, Q, R, s=S)
    assert _rel(mine, theirs) < 1e-8
    assert riccati_residual(fit.A, fit.C, Q, R, S, mine) < 1e-9


def test_riccati_falls_back_to_scipy_when_the_doubling_cannot_run():
    # Undetectable unstable mode: no stabilizing solution; both paths must refuse, not return junk.
    A = np.diag([1.2, 0.5])
    C = np.array([[0.0, 1.0]])
    with pytest.raises((np.linalg.LinAlgError, ValueError)):
        riccati_covariance(A, C, np.zeros((2, 2)), np.eye(1))


def test_diagram_with_shared_eigendecompositions_equals_the_recomputed_one(window):
    _, _, gram = window
    models, eigen = {}, {}
    for n in (6, 8, 10):
        fit = gram.regress(n)
        models[n] = InnovationModel(fit.A, fit.B, fit.C, fit.D, np.zeros((n, fit.C.shape[0])), fit.output_covariance)
        eigen[n] = (fit.eigenvalues, fit.eigenvectors)
    shared = stabilization_diagram(models, 0.02, ModeCriteria(), eigen=eigen)
    fresh = stabilization_diagram(models, 0.02, ModeCriteria())
    for a, b in zip(shared, fresh, strict=True):
        assert a.n_states == b.n_states and len(a.poles) == len(b.poles)
        for p, q in zip(a.poles, b.poles):
            assert p.frequency_hz == pytest.approx(q.frequency_hz, rel=1e-12)
            assert p.damping_ratio == pytest.approx(q.damping_ratio, rel=1e-9, abs=1e-12)
            assert (p.stable_frequency, p.stable_damping, p.stable_shape) == (
                q.stable_frequency, q.stable_damping, q.stable_shape)
    assert sum(len(entry.poles) for entry in shared) >= 6  # the three modes at least twice
