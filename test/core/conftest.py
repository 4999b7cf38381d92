"""Fixtures of the core's tests."""

from __future__ import annotations

import numpy as np
import pytest

from okid_ros.sim.inputs import lowpass_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation


@pytest.fixture(scope="module")
def paper_record() -> tuple[np.ndarray, np.ndarray]:
    """``(u, y)`` of the paper's structure: 3750 samples at 125 Hz, two inputs low-passed at 15 Hz."""
    truth = paper_model()
    u = lowpass_input(3750, 2, 15.0, truth.sample_time_s, seed=3)
    y, _ = simulate_innovation(truth, u, seed=4)
    return u, y
