"""Stochastic realization: ``(A, C)`` at every order and the forward innovation model.

Two sequences of "free responses" are realized by the same ERA (:mod:`okid_ros.core.era`):

(a) the paper's route: a vector autoregression ``y_k = sum_i Ybar_i y_{k-i} + e_k`` (the ARX
    of :mod:`okid_ros.core.arx` with m = 0) gives the observer Markov parameters
    ``Ybar_i = C Abar^(i-1) L`` and, by the OKID recursion
    ``h_k = Ybar_k + sum_(i<k) Ybar_i h_(k-i)``, the stochastic Markov parameters
    ``h_k = C A^(k-1) L`` (``L = A K``); ERA on them gives ``A``, ``C`` and ``L`` directly and the
    VAR residuals the innovation covariance;
(b) covariance-driven SSI / NExT-ERA: the output correlations ``R_k = C A^(k-1) G`` realize
    ``A``, ``C``; ``G = E[x_{k+1} y_k^T]`` and ``R_0`` give the forward innovation model by the
    stochastic Riccati equation (Van Overschee & De Moor 1996, ch. 3)::

        P = A P A^T + (G - A P C^T) (R_0 - C P C^T)^-1 (G - A P C^T)^T,
        L = (G - A P C^T) Re^-1,   Re = R_0 - C P C^T,

    solved by ``scipy.linalg.solve_discrete_are`` in its dual form (X = -P).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg

from okid_ros.core.arx import ArxFit, fit_from_normal_equations
from okid_ros.core.arx_gram import arx_normal_equations
from okid_ros.core.era import HankelDecomposition, decompose_hankel
from okid_ros.core.symmetric_eigen import SymmetricEigen
from okid_ros.core.worker_threads import WorkerThreads

__all__ = [
    "CovarianceDecomposition",
    "OrderRealizer",
    "covariance_decomposition",
    "fit_var",
    "stochastic_markov_from_var",
    "forward_innovation",
    "gain_from_markov",
    "hankel_grams",
    "leading_eigh",
    "subspace_eigh",
]


@dataclass
class CovarianceDecomposition:
    """The leading singular triplets of the block Hankel ``H(0)`` of ``R_1 .. R_2i``, from Gram sums.

    ``H(0)^T H(0)`` and ``H(0)^T H(1)`` (``i r`` square each, ``r`` reference columns) are sums
    along the block diagonals of the Gram of the one block row ``[R_1, .., R_2i]``
    (:func:`hankel_grams`), so neither Hankel matrix is formed: at 28 outputs, 12 references and
    60 block rows that is 1.2e8 flops instead of 2.2e9 for the products with the formed matrices.
    The leading eigenvectors ``V`` of the first give the singular values ``s`` and the right
    vectors; the left vectors ``U = H(0) V / s`` are formed only when asked for
    (:meth:`left_vectors`: at the model's order), their first block row always.

    Attributes
    ----------
    blocks : (2 i, p, r) ``R_1 .. R_2i`` at the reference columns; block_rows : i.
    s : (k,) singular values; Vt : (k, i r) right singular vectors.
    shifted : (k, k) ``U^T H(1) V`` (the state matrix of every order is a corner of it).
    first_rows : (p, k) the first block row of ``U``.
    basis : (i r, c) the Gram's ``c`` leading eigenvectors, c >= k when spare columns were asked
        for (``covariance_decomposition(spare=)``: a start for a nearby record's, ``start=``), else None.
    """

    blocks: np.ndarray
    block_rows: int
    s: np.ndarray
    Vt: np.ndarray
    shifted: np.ndarray
    first_rows: np.ndarray
    basis: np.ndarray | None = field(default=None, repr=False)
    _left: np.ndarray | None = field(default=None, repr=False)

    @property
    def n_outputs(self) -> int:
        return self.blocks.shape[1]

    @property
    def n_block_inputs(self) -> int:
        return self.blocks.shape[2]

    @property
    def max_states(self) -> int:
        """Largest order supported numerically (the rule of :class:`~okid_ros.core.era.HankelDecomposition`)."""
        i, (_, p, r) = self.block_rows, self.blocks.shape
        tol = self.s[0] * np.finfo(float).eps * max(i * p, i * r) if self.s.size else 0.0
        return int(np.sum(self.s > tol))

    def projected(self, n_states: int) -> np.ndarray:
        """``U_n^T H(1) V_n`` (n, n)."""
        return self.shifted[:n_states, :n_states]

    def left_block_row(self, n_states: int) -> np.ndarray:
        """The first block row of ``U_n``: (p, n)."""
        return self.first_rows[:, :n_states]

    def left_vectors(self, n_states: int) -> np.ndarray:
        """``U_n`` (i p, n), formed from ``H(0)`` on the first call."""
        if self._left is None:
            h0 = _block_hankel(self.blocks, self.block_rows, 0)
            self._left = (h0 @ self.Vt.T) / self.s
        return self._left[:, :n_states]


@dataclass
class OrderRealizer:
    """``(A, C)`` of every order from one SVD (the projections made once for the largest order).

    Attributes
    ----------
    decomposition : the Hankel SVD: a :class:`CovarianceDecomposition` or an
        :class:`~okid_ros.core.era.HankelDecomposition` (:func:`okid_ros.core.era.decompose_hankel`).
    max_states : the largest order offered.
    """

    decomposition: CovarianceDecomposition | HankelDecomposition
    max_states: int

    def __post_init__(self) -> None:
        d, n = self.decomposition, self.max_states
        self._sq = np.sqrt(d.s[:n])
        self._projected = d.projected(n)  # (n, n), A of every order is a corner
        # An order's poles are read more than once (the diagram, then the spectral share or the
        # jackknife at a candidate's home order): each eigendecomposition is made once.
        self._eigen: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._eigenvalues: dict[int, np.ndarray] = {}

    def realize(self, n_states: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``A`` (n, n), ``C`` (p, n) and the first block column ``G`` (n, r) of order n."""
        sq = self._sq[:n_states]
        A = self._state_matrix(n_states)
        C = self.decomposition.left_block_row(n_states) * sq
        G = sq[:, None] * self.decomposition.Vt[:n_states, : self.decomposition.n_block_inputs]
        return A, C, G

    def _state_matrix(self, n_states: int) -> np.ndarray:
        """``A`` (n, n) of order n alone (the eigensolvers need no ``C``, ``G``)."""
        sq = self._sq[:n_states]
        return self._projected[:n_states, :n_states] / np.outer(sq, sq)

    def eigen(self, n_states: int) -> tuple[np.ndarray, np.ndarray]:
        """Eigenvalues (n,) and unit right eigenvectors (n, n) of ``A`` of order n (``numpy.linalg.eig``)."""
        if n_states not in self._eigen:
            self._eigen[n_states] = np.linalg.eig(self._state_matrix(n_states))
        return self._eigen[n_states]

    def decompose_orders(self, orders: Iterable[int], threads: WorkerThreads) -> None:
        """Make :meth:`eigen`'s decompositions of ``orders`` now, side by side in ``threads``."""
        missing = [int(n) for n in orders if n not in self._eigen]
        for n, pair in zip(missing, threads.map(lambda n: np.linalg.eig(self._state_matrix(n)), missing)):
            self._eigen[n] = pair

    def eigenvalues(self, n_states: int) -> np.ndarray:
        """Eigenvalues (n,) of ``A`` of order n (those of :meth:`eigen` when it was asked for)."""
        if n_states in self._eigen:
            return self._eigen[n_states][0]
        if n_states not in self._eigenvalues:
            self._eigenvalues[n_states] = np.linalg.eigvals(self._state_matrix(n_states))
        return self._eigenvalues[n_states]

    def observability(self, n_states: int) -> np.ndarray:
        """``Gamma`` (p b, n) of order n (``b`` block rows)."""
        return self.decomposition.left_vectors(n_states) * self._sq[:n_states]


def covariance_decomposition(correlations: np.ndarray, references: np.ndarray, block_rows: int,
                             max_states: int | None = None, *, spare: int = 0, start: np.ndarray | None = None,
                             iterations: int = 0) -> CovarianceDecomposition | HankelDecomposition:
    """Leading singular triplets of the block Hankel of ``R_1 .. R_2i`` (reference columns), ``i = block_rows``.

    Parameters
    ----------
    correlations : (L + 1, p, p) ``R_0 .. R_L``, ``L >= 2 i``.
    references : (r,) the reference channels (Hankel columns).
    max_states : keep only this many singular triplets, from the eigen-decomposition of the
        Gram ``H^T H`` (:class:`CovarianceDecomposition`; the full SVD of a 2000 x 850 Hankel
        takes 1.5 s, this 0.15 s; the leading singular values lose nothing that matters at
        double precision); None: the full SVD of the Hankel matrix.
    spare : (with ``max_states``) also keep this many more eigenvectors of the Gram, as
        ``basis`` (a start for the correlations of a nearby record: ``start=``).
    start : (i r, c) the leading eigenvectors of a nearby record's Gram (its ``basis``; a
        jackknife replicate's differs by one segment): the Gram's leading pairs by
        ``iterations`` block power iterations from them (:func:`subspace_eigh`) where that is
        cheaper than the tridiagonal route, i.e. ``2 iterations c < i r`` and ``c >= max_states``
        (otherwise :func:`leading_eigh`, as without ``start``).
    """
    blocks = correlations[1 : 2 * block_rows + 1][:, :, references]
    if max_states is None:
        return decompose_hankel(blocks, block_rows, block_rows)
    gram, cross = hankel_grams(blocks, block_rows)
    k = int(min(max_states, gram.shape[0]))
    if start is not None and start.shape[0] != gram.shape[0]:
        raise ValueError(f"start has {start.shape[0]} rows, the Gram {gram.shape[0]}")
    if start is not None and k <= start.shape[1] and 2 * iterations * start.shape[1] < gram.shape[0]:
        values, basis = subspace_eigh(gram, start, start.shape[1], iterations=iterations)
    else:
        values, basis = leading_eigh(gram, int(min(k + spare, gram.shape[0])))
    values, V = values[:k], basis[:, :k]
    s = np.sqrt(np.maximum(values, 0.0))
    keep = s > s[0] * 1e-7 if s.size else s.astype(bool)  # the Gram squares the condition number
    s, V = s[keep], V[:, keep]
    # U^T H(1) V = S^-1 V^T H(0)^T H(1) V; the first block row of H(0) is [R_1 .. R_i].
    first_row = blocks[:block_rows].transpose(1, 0, 2).reshape(blocks.shape[1], -1)
    return CovarianceDecomposition(blocks, block_rows, s, V.T, (V.T @ cross @ V) / s[:, None],
                                   (first_row @ V) / s, basis if spare else None)


def hankel_grams(blocks: np.ndarray, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """``H(0)^T H(0)`` and ``H(0)^T H(1)`` of the square block Hankel of ``blocks`` (2 i, p, r), ``i = n_rows``.

    Block ``(a, b)`` of the first is ``sum_c Y_(a+c)^T Y_(b+c)`` over the ``i`` block rows ``c``
    (``Y_k = blocks[k]``), a sum along a block diagonal of the Gram ``T`` of ``[Y_0 .. Y_(2i-1)]``;
    running sums along those diagonals give every block as one difference (the second likewise,
    one block to the right). ``4 i^2 r^2 p`` flops for ``T`` instead of ``2 i^3 r^2 p`` for each
    Hankel product; no library offers block-Hankel Gram products (scipy.linalg.hankel is scalar
    and dense). Equal to the products of the formed matrices to rounding
    (test/core/test_core_output_only.py).
    """
    n_blocks, p, r = blocks.shape
    if n_blocks < 2 * n_rows:
        raise ValueError(f"{n_rows} block rows need {2 * n_rows} blocks, got {n_blocks}")
    row = blocks[: 2 * n_rows].transpose(1, 0, 2).reshape(p, 2 * n_rows * r)
    m, i = 2 * n_rows, n_rows
    # In place, no second array: sums[s, :, t, :] = sum_(d >= 0) T[s-d, :, t-d, :] (the running sums
    # along the block diagonals; the same additions in the same order as into a zero-padded copy).
    sums = (row.T @ row).reshape(m, r, m, r)
    for s in range(1, m):
        sums[s, :, 1:, :] += sums[s - 1, :, :-1, :]
    gram = sums[i - 1 : m - 1, :, i - 1 : m - 1, :].copy()
    gram[1:, :, 1:, :] -= sums[: i - 1, :, : i - 1, :]
    cross = sums[i - 1 : m - 1, :, i:m, :].copy()
    cross[1:] -= sums[: i - 1, :, :i, :]
    return gram.reshape(i * r, i * r), cross.reshape(i * r, i * r)


def leading_eigh(matrix: np.ndarray, k: int, *, alone: bool = False, overwrite: bool = False
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` largest eigenvalues (descending) and their eigenvectors of a symmetric matrix.

    ``matrix`` (m, m) -> values (k,), vectors (m, k). LAPACK's divide-and-conquer route
    (:class:`~okid_ros.core.symmetric_eigen.SymmetricEigen`: Householder tridiagonal form,
    ``dstevd`` on it) with the reflectors applied to the ``k`` vectors kept only.
    ``scipy.linalg.eigh`` offers a subset only through MRRR or inverse iteration
    (``subset_by_index``: ``dsyevr`` / ``dsyevx``), slow on the clustered noise-floor eigenvalues
    of a Hankel Gram (500 x 500, k = 100: 19 ms, 10 of them for the tridiagonal vectors), or
    every vector back-transformed (``driver="evd"``: 16 ms); this takes 11 ms. The same pairs
    to rounding (test/core/test_core_output_only.py). ``alone``: the tridiagonal form's ``k``
    largest pairs alone where the matrix is large enough for that to be cheaper
    (:class:`~okid_ros.core.symmetric_eigen.SymmetricEigen`'s ``largest``; the same pairs to
    rounding). ``overwrite``: ``matrix`` is a scratch array the reduction may overwrite (no copy).
    ValueError on NaN or Inf.
    """
    eigen = SymmetricEigen(matrix, largest=int(min(k, matrix.shape[0])) if alone else None, overwrite=overwrite)
    count = eigen.values.size
    top = np.arange(count - 1, count - 1 - min(k, count), -1)
    return eigen.values[top], eigen.vectors(top)


def subspace_eigh(matrix: np.ndarray, start: np.ndarray, k: int, *, iterations: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` largest eigenpairs of a symmetric matrix from a nearby matrix's leading eigenvectors.

    ``iterations`` block power iterations from ``start`` (m, c), c >= k (orthonormalized each
    time), then Rayleigh-Ritz: the eigenpairs of ``Q^T M Q`` (c, c) on the final basis ``Q``,
    largest first. Each iteration shrinks the error of a pair ``j`` by ``lambda_(c+1) / lambda_j``,
    so the pairs well above the (c + 1)-th eigenvalue converge in one or two, those near it
    (a flat noise floor) are the subspace's best approximations, their Ritz values below the
    eigenvalues (test/core/test_core_output_only_replicates.py). ``matrix`` (m, m) -> values (k,),
    vectors (m, k). ``iterations + 1`` products of ``matrix`` with c columns: a jackknife
    replicate's :func:`covariance_decomposition` at m = 500, c = 110 and two iterations takes
    15 ms, against 24 ms by :func:`leading_eigh`. ValueError when ``start`` does not fit.
    """
    if start.ndim != 2 or start.shape[0] != matrix.shape[0] or not 0 < k <= start.shape[1]:
        raise ValueError(f"start (m, c >= k) for a {matrix.shape[0]}-square matrix and k = {k}, got {start.shape}")
    basis = start
    for _ in range(iterations):
        basis = linalg.qr(matrix @ basis, mode="economic", overwrite_a=True, check_finite=False)[0]
    small = basis.T @ (matrix @ basis)
    # The small problem by the tridiagonal route too (110 square: 0.7 ms, against 1.3 ms by scipy's default MRRR).
    values, vectors = leading_eigh(0.5 * (small + small.T), k)
    return values, basis @ vectors


def _block_hankel(blocks: np.ndarray, n_rows: int, shift: int) -> np.ndarray:
    """Square block Hankel ``H(shift)`` of ``blocks`` (K, p, r) by one fancy index.

    The same matrix as :func:`okid_ros.core.era.block_hankel`, without its Python loop of
    ``hstack`` calls.
    """
    index = np.arange(n_rows)[:, None] + np.arange(n_rows)[None, :] + shift
    _, p, r = blocks.shape
    return blocks[index].transpose(0, 2, 1, 3).reshape(n_rows * p, n_rows * r)


def fit_var(y: np.ndarray, order: int) -> ArxFit:
    """Vector AR of order q on centred outputs ``y`` (N, p): the ARX of :mod:`.arx` with m = 0.

    Ridge-regularized with the penalty chosen by GCV, with an intercept.
    """
    normal = arx_normal_equations(np.zeros((y.shape[0], 0)), y, order)
    return fit_from_normal_equations(normal, order, y.shape[1], 0, "ridge", center=True)


def stochastic_markov_from_var(var: ArxFit, n_terms: int) -> np.ndarray:
    """``h_k = C A^(k-1) L``, k = 1 .. n_terms: (n_terms, p, p), by the OKID recursion.

    ``h_k = Ybar_k + sum_(i=1..k-1) Ybar_i h_(k-i)`` with ``Ybar_k = 0`` beyond the VAR order
    (the predictor's Markov parameters turned into the system's, paper Eq. 24 with y as input).
    """
    coef = var.output_coefficients  # (q, p, p)
    q, p = coef.shape[0], coef.shape[1]
    h = np.zeros((n_terms, p, p))
    terms = np.zeros((q + 1, p, p))  # Ybar_k, then Ybar_i h_(k-i) for i = 1 .. min(k - 1, q)
    for k in range(1, n_terms + 1):
        m = min(k - 1, q)
        terms[0] = coef[k - 1] if k <= q else 0.0
        # One stacked product per k instead of m small ones (the sum in the same order: 12 ms -> 1 ms
        # at q = 50, 4 outputs, 251 terms).
        np.matmul(coef[:m], h[k - 2 :: -1][:m], out=terms[1 : m + 1])
        h[k - 1] = terms[: m + 1].sum(axis=0)
    return h


def gain_from_markov(A: np.ndarray, C: np.ndarray, markov: np.ndarray) -> np.ndarray:
    """Least-squares ``X`` (n, r) of ``markov[k] = C A^k X`` (markov (K, p, r)), A and C fixed."""
    n_terms = markov.shape[0]
    rows = [C]
    for _ in range(n_terms - 1):
        rows.append(rows[-1] @ A)
    return linalg.lstsq(np.vstack(rows), markov.reshape(n_terms * C.shape[0], -1))[0]


def forward_innovation(A: np.ndarray, C: np.ndarray, G: np.ndarray, r0: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray] | None:
    """Predictor gain ``L`` (n, p) and innovation covariance ``Re`` (p, p) of a covariance model.

    Solves the stochastic Riccati equation of the module docstring; None when ``(A, C, G, R_0)``
    is not positive real (no solution, ``Re`` not positive definite or an unstable predictor).
    """
    n, p = A.shape[0], C.shape[0]
    try:
        X = linalg.solve_discrete_are(A.T, C.T, np.zeros((n, n)), r0, s=G)
    except (ValueError, np.linalg.LinAlgError, linalg.LinAlgError):
        return None
    P = -0.5 * (X + X.T)
    Re = r0 - C @ P @ C.T
    Re = 0.5 * (Re + Re.T)
    if not np.all(np.isfinite(Re)) or np.min(linalg.eigvalsh(Re)) <= 1e-12 * np.trace(r0) / p:
        return None
    L = linalg.solve(Re, (G - A @ P @ C.T).T, assume_a="pos").T
    if np.max(np.abs(linalg.eigvals(A - L @ C))) >= 1.0:
        return None
    return L, Re
