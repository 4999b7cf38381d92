"""Recursive MIMO ARX over a sliding window: exact, drift-free and fast.

The estimator keeps the normal equations of the ARX least squares of
:mod:`okid_ros.core.arx` for the regressor rows currently in its window, and solves them lazily
when the coefficients are read. With the regressor of :mod:`okid_ros.core.regressors`,

    phi_k = [u_k; v_{k-1}; ...; v_{k-q}],   v_j = [y_j; u_j],   d = m + q (p + m),

the coefficients after any update are

    Theta = argmin  sum_{k in window} w_k ||y_k - Theta^T phi_k||^2 + penalty trace(Theta^T P^{-1} Theta)
          = (R + penalty P^{-1})^{-1} r,     R = sum w_k phi_k phi_k^T,  r = sum w_k phi_k y_k^T,

with ``w_k = 1`` for a finite window of the last ``W`` rows (exactly the batch solution on those
rows) or ``w_k = lambda^(t - k)`` for infinite history with forgetting factor ``lambda``.

How it stays fast and exact
---------------------------
Rather than ``R``, ``r`` and ``Y^T Y`` separately, the estimator keeps one augmented Gram
matrix ``G = sum w_k psi_k psi_k^T`` (D, D), ``D = (q + 1)(p + m) = d + p``, of the extended
rows ``psi_k = [v_{k-q}; ...; v_{k-1}; v_k]``: each ``psi_k`` is a contiguous slice of the
time-ordered sample buffer, ``R``, ``r`` and ``Y^T Y`` are sub-blocks of ``G`` (a fixed index
permutation), and one symmetric rank-k BLAS update (``dsyrk``) adds or removes a whole block
of rows. Samples are only stored (O(p + m) per sample); rows are added and removed in blocks
of ``block_size``; the solve (one Cholesky, O(d^3)) happens only when the coefficients are read.
Every ``refactor_every`` added rows ``G`` is recomputed from the stored window so that the
rounding of the add/remove cycle never accumulates.

Memory: the sample buffer holds the samples that the rows of the window need, ``W + q`` of
them without gaps (``(W + q)(p + m)`` floats; with many gaps inside the window up to
``q`` more per gap), with 2-4 times that allocated for amortized compaction, plus ``G`` and the prior, O(d^2).

Bad samples and gaps
--------------------
A sample with NaN/Inf is rejected and counted, and breaks the lag history: the next ``q``
accepted samples only refill it and give no regressor row, so no row ever contains data from
both sides of a break (as :func:`okid_ros.core.regressors.arx_regressors` with ``valid``). The
same happens on :meth:`SlidingWindowArx.mark_gap` and, when stamps are given with a sample
time, on a forward time jump larger than ``gap_factor`` sample times; a stamp that does not
advance (duplicate, within ``stamp_tolerance_s``) or goes backwards is rejected and counted.

Prediction errors
-----------------
Each sample with a full lag history gets its one-step prediction error
``e_k = y_k - Theta^T phi_k`` computed with the coefficients current *before* the sample's row
enters the window, i.e. the coefficients of the last solve (a solve happens when the
coefficients are read, or every ``solve_every`` rows if set; ``solve_every=1`` gives the
classic a-priori error of exact recursive least squares, at the cost of a solve per sample).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import linalg
from scipy.linalg import blas, lapack

from okid_ros.core.arx import (
    ArxFit,
    NormalEquations,
    fit_from_normal_equations,
    prior_precision as arx_prior_precision,
    residual_covariance,
    scaled_condition_number,
    solve_fixed_penalty,
    solve_normal_equations,
)
from okid_ros.core.regressors import regressor_length

__all__ = ["SlidingWindowArx", "WindowStatus", "WindowSolution"]

# Status codes of one sample's stamp check.
_STAMP_OK, _STAMP_GAP, _STAMP_OUT_OF_ORDER, _STAMP_DUPLICATE, _STAMP_NONFINITE = range(5)


@dataclass
class WindowStatus:
    """Counters and health of a :class:`SlidingWindowArx`.

    Attributes
    ----------
    samples_seen : samples offered to ``push``/``update`` (accepted or not).
    samples_accepted : samples stored (finite, in order).
    rows_in_window : regressor rows currently in the estimate (after pending blocks are applied).
    window_fill : ``rows_in_window / window`` (1.0 once full; for infinite history the
        effective number of rows ``sum lambda^i`` over ``1 / (1 - lambda)``).
    rejected_nonfinite : samples rejected for NaN/Inf in u, y or the stamp.
    rejected_out_of_order : samples whose stamp went backwards.
    rejected_duplicate : samples whose stamp did not advance (within the tolerance).
    gaps : times the lag history was broken (NaN runs, time jumps, ``mark_gap``).
    condition_number : condition number of the column-scaled ``R`` at the last solve (a 1-norm
        estimate from its Cholesky factor unless ``exact_condition``; inf if singular).
    last_solve_ok : whether the last solve was accepted (else the last good estimate is kept).
    solves : number of solves.
    refactorizations : number of times ``G`` was recomputed from the stored window.
    penalty : regularization penalty used by the last solve.
    adapting : whether new rows enter the window.
    """

    samples_seen: int = 0
    samples_accepted: int = 0
    rows_in_window: int = 0
    window_fill: float = 0.0
    rejected_nonfinite: int = 0
    rejected_out_of_order: int = 0
    rejected_duplicate: int = 0
    gaps: int = 0
    condition_number: float = float("inf")
    last_solve_ok: bool = False
    solves: int = 0
    refactorizations: int = 0
    penalty: float = 0.0
    adapting: bool = True


@dataclass
class WindowSolution:
    """Result of :meth:`SlidingWindowArx.solve`.

    Attributes
    ----------
    theta : (d, p) the coefficients: this window's solution if ``ok``, else the last good one
        (zeros if there never was one).
    ok : whether this window's solution was accepted.
    condition_number : condition number of the column-scaled ``R`` of this window.
    penalty : the penalty used (chosen by GCV if asked).
    n_rows : rows in the window (effective number with forgetting).
    reason : why the solution was rejected ('' if ok).
    """

    theta: np.ndarray
    ok: bool
    condition_number: float
    penalty: float
    n_rows: float
    reason: str = ""


class SlidingWindowArx:
    """MIMO ARX least squares over a sliding window of regressor rows, updated recursively.

    Parameters
    ----------
    order : ARX order q >= 1.
    n_outputs, n_inputs : p and m.
    window : W, the number of regressor rows in the finite-history window; ``None`` for
        infinite history (then ``forgetting`` < 1 discounts old rows; 1.0 keeps them all).
    forgetting : lambda in (0, 1]; must be 1.0 with a finite window.
    prior_precision : ``P^{-1}`` of the coefficients: a scalar c (``c I``), a (d,) diagonal,
        or a full (d, d) symmetric matrix such as ``arx.prior_precision(..., kind="tc")``
        (see :meth:`from_prior`). MATLAB's initial parameter covariance ``P0`` corresponds to
        ``prior_precision = inv(P0)`` with ``penalty = 1``.
    penalty : fixed penalty >= 0 on ``trace(Theta^T P^{-1} Theta)`` (0: plain least squares),
        or "gcv" to choose it at each solve by generalized cross-validation from the normal
        equations (:func:`okid_ros.core.arx.solve_normal_equations`, an eigendecomposition).
    forget_prior : with forgetting, discount the prior like the data (``penalty lambda^t``), as
        classic RLS with an initial covariance does. Default False: the prior stays fixed.
    block_size : rows applied to ``G`` per BLAS call; larger is faster per row, up to ~256.
    refactor_every : recompute ``G`` from the stored window after this many added rows
        (finite window only). Default ``max(100_000, 4 W)``.
    solve_every : solve automatically every this many added rows (None: only when read).
    max_condition_number : a window whose column-scaled ``R`` is worse conditioned than this
        (or singular) is reported as unexcited and the last good estimate is kept. ``inf``
        accepts any window whose regularized system is positive definite.
    exact_condition : compute the condition number exactly (eigenvalues, O(d^3) with a larger
        constant) instead of the LAPACK 1-norm estimate from the Cholesky factor.
    sample_time_s : nominal sample time; with stamps, a forward jump > ``gap_factor`` sample
        times is a gap.
    stamp_tolerance_s : a stamp within this of the last accepted one is a duplicate (default
        half a sample time, or 0 without a sample time).
    gap_factor : see ``sample_time_s``.

    Examples
    --------
    >>> est = SlidingWindowArx(order=2, n_outputs=1, n_inputs=1, window=500, penalty=1e-6)
    >>> rng = np.random.default_rng(0)
    >>> u = rng.standard_normal((1000, 1)); y = np.zeros((1000, 1))
    >>> for k in range(2, 1000):
    ...     y[k] = 1.5 * y[k - 1] - 0.7 * y[k - 2] + 0.5 * u[k - 1]
    >>> errors = est.update(u, y)
    >>> np.round(est.coefficients()[:, 0], 3).tolist()  # [b0, a1, b1, a2, b2]
    [0.0, 1.5, 0.5, -0.7, 0.0]
    """

    def __init__(
        self,
        order: int,
        n_outputs: int,
        n_inputs: int,
        window: int | None = 4000,
        forgetting: float = 1.0,
        prior_precision: float | np.ndarray = 1.0,
        penalty: float | str = 0.0,
        forget_prior: bool = False,
        block_size: int = 128,
        refactor_every: int | None = None,
        solve_every: int | None = None,
        max_condition_number: float = 1e12,
        exact_condition: bool = False,
        sample_time_s: float | None = None,
        stamp_tolerance_s: float | None = None,
        gap_factor: float = 1.5,
    ) -> None:
        if int(order) < 1:
            raise ValueError(f"ARX order must be >= 1, got {order}")
        if int(n_outputs) < 1 or int(n_inputs) < 1:
            raise ValueError(f"need at least one output and one input, got p={n_outputs}, m={n_inputs}")
        self.order = q = int(order)
        self.n_outputs = p = int(n_outputs)
        self.n_inputs = m = int(n_inputs)
        self.n_params = d = regressor_length(q, p, m)
        self._w = w = p + m
        self._D = (q + 1) * w
        if window is not None:
            window = int(window)
            if window < 1:
                raise ValueError(f"window must be >= 1 rows, got {window}")
            if forgetting != 1.0:
                raise ValueError("a finite window and a forgetting factor exclude each other")
        if not 0.0 < float(forgetting) <= 1.0:
            raise ValueError(f"forgetting factor must be in (0, 1], got {forgetting}")
        self.window = window
        self.forgetting = float(forgetting)
        self.forget_prior = bool(forget_prior)
        if isinstance(penalty, str):
            if penalty != "gcv":
                raise ValueError(f"penalty must be a number >= 0 or 'gcv', got {penalty!r}")
            if forget_prior:
                raise ValueError("forget_prior needs a fixed penalty, not 'gcv'")
        elif not (penalty >= 0.0 and math.isfinite(penalty)):
            raise ValueError(f"penalty must be a finite number >= 0, got {penalty}")
        self.penalty = penalty
        self.precision = self._as_precision(prior_precision, d)
        if int(block_size) < 1:
            raise ValueError(f"block_size must be >= 1, got {block_size}")
        self.block_size = int(block_size)
        if refactor_every is None:
            refactor_every = max(100_000, 4 * (window or 0))
        self.refactor_every = int(refactor_every)
        if solve_every is not None and int(solve_every) < 1:
            raise ValueError(f"solve_every must be >= 1 or None, got {solve_every}")
        self.solve_every = None if solve_every is None else int(solve_every)
        self.max_condition_number = float(max_condition_number)
        self.exact_condition = bool(exact_condition)
        if sample_time_s is not None and not sample_time_s > 0:
            raise ValueError(f"sample_time_s must be > 0, got {sample_time_s}")
        self.sample_time_s = None if sample_time_s is None else float(sample_time_s)
        if stamp_tolerance_s is None:
            stamp_tolerance_s = 0.5 * self.sample_time_s if self.sample_time_s else 0.0
        self.stamp_tolerance_s = float(stamp_tolerance_s)
        self.gap_factor = float(gap_factor)

        # psi_k = [v_{k-q}, ..., v_{k-1}, v_k] (time order) -> ARX layout phi_k and target y_k.
        lag_idx = [(q - lag) * w + c for lag in range(1, q + 1) for c in range(w)]
        self._phi_index = np.array([q * w + p + j for j in range(m)] + lag_idx)
        self._y_index = q * w + np.arange(p)
        self.reset()

    # ------------------------------------------------------------------ construction helpers
    @staticmethod
    def _as_precision(prior: float | np.ndarray, d: int) -> np.ndarray:
        arr = np.asarray(prior, dtype=float)
        if arr.ndim == 0:
            if not (arr > 0 and np.isfinite(arr)):
                raise ValueError(f"scalar prior precision must be finite and > 0, got {prior}")
            return float(arr) * np.eye(d)
        if arr.shape == (d,):
            if not (np.all(arr > 0) and np.all(np.isfinite(arr))):
                raise ValueError("diagonal prior precision must be finite and > 0")
            return np.diag(arr)
        if arr.shape == (d, d):
            if not np.all(np.isfinite(arr)):
                raise ValueError("prior precision holds NaN or Inf")
            if not np.allclose(arr, arr.T, rtol=1e-10, atol=1e-12 * np.abs(arr).max()):
                raise ValueError("prior precision matrix must be symmetric")
            return 0.5 * (arr + arr.T)
        raise ValueError(f"prior precision must be a scalar, ({d},) or ({d}, {d}); got shape {arr.shape}")

    @classmethod
    def from_prior(
        cls,
        order: int,
        n_outputs: int,
        n_inputs: int,
        channel_mean_square: np.ndarray,
        kind: str = "ridge",
        decay: float = 0.95,
        **kwargs,
    ) -> "SlidingWindowArx":
        """An estimator with the batch fit's prior ``arx.prior_precision(kind, decay)``.

        ``channel_mean_square`` (p + m,) fixes the channel scaling (e.g. from
        :func:`okid_ros.core.arx.channel_mean_square` of a first batch window), so that the
        window solution equals the batch fit with the same penalty, prior and rows.
        """
        precision = arx_prior_precision(order, n_outputs, n_inputs, channel_mean_square, kind, decay)
        return cls(order, n_outputs, n_inputs, prior_precision=precision, **kwargs)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget all samples, rows, counters and estimates (the configuration is kept)."""
        q, D = self.order, self._D
        cap = 2 * ((self.window or 0) + q + self.block_size) + 16
        self._alloc(cap)
        self._n = 0  # buffer positions in use
        self._lo = 0  # first position that may hold a row of the window
        self._hi = 0  # eligible rows below this position are in G
        self._n_acc = 0  # rows in G (finite window)
        self._n_pend = 0  # eligible rows at positions >= _hi
        self._n_eff = 0.0  # sum of the weights of the rows in G
        self._rows_total = 0  # rows ever added to G
        self._rows_since_refactor = 0
        self._rows_since_solve = 0
        self._run = 0  # accepted samples since the lag history was last broken
        self._last_stamp: float | None = None
        self._G = np.zeros((D, D), order="F")  # upper triangle valid
        self._dirty = True
        self._adapting = True
        self._status = WindowStatus()
        self._set_theta(np.zeros((self.n_params, self.n_outputs)))
        self._have_good = False
        self._last_solution: WindowSolution | None = None

    def _alloc(self, cap: int) -> None:
        self._cap = cap
        self._buf = np.zeros((cap, self._w))
        self._elig = np.zeros(cap, dtype=bool)
        self._start = np.zeros(cap, dtype=bool)  # sample not contiguous with the previous one
        # Row view: _rows[j] is psi of the sample at position j + q, a slice of the buffer.
        self._rows = sliding_window_view(self._buf.reshape(-1), self._D)[:: self._w]

    def _set_theta(self, theta: np.ndarray) -> None:
        p = self.n_outputs
        self._theta = theta
        # Coefficients of psi_k = [v_{k-q}, ..., v_{k-1}, y_k, u_k] (time order, y_k part zero),
        # so that e_k = y_k - psi_k^T theta_psi needs no reordering of the buffer.
        self._theta_psi = np.zeros((self._D, p))
        self._theta_psi[self._phi_index] = theta

    @property
    def adaptation_enabled(self) -> bool:
        """When False, samples still give prediction errors but the window does not change."""
        return self._adapting

    @adaptation_enabled.setter
    def adaptation_enabled(self, on: bool) -> None:
        self._adapting = bool(on)

    def mark_gap(self) -> None:
        """Break the lag history: the next q accepted samples only refill it."""
        if self._run > 0:
            self._status.gaps += 1
        self._run = 0

    # ------------------------------------------------------------------ input checks
    def _check_stamp(self, stamp: float) -> int:
        stamp = float(stamp)
        if not math.isfinite(stamp):
            return _STAMP_NONFINITE
        last = self._last_stamp
        if last is None:
            self._last_stamp = stamp
            return _STAMP_OK
        delta = stamp - last
        if delta < -self.stamp_tolerance_s:
            return _STAMP_OUT_OF_ORDER
        if delta <= self.stamp_tolerance_s:
            return _STAMP_DUPLICATE
        self._last_stamp = stamp
        if self.sample_time_s is not None and delta > self.gap_factor * self.sample_time_s:
            return _STAMP_GAP
        return _STAMP_OK

    def _as_block(self, u_block, y_block) -> tuple[np.ndarray, np.ndarray]:
        m, p = self.n_inputs, self.n_outputs
        u = np.asarray(u_block, dtype=float)
        y = np.asarray(y_block, dtype=float)
        if u.ndim == 1 and m == 1:
            u = u[:, None]
        if y.ndim == 1 and p == 1:
            y = y[:, None]
        if u.ndim != 2 or u.shape[1] != m:
            raise ValueError(f"u block must have shape (N, {m}) (m = {m} inputs); got {u.shape}")
        if y.ndim != 2 or y.shape[1] != p:
            raise ValueError(f"y block must have shape (N, {p}) (p = {p} outputs); got {y.shape}")
        if u.shape[0] != y.shape[0]:
            raise ValueError(f"u and y blocks have different lengths: {u.shape[0]} and {y.shape[0]}")
        return u, y

    # ------------------------------------------------------------------ single-sample path
    def push(self, u_k, y_k, stamp: float | None = None) -> np.ndarray | None:
        """Offer one sample; return its one-step prediction error (p,), or None.

        None means the sample gave no regressor row: rejected (see :attr:`status`) or still
        refilling the lag history after a start or a gap.

        Parameters
        ----------
        u_k : (m,) inputs at sample k.
        y_k : (p,) outputs at sample k.
        stamp : time of the sample in seconds (optional); checked for order, duplicates and
            (with ``sample_time_s``) jumps.
        """
        u = np.asarray(u_k, dtype=float).reshape(-1)
        y = np.asarray(y_k, dtype=float).reshape(-1)
        if u.size != self.n_inputs or y.size != self.n_outputs:
            raise ValueError(
                f"sample must have {self.n_inputs} inputs and {self.n_outputs} outputs; "
                f"got u of size {u.size} and y of size {y.size}"
            )
        st = self._status
        st.samples_seen += 1
        if stamp is not None:
            code = self._check_stamp(stamp)
            if code == _STAMP_OUT_OF_ORDER:
                st.rejected_out_of_order += 1
                return None
            if code == _STAMP_DUPLICATE:
                st.rejected_duplicate += 1
                return None
            if code == _STAMP_NONFINITE:
                st.rejected_nonfinite += 1
                self.mark_gap()
                return None
            if code == _STAMP_GAP:
                self.mark_gap()
        if self._n >= self._cap:
            self._make_room(1)
        n = self._n
        buf = self._buf
        row = buf[n]
        row[: self.n_outputs] = y
        row[self.n_outputs :] = u
        # One sum catches NaN/Inf; only if it is not finite (or overflows) look closer. The
        # slot is only taken (n advanced) once the sample is accepted.
        if not math.isfinite(float(row.sum())) and not np.isfinite(row).all():
            st.rejected_nonfinite += 1
            self.mark_gap()
            return None
        self._n = n + 1
        st.samples_accepted += 1
        self._run += 1
        self._start[n] = self._run == 1
        if self._run <= self.order:
            return None
        # psi_k is the contiguous slice of the buffer ending at this sample.
        err = y - buf[n - self.order : n + 1].reshape(-1) @ self._theta_psi
        if self._adapting:
            self._elig[n] = True
            self._n_pend += 1
            self._rows_since_solve += 1
            if self._n_pend >= self.block_size:
                self._flush()
            if self.solve_every is not None and self._rows_since_solve >= self.solve_every:
                self.solve()
        return err

    # ------------------------------------------------------------------ block path
    def update(self, u_block, y_block, stamps=None) -> np.ndarray:
        """Offer a block of samples; return their one-step prediction errors (N, p).

        Rows of samples without a regressor row (rejected, or refilling the lag history) are
        NaN. The result is the same as pushing the samples one at a time.

        Parameters
        ----------
        u_block : (N, m) inputs (or (N,) if m == 1).
        y_block : (N, p) outputs (or (N,) if p == 1).
        stamps : (N,) times in seconds, optional.
        """
        u, y = self._as_block(u_block, y_block)
        n_in = u.shape[0]
        p, q = self.n_outputs, self.order
        errors = np.full((n_in, p), np.nan)
        if n_in == 0:
            return errors
        st = self._status
        st.samples_seen += n_in
        stamp_code = np.zeros(n_in, dtype=np.int8)
        if stamps is not None:
            stamps = np.asarray(stamps, dtype=float).reshape(-1)
            if stamps.size != n_in:
                raise ValueError(f"stamps must have one entry per sample: {stamps.size} for {n_in}")
            stamp_code = self._classify_stamps(stamps)
        finite = np.isfinite(u).all(axis=1) & np.isfinite(y).all(axis=1)
        nonfinite = (~finite & (stamp_code <= _STAMP_GAP)) | (stamp_code == _STAMP_NONFINITE)
        accepted = finite & (stamp_code <= _STAMP_GAP)
        st.rejected_out_of_order += int(np.count_nonzero(stamp_code == _STAMP_OUT_OF_ORDER))
        st.rejected_duplicate += int(np.count_nonzero(stamp_code == _STAMP_DUPLICATE))
        st.rejected_nonfinite += int(np.count_nonzero(nonfinite))

        # Run length of the lag history after each sample (see push): a break resets it.
        breaks = nonfinite | (stamp_code == _STAMP_GAP)
        inc = accepted.astype(np.int64)
        csum = np.cumsum(inc)
        idx = np.arange(n_in)
        last_break = np.maximum.accumulate(np.where(breaks, idx, -1))
        before_break = np.where(last_break > 0, csum[np.maximum(last_break - 1, 0)], 0)
        run_after = np.where(last_break >= 0, csum - before_break, self._run + csum)
        run_before = np.concatenate([[self._run], run_after[:-1]])
        st.gaps += int(np.count_nonzero(breaks & (run_before > 0)))
        self._run = int(run_after[-1])

        acc_idx = np.flatnonzero(accepted)
        if acc_idx.size == 0:
            return errors
        v_acc = np.hstack([y[acc_idx], u[acc_idx]])
        run_acc = run_after[acc_idx]
        row_ok = run_acc > q
        st.samples_accepted += acc_idx.size
        start = 0
        while start < acc_idx.size:
            # A chunk never crosses a flush or an automatic solve, so every error uses the
            # coefficients that were current before its own sample, as in push.
            room = self.block_size - self._n_pend if self._adapting else self.block_size
            if self.solve_every is not None and self._adapting:
                room = min(room, self.solve_every - self._rows_since_solve)
            stop = min(acc_idx.size, start + max(room, 1))
            count = stop - start
            if self._n + count > self._cap:
                self._make_room(count)
            n0 = self._n
            self._buf[n0 : n0 + count] = v_acc[start:stop]
            self._start[n0 : n0 + count] = run_acc[start:stop] == 1
            ok = row_ok[start:stop]
            pos = n0 + np.flatnonzero(ok)
            if pos.size:
                psi = self._rows[pos - q]
                errors[acc_idx[start:stop][ok]] = y[acc_idx[start:stop][ok]] - psi @ self._theta_psi
                if self._adapting:
                    self._elig[pos] = True
                    self._n_pend += pos.size
                    self._rows_since_solve += pos.size
            self._n = n0 + count
            if self._n_pend >= self.block_size:
                self._flush()
            if self.solve_every is not None and self._rows_since_solve >= self.solve_every:
                self.solve()
            start = stop
        return errors

    def _classify_stamps(self, stamps: np.ndarray) -> np.ndarray:
        """Stamp codes of a block; vectorized when every step is regular, else per sample."""
        last = self._last_stamp
        if last is not None and np.all(np.isfinite(stamps)):
            deltas = np.diff(np.concatenate([[last], stamps]))
            regular = deltas > self.stamp_tolerance_s
            if self.sample_time_s is not None:
                regular &= deltas <= self.gap_factor * self.sample_time_s
            if regular.all():
                self._last_stamp = float(stamps[-1])
                return np.zeros(stamps.size, dtype=np.int8)
        return np.array([self._check_stamp(s) for s in stamps], dtype=np.int8)

    # ------------------------------------------------------------------ normal equations
    def _syrk(self, psi: np.ndarray, alpha: float, beta: float) -> None:
        """``G <- alpha psi^T psi + beta G`` on the upper triangle, in place."""
        self._G = blas.dsyrk(alpha, psi.T, beta=beta, c=self._G, trans=0, lower=0, overwrite_c=1)

    def _flush(self) -> None:
        """Apply the pending rows to ``G`` (and remove the rows that leave the window)."""
        if self._n_pend == 0:
            return
        q = self.order
        n, hi = self._n, self._hi
        add = hi + np.flatnonzero(self._elig[hi:n])
        self._dirty = True
        if self.window is None:
            lam = self.forgetting
            psi = self._rows[add - q]
            if lam == 1.0:
                self._syrk(psi, 1.0, 1.0)
                self._n_eff += add.size
            else:
                weights = lam ** np.arange(add.size - 1, -1, -1, dtype=float)
                self._syrk(psi * np.sqrt(weights)[:, None], 1.0, lam**add.size)
                self._n_eff = lam**add.size * self._n_eff + float(weights.sum())
            self._elig[add] = False
            self._lo = self._hi = n
        else:
            W = self.window
            excess = self._n_acc + add.size - W
            if excess >= self._n_acc:
                # Everything in G leaves: start G afresh from the newest W rows (exact).
                add = add[add.size - W :] if add.size > W else add
                self._G[:] = 0.0
                self._gram(add)
                self._lo = int(add[0])
                self._n_acc = add.size
                self._rows_since_refactor = 0
            else:
                self._syrk(self._rows[add - q], 1.0, 1.0)
                if excess > 0:
                    lo = self._lo
                    old = lo + np.flatnonzero(self._elig[lo:hi])[:excess]
                    self._syrk(self._rows[old - q], -1.0, 1.0)
                    self._lo = int(old[-1]) + 1
                self._n_acc += add.size - max(excess, 0)
                self._rows_since_refactor += add.size
            self._hi = n
            self._n_eff = float(self._n_acc)
        self._rows_total += add.size
        self._n_pend = 0
        if self.window is not None and self._rows_since_refactor >= self.refactor_every:
            self.refactor()

    def _gram(self, positions: np.ndarray, chunk: int = 1024) -> None:
        """Add ``sum psi psi^T`` over rows at ``positions`` to ``G``, in bounded chunks."""
        for s in range(0, positions.size, chunk):
            self._syrk(self._rows[positions[s : s + chunk] - self.order], 1.0, 1.0)

    def refactor(self) -> None:
        """Recompute ``G`` from the rows stored for the window (finite window only)."""
        if self.window is None:
            return
        self._flush()
        lo, hi = self._lo, self._hi
        rows = lo + np.flatnonzero(self._elig[lo:hi])
        self._G[:] = 0.0
        self._gram(rows)
        self._rows_since_refactor = 0
        self._status.refactorizations += 1
        self._dirty = True

    def _make_room(self, count: int) -> None:
        """Compact the buffer to the samples still needed; grow it if they fill half of it."""
        q, n = self.order, self._n
        keep = np.zeros(n + 1, dtype=np.int64)
        keep[max(n - q, 0) : n] = 1  # lag history of the next sample
        lo = self._lo
        rows = lo + np.flatnonzero(self._elig[lo:n])  # rows of the window and pending rows
        if rows.size:
            # Each row needs its own q past samples: mark [r - q, r] by a difference array.
            cover = np.zeros(n + 1, dtype=np.int64)
            np.add.at(cover, rows - q, 1)
            np.add.at(cover, rows + 1, -1)
            keep |= np.cumsum(cover) > 0
        keep = keep[:n].astype(bool)
        kept = np.flatnonzero(keep)
        count_before = np.concatenate([[0], np.cumsum(keep)])  # kept positions below index i
        needed = kept.size + count
        cap = self._cap
        while needed > cap // 2:
            cap *= 2
        v = self._buf[kept]
        elig = self._elig[kept]
        start = self._start[kept]
        # A kept sample whose predecessor was dropped starts a new contiguous segment.
        start[1:] |= np.diff(kept) > 1
        if kept.size:
            start[0] = True
        if cap != self._cap:
            self._alloc(cap)
        self._buf[: kept.size] = v
        self._elig[:] = False
        self._elig[: kept.size] = elig
        self._start[:] = False
        self._start[: kept.size] = start
        self._lo = int(count_before[min(self._lo, n)])
        self._hi = int(count_before[min(self._hi, n)])
        self._n = kept.size

    # ------------------------------------------------------------------ solution
    def normal_equations(self) -> NormalEquations:
        """The window's ``R`` (d, d), ``r`` (d, p), ``Y^T Y`` (p, p) and row count, in ARX layout.

        With forgetting the sums are weighted and ``n_rows`` is the effective row count.
        """
        self._flush()
        G = np.triu(self._G)
        G += np.triu(self._G, 1).T
        pi, yi = self._phi_index, self._y_index
        R = G[np.ix_(pi, pi)]
        r = G[np.ix_(pi, yi)]
        yy = G[np.ix_(yi, yi)]
        n_rows = self._n_eff if self.window is None else self._n_acc
        return NormalEquations(R, r, yy, n_rows)

    def _condition(self, R: np.ndarray) -> float:
        diag = np.diag(R)
        if diag.size == 0 or not np.all(diag > 0):
            return float("inf")
        if self.exact_condition:
            return scaled_condition_number(R)
        s = 1.0 / np.sqrt(diag)
        Rs = R * s[:, None] * s[None, :]
        anorm = float(np.abs(Rs).sum(axis=0).max())  # 1-norm, needed before Rs is overwritten
        chol, info = lapack.dpotrf(Rs, lower=0, clean=0, overwrite_a=1)
        if info != 0:
            return float("inf")
        rcond, info = lapack.dpocon(chol, anorm, uplo="U")
        return float("inf") if info != 0 or rcond <= 0 else 1.0 / rcond

    def solve(self) -> WindowSolution:
        """Solve the window's regularized least squares; keep the last good estimate if unexcited.

        Returns
        -------
        WindowSolution
            ``theta`` (d, p) is this window's solution when ``ok``; otherwise the last good one.
        """
        self._flush()
        if not self._dirty and self._last_solution is not None:
            return self._last_solution
        normal = self.normal_equations()
        st = self._status
        st.solves += 1
        cond = self._condition(normal.R)
        st.condition_number = cond
        penalty = self.penalty
        if not isinstance(penalty, str) and self.forget_prior and self.window is None:
            penalty = penalty * self.forgetting ** self._rows_total
        theta, reason, used = None, "", float("nan") if isinstance(penalty, str) else float(penalty)
        if normal.n_rows == 0:
            reason = "no regressor rows in the window"
        elif not cond <= self.max_condition_number:
            reason = f"unexcited window: condition number {cond:.3g} > {self.max_condition_number:.3g}"
        else:
            try:
                if isinstance(penalty, str):
                    theta, used, _, _ = solve_normal_equations(normal, self.precision, "gcv")
                else:
                    theta = solve_fixed_penalty(normal, self.precision, penalty)
                if not np.all(np.isfinite(theta)):
                    theta, reason = None, "solution not finite"
            except np.linalg.LinAlgError:
                reason = "regularized normal equations not positive definite"
        ok = theta is not None
        if ok:
            self._set_theta(theta)
            self._have_good = True
            st.penalty = used
        st.last_solve_ok = ok
        self._dirty = False
        self._rows_since_solve = 0
        self._last_solution = WindowSolution(
            theta=self._theta, ok=ok, condition_number=cond, penalty=used,
            n_rows=normal.n_rows, reason=reason,
        )
        return self._last_solution

    def coefficients(self) -> np.ndarray:
        """(d, p) coefficients of the current window (solved if needed; last good if unexcited)."""
        return self.solve().theta

    def arx_fit(self, regularization: str = "ridge", penalty: float | str = "gcv", decay: float | str = "gcv") -> ArxFit:
        """The batch fit of :func:`okid_ros.core.arx.fit_from_normal_equations` on this window.

        Identical to ``fit_arx`` on the window's samples (same rows, data-scaled prior chosen
        from the window), independent of this estimator's own fixed prior.
        """
        return fit_from_normal_equations(
            self.normal_equations(), self.order, self.n_outputs, self.n_inputs,
            regularization, penalty, decay,
        )

    def to_arx_fit(self) -> ArxFit:
        """The current estimate (last good) packaged as an :class:`~okid_ros.core.arx.ArxFit`."""
        sol = self.solve()
        normal = self.normal_equations()
        # Effective parameters per output of the fixed-penalty solution: trace((R + lam P)^-1 R).
        lam = sol.penalty if math.isfinite(sol.penalty) else 0.0
        try:
            dof = float(np.trace(linalg.solve(normal.R + lam * self.precision, normal.R, assume_a="pos")))
        except (np.linalg.LinAlgError, ValueError):
            dof = float(self.n_params)
        return ArxFit(
            theta=sol.theta.copy(), order=self.order, n_inputs=self.n_inputs, n_outputs=self.n_outputs,
            residual_covariance=residual_covariance(normal, sol.theta, dof),
            condition_number=sol.condition_number,
            regularization="none" if lam == 0.0 else "custom",
            penalty=lam, effective_parameters=dof, n_rows=int(round(normal.n_rows)),
            extras={"window_solution_ok": sol.ok},
        )

    # ------------------------------------------------------------------ inspection
    def window_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Samples stored for the window, oldest first: ``u`` (n, m), ``y`` (n, p), ``segment_start`` (n,).

        They run from ``q`` samples before the oldest row of the window to the newest sample.
        ``segment_start[i]`` is True where the samples are not contiguous with the previous one
        (after a gap, or where samples no row needs were dropped).
        """
        self._flush()
        q, p, n = self.order, self.n_outputs, self._n
        lo = self._lo if self.window is not None else self._hi
        rows = lo + np.flatnonzero(self._elig[lo:n])
        first = max(int(rows[0]) - q, 0) if rows.size else max(n - q, 0)
        v = self._buf[first:n]
        start = self._start[first:n].copy()
        if start.size:
            start[0] = True
        return v[:, p:].copy(), v[:, :p].copy(), start

    @property
    def status(self) -> WindowStatus:
        """A snapshot of the counters (:class:`WindowStatus`)."""
        st = self._status
        pending = self._n_pend
        if self.window is None:
            lam = self.forgetting
            rows = self._n_eff + pending
            full = 1.0 / (1.0 - lam) if lam < 1.0 else max(rows, 1.0)
            st.rows_in_window = int(round(rows))
            st.window_fill = min(rows / full, 1.0)
        else:
            st.rows_in_window = min(self._n_acc + pending, self.window)
            st.window_fill = st.rows_in_window / self.window
        st.adapting = self._adapting
        return WindowStatus(**vars(st))

    def memory_bytes(self) -> int:
        """Bytes held by the sample buffer, ``G``, the prior and the coefficients."""
        arrays = (self._buf, self._elig, self._start, self._G, self.precision, self._theta, self._theta_psi)
        return int(sum(a.nbytes for a in arrays))
