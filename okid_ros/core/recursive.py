"""The sliding window of ARX regressor rows and its normal equations, updated recursively.

The window keeps the samples its regressor rows are built from and the sums the ARX least
squares of :mod:`okid_ros.core.arx` needs over those rows. With the regressor of
:mod:`okid_ros.core.regressors`,

    phi_k = [u_k; v_{k-1}; ...; v_{k-q}],   v_j = [y_j; u_j],   d = m + q (p + m),

:meth:`SlidingWindowArx.normal_equations` returns, over the rows ``k`` in the window,

    R = sum w_k phi_k phi_k^T (d, d),   r = sum w_k phi_k y_k^T (d, p),   Y^T Y = sum w_k y_k y_k^T,
    phi_sum = sum w_k phi_k (d,),       y_sum = sum w_k y_k (p,),

with ``w_k = 1`` for a finite window of the last ``W`` rows (exactly the sums of the batch
:func:`okid_ros.core.arx.normal_equations` on those rows) or ``w_k = lambda^(t - k)`` for an
infinite history with forgetting factor ``lambda``. Solving them is the ARX fit's job
(:func:`okid_ros.core.arx.fit_from_normal_equations`, :func:`okid_ros.core.arx.solve_fixed_penalty`);
checking sample stamps is the sample grid's (:mod:`okid_ros.service.sample_grid`).

How it stays fast and exact
---------------------------
Rather than ``R``, ``r`` and ``Y^T Y`` separately, the window keeps one augmented Gram matrix
``G`` (D, D), ``D = (q + 1)(p + m) = d + p``, of the extended rows ``psi_k = [v_{k-q}; ...; v_k]``
and their sum ``s`` (:class:`okid_ros.core.window_gram.WindowGram`): each ``psi_k`` is a
contiguous slice of the time-ordered sample buffer, and one symmetric rank-k BLAS update
(``dsyrk``) adds or removes a whole block of rows. Samples are only
stored (O(p + m) per sample); rows are added and removed in blocks of ``block_size``. Every
``refactor_every`` added rows ``G`` and ``s`` are recomputed from the stored window so that the
rounding of the add/remove cycle never accumulates.

Memory: the sample buffer holds the samples that the rows of the window need, ``W + q`` of them
without gaps (``(W + q)(p + m)`` floats; with many gaps inside the window up to ``q`` more per
gap), with 2-4 times that allocated for amortized compaction, plus ``G``, O(D^2).

Bad samples and gaps
--------------------
A sample with NaN/Inf, or with a value beyond ``MAX_SAMPLE_MAGNITUDE`` (1e150: its square,
summed over the window, would overflow the normal equations), is rejected and counted
(``rejected_nonfinite``, ``rejected_magnitude``), and breaks the lag history: the next ``q``
accepted samples only refill it and give no regressor row, so no row ever contains data from
both sides of a break (as :func:`okid_ros.core.regressors.arx_regressors` with ``valid``). The
same happens on :meth:`SlidingWindowArx.mark_gap`, which the caller invokes where samples are
missing (the sample grid says where).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from okid_ros.core.arx import NormalEquations
from okid_ros.core.regressors import regressor_length
from okid_ros.core.window_gram import CANCELLATION_RATIO, WindowGram
from okid_ros.core.window_samples import (
    MAX_SAMPLE_MAGNITUDE,
    MAX_SQUARED_NORM,
    WindowStatus,
    accepted_samples,
    block_arrays,
    count_rejection,
    lag_runs,
    needed_samples,
)

__all__ = ["CANCELLATION_RATIO", "MAX_SAMPLE_MAGNITUDE", "SlidingWindowArx", "WindowStatus"]

class SlidingWindowArx:
    """The normal equations of the ARX regressor rows in a sliding window, updated recursively.

    Parameters
    ----------
    order : ARX order q >= 1.
    n_outputs, n_inputs : p and m.
    window : W, the number of regressor rows in the finite-history window; ``None`` for
        infinite history (then ``forgetting`` < 1 discounts old rows; 1.0 keeps them all).
    forgetting : lambda in (0, 1]; must be 1.0 with a finite window.
    block_size : rows applied to ``G`` per BLAS call; larger is faster per row, up to ~256.
    refactor_every : recompute ``G`` from the stored window after this many added rows
        (finite window only). Default ``max(100_000, 4 W)``.

    Examples
    --------
    >>> from okid_ros.core.arx import solve_fixed_penalty
    >>> window = SlidingWindowArx(2, 1, 1, window=500)
    >>> rng = np.random.default_rng(0)
    >>> u = rng.standard_normal((1000, 1)); y = np.zeros((1000, 1))
    >>> for k in range(2, 1000):
    ...     y[k] = 1.5 * y[k - 1] - 0.7 * y[k - 2] + 0.5 * u[k - 1]
    >>> window.update(u, y)
    1000
    >>> normal = window.normal_equations()
    >>> normal.n_rows
    500
    >>> theta = solve_fixed_penalty(normal, np.eye(5), 1e-6)
    >>> np.round(theta[:, 0], 3).tolist()  # [b0, a1, b1, a2, b2]
    [0.0, 1.5, 0.5, -0.7, 0.0]
    """

    def __init__(
        self,
        order: int,
        n_outputs: int,
        n_inputs: int,
        *,
        window: int | None = 4000,
        forgetting: float = 1.0,
        block_size: int = 128,
        refactor_every: int | None = None,
    ) -> None:
        if int(order) < 1:
            raise ValueError(f"ARX order must be >= 1, got {order}")
        if int(n_outputs) < 1 or int(n_inputs) < 0:  # m = 0: a vector autoregression (output-only)
            raise ValueError(f"need at least one output and m >= 0 inputs, got p={n_outputs}, m={n_inputs}")
        self.order = q = int(order)
        self.n_outputs = p = int(n_outputs)
        self.n_inputs = m = int(n_inputs)
        self.n_params = regressor_length(q, p, m)
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
        if int(block_size) < 1:
            raise ValueError(f"block_size must be >= 1, got {block_size}")
        self.block_size = int(block_size)
        if refactor_every is None:
            refactor_every = max(100_000, 4 * (window or 0))
        self.refactor_every = int(refactor_every)

        self._sums = WindowGram(q, p, m)  # G and s
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget all samples, rows and counters (the configuration is kept)."""
        q = self.order
        cap = 2 * ((self.window or 0) + q + self.block_size) + 16
        self._alloc(cap)
        self._n = 0  # buffer positions in use
        self._lo = 0  # first position that may hold a row of the window
        self._hi = 0  # eligible rows below this position are in G
        self._n_acc = 0  # rows in G (finite window)
        self._n_pend = 0  # eligible rows at positions >= _hi
        self._n_eff = 0.0  # sum of the weights of the rows in G
        self._rows_since_refactor = 0
        self._run = 0  # accepted samples since the lag history was last broken
        self._sums.clear()
        self._adapting = True
        self._status = WindowStatus()

    def _alloc(self, cap: int) -> None:
        self._cap = cap
        self._buf = np.zeros((cap, self._w))
        self._elig = np.zeros(cap, dtype=bool)
        self._start = np.zeros(cap, dtype=bool)  # sample not contiguous with the previous one
        # Row view: _rows[j] is psi of the sample at position j + q, a slice of the buffer.
        self._rows = sliding_window_view(self._buf.reshape(-1), self._D)[:: self._w]

    @property
    def adaptation_enabled(self) -> bool:
        """When False, samples are still stored and counted but the window does not change."""
        return self._adapting

    @adaptation_enabled.setter
    def adaptation_enabled(self, on: bool) -> None:
        self._adapting = bool(on)

    def mark_gap(self) -> None:
        """Break the lag history: the next q accepted samples only refill it."""
        if self._run > 0:
            self._status.gaps += 1
        self._run = 0

    # ------------------------------------------------------------------ samples in
    def push(self, u_k, y_k) -> bool:
        """Offer one sample; return whether it was accepted (False: NaN/Inf, counted, a gap).

        Parameters
        ----------
        u_k : (m,) inputs at sample k.
        y_k : (p,) outputs at sample k.

        Raises
        ------
        ValueError
            If the sizes of ``u_k`` or ``y_k`` are not m and p.
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
        if self._n >= self._cap:
            self._make_room(1)
        n = self._n
        row = self._buf[n]
        row[: self.n_outputs] = y
        row[self.n_outputs :] = u
        # One dot product catches NaN/Inf and huge values (NaN <= x is False); only then look
        # closer. The slot is only taken (n advanced) once the sample is accepted. Beyond 1e154
        # the square overflows to inf, which is the rejection itself, not a warning to print.
        with np.errstate(over="ignore", invalid="ignore"):
            square = row @ row
        if not square <= MAX_SQUARED_NORM:
            count_rejection(row, st)
            self.mark_gap()
            return False
        self._n = n + 1
        st.samples_accepted += 1
        self._run += 1
        self._start[n] = self._run == 1
        if self._run > self.order and self._adapting:
            self._elig[n] = True
            self._n_pend += 1
            if self._n_pend >= self.block_size:
                self._flush()
        return True

    def update(self, u_block, y_block) -> int:
        """Offer a block of samples; return how many were accepted.

        The result is the same as pushing the samples one at a time.

        Parameters
        ----------
        u_block : (N, m) inputs (or (N,) if m == 1).
        y_block : (N, p) outputs (or (N,) if p == 1).
        """
        u, y = block_arrays(u_block, y_block, self.n_inputs, self.n_outputs)
        n_in = u.shape[0]
        st = self._status
        st.samples_seen += n_in
        if n_in == 0:
            return 0
        accepted = accepted_samples(u, y, st)
        run_after, gaps = lag_runs(accepted, self._run)
        st.gaps += gaps
        self._run = int(run_after[-1])
        acc_idx = np.flatnonzero(accepted)
        if acc_idx.size == 0:
            return 0
        v_acc = np.hstack([y[acc_idx], u[acc_idx]])
        run_acc = run_after[acc_idx]
        row_ok = run_acc > self.order
        st.samples_accepted += acc_idx.size
        start = 0
        while start < acc_idx.size:
            # Chunks of at most one block keep the buffer (and each BLAS call) bounded.
            room = self.block_size - self._n_pend if self._adapting else self.block_size
            stop = min(acc_idx.size, start + max(room, 1))
            count = stop - start
            if self._n + count > self._cap:
                self._make_room(count)
            n0 = self._n
            self._buf[n0 : n0 + count] = v_acc[start:stop]
            self._start[n0 : n0 + count] = run_acc[start:stop] == 1
            if self._adapting:
                pos = n0 + np.flatnonzero(row_ok[start:stop])
                self._elig[pos] = True
                self._n_pend += pos.size
            self._n = n0 + count
            if self._n_pend >= self.block_size:
                self._flush()
            start = stop
        return int(acc_idx.size)

    # ------------------------------------------------------------------ normal equations
    def _flush(self) -> None:
        """Apply the pending rows to ``G`` and ``s`` (and remove the rows that leave the window)."""
        if self._n_pend == 0:
            return
        q = self.order
        n, hi = self._n, self._hi
        add = hi + np.flatnonzero(self._elig[hi:n])
        cancelled = False
        if self.window is None:
            discount, weight = self._sums.add_discounted(self._rows[add - q], self.forgetting)
            self._n_eff = discount * self._n_eff + weight
            self._elig[add] = False
            self._lo = self._hi = n
        else:
            W = self.window
            excess = self._n_acc + add.size - W
            if excess >= self._n_acc:
                # Everything in G leaves: start G afresh from the newest W rows (exact).
                add = add[add.size - W :] if add.size > W else add
                self._recompute(add)
                self._lo = int(add[0])
                self._n_acc = add.size
            else:
                self._sums.add(self._rows[add - q])
                if excess > 0:
                    lo = self._lo
                    old = lo + np.flatnonzero(self._elig[lo:hi])[:excess]
                    cancelled = self._sums.remove(self._rows[old - q])  # a row far beyond what stays: recompute
                    self._lo = int(old[-1]) + 1
                self._n_acc += add.size - max(excess, 0)
                self._rows_since_refactor += add.size
            self._hi = n
            self._n_eff = float(self._n_acc)
        self._n_pend = 0
        if self.window is not None and (cancelled or self._rows_since_refactor >= self.refactor_every):
            self.refactor()

    def _recompute(self, positions: np.ndarray) -> None:
        """Set ``G`` and ``s`` to the sums over the rows at ``positions``."""
        self._sums.recompute(self._rows, positions - self.order)
        self._rows_since_refactor = 0

    def refactor(self) -> None:
        """Recompute ``G`` and ``s`` from the rows stored for the window (finite window only)."""
        if self.window is None:
            return
        self._flush()
        lo, hi = self._lo, self._hi
        self._recompute(lo + np.flatnonzero(self._elig[lo:hi]))
        self._status.refactorizations += 1

    def _make_room(self, count: int) -> None:
        """Compact the buffer to the samples still needed; grow it if they fill half of it."""
        q, n = self.order, self._n
        lo = self._lo
        keep = needed_samples(n, q, lo + np.flatnonzero(self._elig[lo:n]))  # rows of the window and pending rows
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

    # ------------------------------------------------------------------ results
    def normal_equations(self) -> NormalEquations:
        """The window's sums in ARX layout (module docstring), as :class:`~okid_ros.core.arx.NormalEquations`.

        ``R`` (d, d), ``r`` (d, p), ``yy`` (p, p), ``phi_sum`` (d,), ``y_sum`` (p,); ``n_rows``
        is the row count (an int), or with forgetting the effective row count ``sum w_k``.
        """
        self._flush()
        zero = np.empty(0, dtype=np.int64)
        if self.window is not None:  # only downdates leave residue; infinite history subtracts nothing
            zero = np.flatnonzero(~np.any(self._buf[self._window_first():self._n] != 0, axis=0))
        return self._sums.normal_equations(self._n_eff if self.window is None else self._n_acc, zero)

    def _window_first(self) -> int:
        """Buffer position of the first sample the window's rows reach (``q`` before its oldest row)."""
        lo = self._lo if self.window is not None else self._hi
        rows = lo + np.flatnonzero(self._elig[lo:self._n])
        return max(int(rows[0]) - self.order, 0) if rows.size else max(self._n - self.order, 0)

    def window_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Samples stored for the window, oldest first: ``u`` (n, m), ``y`` (n, p), ``segment_start`` (n,).

        They run from ``q`` samples before the oldest row of the window to the newest sample.
        ``segment_start[i]`` is True where the samples are not contiguous with the previous one
        (after a gap, or where samples no row needs were dropped).
        """
        self._flush()
        p, n = self.n_outputs, self._n
        first = self._window_first()
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
        """Bytes held by the sample buffer, ``G`` and ``s``."""
        arrays = (self._buf, self._elig, self._start, self._sums.gram, self._sums.row_sum)
        return int(sum(a.nbytes for a in arrays))
