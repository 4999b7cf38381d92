"""Every order's state-sequence regressions from one Gram matrix of the window (no pass over the data).

The weighted ERA states are linear in the past-data vector, ``xhat_k = z_k T`` with
``T = (S^-1/2 U^T H(0))^T`` (``(p + m) c``, n) and ``z_k = [v_{k-1}; ...; v_{k-c}]``,
``v = [y; u]``. With the extended vector ``e_k = [y_k; u_k; z_k]`` every quantity the state
completion regresses is linear in ``e_k``:

    y_k = e_k[:p],   u_k = e_k[p:p+m],   xhat_k = e_k[p+m:] T,   xhat_{k+1} = e_k[:(p+m) c] T

(``z_{k+1}`` is ``e_k`` without its oldest block). So one Gram ``G = sum_k e_k e_k^T`` of the
window gives the Gram of ``[u, xhat, y, xhat_next]`` at the largest order by two small matrix
products, and the Gram of any order's regressors is a leading sub-block of it (the ERA states of
order n are the first n of the largest order's). The regressions of
:mod:`okid_ros.core.state_completion` (output equation, state equation, residual covariances
``Q``, ``R``, ``S``) then cost ``O(n^3)`` per order instead of ``O(N n^2)``: the idea of the
fast multi-order subspace identification (Döhler & Mevel 2012), applied to the ERA states.

The solves mirror ``state_completion._lstsq`` (column-scaled normal equations with a 1e-10
ridge), so the models equal the data-pass ones to rounding.
"""

from __future__ import annotations

import numpy as np
from scipy import linalg

from okid_ros.core.arx_gram import lagged_gram
from okid_ros.core.stable_matrix import stabilize_with_eigen
from okid_ros.core.statespace import free_parameters

__all__ = ["StateGram", "GramRegression", "fewest_state_samples"]


def fewest_state_samples(n_states: int, n_inputs: int, n_outputs: int) -> int:
    """The fewest samples of a state sequence its state and output equations are regressed on (twice the unknowns)."""
    return 2 * (n_states + n_inputs + n_outputs) + 1


