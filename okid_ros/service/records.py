"""One serialized shape of a mode, of a structural change and of a model update.

Every output that carries a mode takes it from :func:`mode_record`: the JSON lines of
``okid-ros process`` and ``okid-ros track``, the modal CSV (:mod:`okid_ros.tools.exports`) and
the ``okid_msgs/Mode`` message (:func:`okid_ros.nodes.conversions.mode_msg`, which adds the
shape). The fields are the union of the shapes these outputs had (``process`` had no
``stability``, ``track`` had all of them): a field is added, never renamed.

Values are JSON-ready: plain numbers, ``None`` where an indicator is unknown (NaN in the core
and in messages).

>>> from okid_ros.core.modal import Mode
>>> mode = Mode(37.1, 5.9, 0.003, 0.9 + 0.4j, np.array([1.0, 0.5j]), 0.9, 1.0, 0.99, True, True, id=3)
>>> record = mode_record(mode)
>>> record["id"], record["frequency_hz"], record["mac_previous"]
(3, 5.9, None)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["MODE_FIELDS", "MESSAGE_MODE_FIELDS", "change_record", "mode_record", "mode_shape", "update_record"]

#: Fields of a mode record, in order.
MODE_FIELDS = ("id", "frequency_rad_s", "frequency_hz", "damping_ratio", "emac", "mpc", "msv", "mac_previous",
               "stability", "stable", "frequency_hz_std", "damping_ratio_std")
#: The fields ``okid_msgs/Mode`` has of them (besides the shape).
MESSAGE_MODE_FIELDS = tuple(name for name in MODE_FIELDS if name != "stability")


def _number(value: Any) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def mode_record(mode: Any) -> dict:
    """JSON-ready dict of a core :class:`~okid_ros.core.modal.Mode` (unknown indicators: None)."""
    record: dict[str, Any] = {"id": int(mode.id)}
    for name in MODE_FIELDS[1:]:
        if name == "stable":
            record[name] = bool(mode.stable)
        elif name in ("frequency_rad_s", "frequency_hz", "damping_ratio"):
            record[name] = float(getattr(mode, name))
        else:
            record[name] = _number(getattr(mode, name, math.nan))
    return record


def mode_shape(mode: Any) -> tuple[list[float], list[float]]:
    """The mode's shape at the p outputs: real parts, imaginary parts."""
    shape = np.asarray(mode.shape, dtype=complex).reshape(-1)
    return [float(x) for x in shape.real], [float(x) for x in shape.imag]


def change_record(change: Any) -> dict:
    """JSON-ready dict of a :class:`~okid_ros.service.results.StructuralChangeEvent`."""
    return {
        "change_id": int(change.change_id),
        "change_stamp_s": float(change.change_stamp_s),
        "detection_stamp_s": float(change.stamp_s),
        "detection_delay_samples": int(change.detection_delay_samples),
        "statistic": float(change.statistic),
        "threshold": float(change.threshold),
        "variance_ratio": float(change.variance_ratio),
        "modes_before": [mode_record(m) for m in change.modes_before],
        "modes_after": [mode_record(m) for m in change.modes_after],
        "retired_ids": [int(i) for i in change.retired_ids],
    }


def update_record(update: Any, applied_at_stamp_s: float, change: dict | None = None, *,
                  after_last_sample: bool = False) -> dict:
    """JSON line of an accepted model (:class:`~okid_ros.service.results.ModelUpdate`).

    ``change``: the :func:`change_record` of a change declared since the previous update.
    ``after_last_sample``: the model was switched in after the record's last sample (at its end;
    ``applied_at_stamp_s`` is that sample's stamp), so it produced no modal states.
    """
    record = {
        "stamp_s": float(update.stamp_s),
        "applied_at_stamp_s": float(applied_at_stamp_s),
        "model_id": int(update.model_id),
        "arx_model_id": int(update.arx_model_id),
        "n_states": int(update.model.n_states),
        "n_inputs": int(update.model.n_inputs),  # 0: output-only
        "window_samples": int(update.window_samples),
        "realization_time_s": float(update.realization_time_s),
        "modes": [mode_record(m) for m in update.modes],
        "change_detected": change is not None,
        "applied_after_last_sample": bool(after_last_sample),
    }
    if change is not None:
        record.update(change_stamp_s=change["change_stamp_s"], change_detection_stamp_s=change["detection_stamp_s"],
                      change_statistic=change["statistic"])
    return record
