"""Which samples the sliding ARX window accepts and still needs, and its counters (split from :mod:`.recursive`).

A sample with NaN/Inf or a value beyond :data:`MAX_SAMPLE_MAGNITUDE` is rejected and counted in
:class:`WindowStatus`; the window then breaks its lag history (see :mod:`okid_ros.core.recursive`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_SAMPLE_MAGNITUDE", "WindowStatus", "accepted_run", "accepted_samples", "block_arrays",
           "count_rejection", "in_bound", "lag_runs", "needed_samples"]

#: Largest |value| a sample may hold: W (p + m) squares of it still fit in float64 (1.8e308) for
#: windows up to 1e7 rows. Records in such units are identified in batch after scaling
#: (okid_ros/core/scaling.py); the window keeps the raw sums the service solves.
MAX_SAMPLE_MAGNITUDE = 1e150
MAX_SQUARED_NORM = MAX_SAMPLE_MAGNITUDE**2


@dataclass
class WindowStatus:
    """Counters and health of a :class:`~okid_ros.core.recursive.SlidingWindowArx`.

    Attributes
    ----------
    samples_seen : samples offered to ``push``/``update`` (accepted or not).
    samples_accepted : samples stored (finite).
    rows_in_window : regressor rows currently in the window (pending blocks included).
    window_fill : fraction of the full window, ``rows_in_window / window`` (1.0 once full; for
        infinite history the effective number of rows ``sum lambda^i`` over ``1 / (1 - lambda)``).
    rejected_nonfinite : samples rejected for NaN/Inf in u or y.
    rejected_magnitude : samples rejected for a value beyond ``MAX_SAMPLE_MAGNITUDE`` (units
        too small for the normal equations' squares: rescale the channel).
    gaps : times the lag history was broken (NaN samples, ``mark_gap``).
    refactorizations : times ``G`` was recomputed from the stored window.
    adapting : whether new rows enter the window.
    """

    samples_seen: int = 0
    samples_accepted: int = 0
    rows_in_window: int = 0
    window_fill: float = 0.0
    rejected_nonfinite: int = 0
    gaps: int = 0
    rejected_magnitude: int = 0
    refactorizations: int = 0
    adapting: bool = True


def block_arrays(u_block, y_block, m: int, p: int) -> tuple[np.ndarray, np.ndarray]:
    """A block of samples as float arrays u (N, m), y (N, p), or ValueError naming the wrong size."""
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


def accepted_samples(u: np.ndarray, y: np.ndarray, status: WindowStatus) -> np.ndarray:
    """(N,) bool: the samples of a block the window may use; the rejections counted in ``status``."""
    finite = np.isfinite(u).all(axis=1) & np.isfinite(y).all(axis=1)
    with np.errstate(over="ignore", invalid="ignore"):
        accepted = finite & (np.einsum("ij,ij->i", u, u) + np.einsum("ij,ij->i", y, y) <= MAX_SQUARED_NORM)
    status.rejected_nonfinite += int(np.count_nonzero(~finite))
    status.rejected_magnitude += int(np.count_nonzero(finite & ~accepted))
    return accepted


def in_bound(u: np.ndarray, y: np.ndarray) -> bool:
    """Whether one sample ``u`` (m,), ``y`` (p,) is finite and within :data:`MAX_SAMPLE_MAGNITUDE` (nodes 1 and 2)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return float(u @ u + y @ y) <= MAX_SQUARED_NORM  # NaN fails the comparison


def count_rejection(sample: np.ndarray, status: WindowStatus) -> None:
    """Count one rejected sample ``[y; u]`` in ``status`` by its reason (NaN/Inf or magnitude)."""
    if np.isfinite(sample).all():
        status.rejected_magnitude += 1
    else:
        status.rejected_nonfinite += 1


def lag_runs(accepted: np.ndarray, run: int) -> tuple[np.ndarray, int]:
    """The lag history's run length after each sample of a block, and how many runs its rejections broke.

    ``accepted`` (N,), N >= 1, from :func:`accepted_samples`: a rejected sample breaks the run
    (a gap where one had begun, as ``mark_gap`` counts it); ``run``: the run before the block.
    """
    n_in = accepted.size
    breaks = ~accepted
    csum = np.cumsum(accepted.astype(np.int64))
    last_break = np.maximum.accumulate(np.where(breaks, np.arange(n_in), -1))
    before_break = np.where(last_break > 0, csum[np.maximum(last_break - 1, 0)], 0)
    run_after = np.where(last_break >= 0, csum - before_break, run + csum)
    run_before = np.concatenate([[run], run_after[:-1]])
    return run_after, int(np.count_nonzero(breaks & (run_before > 0)))


def needed_samples(n: int, order: int, rows: np.ndarray) -> np.ndarray:
    """(n,) bool: the stored samples still needed, the next sample's lag history and each row's ``order`` past.

    ``rows``: the buffer positions of the window's rows and of the pending ones (a row at ``r``
    reads the samples ``r - order`` to ``r``).
    """
    keep = np.zeros(n + 1, dtype=np.int64)
    keep[max(n - order, 0) : n] = 1  # lag history of the next sample
    if rows.size:
        # Each row needs its own q past samples: mark [r - q, r] by a difference array.
        cover = np.zeros(n + 1, dtype=np.int64)
        np.add.at(cover, rows - order, 1)
        np.add.at(cover, rows + 1, -1)
        keep |= np.cumsum(cover) > 0
    return keep[:n].astype(bool)


def accepted_run(accepted: np.ndarray, lo: int, hi: int) -> int:
    """The end of the run of accepted samples from ``lo`` (``accepted`` (N,) bool): the first refused one, or ``hi``."""
    refused = np.flatnonzero(~accepted[lo:hi])
    return lo + int(refused[0]) if refused.size else hi
