"""The canonical-variate (CVA) realization of output-only records against known truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg, signal

from okid_bench.output_only_cases import OutputOnlyCase, score_modes
from okid_ros.core.canonical_realization import _lagged, _toeplitz_factor, canonical_decomposition
from okid_ros.core.identified_model import IdentificationError
from okid_ros.core.output_covariance import RecordSums, _lag_sums, output_correlations, record_correlations
from okid_ros.core.output_only import identify_output_only
from okid_ros.core.stochastic_realization import OrderRealizer
from okid_ros.sim.models import modal_structure


def _system(n_outputs: int = 6, seed: int = 3):
    return modal_structure([3.0, 7.0, 7.07, 12.0], 0.005, 1, n_outputs, 1 / 50, seed=seed, output="acceleration",
                           disturbance_std=1.0)


def _exact_correlations(system, n_lags: int) -> np.ndarray:
    """``R_0 .. R_n_lags`` of the system driven by its noise alone: ``R_k = C A^(k-1) G``."""
    A, C = system.A, system.C
    Q, R, S = system.process_noise_covariance, system.measurement_noise_covariance, system.cross_covariance
    sigma = linalg.solve_discrete_lyapunov(A, Q)
    G = A @ sigma @ C.T + S
    out = [C @ sigma @ C.T + R]
    power = np.eye(A.shape[0])
    for _ in range(n_lags):
        out.append(C @ power @ G)
        power = power @ A
    return np.array(out)


def _sorted_poles(eigenvalues: np.ndarray) -> np.ndarray:
    return np.sort_complex(eigenvalues[eigenvalues.imag > 0])


@pytest.mark.parametrize("n_outputs, references", [(6, np.arange(6)), (6, np.array([0, 2, 5])), (1, np.arange(1))])
def test_exact_correlations_give_the_true_poles_at_the_true_order(n_outputs, references) -> None:
    system = _system(n_outputs)
    block_rows = 12
    decomposition = canonical_decomposition(_exact_correlations(system, 2 * block_rows), references, block_rows, 20)
    realizer = OrderRealizer(decomposition, 8)
    A, C, G = realizer.realize(8)
    # Exact correlations give the exact poles at any block rows (the weighted H(1) is Gamma A Ctrl);
    # a regression on the states of a finite past was off by 3e-6 to 3e-2 here.
    np.testing.assert_allclose(_sorted_poles(np.linalg.eigvals(A)), _sorted_poles(np.linalg.eigvals(system.A)),
                               atol=1e-9)
    assert np.all(decomposition.s <= 1.0 + 1e-9)  # canonical correlations
    # The realized covariance model reproduces the correlations: R_k = C A^(k-1) G at the reference columns.
    exact = _exact_correlations(system, 5)
    np.testing.assert_allclose(C @ np.linalg.matrix_power(A, 3) @ G, exact[4][:, references], rtol=1e-5,
                               atol=1e-6 * np.abs(exact[4]).max())


def test_the_record_correlations_are_positive_semidefinite_where_the_segment_means_are_not() -> None:
    rng = np.random.default_rng(0)
    resonance = 0.99 * np.exp(0.3j)  # a lightly damped mode: its spectrum nearly vanishes away from the peak
    y = signal.lfilter([1.0], np.poly([resonance, np.conj(resonance)]).real, rng.standard_normal(3000))[:, None]
    lags = 120

    def smallest(correlations: np.ndarray) -> float:
        return float(np.linalg.eigvalsh(linalg.toeplitz(correlations[:, 0, 0]))[0])

    assert smallest(output_correlations(y, lags, 5).mean) < 0  # the unbiased segment means: indefinite
    assert smallest(record_correlations(y, lags)) > -1e-12
    present = np.ones(y.shape[0], bool)
    present[1000:1600] = False
    assert smallest(record_correlations(y, lags, present=present)) > -1e-12


@pytest.fixture(scope="module")
def close_pair_case():
    case = OutputOnlyCase("test", _system(), 20_000, "close pair")
    return case, case.simulate(seed=11)


def test_the_canonical_route_finds_the_simulated_close_pair(close_pair_case) -> None:
    case, y = close_pair_case
    model = identify_output_only(y, case.sample_time_s, method="ssi-cva")
    found = [{"frequency_hz": m.frequency_hz, "damping_ratio": m.damping_ratio, "shape": m.shape} for m in model.modes]
    score = score_modes(found, case.truth())
    assert model.method == "ssi-cva" and model.n_inputs == 0 and model.stability_problem() == ""
    assert score["spurious"] == 0 and len(score["modes"]) == 4
    for row in score["modes"]:
        assert abs(row["frequency_error"]) < 0.002
        assert abs(row["damping_error"]) < 0.3
        assert row["mac"] >= 0.95
    assert model.uncertainty.method == "jackknife"
    assert all(0 < m.frequency_hz_std < 0.01 * m.frequency_hz and m.damping_ratio_std > 0 for m in model.modes)


@pytest.mark.parametrize("span", [(0, 500), (1200, 1700), (2500, 3000), (10, 40)])
def test_the_record_sums_less_a_span_equal_the_correlations_with_the_span_absent(span) -> None:
    rng = np.random.default_rng(1)
    y = rng.standard_normal((3000, 3))
    present = np.ones(3000, bool)
    present[700:760] = False
    mask = present.copy()
    mask[span[0] : span[1]] = False
    expected = record_correlations(y, 60, present=mask)
    np.testing.assert_allclose(RecordSums.of(y, 60, present).without(*span), expected, rtol=1e-10,
                               atol=1e-12 * np.abs(expected).max())


@pytest.mark.parametrize("with_less", [False, True])
def test_the_lag_sums_of_one_transform_per_channel_pair_are_the_direct_sums(with_less) -> None:
    # Pairs i < j are read from the tail (negative lags) of the pair (j, i)'s inverse transform.
    rng = np.random.default_rng(4)
    y = rng.standard_normal((700, 4)) * [1.0, 3.0, 0.1, 20.0]
    less = y.copy()
    less[200:450] = 0.0
    max_lag = 30
    got = _lag_sums(y, max_lag, 1024, less=less if with_less else None)
    for k in range(max_lag + 1):
        expected = y[k:].T @ y[: y.shape[0] - k]
        if with_less:
            expected -= less[k:].T @ less[: less.shape[0] - k]
        np.testing.assert_allclose(got[k], expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())
    np.testing.assert_array_equal(got[0], got[0].T)  # exactly: the weights' Cholesky reads either triangle


def _formed_realization(correlations: np.ndarray, block_rows: int, order: int, references: np.ndarray | None = None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The textbook formulas on formed matrices, two Cholesky factors: canonical correlations, ``A``, ``C``, ``G``."""
    i, p = block_rows, correlations.shape[1]
    references = np.arange(p) if references is None else references

    def lag(k: int, rows=references) -> np.ndarray:
        return correlations[k][rows][:, references] if k >= 0 else correlations[-k][references][:, rows].T

    def blocks(index) -> np.ndarray:
        return np.block([[lag(index(a, b)) for b in range(i)] for a in range(i)])

    low_past = linalg.cholesky(blocks(lambda a, b: b - a), lower=True)
    low_future = linalg.cholesky(blocks(lambda a, b: a - b), lower=True)

    def weighted(shift: int) -> np.ndarray:
        hankel = blocks(lambda a, b: a + b + 1 + shift)
        return linalg.solve_triangular(low_future, linalg.solve_triangular(low_past, hankel.T, lower=True).T,
                                       lower=True)

    U, s, Vt = np.linalg.svd(weighted(0))
    assert references.size * i == s.size
    q = np.sqrt(s[:order])
    first_row = np.hstack([lag(b + 1, rows=np.arange(p)) for b in range(i)])  # every output
    C = first_row @ linalg.solve_triangular(low_past, Vt[:order].T, lower=True, trans="T") / q
    G = q[:, None] * (Vt[:order] @ low_past[: references.size].T)
    return s, (U[:, :order].T @ weighted(1) @ Vt[:order].T) / np.outer(q, q), C, G


