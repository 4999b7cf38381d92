"""Eigenvalues of a state matrix moved inside the unit circle (steps 3 of the state completion).

On measured data a realization of high order carries poles on or outside the unit circle,
which are not structural modes and would make the model useless for simulation and the
estimator: they are moved inside (modulus ``min(1 / |lambda|, max_radius)``, angle kept, so the
frequency stays). Used by :mod:`.state_completion` and :mod:`.state_gram` (a module of its own
so that the two can import each other's parts without a cycle).
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import linalg

__all__ = ["stabilize_state_matrix", "stabilize_with_eigen", "MAX_BASIS_CONDITION"]


def stabilize_state_matrix(A: np.ndarray, *, max_radius: float = 0.9999) -> tuple[np.ndarray, int]:
    """Move the eigenvalues of ``A`` on or outside the unit circle inside it.

    Parameters
    ----------
    A : (n, n) real state matrix.
    max_radius : largest modulus of a moved eigenvalue, in (0, 1). Stable eigenvalues are not
        touched, however close to 1 (a lightly damped mode sampled fast has ``|lambda|``
        within 1e-4 of 1).

    Returns
    -------
    A_stable : (n, n) real, the same eigenvectors, the moved eigenvalues at modulus
        ``min(1 / |lambda|, max_radius)`` (a reflection for unstable ones).
    n_moved : how many eigenvalues were moved.
    """
    A_stable, n_moved, _ = stabilize_with_eigen(A, max_radius=max_radius)
    return A_stable, n_moved


def stabilize_with_eigen(
    A: np.ndarray, *, max_radius: float = 0.9999
) -> tuple[np.ndarray, int, tuple[np.ndarray, np.ndarray]]:
    """:func:`stabilize_state_matrix` and the eigendecomposition of the result.

    Returns ``(A_stable, n_moved, (lambda (n,), V (n, n)))`` from one ``eig`` (shared with the
    stabilization diagram).
    """
    lam, V = linalg.eig(A)
    moved = np.abs(lam) >= 1.0 - 1e-12
    if not moved.any():
        return A, 0, (lam, V)
    V_inv = _basis_inverse(V)
    if V_inv is None:
        # Defective or nearly so: no eigenbasis to work in; shrink the whole matrix instead.
        factor = max_radius / np.max(np.abs(lam))
        return A * factor, int(moved.sum()), (lam * factor, V)
    new = lam.copy()
    mod = np.abs(lam[moved])
    new[moved] = lam[moved] / mod * np.minimum(1.0 / mod, max_radius)
    A_stable = (V * new) @ V_inv
    return np.real(A_stable), int(moved.sum()), (new, V)


# An eigenbasis with a 2-norm condition number above this is taken as defective.
MAX_BASIS_CONDITION = 1e10


def _basis_inverse(V: np.ndarray) -> np.ndarray | None:
    """``inv(V)`` (n, n), or None when ``cond(V) > MAX_BASIS_CONDITION`` (2-norm) or V is singular.

    The 2-norm condition number lies between ``cond_F / n`` and ``cond_F`` (Frobenius norms of
    ``V`` and its inverse, which is needed anyway): the SVD of ``V`` is computed only when that
    bracket straddles the limit.
    """
    try:
        with warnings.catch_warnings():  # an ill-conditioned basis is refused below, by its condition number
            warnings.simplefilter("ignore", linalg.LinAlgWarning)
            V_inv = linalg.inv(V)
    except (linalg.LinAlgError, ValueError):
        return None
    if not np.all(np.isfinite(V_inv)):
        return None
    frobenius = np.linalg.norm(V) * np.linalg.norm(V_inv)
    if frobenius <= MAX_BASIS_CONDITION:
        return V_inv
    if frobenius / V.shape[0] > MAX_BASIS_CONDITION or np.linalg.cond(V) > MAX_BASIS_CONDITION:
        return None
    return V_inv
