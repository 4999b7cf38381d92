"""The monitor's table from ModalStates of values no node publishes (any publisher on the topic reaches it)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from okid_ros.tools.monitor import ModalStatesView


def _states(coords, frequency_hz: float = 5.0):
    mode = SimpleNamespace(id=0, frequency_hz=frequency_hz, frequency_rad_s=2 * math.pi * frequency_hz,
                           damping_ratio=0.01, emac=0.9, mpc=0.99, msv=0.5, mac_previous=math.nan, stable=True)
    stamp = SimpleNamespace(sec=100, nanosec=0)
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp), model_id=1, modes=[mode],
                           modal_coordinates=list(coords), y_estimated=[0.0], innovation=[1e200])


@pytest.mark.parametrize(("coords", "shown"), [((1e200, 0.0), "inf"), ((math.nan, 1.0), "-"),
                                               ((3.0, 4.0), "5.000e+00")])
def test_modal_coordinates_beyond_float64_squares_are_shown_not_a_crash(coords, shown):
    """Was ``OverflowError: (34, 'Numerical result out of range')`` from ``1e200 ** 2``: the monitor ended, exit 70."""
    view = ModalStatesView(window_samples=4)
    view.update(_states(coords))
    row = view.render("t", now=0.0).splitlines()[2].split()
    assert row[0] == "0" and row[-1] == shown
