"""Canonical-variate (CVA) weighted realization: ``(A, C)`` of every order from the weighted Hankel.

The covariance route of :mod:`.stochastic_realization` realizes the unweighted Hankel of the
output correlations, which is not an efficient estimator (docs/benchmarks-output-only.md,
"What the records allow"). Canonical-variate analysis (Larimore 1990; Bauer & Ljung 2002, Bauer
2005 "Asymptotic properties of subspace estimators", Automatica 41) weights the past/future
covariance Hankel by inverse factors of the past and the future covariances. Without observed
inputs every quantity is a product of output correlations ``R_k`` (reference channels ``r`` of
``p``, ``i`` block rows)::

    z_k  = [y_(k-1); ..; y_(k-i)],  y+_k = [y_k; ..; y_(k+i-1)]   (references)
    Sigma_pp = E[z_k z_k^T] = L_p L_p^T,   Sigma_ff = E[y+_k y+_k^T] = J Sigma_pp J = (J L_p) (J L_p)^T
    H(0) = E[y+_k z_k^T] (blocks R_(a+b+1)),   H(1) = E[y+_(k+1) z_k^T] (blocks R_(a+b+2))
    L_p^-1 J H(0) L_p^-T = U S V^T,   A = S^-1/2 U^T L_p^-1 J H(1) L_p^-T V S^-1/2

(ERA on the weighted Hankels: ``H(1) = Gamma A Ctrl`` exactly, so ``A`` is exact for exact
correlations at any ``i``), ``C`` the first block row of the observability
``H(0) L_p^-T V S^-1/2`` (every output) and ``G`` the first block column of ``S^1/2 V^T L_p^T``.
``J`` reverses the block rows: the future is the past read backwards, so one Cholesky factor
whitens both, and ``J H(0)`` is block Toeplitz (blocks ``R_(i-a+b)``). Any factor ``F`` of
``Sigma_ff = F F^T`` gives the same ``S``, ``V`` and ``A``: ``F^-1 = Q L_f^-1`` (``L_f`` the
future's Cholesky factor, ``Q`` orthogonal) only turns ``U`` into ``Q U``.
Every order's ``A`` is a corner of one matrix, so the same
:class:`~.stochastic_realization.OrderRealizer` reads the orders, the diagram, the screening and
the jackknife. ``A`` by regression on the states ``x_k = S^1/2 V^T L_p^-1 z_k`` (the textbook
CVA) was measured too and rejected: states of a finite past are not the Kalman filter's, and a
weakly observed mode's damping came out up to 8 times its own. The correlations must be the
record's **biased** ones (:func:`.output_covariance.record_correlations`): their block Toeplitz
matrices are positive semidefinite and consistent with one another, which the unbiased segment
means are not (their past covariance is indefinite on a one-channel record).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg
from scipy.linalg import blas

from okid_ros.core.identified_model import IdentificationError
from okid_ros.core.output_covariance import OutputCorrelations, RecordSums
from okid_ros.core.stochastic_realization import CovarianceDecomposition, leading_eigh

__all__ = ["CanonicalDecomposition", "CanonicalWeights", "canonical_decomposition", "canonical_replicates"]


@dataclass(frozen=True)
class CanonicalWeights:
    """The lower Cholesky factor ``L_p`` (i r square) of the past covariance, which whitens the future too.

    The future's covariance is the past's with its block rows and columns reversed,
    ``Sigma_ff = J Sigma_pp J`` (blocks ``R_(a-b)`` and ``R_(b-a)``), so ``J L_p`` is a factor of
    it: ``L_p^-1 J`` whitens the future. It differs from ``L_f^-1`` by an orthogonal matrix on the
    left (``L_p^-1 J L_f``), which leaves the weighted Hankel's singular values and right vectors,
    and ``A``, ``C``, ``G``, as they are; one Cholesky factor instead of two.
    """

    low_past: np.ndarray

    @classmethod
    def of(cls, lagged: np.ndarray, block_rows: int) -> CanonicalWeights:
        """The factor of the block Toeplitz past covariance of ``lagged`` (:func:`_lagged`).

        Raises IdentificationError when it is not positive definite (references that are
        linearly dependent).
        """
        try:  # blocks R_(b-a); symmetric, so its transpose is itself in Fortran order: factored in place
            low_past = linalg.cholesky(_block_matrix(lagged, block_rows, block_rows, -1, 1).T, lower=True,
                                       overwrite_a=True, check_finite=False)
        except linalg.LinAlgError:
            raise IdentificationError("the reference channels' covariance is not positive definite: "
                                      "no canonical-variate weighting") from None
        return cls(low_past)

    def weighted_transpose(self, reversed_hankel: np.ndarray) -> np.ndarray:
        """``(L_p^-1 J H L_p^-T)^T`` (i r square, Fortran order) of ``J H`` (the Hankel ``H``'s block rows reversed)."""
        right = blas.dtrsm(1.0, self.low_past, reversed_hankel.T, side=1, lower=1, trans_a=1)  # H^T J L_p^-T
        return blas.dtrsm(1.0, self.low_past, right, lower=1, overwrite_b=1)

    def future_transform(self, x: np.ndarray) -> np.ndarray:
        """``L_p^-1 x`` (i r, c): the future's whitening of ``x`` with its block rows reversed."""
        return linalg.solve_triangular(self.low_past, x, lower=True, overwrite_b=True, check_finite=False)

    def past_transform(self, x: np.ndarray) -> np.ndarray:
        """``L_p^-T x`` (i r, c)."""
        return linalg.solve_triangular(self.low_past, x, lower=True, trans="T", check_finite=False)


@dataclass
class CanonicalDecomposition(CovarianceDecomposition):
    """The weighted Hankel's leading singular values and the realization of every order up to ``len(s)``.

    :class:`~.stochastic_realization.CovarianceDecomposition`'s fields, read by
    :class:`~.stochastic_realization.OrderRealizer` as there (with ``q = sqrt(s)``: ``A = shifted /
    (q q^T)``, ``C = first_rows q``, ``G = q Vt[:, :r]``), of the weighted Hankel:

    Attributes
    ----------
    s : (k,) canonical correlations (descending, at most 1).
    shifted : (k, k) ``U^T L_p^-1 J H(1) L_p^-T V``.
    first_rows : (p, k) ``[R_1 .. R_i] T / s`` (``T = L_p^-T V``), every output.
    Vt : (k, r) ``V^T L_p^T`` at the first block's columns.
    transform : (i r, k) ``T``.
    """

    transform: np.ndarray | None = field(default=None, repr=False)

    @property
    def max_states(self) -> int:
        """Every singular value kept (those below ``1e-7`` of the first were dropped)."""
        return int(self.s.size)

    def left_vectors(self, n_states: int) -> np.ndarray:
        """``H(0) T / s`` (i p, n), every output (the observability divided by ``sqrt(s)``)."""
        if self._left is None:
            i, (_, p, r) = self.block_rows, self.blocks.shape
            index = np.arange(i)[:, None] + np.arange(i)[None, :]
            hankel = self.blocks[index].transpose(0, 2, 1, 3).reshape(i * p, i * r)
            self._left = (hankel @ self.transform) / self.s
        return self._left[:, :n_states]


def _block_matrix(lagged: np.ndarray, block_rows: int, start: int, row_step: int, column_step: int) -> np.ndarray:
    """(i r, i r) the block matrix whose block ``(a, b)`` is ``lagged[start + row_step a + column_step b]``.

    Steps of +-1 (block Toeplitz and Hankel): each block row is a run of consecutive blocks of
    ``lagged`` laid side by side, so the matrix is a strided view of that one wide row, copied by
    rows (fancy indexing the (i, i) blocks and transposing them took 10-20 times as long).
    """
    i, r = block_rows, lagged.shape[1]
    if column_step < 0:  # the blocks in reverse: lagged[K - 1 - k] at k
        lagged, start, row_step = lagged[::-1], lagged.shape[0] - 1 - start, -row_step
    wide = lagged.transpose(1, 0, 2).reshape(r, -1)  # block k of lagged at columns k r ..
    first = start + min(0, row_step * (i - 1))  # the leftmost block row's first block
    if first < 0 or first + abs(row_step) * (i - 1) + i > lagged.shape[0]:
        raise ValueError(f"blocks {start} + {row_step} a + {column_step} b are not all in 0 .. {lagged.shape[0] - 1}")
    rows = np.lib.stride_tricks.as_strided(wide[:, first * r :], shape=(i, r, i * r),
                                           strides=(abs(row_step) * r * wide.strides[1], *wide.strides),
                                           writeable=False)
    return (rows if row_step >= 0 else rows[::-1]).reshape(i * r, i * r)


def _lagged(correlations: np.ndarray, references: np.ndarray, block_rows: int) -> np.ndarray:
    """(3 i + 1, r, r) ``R_k`` at the references, ``lagged[i + k] = R_k`` for k = -i .. 2 i."""
    i = block_rows
    ref = correlations[: 2 * i + 1][:, references][:, :, references]  # (2 i + 1, r, r), R_0 .. R_2i
    return np.concatenate([ref[i:0:-1].transpose(0, 2, 1), ref])


def canonical_decomposition(correlations: np.ndarray, references: np.ndarray, block_rows: int,
                            max_states: int) -> CanonicalDecomposition:
    """The CVA-weighted realization of the module docstring from the record's biased correlations.

    Parameters
    ----------
    correlations : (L + 1, p, p) ``R_0 .. R_L``, ``L >= 2 i``, biased
        (:func:`.output_covariance.record_correlations`).
    references : (r,) the reference channels (past and future).
    block_rows : i, the past's and the future's length.
    max_states : keep this many singular triplets at most.

    Raises IdentificationError when a covariance is not positive definite (references that are
    linearly dependent).
    """
    i = int(block_rows)
    lagged = _lagged(correlations, references, i)
    r = lagged.shape[1]
    weights = CanonicalWeights.of(lagged, i)
    reversed_hankel = _block_matrix(lagged, i, 2 * i, -1, 1)  # J H(0): block (a, b) is R_(i-a+b)
    weighted = weights.weighted_transpose(reversed_hankel)  # M^T, M = L_p^-1 J H(0) L_p^-T
    # M^T M's lower triangle, all the eigensolver reads (dsyrk: half a product's flops); its
    # leading pairs alone from the tridiagonal form where that is cheaper (a long record's lags).
    values, V = leading_eigh(blas.dsyrk(1.0, weighted, lower=1), int(min(max_states, i * r)), alone=True)
    s = np.sqrt(np.maximum(values, 0.0))
    keep = s > s[0] * 1e-7 if s.size else s.astype(bool)  # the Gram squares the condition number
    s, V = s[keep], V[:, keep]
    transform = weights.past_transform(V)
    # U = M V / s, so U^T M(1) V = (M V)^T L_p^-1 J H(1) T / s: products with k columns, M(1) never formed.
    # J H(1)'s block row 0 is H(1)'s last, R_(i+1) .. R_2i, its block row a J H(0)'s a - 1.
    last_row = lagged[2 * i + 1 :].transpose(1, 0, 2).reshape(r, i * r)
    future = weights.future_transform(np.vstack([last_row @ transform, reversed_hankel[: (i - 1) * r] @ transform]))
    shifted = ((weighted.T @ V).T @ future) / s[:, None]
    first_row = correlations[1 : i + 1].transpose(1, 0, 2)[:, :, references].reshape(correlations.shape[1], i * r)
    return CanonicalDecomposition(blocks=correlations[1 : 2 * i + 1][:, :, references], block_rows=i, s=s,
                                  Vt=V.T @ weights.low_past[:r].T, shifted=shifted,
                                  first_rows=(first_row @ transform) / s, transform=transform)


def canonical_replicates(sums: RecordSums, segments: OutputCorrelations, references: np.ndarray, block_rows: int,
                         max_states: int) -> Callable[[int], CanonicalDecomposition]:
    """``replicate(j)``: the decomposition of the record with segment ``j`` of ``segments`` marked absent.

    The jackknife's replicates (:class:`.output_only_support.Jackknife`, ``decompose=``), each from
    the biased correlations of the whole record (``sums``, lags ``2 block_rows``) less one segment.
    """
    def replicate(j: int) -> CanonicalDecomposition:
        return canonical_decomposition(sums.without(*segments.spans[j]), references, block_rows, max_states)

    return replicate
