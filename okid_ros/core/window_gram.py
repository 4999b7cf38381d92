"""The augmented Gram matrix of a sliding ARX window's rows, updated by blocks of rows.

:class:`okid_ros.core.recursive.SlidingWindowArx` keeps, rather than ``R``, ``r`` and ``Y^T Y``
separately, one augmented Gram matrix ``G = sum w_k psi_k psi_k^T`` (D, D),
``D = (q + 1)(p + m) = d + p``, of the extended rows ``psi_k = [v_{k-q}; ...; v_{k-1}; v_k]``,
``v_j = [y_j; u_j]``, and their sum ``s = sum w_k psi_k`` (D,). ``R``, ``r``, ``Y^T Y``,
``phi_sum`` and ``y_sum`` are sub-blocks of ``G`` and ``s`` (a fixed index permutation), and one
symmetric rank-k BLAS update (``dsyrk``) adds or removes a whole block of rows.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import blas

from okid_ros.core.arx import NormalEquations

__all__ = ["CANCELLATION_RATIO", "WindowGram"]

#: A row leaving the window whose square exceeds this times what stays on its diagonal of ``G``
#: has ``G`` recomputed from the stored rows: the subtraction would leave ~2e-10 of what stays
#: (eps times this). Below it the rounding is harmless (a glitch of 1e4 output spreads leaving a
#: window of 3750 rows, a ratio of 3e4: the same modes); an impact of hundreds of spreads, which
#: the gate lets in, costs no recompute (at 28 outputs, q 20, a recompute of 6000 rows takes 0.08 s).
CANCELLATION_RATIO = 1e6


class WindowGram:
    """``G`` (upper triangle valid) and ``s`` of a window's extended rows (module docstring).

    Parameters
    ----------
    order : ARX order q >= 1.
    n_outputs, n_inputs : p and m.
    """

    def __init__(self, order: int, n_outputs: int, n_inputs: int) -> None:
        q, p, m = order, n_outputs, n_inputs
        self.order, self._w = q, p + m
        self.size = (q + 1) * self._w
        # psi_k = [v_{k-q}, ..., v_{k-1}, v_k] (time order) -> ARX layout phi_k and target y_k.
        lag_idx = [(q - lag) * self._w + c for lag in range(1, q + 1) for c in range(self._w)]
        self._phi_index = np.array([q * self._w + p + j for j in range(m)] + lag_idx)
        self._y_index = q * self._w + np.arange(p)
        self.clear()

    def clear(self) -> None:
        """Set ``G`` and ``s`` to zero (no rows)."""
        self.gram = np.zeros((self.size, self.size), order="F")
        self.row_sum = np.zeros(self.size)

    def _syrk(self, psi: np.ndarray, alpha: float, beta: float) -> None:
        """``G <- alpha psi^T psi + beta G`` on the upper triangle, in place."""
        self.gram = blas.dsyrk(alpha, psi.T, beta=beta, c=self.gram, trans=0, lower=0, overwrite_c=1)

    def add(self, psi: np.ndarray) -> None:
        """Add the rows ``psi`` (k, D) with weight 1."""
        self._syrk(psi, 1.0, 1.0)
        self.row_sum += psi.sum(axis=0)

    def remove(self, psi: np.ndarray) -> bool:
        """Take the rows ``psi`` (k, D) out; return whether that left more than rounding of what stays.

        Subtracting a row leaves about ``eps`` times its squares in ``G``: a glitch of 1e8 output
        spreads that left the window ruined every fit until the next refactorization (1e5 rows
        later), with a glitch of 1e100 NaN. True where a row's square in some coordinate exceeds
        :data:`CANCELLATION_RATIO` times what stays on that diagonal: ``G`` is to be recomputed.
        """
        self._syrk(psi, -1.0, 1.0)
        self.row_sum -= psi.sum(axis=0)
        peak = np.max(psi * psi, axis=0)
        return bool(np.any(peak > CANCELLATION_RATIO * np.diagonal(self.gram)))

    def add_discounted(self, psi: np.ndarray, forgetting: float) -> tuple[float, float]:
        """Discount ``G`` and ``s`` by ``forgetting`` per row and add the rows ``psi`` (k, D), newest last.

        Returns
        -------
        discount : what the old rows' weights were multiplied by; weight : the new rows' weights' sum.
        """
        count = psi.shape[0]
        if forgetting == 1.0:
            self.add(psi)
            return 1.0, count
        weights = forgetting ** np.arange(count - 1, -1, -1, dtype=float)
        self._syrk(psi * np.sqrt(weights)[:, None], 1.0, forgetting**count)
        self.row_sum = forgetting**count * self.row_sum + weights @ psi
        return forgetting**count, float(weights.sum())

    def recompute(self, rows: np.ndarray, indices: np.ndarray, chunk: int = 1024) -> None:
        """Set ``G`` and ``s`` to the sums over ``rows[indices]``, in bounded chunks."""
        self.gram[:] = 0.0
        self.row_sum[:] = 0.0
        for s in range(0, indices.size, chunk):
            self.add(rows[indices[s : s + chunk]])

    def normal_equations(self, n_rows: float, zero_channels: np.ndarray) -> NormalEquations:
        """The sums in ARX layout, the channels of ``zero_channels`` (indices into ``v``) exactly zero.

        A channel zero on every sample the window's rows hold sums to zero exactly; the
        downdates leave rounding residue instead (+-1e-16 of its former level), which looked
        like a live channel of tiny spread and kept a dead input from being named.
        """
        G = np.triu(self.gram)
        G += np.triu(self.gram, 1).T
        row_sum = self.row_sum.copy()
        if zero_channels.size:
            columns = (np.arange(self.order + 1)[:, None] * self._w + zero_channels[None, :]).ravel()
            G[columns, :] = 0.0
            G[:, columns] = 0.0
            row_sum[columns] = 0.0
        pi, yi = self._phi_index, self._y_index
        return NormalEquations(
            R=G[np.ix_(pi, pi)], r=G[np.ix_(pi, yi)], yy=G[np.ix_(yi, yi)], n_rows=n_rows,
            phi_sum=row_sum[pi], y_sum=row_sum[yi],
        )
