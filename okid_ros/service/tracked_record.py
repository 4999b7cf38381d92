"""A record tracked offline (``okid-ros track``): what it holds besides the structure's response, and its samples.

The windows are fitted on the record as node 1 takes it live (its glitch gates: service/window_gates.py). Only a sensor
re-zero node 2's watch finds is taken off the samples from where it lies, as node 2 does
(:class:`okid_ros.service.record_watch.RecordWatch`, which runs the watch over the record). :class:`TrackedRecord`
keeps which samples are missing, where the window restarted, and hands the realization its samples. What is named
before the tracking (:func:`tracked_record_warnings`): the missing samples (NaN/Inf, skipped as the nodes skip
them) and the sensor faults ``identify`` names (:func:`okid_ros.core.sensor_faults.record_fault_warnings`:
clipping, an output held alone, frozen outputs, level shifts, spikes, drift, harmonic lines the inputs lack), on the
samples the window accepts (:func:`okid_ros.core.window_samples.accepted_samples`).
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.realization_window import realization_window
from okid_ros.core.sensor_faults import record_fault_warnings
from okid_ros.core.window_samples import WindowStatus, accepted_samples
from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams

__all__ = ["TrackedRecord", "node_1_params", "tracked_record_warnings"]


def tracked_record_warnings(u: np.ndarray, y: np.ndarray, sample_time_s: float, *,
                            scaled: tuple[np.ndarray, np.ndarray] | None = None) -> list[str]:
    """The warnings of a record before it is tracked: its missing samples, then its sensor faults.

    Parameters
    ----------
    u : (N, m) inputs (m = 0: output-only); y : (N, p) outputs, in the record's units (NaN/Inf
        at missing samples): the values the warnings quote; sample_time_s : sample time (s).
    scaled : ``(u, y)`` as the windows see them, divided by their scales
        (:class:`okid_ros.core.channels.ChannelScales`); None: the windows see ``u``, ``y``.
    """
    warnings = []
    bad = ~(np.isfinite(u).all(axis=1) & np.isfinite(y).all(axis=1))
    if bad.any():
        warnings.append(f"{int(bad.sum())} of the {bad.size} samples hold NaN/Inf (the first at sample "
                        f"{int(np.argmax(bad))}): they are skipped as missing samples, as the nodes do (short gaps "
                        f"bridged, the ARX rows that reach them left out)")
    # The samples the window leaves out (beyond 1e150 too) are missing for the faults' rules as well.
    valid = accepted_samples(*((u, y) if scaled is None else scaled), WindowStatus())
    return warnings + record_fault_warnings(u, y, valid=valid, sample_time_s=sample_time_s)


def node_1_params(sample_time_s: float, order: int, n_outputs: int, n_inputs: int, *, window: int,
                  regularization: str, penalty: float | str, restart_min_fill: float) -> ArxIdentificationParams:
    """Node 1's options of ``track``'s window: the node's defaults but the window, ARX order and regularization.

    ``penalty``: "gcv" (node 1's ``arx.penalty_by_gcv``: the penalty and TC decay by GCV at each solve) or a
    fixed penalty (the TC decay then node 1's fixed ``arx.tc_decay``).
    """
    fixed = {} if penalty == "gcv" else {"penalty": float(penalty)}
    return ArxIdentificationParams(sample_time_s=float(sample_time_s), order=int(order), n_outputs=n_outputs,
                                   n_inputs=n_inputs, window_length=int(window), regularization=regularization,
                                   penalty_by_gcv=not fixed, restart_min_fill=float(restart_min_fill), **fixed)


class TrackedRecord:
    """The record as the window sees it: which samples are missing (NaN/Inf), where the window restarted.

    Parameters
    ----------
    u : (N, m); y : (N, p) the record (divided by its powers of two where a group needs it); order : the ARX order q.
    params : node 1's options of the window (its ``window_length``, ``min_window_fill`` and ``restart_min_fill``
        say how many rows a model needs); None: node 1's defaults with a window of one row.
    """

    def __init__(self, u, y, order: int, *, params: ArxIdentificationParams | None = None) -> None:
        self.u, self.y, self.order = u, y, int(order)
        # Node 1's rule of the rows a valid snapshot needs (min_window_fill; after a change restart_min_fill).
        self.fills = ArxIdentificationParams(window_length=1) if params is None else params
        # The samples the window accepts (finite, within its magnitude limit): the others are missing.
        self.present = accepted_samples(u, y, WindowStatus())
        self.n_missing = int(self.present.size - np.count_nonzero(self.present))
        self.max_gap = int(ModalEstimationParams.max_gap_samples)  # the nodes' default bridge
        self.origin = 0  # the window's first sample (the last change point)
        self.steps: list[int] = []  # where output steps taken off lie (service/record_watch.py; a window's ARX
        # fit may hold them)
        self._realized = (-1, -1)  # the newest row of the last window realized, its update's sample
        # A regressor row k needs samples k - q .. k; rows_before[i]: such rows before sample i.
        missing_before = np.concatenate([[0], np.cumsum(~self.present)])
        k = np.arange(self.order, self.present.size)
        whole = np.zeros(self.present.size, dtype=bool)
        whole[k] = missing_before[k + 1] == missing_before[k - self.order]
        self._rows_before = np.concatenate([[0], np.cumsum(whole)])

    def window_samples(self, fit, k: int, rows: int):
        """The samples of the window of ``rows`` rows ending at sample ``k`` for its realization.

        Its rows are the last ``rows`` samples whose ``q`` lags are all present; missing samples among them
        are filled or end the run as on node 2 (:func:`okid_ros.core.realization_window.realization_window`).
        """
        start = self.window_start(k, rows)
        present = np.flatnonzero(self.present[start : k + 1]) + start
        skipped = np.diff(present, prepend=present[0]) - 1
        skipped[0] = 0
        after = self.present[k : k + 2].all() and k + 1 < self.present.size  # its last sample judged by the next
        return realization_window(self.u[present], self.y[present], skipped, fit, max_gap=self.max_gap,
                                  need=rows + self.order, refit=any(start < i <= k for i in self.steps),
                                  next_sample=(self.u[k + 1], self.y[k + 1]) if after else None)

    def waiting(self, k: int, rows: int, status, changes: list) -> str:
        """Why the update at sample ``k`` gives no model, or "" (it is then the last realized).

        Too few rows for node 1 (:meth:`ArxIdentificationParams.rows_needed`: a snapshot of a window filled less than
        ``arx.min_window_fill``, after a change ``arx.restart_min_fill``, is refused), or none since the last
        realized (the data stopped: that model again would read as new).
        """
        if rows < (needed := self.fills.rows_needed(bool(changes))):
            return _waiting(status, changes, rows, needed)
        # The last sample up to k that ends a regressor row (its q lags present).
        newest = int(self._rows_before.searchsorted(self._rows_before[k + 1], side="left")) - 1
        if newest == self._realized[0]:
            return f"no sample since sample {newest}: the window is the one of the update at sample {self._realized[1]}"
        self._realized = (newest, k)
        return ""

    def window_start(self, k: int, rows: int) -> int:
        """The first sample of the window of ``rows`` rows ending at sample ``k`` (its oldest row's first lag)."""
        q, before = self.order, self._rows_before
        if rows <= 0:
            return k - q + 1
        # The oldest row is the last sample with the count of rows before it that leaves ``rows``
        # rows up to k (or the first row after the restart).
        oldest = max(int(before[k + 1]) - rows, int(before[min(self.origin + q, k)]))
        return int(np.searchsorted(before, oldest, side="right")) - 1 - q


def _waiting(status, changes: list, rows: int, needed: int) -> str:
    """Why the window holds too few rows for a model: a restart at a change, or rejected samples."""
    if changes:
        return f"window restarted at the change (sample {changes[-1].change_index}): {rows} of the {needed} rows needed"
    rejected = [f"{count} samples rejected {why}" for count, why in (
        (status.rejected_magnitude, "for values beyond 1e150 (rescale those channels)"),
        (status.rejected_nonfinite, "for NaN/Inf")) if count]
    why = f": {', '.join(rejected)}" if rejected else ""
    return f"the window holds {rows} of the {needed} rows needed{why}"
