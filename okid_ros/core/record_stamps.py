"""The stamps a record may carry beside its samples (``stamp_s``, as `okid-ros export` writes them).

`identify` and `track` take a record's samples as consecutive on one grid of ``sample_time_s``;
the stamps are not needed for that, but they show where that does not hold: a record glued from
two exports (100 s apart) had its samples either side of the seam taken as neighbours, in silence.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MAX_STAMP_SLIP", "stamp_jump_problem"]

#: Sample times a step of the stamps may be off the grid's: an exported record's stamps are its
#: messages' own, each within half a sample time of its slot, so steps are within one of the grid's.
MAX_STAMP_SLIP = 2.0


def stamp_jump_problem(stamps: object, sample_time_s: object, *, n_samples: int, rows: bool = False) -> str:
    """Why ``stamps`` (N,) [s] are not the stamps of ``n_samples`` consecutive samples, or "".

    A step more than :data:`MAX_STAMP_SLIP` sample times off ``sample_time_s`` (forward or back),
    or any step back (samples out of time order), is named with its samples (``rows``: a CSV's data
    rows, from 1) and its size; stamps of another length than the samples are refused too. NaN
    stamps, and a sample time that is no positive number (refused by the record's own check), are
    not judged.
    """
    try:
        dt = float(np.asarray(sample_time_s, dtype=float).reshape(-1)[0]) if np.size(sample_time_s) == 1 else 0.0
        stamps = np.asarray(stamps, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return "stamp_s is not an array of numbers (seconds)"
    if stamps.size != n_samples:
        return f"stamp_s holds {stamps.size} stamps for {n_samples} samples"
    if not 0.0 < dt < np.inf:
        return ""
    steps = np.diff(stamps)
    with np.errstate(invalid="ignore"):
        # A step back is samples out of time order (rows sorted or pasted wrong): two rows swapped step
        # back by one sample time, within the slip, and were taken in silence.
        off = np.flatnonzero((np.abs(steps - dt) > MAX_STAMP_SLIP * dt) | (steps < 0))
    if not off.size:
        return ""
    i = int(off[0])
    where = f"data rows {i + 1} and {i + 2}" if rows else f"samples {i} and {i + 1}"
    if -MAX_STAMP_SLIP * dt <= steps[i] < 0:
        return (f"stamp_s steps back by {-steps[i]:.6g} s between {where}: the samples are not in time order "
                f"(rows sorted or pasted wrong?); identify and track take them as consecutive on one grid")
    more = f" (and {off.size - 1} more such step(s))" if off.size > 1 else ""
    return (f"stamp_s jumps by {steps[i]:+.6g} s ({steps[i] / dt:+.6g} sample times of {dt:g} s) between {where}"
            f"{more}: identify and track take the samples as consecutive on one grid (a record glued from two?); "
            f"identify each part on its own")