def test_a_long_window_realizes_what_the_formed_weighted_hankel_does(close_pair_case) -> None:
    # 70 block rows of 6 outputs: the Gram (420 square) is ten times the 40 pairs kept, so its leading pairs
    # come alone from the tridiagonal form, and the shifted Hankel enters only through products with them.
    _, y = close_pair_case
    block_rows, top = 70, 40
    correlations = record_correlations(y - y.mean(axis=0), 2 * block_rows)
    decomposition = canonical_decomposition(correlations, np.arange(6), block_rows, top)
    s, A = _formed_realization(correlations, block_rows, 8)[:2]
    np.testing.assert_allclose(decomposition.s, s[:top], rtol=1e-10)
    realizer = OrderRealizer(decomposition, top)
    np.testing.assert_allclose(_sorted_poles(realizer.eigenvalues(8)), _sorted_poles(np.linalg.eigvals(A)), atol=1e-10)
    for order in (16, 24):  # noise poles too, where the singular values are apart
        expected = np.linalg.eigvals(_formed_realization(correlations, block_rows, order)[1])
        np.testing.assert_allclose(np.sort_complex(realizer.eigenvalues(order)), np.sort_complex(expected), atol=1e-8)


def test_one_factor_whitening_the_past_and_the_future_realizes_what_two_did(close_pair_case) -> None:
    # The future whitened by the past's factor with its block rows reversed: the same canonical correlations
    # and, up to a change of state basis, the same A, C and G as with the future's own Cholesky factor. Three
    # references of six outputs, a Gram (180 square) 7.5 times the 24 pairs kept.
    _, y = close_pair_case
    block_rows, top, order, references = 60, 24, 8, np.array([0, 2, 5])
    correlations = record_correlations(y - y.mean(axis=0), 2 * block_rows)
    decomposition = canonical_decomposition(correlations, references, block_rows, top)
    s, A, C, G = _formed_realization(correlations, block_rows, order, references)
    np.testing.assert_allclose(decomposition.s, s[:top], rtol=1e-10)
    A_new, C_new, G_new = OrderRealizer(decomposition, top).realize(order)
    np.testing.assert_allclose(_sorted_poles(np.linalg.eigvals(A_new)), _sorted_poles(np.linalg.eigvals(A)), atol=1e-10)
    for power in (0, 1, 5):  # the covariance model's R_(k+1) = C A^k G, invariant to the state basis
        expected = C @ np.linalg.matrix_power(A, power) @ G
        np.testing.assert_allclose(C_new @ np.linalg.matrix_power(A_new, power) @ G_new, expected, rtol=0,
                                   atol=1e-10 * np.abs(expected).max())


