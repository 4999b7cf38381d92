"""The factored symmetric eigendecomposition against scipy.linalg.eigh, and the ridge fit built on it."""

import numpy as np
import pytest
from scipy import linalg

from okid_ros.core.least_squares import NormalEquations, solve_normal_equations
from okid_ros.core.symmetric_eigen import LARGEST_ALONE_RATIO, SymmetricEigen


@pytest.mark.parametrize("size", [1, 2, 7, 60])
def test_values_and_products_equal_those_of_eigh(size):
    rng = np.random.default_rng(size)
    x = rng.standard_normal((2 * size + 3, size))
    matrix = x.T @ x
    eigen = SymmetricEigen(matrix)
    values, vectors = linalg.eigh(matrix)
    np.testing.assert_allclose(eigen.values, values, rtol=0, atol=1e-12 * values.max())
    # Vectors are unique up to sign (the spectrum here is simple): compare V^T b and V c through V.
    signs = np.sign(np.sum(eigen.vectors(np.arange(size)) * vectors, axis=0))
    b, c = rng.standard_normal((size, 3)), rng.standard_normal(size)
    np.testing.assert_allclose(eigen.project(b), signs[:, None] * (vectors.T @ b), atol=1e-10)
    np.testing.assert_allclose(eigen.expand(c), vectors @ (signs * c), atol=1e-10)
    np.testing.assert_allclose(eigen.expand(eigen.project(b)), b, atol=1e-10)


def test_a_matrix_with_nan_is_refused_like_eigh():
    with pytest.raises(ValueError):
        SymmetricEigen(np.array([[1.0, np.nan], [np.nan, 1.0]]))


def _full_precision(rng) -> np.ndarray:
    """A correlated prior's precision (the "tc" kind's shape: nothing is zero off the diagonal)."""
    x = rng.standard_normal((30, 12))
    return x.T @ x / 30 + np.eye(12)


@pytest.mark.parametrize("kind", ["diagonal", "full"])
def test_the_ridge_fit_solves_its_own_regularized_equations(kind):
    # The diagonal precision is whitened by a scaling, the full one by triangular solves.
    rng = np.random.default_rng(3)
    phi, y = rng.standard_normal((400, 12)), rng.standard_normal((400, 2))
    normal = NormalEquations(phi.T @ phi, phi.T @ y, y.T @ y, 400)
    precision = np.diag(rng.uniform(0.5, 2.0, 12)) if kind == "diagonal" else _full_precision(rng)
    theta, penalty, _, _ = solve_normal_equations(normal, precision, "gcv")
    expected = linalg.solve(normal.R + penalty * precision, normal.r)  # the precision is the penalty's matrix
    np.testing.assert_allclose(theta, expected, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("bad, error", [(0.0, linalg.LinAlgError), (-1.0, linalg.LinAlgError),
                                        (np.nan, ValueError), (np.inf, ValueError)])
def test_a_diagonal_precision_that_is_not_positive_is_refused_as_cholesky_refuses_it(bad, error):
    rng = np.random.default_rng(4)
    phi, y = rng.standard_normal((50, 3)), rng.standard_normal((50, 1))
    normal = NormalEquations(phi.T @ phi, phi.T @ y, y.T @ y, 50)
    precision = np.diag([1.0, bad, 2.0])
    with pytest.raises(error):
        linalg.cholesky(precision, lower=True)
    with pytest.raises(error):
        solve_normal_equations(normal, precision, 1.0)


@pytest.mark.parametrize("largest", [1, 6])
def test_the_largest_pairs_alone_are_those_of_eigh(largest):
    # A matrix LARGEST_ALONE_RATIO times the pairs asked for: only those are computed (MRRR on the tridiagonal form).
    size = LARGEST_ALONE_RATIO * largest + 3
    rng = np.random.default_rng(largest)
    x = rng.standard_normal((size + 5, size))
    matrix = x.T @ x
    eigen = SymmetricEigen(matrix, largest=largest)
    values, vectors = linalg.eigh(matrix)
    assert eigen.values.shape == (largest,)
    np.testing.assert_allclose(eigen.values, values[-largest:], rtol=0, atol=1e-12 * values.max())
    found = eigen.vectors(np.arange(largest))
    signs = np.sign(np.sum(found * vectors[:, -largest:], axis=0))
    np.testing.assert_allclose(found * signs, vectors[:, -largest:], atol=1e-10)
    # Below the ratio every pair is computed, as without ``largest``.
    small = matrix[: size - 4, : size - 4]
    np.testing.assert_array_equal(SymmetricEigen(small, largest=largest).values, SymmetricEigen(small).values)


def test_the_largest_pairs_come_from_every_pair_where_mrrr_fails(monkeypatch):
    size, largest = LARGEST_ALONE_RATIO * 4 + 3, 4
    rng = np.random.default_rng(7)
    x = rng.standard_normal((size + 5, size))
    matrix = x.T @ x

    def failing(*args, **kwargs):
        raise linalg.LinAlgError("dstemr failed")

    monkeypatch.setattr(linalg, "eigh_tridiagonal", failing)
    eigen = SymmetricEigen(matrix, largest=largest)
    values, vectors = np.linalg.eigh(matrix)
    np.testing.assert_allclose(eigen.values[-largest:], values[-largest:], rtol=0, atol=1e-12 * values.max())
    found = eigen.vectors(np.arange(eigen.values.size - largest, eigen.values.size))
    np.testing.assert_allclose(np.abs(np.sum(found * vectors[:, -largest:], axis=0)), 1.0, atol=1e-10)
