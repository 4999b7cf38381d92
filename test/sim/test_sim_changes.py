"""okid_ros/sim/changes.py: the benchmark's structural changes have the truth they claim."""

from __future__ import annotations

import numpy as np
import pytest

from okid_bench.changes import SAMPLE_TIME_S, change_case
from okid_ros.core.modal import mac


def _discrete_modes(system) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lam, V = np.linalg.eig(system.A)
    s = np.log(lam.astype(complex)) / SAMPLE_TIME_S
    keep = np.flatnonzero(s.imag > 0)
    keep = keep[np.argsort(np.abs(s[keep]))]
    s = s[keep]
    return np.abs(s) / (2 * np.pi), -s.real / np.abs(s), system.C @ V[:, keep]


@pytest.mark.parametrize("kind, size", [("frequency", 0.06), ("damping", 2.0), ("stiffness", 0.2)])
def test_change_cases_match_their_truth(kind, size):
    case = change_case(kind, size)
    for system, freqs, damping in ((case.before, case.old_frequencies_hz, case.old_damping),
                                   (case.after, case.new_frequencies_hz, case.new_damping)):
        f, z, _ = _discrete_modes(system)
        np.testing.assert_allclose(f, freqs, rtol=1e-9)
        np.testing.assert_allclose(z, damping, rtol=1e-6)
    _, _, shapes_before = _discrete_modes(case.before)
    _, _, shapes_after = _discrete_modes(case.after)
    macs = [mac(a, b) for a, b in zip(shapes_before.T, shapes_after.T)]
    if kind == "stiffness":
        assert min(macs) < 0.99  # a local change alters the mode shapes
        assert np.ptp(case.new_frequencies_hz / case.old_frequencies_hz) > 0.01  # and not uniformly
    else:
        assert min(macs) > 0.99
    u, y = case.simulate(600, 300, seed=0)
    assert u.shape == (600, 2) and y.shape == (600, 3) and np.all(np.isfinite(y))
    with pytest.raises(ValueError, match="unknown change kind"):
        change_case("mass", 0.1)
