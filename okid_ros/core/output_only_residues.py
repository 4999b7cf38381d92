"""Listed modes' shapes from a pole-residue fit of the record's output correlations.

Given the poles, the output correlations are linear in the modes' residues: with ``R_k = E[y_(t+k)
y_t^T]`` restricted to the reference columns,

    R_k = sum_j X_j lambda_j^(k-1) + conj(X_j) conj(lambda_j)^(k-1),   k = 1 .. L,

where ``X_j = phi_j g_j^T`` (p, r) is mode j's residue: its output shape ``phi_j`` times its
reference participation ``g_j``. With every pole of the model fixed (the listed modes' and the
model's others, so that no listed residue takes in what they carry), one least-squares solve over
every lag gives all residues at once (the time-domain least-squares residue fit of experimental
modal analysis, LSFD's second stage); a mode's shape is its residue's first left singular vector.

Why not the realization's ``C psi_j``: of two close poles the eigenvectors are ill-conditioned,
and the error of the weaker pole's eigenvector is mostly along its partner's; where the partner's
response is much the larger (twin chains, one chain forced) the weaker mode was listed with a
shape that was mostly its partner's. The fit asks of each pole only the part of the correlations
its own decay and phase explain, with no assumption on how the true shapes lie to each other.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.modal import phase_reference_row

__all__ = ["residues", "fit_residue_shapes"]


def residues(correlations: np.ndarray, eigenvalues: np.ndarray, references: np.ndarray) -> np.ndarray:
    """The least-squares residues ``X_j`` (J, p, r) of the poles ``eigenvalues`` in the correlations ``R_1 .. R_L``.

    Parameters
    ----------
    correlations : (L + 1, p, p) ``R_0 .. R_L`` (``R_0`` is not fitted: it holds the measurement noise).
    eigenvalues : (J,) discrete poles, one of each pair (a real pole's residue comes out real).
    references : (r,) the reference columns fitted.

    Examples
    --------
    >>> lam = np.array([0.9 * np.exp(0.3j)])
    >>> X = np.array([[1.0 + 0.5j], [2.0 - 1.0j]])
    >>> R = np.stack([2 * (X * lam[0] ** (k - 1)).real if k else np.eye(2)[:, :1] for k in range(30)])
    >>> R = np.concatenate([R, np.zeros_like(R)], axis=2)
    >>> bool(np.allclose(residues(R, lam, np.array([0]))[0], X))
    True
    """
    lags = np.arange(correlations.shape[0] - 1, dtype=float)  # k - 1 for k = 1 .. L
    powers = eigenvalues[None, :] ** lags[:, None]  # (L, J)
    real = np.isclose(eigenvalues.imag, 0.0)
    # Real unknowns: a complex pole contributes 2 Re(X lam^k) = 2 Re X Re lam^k - 2 Im X Im lam^k.
    basis = np.concatenate([np.where(real, 1.0, 2.0) * powers.real, -2.0 * powers[:, ~real].imag], axis=1)
    target = correlations[1:][:, :, references].reshape(lags.size, -1)
    # Scaled columns: poles of very different decay give columns of very different size.
    norms = np.maximum(np.linalg.norm(basis, axis=0), np.finfo(float).tiny)
    solution = np.linalg.lstsq(basis / norms, target, rcond=None)[0] / norms[:, None]
    shape = (eigenvalues.size,) + correlations.shape[1:2] + (references.size,)
    found = solution[:eigenvalues.size].reshape(shape).astype(complex)
    found[~real] += 1j * solution[eigenvalues.size:].reshape((-1,) + shape[1:])
    return found


def fit_residue_shapes(modes: list, correlations: np.ndarray, eigenvalues: np.ndarray, references: np.ndarray
                       ) -> list:
    """Give each listed mode the shape of its least-squares residue (the module's fit); the same objects back.

    Parameters
    ----------
    modes : listed modes (:class:`~okid_ros.core.modal.Mode`: ``eigenvalue`` its pole in the model,
        ``shape`` unit norm, replaced in place).
    correlations : (L + 1, p, p) the record's output correlations, in the units of the shapes.
    eigenvalues : every eigenvalue of the model (the listed modes' among them).
    references : (r,) reference columns.
    """
    poles = np.asarray(eigenvalues, complex)
    poles = poles[poles.imag >= 0]
    if not modes or modes[0].shape.size < 2 or poles.size == 0:
        return modes  # one output: a shape is a sign
    fitted = residues(correlations, poles, np.asarray(references, int))
    for mode in modes:
        residue = fitted[int(np.argmin(np.abs(poles - mode.eigenvalue)))]
        left, singular, _ = np.linalg.svd(residue, full_matrices=False)
        if not singular[0] > 0 or not np.all(np.isfinite(left[:, 0])):
            continue  # nothing of the mode in the correlations: the realization's shape stays
        shape = left[:, 0]
        mode.shape = shape * np.exp(-1j * np.angle(shape[phase_reference_row(shape)]))
    return modes
