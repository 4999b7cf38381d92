"""The response-dominance criterion of a physical mode (core/modal.py, ModeCriteria.min_dominance).

A resonance makes up most of the model's frequency response at its own frequency; a broad, weakly
driven pole pair next to a sharp mode (what the whole steel-subframe record's models carried at 400
and 415 Hz, shares 0.08 and 0.04) does not, and is not listed.
"""

from __future__ import annotations

import numpy as np
import pytest

from okid_ros.core.modal import identify_modes, modal_form
from okid_ros.core.options import ModeCriteria
from okid_ros.sim import modal_structure


def _with_broad_pole(seed: int):
    """Three sharp modes and a broad, weakly driven one (9 % damping) 0.5 % below the 8.14 Hz mode."""
    dt = 0.01
    structure = modal_structure([3.0, 8.1, 8.14, 12.0], [0.005, 0.09, 0.003, 0.005], 2, 6, dt, seed=seed)
    B = structure.B.copy()
    B[2:4] *= 0.1  # the broad mode's states (q, q'): a tenth of the input participation
    return structure.A, B, structure.C, structure.D, dt


def test_a_broad_pole_under_a_stronger_mode_is_not_a_mode():
    rejected = 0
    for seed in range(1, 9):
        A, B, C, D, dt = _with_broad_pole(seed)
        modes, _ = identify_modes(A, B, C, dt, D=D)
        by_frequency = {round(m.frequency_hz, 2): m for m in modes}
        assert set(by_frequency) == {3.0, 8.1, 8.14, 12.0}
        for f in (3.0, 8.14, 12.0):
            assert by_frequency[f].dominance > 0.9, (seed, f, by_frequency[f].dominance)
            assert by_frequency[f].physical
        broad = by_frequency[8.1]
        assert broad.physical == (broad.dominance >= ModeCriteria().min_dominance)
        rejected += not broad.physical
        # The criterion alone decides: without it the broad pair passes every other one.
        relaxed, _ = identify_modes(A, B, C, dt, D=D, criteria=ModeCriteria(min_dominance=0.0))
        assert all(m.physical for m in relaxed)
    assert rejected >= 6


def test_an_isolated_mode_makes_up_its_whole_response_and_the_form_lists_the_physical_modes():
    sharp = modal_structure([2.0, 5.0, 11.0], 0.01, 1, 3, 0.01, seed=4)
    modes, _ = identify_modes(sharp.A, sharp.B, sharp.C, 0.01, D=sharp.D)
    assert [m.dominance for m in modes] == pytest.approx([1.0, 1.0, 1.0], abs=0.02)
    K = np.zeros((sharp.A.shape[0], 3))
    form = modal_form(sharp.A, sharp.B, sharp.C, K, 0.01, D=sharp.D)
    assert [round(m.frequency_hz, 3) for m in form.modes] == [2.0, 5.0, 11.0]
    assert form.modes[0].as_dict()["dominance"] == pytest.approx(modes[0].dominance)


def test_without_inputs_the_dominance_is_not_judged():
    sharp = modal_structure([2.0, 5.0], 0.01, 1, 3, 0.01, seed=4)
    modes, _ = identify_modes(sharp.A, np.zeros((sharp.A.shape[0], 0)), sharp.C, 0.01,
                              criteria=ModeCriteria(min_msv=0.0))
    assert all(np.isnan(m.dominance) for m in modes)
    assert all(m.physical for m in modes)
    assert modes[0].as_dict()["dominance"] is None
