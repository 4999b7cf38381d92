"""The output-only jackknife's replicates from the record's leading subspace against their exact decompositions."""

from __future__ import annotations

import numpy as np
import pytest

from okid_ros.core.mode_jackknife import ITERATIONS, SPARE_COLUMNS, nearest_modes
from okid_ros.core.output_covariance import output_correlations
from okid_ros.core.output_only_support import Jackknife
from okid_ros.core.stochastic_realization import (
    covariance_decomposition,
    hankel_grams,
    leading_eigh,
    subspace_eigh,
)
from okid_ros.sim.models import modal_structure
from okid_ros.sim.simulators import simulate_noisy

SAMPLE_TIME_S = 1 / 50
FREQUENCIES_HZ = (1.0, 2.5, 6.0, 11.0)
DAMPING = 0.01
#: Hankel block rows, references (5 outputs) and the highest order: a 250-square Gram, large
#: enough for the replicates' block power iterations (2 ITERATIONS (40 + SPARE_COLUMNS) < 250).
BLOCK_ROWS, TOP = 50, 40


@pytest.fixture(scope="module")
def correlations():
    """Eight segments' correlations of a simulated ambient record of four modes, 5 outputs, 600 s."""
    system = modal_structure(FREQUENCIES_HZ, DAMPING, 1, 5, SAMPLE_TIME_S, seed=2, output="acceleration",
                             disturbance_std=1.0)
    y = simulate_noisy(system, np.zeros((30_000, 1)), seed=4)
    return output_correlations(y - y.mean(axis=0), 2 * BLOCK_ROWS, 8)


def _true_poles() -> np.ndarray:
    s = [2j * np.pi * f * np.sqrt(1 - DAMPING**2) - DAMPING * 2 * np.pi * f for f in FREQUENCIES_HZ]
    return np.exp(np.array(s) * SAMPLE_TIME_S)


def test_subspace_eigh_gives_a_replicates_leading_pairs_from_the_records(correlations) -> None:
    """Pairs far above the noise floor equal ``leading_eigh``'s to rounding; the rest are Ritz pairs below them."""
    references = np.arange(5)
    record = covariance_decomposition(correlations.mean, references, BLOCK_ROWS, TOP, spare=SPARE_COLUMNS)
    assert record.basis.shape == (BLOCK_ROWS * 5, TOP + SPARE_COLUMNS) and record.s.size == TOP
    gram, _ = hankel_grams(correlations.leave_one_out(2)[1 : 2 * BLOCK_ROWS + 1][:, :, references], BLOCK_ROWS)
    exact, exact_vectors = leading_eigh(gram, TOP + SPARE_COLUMNS + 1)
    values, vectors = subspace_eigh(gram, record.basis, TOP, iterations=ITERATIONS)
    assert values.shape == (TOP,) and vectors.shape == (gram.shape[0], TOP)
    # The modes' pairs (8: four modes) stand 1e5 above the (c + 1)-th eigenvalue: converged. Without
    # the power iterations (the record's subspace as it is) they are off by 3e-6.
    above = exact[:TOP] > 1e3 * exact[-1]
    assert np.sum(above) >= 2 * len(FREQUENCIES_HZ)
    np.testing.assert_allclose(values[above], exact[:TOP][above], rtol=1e-12)
    assert np.all(np.abs(np.sum(vectors[:, above] * exact_vectors[:, :TOP][:, above], axis=0)) > 1 - 1e-12)
    # Ritz values lie below the eigenvalues (Cauchy interlacing), largest first, orthonormal vectors.
    assert np.all(values <= exact[:TOP] * (1 + 1e-12)) and np.all(np.diff(values) <= 0)
    np.testing.assert_allclose(vectors.T @ vectors, np.eye(TOP), atol=1e-12)
    with pytest.raises(ValueError, match="start"):
        subspace_eigh(gram, record.basis[:-1], TOP, iterations=ITERATIONS)
    with pytest.raises(ValueError, match="start"):
        subspace_eigh(gram, record.basis, TOP + SPARE_COLUMNS + 1, iterations=ITERATIONS)


def test_jackknife_from_the_records_subspace_reads_the_exact_replicates_modes(correlations) -> None:
    """Each replicate's modes at the structure's order, and the standard deviations, as the exact replicates'."""
    references = np.arange(5)
    record = covariance_decomposition(correlations.mean, references, BLOCK_ROWS, TOP, spare=SPARE_COLUMNS)
    exact = Jackknife(correlations, references, BLOCK_ROWS, TOP)
    fast = Jackknife(correlations, references, BLOCK_ROWS, TOP, start=record.basis)
    truth, n_modes = _true_poles(), 2 * len(FREQUENCIES_HZ)
    for slow, quick in zip(exact.realizers, fast.realizers):
        assert quick.max_states == slow.max_states == TOP
        f_exact, z_exact = nearest_modes(slow.eigenvalues(n_modes), truth, SAMPLE_TIME_S)
        f_fast, z_fast = nearest_modes(quick.eigenvalues(n_modes), truth, SAMPLE_TIME_S)
        np.testing.assert_allclose(f_fast, f_exact, rtol=1e-10)
        np.testing.assert_allclose(z_fast, z_exact, rtol=1e-9)
    # A few orders higher the noise floor's directions enter, approximated: the spread moves by 1e-5.
    for spread, spread_exact in zip(fast.std(truth, 12, SAMPLE_TIME_S), exact.std(truth, 12, SAMPLE_TIME_S)):
        np.testing.assert_allclose(spread, spread_exact, rtol=1e-3)


def test_a_small_gram_is_decomposed_from_scratch(correlations) -> None:
    """Where the iterations would cost as much as the tridiagonal route (2 ITERATIONS c >= i r) nothing changes."""
    references, rows, top = np.arange(5), 20, 16  # a 100-square Gram, c = 26
    record = covariance_decomposition(correlations.mean, references, rows, top, spare=SPARE_COLUMNS)
    replicate = correlations.leave_one_out(5)
    fast = covariance_decomposition(replicate, references, rows, top, start=record.basis, iterations=ITERATIONS)
    exact = covariance_decomposition(replicate, references, rows, top)
    assert np.array_equal(fast.s, exact.s) and np.array_equal(fast.shifted, exact.shifted)
    assert exact.basis is None
    with pytest.raises(ValueError, match="rows"):
        covariance_decomposition(replicate, references, rows + 1, top, start=record.basis, iterations=ITERATIONS)
