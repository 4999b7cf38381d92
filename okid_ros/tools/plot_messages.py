"""The model messages `plot` draws, decoded and checked: one that cannot be drawn is left out and counted.

A bag's ``arx_model`` and ``state_space_model`` topics hold what was published on them: a
recording of ``okid-ros record`` takes any publisher's messages, not only the nodes'. A
message whose arrays do not have the sizes its counts give, whose values are not finite, whose
sample time is not a positive number of seconds or whose ``A`` is unstable (node 2 publishes no
such model) cannot be drawn: each reader raises ``ValueError`` with the reason, and
:class:`LeftOut` counts those messages for one warning, the figures drawn from the others.
"""

from __future__ import annotations

import math
import warnings
from collections import Counter
from typing import Any

import numpy as np

from okid_ros.errors import OkidWarning

__all__ = ["LeftOut", "arx_markov", "state_space_model"]


def _array(msg: Any, name: str, rows: int, cols: int) -> np.ndarray:
    values = np.asarray(getattr(msg, name), dtype=float)
    if values.size != rows * cols:
        raise ValueError(f"{name} has {values.size} values, its sizes give {rows} x {cols}")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{name} holds values that are not finite")
    return values.reshape(rows, cols)


def _sample_time_s(msg: Any) -> float:
    sample_time_s = float(msg.sample_time_s)
    if not (math.isfinite(sample_time_s) and sample_time_s > 0):
        raise ValueError(f"sample_time_s {sample_time_s!r} is not a positive number of seconds")
    return sample_time_s


def _mode(mode: Any, n_outputs: int) -> dict:
    frequency_hz, damping_ratio = float(mode.frequency_hz), float(mode.damping_ratio)
    if not (math.isfinite(frequency_hz) and math.isfinite(damping_ratio)):
        raise ValueError(f"mode {int(mode.id)}: frequency_hz {frequency_hz!r}, damping_ratio {damping_ratio!r}")
    real, imag = np.asarray(mode.shape_real, float), np.asarray(mode.shape_imag, float)
    if real.size != n_outputs or imag.size not in (0, n_outputs):
        raise ValueError(f"mode {int(mode.id)}: its shape has {real.size} real and {imag.size} imaginary values, "
                         f"the model {n_outputs} outputs")
    return {"id": int(mode.id), "frequency_hz": frequency_hz, "damping_ratio": damping_ratio,
            "shape": real + 1j * (imag if imag.size else 0.0)}


def state_space_model(msg: Any) -> dict:
    """``A, B, C, D, K, n, model_id, sample_time_s, modes`` of a StateSpaceModel message; ValueError if not drawable."""
    n, p, m = int(msg.n_states), int(msg.n_outputs), int(msg.n_inputs)
    model = {"A": _array(msg, "a", n, n), "B": _array(msg, "b", n, m), "C": _array(msg, "c", p, n),
             "D": _array(msg, "d", p, m), "K": _array(msg, "k", n, p), "n": n, "model_id": int(msg.model_id),
             "sample_time_s": _sample_time_s(msg), "modes": [_mode(mode, p) for mode in msg.modes]}
    radius = float(np.max(np.abs(np.linalg.eigvals(model["A"])))) if n else 0.0
    if not radius < 1:
        raise ValueError(f"A is unstable (spectral radius {radius:.4g}): node 2 publishes no such model")
    return model


def arx_markov(msg: Any) -> np.ndarray:
    """The system Markov parameters (count, p, m) of a valid ArxModel message; ValueError if not drawable."""
    count, p, m = int(msg.markov_parameters_count), int(msg.n_outputs), int(msg.n_inputs)
    return _array(msg, "markov_parameters", count, p * m).reshape(count, p, m)


class LeftOut:
    """The model messages of a bag left out of the figures, counted per topic, with the last one's reason."""

    def __init__(self) -> None:
        self.counts: Counter = Counter()
        self.last: dict[str, str] = {}

    def add(self, topic: str, msg: Any, exc: ValueError) -> None:
        self.counts[topic] += 1
        self.last[topic] = f"model {int(msg.model_id)}: {exc}"

    def warn(self, bag: str, totals: dict[str, int]) -> None:
        """One warning per topic with messages left out (nothing when none was)."""
        for topic, count in self.counts.items():
            warnings.warn(f"{bag}: {count} of the {totals.get(topic, count)} messages on {topic} left out, not drawn "
                          f"(the last: {self.last[topic]})", OkidWarning, stacklevel=3)
