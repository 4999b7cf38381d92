"""Eigensystem Realization Algorithm (Juang & Pappa 1985), optionally data-weighted.

Given Markov blocks ``Y_i = C A^{i-1} B`` (i = 1, 2, ...; each (p, r); ``B`` is the system's
input matrix for system Markov parameters and ``[L, Bbar]`` for observer ones), the block
Hankel matrices

    H(s) = [[Y_{1+s},     Y_{2+s},   ..., Y_{c+s}    ],
            [Y_{2+s},     Y_{3+s},   ..., Y_{c+1+s}  ],
            ...
            [Y_{b+s},     ...,            Y_{b+c-1+s}]]          (p b, r c)

factor as ``H(s) = Gamma A^s Ctrb``. With the SVD ``H(0) W = U S V^T`` truncated to n states,

    Gamma = U_n S_n^{1/2},   A = S_n^{-1/2} U_n^T H(1) W V_n S_n^{-1/2},
    C = Gamma[:p],           B = pinv(Gamma) H(0)[:, :r].

``W = I`` is the paper's ERA. For the observer Markov parameters of an ARX model the block
columns of ``H(0)`` multiply the past data ``z_k = [v_{k-1}; ...; v_{k-c}]``, so weighting on the
right by a square root of ``E[z z^T]`` ranks the singular directions by the output energy they
carry on the actual data, the weighting of subspace methods. Directions the input never excited
then drop out instead of producing unstable or spurious poles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

__all__ = [
    "Realization",
    "HankelDecomposition",
    "block_hankel",
    "decompose_hankel",
    "default_hankel_size",
    "era",
]


@dataclass
class Realization:
    """Output of :func:`era`.

    Attributes
    ----------
    A : (n, n); B : (n, r) the realized input matrix of the Markov blocks; C : (p, n).
    singular_values : all singular values of the (weighted) ``H(0)``, descending.
    observability : (p b, n) ``Gamma``.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    singular_values: np.ndarray
    observability: np.ndarray


def default_hankel_size(n_blocks: int) -> tuple[int, int]:
    """Block rows and columns that use all ``n_blocks`` Markov blocks for ``H(0)`` and ``H(1)``."""
    n_rows = max(n_blocks // 2, 1)
    n_cols = max(n_blocks - n_rows, 1)
    return n_rows, n_cols


def block_hankel(blocks: np.ndarray, n_rows: int, n_cols: int, shift: int = 0) -> np.ndarray:
    """Block Hankel matrix ``H(shift)`` of ``blocks`` (K, p, r), blocks[0] being ``Y_1``."""
    k, p, r = blocks.shape
    if shift + n_rows + n_cols - 1 > k:
        raise ValueError(
            f"Hankel {n_rows}x{n_cols} with shift {shift} needs {shift + n_rows + n_cols - 1} "
            f"Markov blocks, only {k} available"
        )
    out = np.empty((p * n_rows, r * n_cols))
    for i in range(n_rows):
        out[i * p : (i + 1) * p] = np.hstack(blocks[i + shift : i + shift + n_cols])
    return out


@dataclass
class HankelDecomposition:
    """The SVD of a (weighted) block Hankel matrix, realized at any order by :meth:`realize`."""

    h0: np.ndarray
    h1w: np.ndarray
    U: np.ndarray
    s: np.ndarray
    Vt: np.ndarray
    n_outputs: int
    n_block_inputs: int

    @property
    def max_states(self) -> int:
        """Largest order the Hankel matrix can support numerically."""
        tol = self.s[0] * np.finfo(float).eps * max(self.h0.shape) if self.s.size else 0.0
        return int(np.sum(self.s > tol))

    def projected(self, n_states: int) -> np.ndarray:
        """``U_n^T H(1) W V_n`` (n, n): the state matrix of order n before the ``S^-1/2`` scaling."""
        return self.U[:, :n_states].T @ self.h1w @ self.Vt[:n_states].T

    def left_block_row(self, n_states: int) -> np.ndarray:
        """The first block row of ``U_n``: (p, n)."""
        return self.U[: self.n_outputs, :n_states]

    def left_vectors(self, n_states: int) -> np.ndarray:
        """``U_n`` (b p, n)."""
        return self.U[:, :n_states]

    def realize(self, n_states: int) -> Realization:
        """Truncate to ``n_states`` and return ``(A, B, C)``."""
        if not 1 <= n_states <= self.max_states:
            raise ValueError(
                f"n_states must be in 1..{self.max_states} (the numerical rank of the Hankel matrix), "
                f"got {n_states}"
            )
        p, r = self.n_outputs, self.n_block_inputs
        Un, sn, Vn = self.U[:, :n_states], self.s[:n_states], self.Vt[:n_states].T
        sq = np.sqrt(sn)
        gamma = Un * sq
        A = (Un.T @ self.h1w @ Vn) / np.outer(sq, sq)
        B = linalg.lstsq(gamma, self.h0[:, :r])[0]
        return Realization(A=A, B=B, C=gamma[:p].copy(), singular_values=self.s, observability=gamma)


def decompose_hankel(
    blocks: np.ndarray,
    n_rows: int | None = None,
    n_cols: int | None = None,
    right_weight: np.ndarray | None = None,
) -> HankelDecomposition:
    """Form ``H(0) W`` and ``H(1) W`` from Markov blocks ``Y_1, Y_2, ...`` and take the SVD.

    Parameters
    ----------
    blocks : (K, p, r) Markov blocks, ``blocks[i] = C A^i B`` (the feedthrough excluded).
    n_rows, n_cols : Hankel block rows b and columns c, ``b + c <= K`` (default: split K).
    right_weight : (r c, r c), optional square root ``W`` of the covariance of the past data,
        e.g. a Cholesky factor.
    """
    k, p, r = blocks.shape
    if n_rows is None or n_cols is None:
        dr, dc = default_hankel_size(k - 1)
        n_rows = dr if n_rows is None else n_rows
        n_cols = dc if n_cols is None else n_cols
    if n_rows < 1 or n_cols < 1 or n_rows + n_cols > k:
        raise ValueError(
            f"Hankel {n_rows}x{n_cols} blocks needs {n_rows + n_cols} Markov blocks, have {k}"
        )
    h0 = block_hankel(blocks, n_rows, n_cols, 0)
    h1 = block_hankel(blocks, n_rows, n_cols, 1)
    if right_weight is not None:
        if right_weight.shape != (h0.shape[1], h0.shape[1]):
            raise ValueError(f"right_weight must be {(h0.shape[1],) * 2}, got {right_weight.shape}")
        h0w, h1w = h0 @ right_weight, h1 @ right_weight
    else:
        h0w, h1w = h0, h1
    U, s, Vt = linalg.svd(h0w, full_matrices=False)
    return HankelDecomposition(h0=h0, h1w=h1w, U=U, s=s, Vt=Vt, n_outputs=p, n_block_inputs=r)


def era(
    blocks: np.ndarray,
    n_states: int,
    n_rows: int | None = None,
    n_cols: int | None = None,
    right_weight: np.ndarray | None = None,
) -> Realization:
    """Realize ``(A, B, C)`` of order ``n_states`` from Markov blocks (see :func:`decompose_hankel`)."""
    return decompose_hankel(blocks, n_rows, n_cols, right_weight).realize(n_states)
