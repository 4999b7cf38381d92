"""Node 1's rules for a structural change it is told of: which restart of its window it refuses, and why.

:meth:`~okid_ros.service.identification.ArxIdentificationService.restart_at` judges each
``StructuralChange`` by them before the restart (a replay of the samples held, ~9 ms at window 2000,
order 40, p = m = 2, under the lock node 1's input thread needs). A change is refused when the restart
would change nothing or cannot be of the samples here: the window starts at or after its stamp already
(node 2 reports each change twice; a replayed or misbehaving publisher sends it again and again, or older
ones), it is stamped before the samples held, far after the newest, or not at all, or nothing is held.
A change taken is a pending restart, applied once before the window's next solve; a newer change before
then supersedes it (:func:`superseded_refusal`), so that however many come between two solves the window
is replayed once. Node 2 declares no second change before a model of the first's new structure is
accepted (its change test re-arms with such a model), so a change it sends never supersedes another.
Each refusal is an :class:`IgnoredChange` phrase with the reason, counted as node 2 counts its refused
ArxModels (:func:`~okid_ros.service.results.why_text`).
"""

from __future__ import annotations

import math

import numpy as np

from okid_ros.core.recursive import SlidingWindowArx

__all__ = ["MAX_CHANGE_LEAD_S", "IgnoredChange", "change_refusal", "replay_rows", "restart_window",
           "started_refusal", "superseded_refusal"]

#: How far after the newest sample of the window a structural change may be stamped: node 1 may
#: lag node 2 by its input queue (at most a few hundred samples at the nodes' rates).
MAX_CHANGE_LEAD_S = 2.0


class IgnoredChange:
    """Why node 1 ignores a structural change (:func:`change_refusal`), as "N ..." reads them."""

    STAMP = "without a finite stamp"
    NOTHING_HELD = "while node 1 held no sample"
    BEFORE_HELD = "stamped before the samples node 1 holds"
    FUTURE = "stamped far after node 1's newest sample"
    STARTED = "whose stamp the window starts at or after already (the same change again, or an older one)"
    SUPERSEDED = "superseded by a later one before the window's next solve"


def change_refusal(change_stamp_s: float, *, oldest_s: float, newest_s: float, last_restart_s: float,
                   sample_time_s: float) -> tuple[str, str] | None:
    """Why a restart at ``change_stamp_s`` is refused for its stamp, as (``IgnoredChange`` phrase, reason); or None.

    ``oldest_s``, ``newest_s``: the stamps of the oldest and newest samples held (nan: none);
    ``last_restart_s``: the last restart's change stamp (nan: none since the start or reset). One from
    the future would empty the window and, as the last restart, make every real change before it
    ignored; one before the samples held (or before 0) replayed them all for nothing, as they are all
    of the new structure already; with none held there is nothing to restart.
    """
    tol = 0.5 * sample_time_s
    if not math.isfinite(change_stamp_s):
        return IgnoredChange.STAMP, f"structural change stamped {change_stamp_s}"
    if not math.isfinite(oldest_s):
        return IgnoredChange.NOTHING_HELD, (f"structural change at {change_stamp_s:.3f} s while no sample is held: "
                                            "nothing to restart")
    if change_stamp_s < max(0.0, oldest_s - tol):
        return IgnoredChange.BEFORE_HELD, (f"structural change at {change_stamp_s:.3f} s, before the oldest sample "
                                           f"node 1 holds ({oldest_s:.3f} s): they are all of the new structure")
    if change_stamp_s > newest_s + MAX_CHANGE_LEAD_S:
        return IgnoredChange.FUTURE, (f"structural change at {change_stamp_s:.3f} s, more than MAX_CHANGE_LEAD_S "
                                      f"{MAX_CHANGE_LEAD_S:g} s after the newest sample here ({newest_s:.3f} s)")
    if change_stamp_s <= last_restart_s + tol:  # nan: no restart yet
        return IgnoredChange.STARTED, (f"structural change at {change_stamp_s:.3f} s, at or before the last "
                                       f"restart's ({last_restart_s:.3f} s)")
    return None


def replay_rows(gaps: np.ndarray, order: int) -> int:
    """The regressor rows a restart's replay of samples with lag-history breaks ``gaps`` (N,) gives.

    A run of samples (from the first, and from each non-zero ``gaps``) gives a row from its
    ``order + 1``-th sample on, as :func:`restart_window` enters them.
    """
    index = np.arange(len(gaps))
    run_start = np.maximum.accumulate(np.where((np.asarray(gaps) != 0) | (index == 0), index, 0))
    return int(np.count_nonzero(index - run_start >= order))


def started_refusal(change_stamp_s: float, *, rows_from_change: int, window_rows: int) -> tuple[str, str] | None:
    """``IgnoredChange.STARTED`` with its reason if the window's rows are all of samples from the change on; or None.

    ``rows_from_change``: the rows a restart would replay (:func:`replay_rows`); ``window_rows``: the
    rows the sliding window holds. Every row the window holds is among them when they are as many (the
    replay gives the newest rows of the same samples), so the restart would rebuild the same window; the
    window has slid past a change it restarted at, or past an older one.
    """
    if rows_from_change < window_rows:
        return None
    return IgnoredChange.STARTED, (f"structural change at {change_stamp_s:.3f} s: the window's {window_rows} rows "
                                   "are all of samples from it on already")


def superseded_refusal(pending_stamp_s: float, change_stamp_s: float) -> tuple[str, str]:
    """``IgnoredChange.SUPERSEDED`` with its reason: the restart pending at ``pending_stamp_s`` gives way to a later.

    The window is read only by a solve, so the restart at the later ``change_stamp_s``, applied before
    it, gives the window that restarting at both in turn would (its samples are the later one's).
    """
    return IgnoredChange.SUPERSEDED, (f"structural change at {pending_stamp_s:.3f} s, superseded by the one at "
                                      f"{change_stamp_s:.3f} s before the window's restart was applied")


def restart_window(window: SlidingWindowArx, u: np.ndarray, y: np.ndarray, gaps: np.ndarray | None = None) -> None:
    """Restart a sliding ARX window at a structural change with the samples from the change point on.

    ``u`` (N, m), ``y`` (N, p): the samples from the change point to the newest; ``gaps`` (N,):
    non-zero where the lag history breaks before a sample (None: none, the samples go in as
    one block). Adaptation on or off is kept. (Node 1 at a StructuralChange, ``okid-ros track``
    at a change it declares.)
    """
    adapting = window.adaptation_enabled
    window.reset()
    window.adaptation_enabled = adapting
    if gaps is None:
        window.update(u, y)
        return
    for k in range(u.shape[0]):
        if gaps[k]:
            window.mark_gap()
        window.push(u[k], y[k])