class GramRegression:
    """The state-equation regressions of one order, from the Gram (see :class:`StateGram`).

    Attributes
    ----------
    A (n, n) stable; B (n, m); C (p, n); D (p, m); eigenvalues (n,) of ``A`` and eigenvectors
    (n, n) (after moving the unstable ones); output_covariance (p, p) of ``v = y - C x - D u``;
    n_samples : rows of the window.
    """

    def __init__(self, A, B, C, D, *, eigen, covariances, n_samples):
        self.A, self.B, self.C, self.D = A, B, C, D
        self.eigenvalues, self.eigenvectors = eigen
        q_pair, self.output_covariance, self._S = covariances
        self._Q, self._pair_R = q_pair if q_pair is not None else (None, None)
        self.n_samples = n_samples

    def noise_covariances(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``Q`` (n, n), ``R`` (p, p), ``S`` (n, p) as :func:`kalman_gain.noise_covariances` gives them."""
        n = self.A.shape[0]
        if self._Q is None:
            raise ValueError("regress(..., covariances=True) gives the noise covariances")
        joint = np.block([[self._Q, self._S], [self._S.T, self._pair_R]])
        joint = 0.5 * (joint + joint.T)
        scale = max(np.trace(joint) / joint.shape[0], np.finfo(float).tiny)
        joint += 1e-10 * scale * np.eye(joint.shape[0])
        return joint[:n, :n], joint[n:, n:], joint[:n, n:]

    def bic(self) -> float:
        """BIC of the output-equation residuals (what the screening of orders compares)."""
        sign, logdet = np.linalg.slogdet(self.output_covariance)
        if sign <= 0 or not np.isfinite(logdet):
            return float("inf")
        n, p, m = self.A.shape[0], self.C.shape[0], self.B.shape[1]
        return float(self.n_samples * logdet + free_parameters(n, p, m) * np.log(self.n_samples))


def _scaled_solve(gram: np.ndarray, cross: np.ndarray) -> np.ndarray:
    """Least-squares coefficients (regressors x targets) from Grams, as ``state_completion._lstsq``."""
    scale = np.sqrt(np.maximum(np.diag(gram), np.finfo(float).tiny))
    scaled = gram / np.outer(scale, scale)
    scaled[np.diag_indices_from(scaled)] += 1e-10
    rhs = cross / scale[:, None]
    try:
        coef = linalg.cho_solve(linalg.cho_factor(scaled, check_finite=False), rhs, check_finite=False)
    except linalg.LinAlgError:
        coef = linalg.lstsq(scaled, rhs, lapack_driver="gelsy")[0]
    return coef / scale[:, None]


class StateGram:
    """The Gram of the window's extended past vectors, and every order's regressions from it.

    Parameters
    ----------
    u : (N, m); y : (N, p) the window's samples (offsets removed).
    n_cols : Hankel block columns c (the past vector's lags).
    valid : (N,) bool, optional mask; rows whose past crosses an invalid sample are left out
        (no contiguity is needed: ``xhat_{k+1}`` comes from ``e_k`` itself).
    """

    def __init__(self, u: np.ndarray, y: np.ndarray, n_cols: int, valid: np.ndarray | None = None):
        m, p = u.shape[1], y.shape[1]
        self.m, self.p, self.n_cols = m, p, n_cols
        self._u, self._y = u, y
        # The Gram of e_k = [y_k; u_k; z_k] over the rows, z_k the past data, from sums of lagged
        # products (:mod:`.arx_gram`), without the (M, (p + m) (c + 1)) matrix of rows.
        gram, _, rows = lagged_gram(u, y, n_cols, valid)
        self.rows = rows
        self.n_samples = max(rows.size, 1)
        self.gram = gram / self.n_samples
        # The state equation pairs (x_k, x_{k+1}) of all rows but the last, as the data-pass
        # regressions do (same models to rounding): the Gram less the last row, per pair.
        last = self._extended(rows[-1:])[0] if rows.size else np.zeros(gram.shape[0])
        self._pairs = max(self.n_samples - 1, 1)
        self._pair_gram = (self.gram * self.n_samples - np.outer(last, last)) / self._pairs
        self._base: np.ndarray | None = None

    @classmethod
    def of_states(cls, states: np.ndarray, u: np.ndarray, y: np.ndarray) -> "StateGram":
        """The Gram of a given state sequence: ``regress(n)`` then regresses it as the data pass does.

        ``states`` (N, n), ``u`` (N, m), ``y`` (N, p): ``regress(n, covariances=True)`` gives what
        :func:`.state_completion.regress_state_equations` and the residual covariances give.

        Raises
        ------
        ValueError if the states are not finite.
        """
        if not np.all(np.isfinite(states)):
            raise ValueError("the state sequence is not finite")
        n_samples, n = states.shape
        self = cls.__new__(cls)
        self.m, self.p, self.n_cols = u.shape[1], y.shape[1], 0
        self.rows = np.arange(n_samples)
        self.n_samples = max(n_samples, 1)
        self._pairs = max(n_samples - 1, 1)
        pairs = np.hstack([u[:-1], states[:-1], y[:-1], states[1:]])  # [u, x, y, x_next]
        self._pair_base = pairs.T @ pairs
        base = self._pair_base.copy()
        last = np.concatenate([u[-1], states[-1], y[-1]])
        k = last.size
        base[:k, :k] += np.outer(last, last)  # the output equation uses every row
        self._base = base / self.n_samples
        self._pair_base /= self._pairs
        self._top = n
        return self

    def without(self, segment_gram: np.ndarray, segment_rows: int) -> "StateGram":
        """The Gram of the window less some of its rows (a jackknife replicate, :mod:`.mode_jackknife`).

        ``segment_gram`` is the unnormalized lagged Gram of those rows (:func:`.arx_gram.lagged_gram`
        at ``n_cols``). The state pairs take the replicate's whole Gram: the one row the data pass
        leaves out of them is not tracked here. :meth:`set_states` is needed again.
        """
        other = StateGram.__new__(StateGram)
        other.m, other.p, other.n_cols = self.m, self.p, self.n_cols
        other._u, other._y, other.rows = self._u, self._y, self.rows
        other.n_samples = max(self.n_samples - int(segment_rows), 1)
        other.gram = (self.gram * self.n_samples - segment_gram) / other.n_samples
        other._pairs = max(other.n_samples - 1, 1)
        other._pair_gram = other.gram
        other._base = None
        return other

    def past_weight(self) -> np.ndarray:
        """Lower Cholesky factor of the past data's covariance ``z^T z / M`` (the ERA weighting)."""
        w = self.p + self.m
        cov = self.gram[w:, w:]
        jitter = 1e-10 * max(np.trace(cov) / cov.shape[0], np.finfo(float).tiny)
        return linalg.cholesky(cov + jitter * np.eye(cov.shape[0]), lower=True)

    def set_states(self, transform: np.ndarray) -> None:
        """The ERA states' map ``T`` ((p + m) c, n_max): Gram of ``[u, x, y, x_next]`` at ``n_max``."""
        m, p, w = self.m, self.p, self.p + self.m
        d = self.gram.shape[0]
        top = transform.shape[1]
        cols = np.zeros((d, m + top + p + top))
        cols[p:w, :m] = np.eye(m)
        cols[w:, m : m + top] = transform
        cols[:p, m + top : m + top + p] = np.eye(p)
        cols[: d - w, m + top + p :] = transform
        self._transform = transform
        self._base = cols.T @ self.gram @ cols
        # A replicate's pairs share its Gram (:meth:`without`): one product serves both.
        self._pair_base = self._base if self._pair_gram is self.gram else cols.T @ self._pair_gram @ cols
        self._top = top

    @property
    def max_states(self) -> int:
        return 0 if self._base is None else self._top

    def states(self, n: int) -> np.ndarray:
        """(M, n) the ERA state sequence of the window's rows."""
        return self._extended(self.rows)[:, self.p + self.m :] @ self._transform[:, :n]

    def _extended(self, rows: np.ndarray) -> np.ndarray:
        """``e_k = [y_k; u_k; v_{k-1}; ..; v_{k-c}]`` (len(rows), (p + m) (c + 1)) of the given rows."""
        s = np.hstack([self._y, self._u])
        index = np.asarray(rows)[:, None] - np.arange(self.n_cols + 1)[None, :]
        return s[index].reshape(len(rows), -1)

    def _indices(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        m, p, top = self.m, self.p, self._top
        return (np.arange(m), m + np.arange(n), m + top + np.arange(p), m + top + p + np.arange(n))

    def regress(self, n: int, *, max_radius: float = 0.9999, covariances: bool = False,
                stabilize: bool = True) -> GramRegression:
        """Steps 1-3 of :mod:`.state_completion` at order n (and ``Q``, ``S`` if asked).

        ``stabilize=False``: ``A`` as regressed, with its eigenvalues but no eigenvectors (the
        jackknife's replicates, :mod:`.mode_jackknife`, need only the poles near the modes).

        Raises
        ------
        ValueError if n exceeds the states given to :meth:`set_states` or too few samples.
        """
        if self._base is None or not 1 <= n <= self._top:
            raise ValueError(f"order {n} outside the Gram's states 1..{self.max_states}")
        m, p = self.m, self.p
        if self.n_samples < fewest_state_samples(n, m, p):
            raise ValueError(f"{self.n_samples} samples are too few to fit a {n}-state model")
        iu, ix, iy, ixn = self._indices(n)
        sub = np.concatenate([ix, iu, iy, ixn])
        k1 = n + m
        g = self._base[np.ix_(sub[: k1 + p], sub[: k1 + p])]  # order [x, u, y]: all rows
        cd = _scaled_solve(g[:k1, :k1], g[:k1, k1 : k1 + p])  # (n + m, p)
        v_coef = np.zeros((k1 + p, p))
        v_coef[:k1] = -cd
        v_coef[k1:] = np.eye(p)
        r_cov = v_coef.T @ g @ v_coef
        g = self._pair_base[np.ix_(sub, sub)]  # order [x, u, y, x_next]: the pairs
        C, D = cd[:n].T, cd[n:].T
        # Coefficients over [x, u, y, x_next] of v = y - C x - D u; the regressors [x, u, v] are
        # reg = [[I, v_coef[:k1]], [0, v_coef[k1:]], [0, 0]]: g @ reg and reg^T g reg by blocks
        # (products with its identity and zero blocks would be most of the flops at n ~ 100).
        size = g.shape[0]
        v_coef = np.vstack([v_coef, np.zeros((n, p))])
        k2 = k1 + p
        g_reg = np.empty((size, k2))
        g_reg[:, :k1] = g[:, :k1]
        g_reg[:, k1:] = g[:, :k2] @ v_coef[:k2]
        reg_gram = np.vstack([g_reg[:k1], v_coef[:k2].T @ g_reg[:k2]])  # reg^T g reg
        abl = _scaled_solve(reg_gram, g_reg[k2:].T)  # targets x_next
        A, B = abl[:n].T, abl[n:k1].T
        if stabilize:
            A, n_moved, eigen = stabilize_with_eigen(A, max_radius=max_radius)
        else:
            n_moved, eigen = 0, (linalg.eigvals(A), None)
        if n_moved:
            # [u, v] on x_next - A x: the rows [x, u, y] of g times the target's coefficients.
            g_target = g[:k2, k2:] - g[:k2, :n] @ A.T
            bl = _scaled_solve(reg_gram[n:, n:], np.vstack([g_target[n:k1], v_coef[:k2].T @ g_target]))
            B = bl[:m].T
        q_cov = s_cov = None
        if covariances:
            w_coef = np.zeros((size, n))
            w_coef[:n] = -A.T
            w_coef[n:k1] = -B.T
            w_coef[k1 + p :] = np.eye(n)
            gw = g @ w_coef
            q_cov, s_cov = w_coef.T @ gw, gw.T @ v_coef
            pair_r = v_coef.T @ g @ v_coef  # R of the pairs, as noise_covariances(w, v[:-1])
            q_cov, s_cov = (q_cov, pair_r), s_cov
        r_cov = 0.5 * (r_cov + r_cov.T)
        return GramRegression(A, B, C, D, eigen=eigen, covariances=(q_cov, r_cov, s_cov), n_samples=self.n_samples)

