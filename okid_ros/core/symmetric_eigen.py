"""The eigendecomposition of a symmetric matrix with its eigenvectors kept factored.

``M = V diag(values) V^T`` with ``V = Q Z``: ``Q`` the Householder reflectors of the tridiagonal
form ``T = Q^T M Q`` (LAPACK ``dsytrd``) and ``Z`` the eigenvectors of ``T`` (``dstevd``,
divide and conquer). ``scipy.linalg.eigh`` forms ``V`` by applying ``Q`` to all ``m`` columns of
``Z`` (``2 m^3`` flops, about a third of the whole); the users here need ``V`` only on a few
vectors: ``V^T b`` and ``V c`` for the ridge fit's right-hand sides
(:func:`okid_ros.core.least_squares.solve_normal_equations`), or the leading columns of ``V``
(:func:`okid_ros.core.stochastic_realization.leading_eigh`). SciPy offers no eigensolver that
returns the factored form, so the three LAPACK routines are called directly.
"""

from __future__ import annotations

import numpy as np
from scipy import linalg
from scipy.linalg import lapack

__all__ = ["SymmetricEigen", "LARGEST_ALONE_RATIO"]

#: A few largest pairs are taken alone from the tridiagonal form (MRRR, ``dstemr``) where the matrix
#: is at least this many times their number: ``dstevd`` forms all ``m`` tridiagonal vectors
#: (``m^3``), MRRR only those asked for, but it is the slower of the two on small matrices (k = 100
#: of a canonical-variate Gram: even near m = 550, twice as fast at 1000; docs/benchmarks-output-only.md,
#: forty-fourth session).
LARGEST_ALONE_RATIO = 6


class SymmetricEigen:
    """Eigenvalues (ascending) of a symmetric matrix, and products with its eigenvectors.

    Parameters
    ----------
    matrix : (m, m) symmetric (its lower triangle is read), finite.
    largest : only the ``largest`` greatest pairs are wanted: ``values`` (ascending) and
        :meth:`vectors` hold just those where ``m >= LARGEST_ALONE_RATIO * largest`` (then
        :meth:`project` and :meth:`expand` are with those vectors alone); None: every pair.
    overwrite : the reduction may use ``matrix``'s storage (no copy of a Fortran-ordered one); its
        contents are then undefined.

    Raises
    ------
    ValueError on NaN or Inf (as ``scipy.linalg.eigh``); numpy.linalg.LinAlgError when LAPACK fails.
    """

    def __init__(self, matrix: np.ndarray, *, largest: int | None = None, overwrite: bool = False) -> None:
        matrix = np.asarray_chkfinite(matrix, dtype=float)
        m = matrix.shape[0]
        self.size = m
        self._reflectors = self._tau = None
        if m < 2:  # no reflector: V is Z
            self.values, self._z = linalg.eigh(matrix)
            return
        lwork = int(lapack.dsytrd_lwork(m, lower=1)[0])
        self._reflectors, diagonal, off_diagonal, self._tau, info = lapack.dsytrd(
            matrix, lower=1, lwork=lwork, overwrite_a=overwrite)
        if info:
            raise np.linalg.LinAlgError(f"symmetric eigendecomposition failed (dsytrd {info})")
        if largest is not None and 0 < largest and m >= LARGEST_ALONE_RATIO * largest:
            try:  # scipy's default for a subset is bisection and inverse iteration (stebz, stein): 1.4 times slower
                self.values, self._z = linalg.eigh_tridiagonal(diagonal, off_diagonal, select="i",
                                                               select_range=(m - largest, m - 1), check_finite=False,
                                                               lapack_driver="stemr")
                return
            except linalg.LinAlgError:  # MRRR's rare failure to separate a cluster: every pair by divide and conquer
                pass
        self.values, self._z, info_d = lapack.dstevd(diagonal, off_diagonal)
        if info_d:
            raise np.linalg.LinAlgError(f"symmetric eigendecomposition failed (dstevd {info_d})")

    def _apply_q(self, x: np.ndarray, transpose: bool) -> np.ndarray:
        """``Q x`` or ``Q^T x`` for x (m, k)."""
        out = np.array(x, dtype=float, order="F", copy=True)
        if self._reflectors is None or out.shape[1] == 0:
            return out
        m = self.size
        # Q = H(1) .. H(m-1) of dsytrd (lower) is the Q of a QR factorization of reflectors[1:, :m-1]
        # acting on rows 1.. (what dormtr does; scipy wraps dormqr only).
        applied, _, info = lapack.dormqr(b"L", b"T" if transpose else b"N", self._reflectors[1:, : m - 1],
                                         self._tau, out[1:], max(1, 64 * out.shape[1]))
        if info:
            raise np.linalg.LinAlgError(f"symmetric eigendecomposition failed (dormqr {info})")
        out[1:] = applied
        return out

    def project(self, b: np.ndarray) -> np.ndarray:
        """``V^T b``: b (m,) or (m, k)."""
        b = np.asarray(b, dtype=float)
        out = self._z.T @ self._apply_q(b.reshape(self.size, -1), transpose=True)
        return out.reshape(b.shape)

    def expand(self, c: np.ndarray) -> np.ndarray:
        """``V c``: c (m,) or (m, k)."""
        c = np.asarray(c, dtype=float)
        out = self._apply_q(self._z @ c.reshape(self.size, -1), transpose=False)
        return out.reshape(c.shape)

    def vectors(self, columns: np.ndarray) -> np.ndarray:
        """The eigenvectors ``V[:, columns]`` (m, len(columns)), of ``values[columns]``."""
        return self._apply_q(self._z[:, np.asarray(columns)], transpose=False)
