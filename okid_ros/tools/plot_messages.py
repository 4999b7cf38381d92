"""The model messages `plot` draws, decoded and checked: one that cannot be drawn is left out and counted.

A bag's ``arx_model`` and ``state_space_model`` topics hold what was published on them: a
recording of ``okid-ros record`` takes any publisher's messages, not only the nodes'. A
message whose arrays do not have the sizes its counts give, whose values are not finite, whose
sample time is not a positive number of seconds (the checks of the one decoder,
:func:`~okid_ros.nodes.conversions.state_space_from_msg`) or whose ``A`` is unstable (node 2 publishes no
such model) cannot be drawn: each reader raises ``ValueError`` with the reason, and
:class:`LeftOut` counts those messages for one warning, the figures drawn from the others.
"""

from __future__ import annotations

import warnings
from collections import Counter
from typing import Any

import numpy as np

from okid_ros.errors import OkidWarning
from okid_ros.nodes.conversions import message_array, state_space_from_msg

__all__ = ["LeftOut", "arx_markov", "state_space_model"]


def state_space_model(msg: Any) -> dict:
    """A StateSpaceModel message, decoded and checked by ``state_space_from_msg``, its ``A`` stable; else ValueError."""
    model = state_space_from_msg(msg)
    radius = float(np.max(np.abs(np.linalg.eigvals(model["A"])))) if model["A"].size else 0.0
    if not radius < 1:
        raise ValueError(f"A is unstable (spectral radius {radius:.4g}): node 2 publishes no such model")
    return model


def arx_markov(msg: Any) -> np.ndarray:
    """The system Markov parameters (count, p, m) of a valid ArxModel message; ValueError if not drawable."""
    count, p, m = int(msg.markov_parameters_count), int(msg.n_outputs), int(msg.n_inputs)
    return message_array(msg, "markov_parameters", (count, p * m)).reshape(count, p, m)


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
