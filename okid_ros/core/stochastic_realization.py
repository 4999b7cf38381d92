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

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from okid_ros.core.arx import ArxFit, fit_from_normal_equations
from okid_ros.core.arx_gram import arx_normal_equations
from okid_ros.core.era import HankelDecomposition, decompose_hankel

__all__ = [
    "OrderRealizer",
    "covariance_decomposition",
    "fit_var",
    "stochastic_markov_from_var",
    "forward_innovation",
    "gain_from_markov",
]


@dataclass
class OrderRealizer:
    """``(A, C)`` of every order from one SVD (the projections made once for the largest order).

    Attributes
    ----------
    decomposition : the Hankel SVD (:func:`okid_ros.core.era.decompose_hankel`).
    max_states : the largest order offered.
    """

    decomposition: HankelDecomposition
    max_states: int

    def __post_init__(self) -> None:
        d, n = self.decomposition, self.max_states
        self._sq = np.sqrt(d.s[:n])
        self._projected = d.U[:, :n].T @ d.h1w @ d.Vt[:n].T  # (n, n), A of every order is a corner

    def realize(self, n_states: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``A`` (n, n), ``C`` (p, n), ``Gamma`` (p b, n) and the first block column ``G`` (n, r) of order n."""
        sq = self._sq[:n_states]
        A = self._projected[:n_states, :n_states] / np.outer(sq, sq)
        gamma = self.decomposition.U[:, :n_states] * sq
        r = self.decomposition.n_block_inputs
        G = sq[:, None] * self.decomposition.Vt[:n_states, :r]
        return A, gamma[: self.decomposition.n_outputs].copy(), gamma, G


def covariance_decomposition(correlations: np.ndarray, references: np.ndarray, block_rows: int,
                             max_states: int | None = None) -> HankelDecomposition:
    """SVD of the block Hankel of ``R_1 .. R_2i`` (reference columns), ``i = block_rows``.

    Parameters
    ----------
    correlations : (L + 1, p, p) ``R_0 .. R_L``, ``L >= 2 i``.
    references : (r,) the reference channels (Hankel columns).
    max_states : keep only this many singular triplets, from the eigen-decomposition of the
        smaller Gram matrix ``H^T H`` (the full SVD of a 2000 x 850 Hankel takes 1.5 s, this
        0.15 s; the leading singular values lose nothing that matters at double precision).
    """
    blocks = correlations[1 : 2 * block_rows + 1][:, :, references]
    if max_states is None:
        return decompose_hankel(blocks, block_rows, block_rows)
    h0 = _block_hankel(blocks, block_rows, 0)
    h1 = _block_hankel(blocks, block_rows, 1)
    k = int(min(max_states, h0.shape[1]))
    values, V = linalg.eigh(h0.T @ h0, subset_by_index=[h0.shape[1] - k, h0.shape[1] - 1])
    order = np.argsort(values)[::-1]
    s = np.sqrt(np.maximum(values[order], 0.0))
    V = V[:, order]
    keep = s > s[0] * 1e-7 if s.size else s.astype(bool)  # the Gram squares the condition number
    s, V = s[keep], V[:, keep]
    U = (h0 @ V) / s
    return HankelDecomposition(h0=h0, h1w=h1, U=U, s=s, Vt=V.T, n_outputs=blocks.shape[1],
                               n_block_inputs=blocks.shape[2])


def _block_hankel(blocks: np.ndarray, n_rows: int, shift: int) -> np.ndarray:
    """Square block Hankel ``H(shift)`` of ``blocks`` (K, p, r) by one fancy index.

    The same matrix as :func:`okid_ros.core.era.block_hankel`, without its Python loop of
    ``hstack`` calls (0.1 s per 500 x 500 Hankel, paid 18 times by the jackknife).
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
    for k in range(1, n_terms + 1):
        acc = coef[k - 1].copy() if k <= q else np.zeros((p, p))
        for i in range(1, min(k - 1, q) + 1):
            acc += coef[i - 1] @ h[k - i - 1]
        h[k - 1] = acc
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