@pytest.mark.parametrize("references", [np.arange(6), np.array([1, 4]), np.array([3])])
def test_the_block_schur_factor_is_the_first_block_columns_of_the_dense_cholesky_factor(close_pair_case,
                                                                                         references) -> None:
    # [y_(k-i); ..; y_(k+i-1)] in time order has the block Toeplitz covariance of blocks R_(a-b); its lower
    # Cholesky factor is [[L, 0], [Sigma_fp L^-T, L2]], returned transposed by blocks (L2 only where asked for).
    _, y = close_pair_case
    block_rows = 25
    correlations = record_correlations(y - y.mean(axis=0), 2 * block_rows)
    r, n = references.size, block_rows * references.size
    lags = correlations[: 2 * block_rows][:, references][:, :, references]
    covariance = np.block([[lags[a - b] if a >= b else lags[b - a].T for b in range(2 * block_rows)]
                           for a in range(2 * block_rows)])
    factor = linalg.cholesky(covariance, lower=True)
    past, cross, future = _toeplitz_factor(_lagged(correlations, references, block_rows), block_rows,
                                           conditional=True)
    assert past.shape == cross.shape == future.shape == (n, n) and r * block_rows == n
    np.testing.assert_allclose(past, factor[:n, :n].T, rtol=0, atol=1e-11 * np.abs(factor).max())
    np.testing.assert_allclose(cross, factor[n:, :n].T, rtol=0, atol=1e-11 * np.abs(factor).max())
    np.testing.assert_allclose(future, factor[n:, n:].T, rtol=0, atol=1e-11 * np.abs(factor).max())
    for upper in (past, future):  # exactly triangular: read whole as triangular factors
        assert np.array_equal(upper, np.triu(upper))
    assert _toeplitz_factor(_lagged(correlations, references, block_rows), block_rows)[2] is None


