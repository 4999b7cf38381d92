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
whitens both. Any factor ``F`` of ``Sigma_ff = F F^T`` gives the same ``S``, ``V`` and ``A``:
``F^-1 = Q L_f^-1`` (``L_f`` the future's Cholesky factor, ``Q`` orthogonal) only turns ``U``
into ``Q U``. The factor used is ``L`` of the past in time order, ``J z_k``, whose covariance is
the future's; with ``L = J L_p Q`` (``Q`` orthogonal) the weighted Hankel
``L^-1 H(0) J L^-T = Q^T M Q`` and the past's directions ``J L^-T (Q^T V) = L_p^-T V`` are the
module's. ``L`` and ``H(0) J L^-T`` are the first ``i`` block columns of the Cholesky factor of
the block Toeplitz covariance of past and future together, which the block Schur algorithm
makes without a dense factor or solve (:func:`_toeplitz_factor`). Its last ``i`` block columns,
``L2``, factor the future's covariance given the past, so ``M M^T = I - W W^T`` with ``W = L^-1
L2`` a product of triangular matrices: ``U`` comes from that Gram at a third of the flops of
``M`` and ``M^T M`` (:func:`_reversed_conditional_gram`), ``V = M^T U / s``.
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

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg
from scipy.linalg import blas, lapack

from okid_ros.core.identified_model import IdentificationError
from okid_ros.core.output_covariance import OutputCorrelations, RecordSums
from okid_ros.core.stochastic_realization import CovarianceDecomposition, leading_eigh

__all__ = ["CanonicalDecomposition", "canonical_decomposition", "canonical_replicates"]


def _checked(result: tuple) -> np.ndarray:
    """The array of a LAPACK call's ``(array, info)``; LinAlgError where ``info`` is not 0 (not definite, singular)."""
    array, info = result
    if info:
        raise linalg.LinAlgError(f"LAPACK info {info}")
    return array


def _schur_rows(lagged: np.ndarray, block_rows: int, count: int) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(c, row)``: the block Toeplitz covariance's upper Cholesky factor's block row at column ``c``.

    The covariance of ``[y_(k-i); ..; y_(k+i-1)]`` (past, then future, in time order) is block
    Toeplitz, blocks ``R_(a-b)``. The block Schur algorithm (Kailath & Sayed 1999, "Fast reliable
    algorithms for matrices with structure", ch. 1) makes one block row of its upper factor per
    step from a generator of ``2 r`` rows: ``O(i^2 r^3)`` flops in products of ``r`` rows, where a
    dense Cholesky factor takes ``(2 i r)^3 / 3`` (scipy and LAPACK have no block Toeplitz factor:
    ``solve_toeplitz`` and ``matmul_toeplitz`` are scalar). ``row`` (r, 2 i r - c) holds the
    columns from ``c`` on, for the first ``count`` block rows; it is a buffer the next step
    overwrites. Each step's ``r``-square Cholesky factors raise LinAlgError exactly when the
    leading ``c + r`` rows' covariance is not positive definite.
    """
    i, r = block_rows, lagged.shape[1]
    width = 2 * i * r
    # Sigma - Z Sigma Z^T = P^T P - Q^T Q (Z: down one block): P the first block row R_0, R_-1 .. R_-(2i-1)
    # scaled by R_0's factor, Q the same without its first block. Block row k of the factor is P then.
    upper = linalg.cholesky(lagged[i], lower=False, check_finite=False)
    rows = linalg.solve_triangular(upper, lagged[i : 3 * i].transpose(2, 0, 1).reshape(r, width), trans="T",
                                   check_finite=False)
    rows[:, :r] = upper  # the product's rounding below the diagonal left out, here and at every step
    yield 0, rows
    # The generator (P moved right one block, over Q), contiguous, in one buffer, and each step's small arrays,
    # made once: a Python step per block row, where fresh arrays (stacks, identities) cost more than the work.
    generator_buffer = np.empty(2 * r * (width - r))
    generator = generator_buffer.reshape(2 * r, width - r)
    generator[:r], generator[r:] = rows[:, : width - r], rows[:, r:]
    step, eye = np.empty((2 * r, 2 * r)), np.eye(r)
    upper_rhs, lower_rhs = np.empty((r, 2 * r), order="F"), np.empty((r, 2 * r), order="F")
    end = count * r
    for c in range(r, end, r):
        # One J-unitary step zeroes Q's first block and leaves P's triangular: the new P is the factor's row.
        # LAPACK's own calls on these r-square blocks: scipy's checks cost more than the work here.
        p0, q0 = generator[:r, :r], generator[r:, :r]
        top = _checked(lapack.dpotrf(p0.T @ p0 - q0.T @ q0, lower=0, clean=1))
        upper_rhs[:, :r], upper_rhs[:, r:] = p0.T, -q0.T
        step[:r] = _checked(lapack.dtrtrs(top, upper_rhs, lower=0, trans=1, overwrite_b=1))
        last = c + r >= end  # the last row needs no update of Q
        if not last:
            ratio = _checked(lapack.dtrtrs(p0, q0.T, lower=0, trans=1)).T  # Q0 P0^-1
            low = _checked(lapack.dpotrf(eye - ratio @ ratio.T, lower=1, clean=1))
            lower_rhs[:, :r], lower_rhs[:, r:] = -ratio, eye
            step[r:] = _checked(lapack.dtrtrs(low, lower_rhs, lower=1, overwrite_b=1))
        columns = width - c
        moved = step[: r if last else 2 * r] @ generator
        moved[:r, :r] = top
        yield c, moved[:r]
        if not last:  # P keeps its columns, Q moves left one block
            generator = generator_buffer[: 2 * r * (columns - r)].reshape(2 * r, columns - r)
            generator[:r], generator[r:] = moved[:r, : columns - r], moved[r:, r:]


def _toeplitz_factor(lagged: np.ndarray, block_rows: int, *, conditional: bool = False
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``L^T``, ``(Sigma_fp L^-T)^T`` and ``L2^T`` (i r square each) of the past-and-future factor.

    The lower Cholesky factor of the past-and-future covariance (:func:`_schur_rows`) is
    ``[[L, 0], [Sigma_fp L^-T, L2]]``: ``L`` the factor of the past's (and, the same matrix, the
    future's) covariance, ``L2 L2^T = Sigma_ff - Sigma_fp Sigma_pp^-1 Sigma_pf`` the future's
    covariance given the past. ``L2^T`` only where ``conditional`` and its steps succeed, else None.
    Raises IdentificationError when the past's covariance is not positive definite (references
    that are linearly dependent).
    """
    i, r = block_rows, lagged.shape[1]
    n = i * r
    past, cross = np.zeros((n, n)), np.empty((n, n))  # [L^T, L^-1 Sigma_pf]: each block row's two parts
    future, made = (np.zeros((n, n)) if conditional else None), 0
    try:
        for c, row in _schur_rows(lagged, i, 2 * i if conditional else i):
            if c < n:
                past[c : c + r, c:], cross[c : c + r] = row[:, : n - c], row[:, n - c :]
            else:
                future[c - n : c - n + r, c - n :] = row
            made = c + r
    except linalg.LinAlgError:  # the generator's differences lose what a nearly singular covariance keeps
        if made < n:
            return (*_dense_factor(lagged, block_rows), None)
        future = None
    return past, cross, future


def _reversed_conditional_gram(past: np.ndarray, future: np.ndarray, *, panel: int = 128) -> np.ndarray:
    """(n, n) Fortran order, lower triangle ``J (I - W W^T) J``, ``W = L^-1 L2`` (``J`` reverses the order).

    ``past`` and ``future`` are ``L^T`` and ``L2^T`` of :func:`_toeplitz_factor`. With ``M = L^-1
    Sigma_fp L^-T`` (``X = Sigma_fp L^-T``), ``M M^T = L^-1 X X^T L^-T = L^-1 (L L^T - L2 L2^T)
    L^-T = I - W W^T``: ``M``'s Gram on the future's side from two triangular matrices. ``W`` is
    lower triangular, made by panels of ``panel`` rows (forward substitution, the products with
    the rows already made read only their nonzero columns): ``n^3 / 3`` flops, where ``dtrsm``
    treats a right-hand side as full (``M`` by ``dtrsm`` and its Gram by ``dsyrk``: ``2 n^3``).
    ``W W^T`` by LAPACK's ``dlauum`` (the product of a triangular matrix with its transpose, ``n^3
    / 3``), which takes ``X^T X`` of a lower ``X``: ``X = J W^T J``, whose memory in Fortran order
    is ``W``'s in C order read backwards.
    """
    n = past.shape[0]
    low, low_future = past.T, future.T  # L, L2 (views)
    w = np.zeros((n, n))
    for start in range(0, n, panel):
        stop = min(start + panel, n)
        # Rows start:stop of W: L_pp^-1 (L2_p - L_pb W_b), b the rows before; columns from stop on are zero, and
        # W_b's panel of columns from q on is zero above row q.
        rhs = low_future[start:stop, :stop].copy()
        for column in range(0, start, panel):
            rhs[:, column : column + panel] -= low[start:stop, column:start] @ w[column:start, column : column + panel]
        w[start:stop, :stop] = blas.dtrsm(1.0, low[start:stop, start:stop], rhs.T, side=1, lower=1, trans_a=1,
                                          overwrite_b=1).T
    reversed_w = w.ravel()[::-1].copy().reshape((n, n), order="F")
    gram = _checked(lapack.dlauum(reversed_w, lower=1, overwrite_c=1))
    np.negative(gram, out=gram)
    gram.flat[:: n + 1] += 1.0
    return gram


def _dense_factor(lagged: np.ndarray, block_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_toeplitz_factor`'s result by a dense Cholesky factor of the past's covariance and a triangular solve.

    Backward stable where the block Schur steps are not: their ``P0^T P0 - Q0^T Q0`` cancels on a
    nearly singular covariance (outputs with little or no sensor noise) that a dense factor still
    takes. Raises IdentificationError when the covariance is not positive definite.
    """
    i, r = block_rows, lagged.shape[1]
    first = lagged[i : 3 * i].transpose(2, 0, 1).reshape(r, 2 * i * r)  # block d: Sigma's block (a, a + d)
    blocks = [first[:, d * r : (d + 1) * r] for d in range(2 * i)]
    rows = np.vstack([np.hstack([blocks[b - a] if b >= a else blocks[a - b].T for b in range(2 * i)])
                      for a in range(i)])  # the past's block rows of the past-and-future covariance
    n = i * r
    try:
        low = linalg.cholesky(rows[:, :n], lower=True, check_finite=False)
    except linalg.LinAlgError:
        raise IdentificationError("the reference channels' covariance is not positive definite: "
                                  "no canonical-variate weighting") from None
    return low.T.copy(), linalg.solve_triangular(low, rows[:, n:], lower=True, check_finite=False)


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


def _leading_pairs(past: np.ndarray, cross: np.ndarray, future: np.ndarray | None, count: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``s`` (descending), ``V`` and ``U s`` (or None) of ``M = L^-1 Sigma_fp L^-T``'s ``count`` leading triplets.

    ``past``, ``cross`` and ``future`` as :func:`_toeplitz_factor` returns them. With the future's
    conditional factor, ``U`` from ``M M^T`` (:func:`_reversed_conditional_gram`) and ``V = M^T U /
    s = cross L^-T U / s``; without it (its steps failed), ``V`` from ``M^T M``: ``M`` by ``dtrsm``,
    its Gram's lower triangle by ``dsyrk`` (half a product's flops), and ``U`` is left to the caller.
    The leading pairs come alone from the tridiagonal form where that is cheaper (a long record's
    lags). Singular values below ``1e-7`` of the first are dropped (the Gram squares the condition
    number).
    """
    if future is None:
        weighted = blas.dtrsm(1.0, past.T, cross.T, lower=1)  # M, future x past (cross kept for its product with V)
        values, right = leading_eigh(blas.dsyrk(1.0, weighted, trans=1, lower=1), count, alone=True, overwrite=True)
        left = None
    else:
        values, left = leading_eigh(_reversed_conditional_gram(past, future), count, alone=True, overwrite=True)
        left = left[::-1]  # the Gram's rows and columns were reversed
    s = np.sqrt(np.maximum(values, 0.0))
    keep = s > s[0] * 1e-7 if s.size else s.astype(bool)
    s = s[keep]
    if left is None:
        return s, right[:, keep], None
    left = left[:, keep] * s
    right = (cross @ linalg.solve_triangular(past, left, check_finite=False)) / s**2
    return s, right, left


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
    n = i * r
    # Time order: L (lower, the past's factor, the future's too) and L^-1 Sigma_fp L^-T = L^-1 H(0) J L^-T, the
    # module's M with the past's and the future's blocks both reversed (orthogonal changes: same S and A).
    past_upper, cross, future = _toeplitz_factor(lagged, i, conditional=True)
    low = past_upper.T  # Fortran order: no copies for BLAS
    s, V, left = _leading_pairs(past_upper, cross, future, int(min(max_states, n)))
    # T = J L^-T V: the past's directions on z (the past read backwards, as the Hankel's columns).
    transform = linalg.solve_triangular(past_upper, V, check_finite=False).reshape(i, r, -1)[::-1].reshape(n, -1)
    # H(0) T = Sigma_fp L^-T V (H(0)'s columns are the past read backwards) = cross^T V = L M V = L U s, so
    # U^T L^-1 H(1) T = (U s)^T L^-1 H(1) T / s: with U known, a triangular product and a solve with k columns
    # (without, cross^T V and a solve with 2 k: M V as a product costs twice that solve), M(1) never formed.
    # H(1)'s block row a is H(0)'s a + 1, its last R_(i+1) .. R_2i.
    hankel_t = cross.T @ V if left is None else blas.dtrmm(1.0, low, left, lower=1)
    last_row = lagged[2 * i + 1 :].transpose(1, 0, 2).reshape(r, n)
    shifted_t = np.vstack([hankel_t[r:], last_row @ transform])
    if left is None:
        solved = linalg.solve_triangular(low, np.hstack([hankel_t, shifted_t]), lower=True, overwrite_b=True,
                                         check_finite=False)
        left, solved = solved[:, : V.shape[1]], solved[:, V.shape[1] :]
    else:
        solved = linalg.solve_triangular(low, shifted_t, lower=True, overwrite_b=True, check_finite=False)
    shifted = (left.T @ solved) / s[:, None]
    first_row = correlations[1 : i + 1].transpose(1, 0, 2)[:, :, references].reshape(correlations.shape[1], n)
    # V^T L^T at z's first block: Sigma_z T's first block row, L's last block row times V.
    return CanonicalDecomposition(blocks=correlations[1 : 2 * i + 1][:, :, references], block_rows=i, s=s,
                                  Vt=(low[n - r :] @ V).T, shifted=shifted,
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
