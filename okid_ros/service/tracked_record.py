"""What a record tracked offline (``okid-ros track``) holds besides the structure's response, said once before.

The windows are fitted on the record as recorded: they are what node 1 sees live, so nothing
here changes a sample. What is named: the missing samples (NaN/Inf, skipped as the nodes skip
them) and the sensor faults ``identify`` names (:func:`okid_ros.core.sensor_faults.record_fault_warnings`:
clipping, an output held alone, frozen outputs, level shifts, spikes, drift, harmonic lines the inputs lack), on the
samples the window accepts (:func:`okid_ros.core.window_samples.accepted_samples`).
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.sensor_faults import record_fault_warnings
from okid_ros.core.window_samples import WindowStatus, accepted_samples

__all__ = ["tracked_record_warnings"]


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