def test_a_future_the_past_does_not_factor_leaves_the_gram_to_the_past_side() -> None:
    # R_0 = I outweighs the past's other lags, R_5 = 2 I makes the past-and-future covariance indefinite: the
    # continued Schur steps fail, the past's factor stands, and M^T M (dtrsm, dsyrk) gives the canonical
    # correlations in place of I - W W^T.
    block_rows, p = 3, 2
    correlations = 0.1 * np.random.default_rng(1).standard_normal((2 * block_rows + 1, p, p))
    correlations[0], correlations[5] = np.eye(p), 2 * np.eye(p)
    past, cross, future = _toeplitz_factor(_lagged(correlations, np.arange(p), block_rows), block_rows,
                                           conditional=True)
    assert future is None and past.shape == cross.shape == (6, 6)
    decomposition = canonical_decomposition(correlations, np.arange(p), block_rows, 6)
    s = _formed_realization(correlations, block_rows, 2)[0]
    assert decomposition.s.size >= 4
    np.testing.assert_allclose(decomposition.s, s[: decomposition.s.size], rtol=1e-10)


def test_linearly_dependent_references_have_no_canonical_weighting(close_pair_case) -> None:
    _, y = close_pair_case
    y = y - y.mean(axis=0)
    twice = np.column_stack([y, y[:, 2]])  # reference 6 repeats reference 2: a singular past covariance
    with pytest.raises(IdentificationError, match="not positive definite"):
        canonical_decomposition(record_correlations(twice, 40), np.array([0, 2, 6]), 20, 10)


def test_outputs_without_sensor_noise_keep_their_canonical_weighting() -> None:
    # Four modes seen by three accelerometers under one white force, no sensor noise: the past's covariance is
    # nearly singular. The block Schur steps' differences P0^T P0 - Q0^T Q0 lost its definiteness there (refused:
    # "not positive definite") where the dense factor the route used before takes it; the factor falls back to it.
    rng = np.random.default_rng(0)
    frequency_hz, damping = np.array([1.3, 3.1, 4.7, 7.9]), np.array([0.01, 0.02, 0.01, 0.015])
    w, dt, n_modes = 2 * np.pi * frequency_hz, 0.02, 4
    shapes = rng.standard_normal((3, n_modes))
    a = np.block([[np.zeros((n_modes, n_modes)), np.eye(n_modes)], [-np.diag(w**2), -np.diag(2 * damping * w)]])
    force = rng.standard_normal((n_modes, 1))
    b = np.vstack([np.zeros((n_modes, 1)), force])
    discrete = signal.cont2discrete((a, b, shapes @ a[n_modes:], shapes @ force), dt, method="zoh")
    _, y, _ = signal.dlsim(discrete[:4] + (dt,), rng.standard_normal((20000, 1)))
    model = identify_output_only(y, dt)
    found = np.array(sorted(mode.frequency_hz for mode in model.modes))
    assert found.size == n_modes
    np.testing.assert_allclose(found, frequency_hz, rtol=0.005)  # zoh: the record's poles are exp(s dt)
