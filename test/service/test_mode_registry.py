"""okid_ros/service/mode_registry.py: persistent ids, memory, and retirement after a change."""

from __future__ import annotations

import math

import numpy as np

from okid_ros.core.modal import Mode
from okid_ros.service.mode_registry import ModeRegistry


def mode(frequency_hz: float, shape) -> Mode:
    w = 2 * math.pi * frequency_hz
    shape = np.asarray(shape, dtype=complex)
    return Mode(w, frequency_hz, 0.01, complex(0.9, 0.1), shape / np.linalg.norm(shape), 1.0, 1.0, 1.0, True, True)


def registry() -> ModeRegistry:
    return ModeRegistry(max_frequency_change=0.05, min_mac=0.7, mode_memory=2)


def test_ids_are_kept_by_frequency_and_mac_and_fresh_otherwise():
    reg = registry()
    first = reg.assign([mode(5.0, [1, 0]), mode(14.0, [0, 1])], reg.match([mode(5.0, [1, 0]), mode(14.0, [0, 1])]))
    assert [m.id for m in first] == [0, 1] and all(math.isnan(m.mac_previous) for m in first)
    new = [mode(5.1, [1, 0.1]), mode(14.1, [1, 0])]  # 14.1 Hz: frequency fits, shape does not
    second = reg.assign(new, reg.match(new))
    assert second[0].id == 0 and second[0].mac_previous > 0.95
    assert second[1].id == 2 and math.isnan(second[1].mac_previous)
    # Mode 1 is remembered for mode_memory models: it comes back with its id.
    back = [mode(14.0, [0, 1])]
    assert reg.assign(back, reg.match(back))[0].id == 1


def test_after_a_change_only_the_modes_before_count_and_the_others_are_retired():
    reg = registry()
    before = reg.assign([mode(5.0, [1, 0]), mode(14.0, [0, 1]), mode(20.0, [1, 1])],
                        reg.match([mode(5.0, [1, 0]), mode(14.0, [0, 1]), mode(20.0, [1, 1])]))
    after = [mode(4.9, [1, 0]), mode(13.0, [0, 1])]  # 2 % and 7 % drops; the 20 Hz mode is gone
    matches = reg.match(after, against=[m for m in before])
    modes = reg.assign(after, matches)
    assert [m.id for m in modes] == [0, 3]  # 7 % > max_frequency_change: a new id
    gone = reg.retire_except({m.id for m in modes})
    assert gone == [1, 2] and reg.retired == 2 and len(reg) == 2
    # A retired id never comes back, even for a mode like the old one.
    again = [mode(14.0, [0, 1]), mode(20.0, [1, 1])]
    assert [m.id for m in reg.assign(again, reg.match(again))] == [4, 5]


def test_a_returning_mode_takes_the_id_it_was_last_seen_with_not_an_older_one():
    reg = ModeRegistry(max_frequency_change=0.05, min_mac=0.7, mode_memory=10)
    old = reg.assign([mode(48.5, [1, 0.2])], reg.match([mode(48.5, [1, 0.2])]))[0].id
    reg.configure(max_frequency_change=1e-9, min_mac=1.0, mode_memory=10)  # nothing matches: a fresh id
    newer = reg.assign([mode(48.6, [1, 0.25])], reg.match([mode(48.6, [1, 0.25])]))[0].id
    assert newer != old
    reg.configure(max_frequency_change=0.05, min_mac=0.7, mode_memory=10)
    reg.assign([], [])  # the mode is missing from one model
    # It is closer to the old entry (same frequency and shape), but continues the newer one.
    back = reg.assign([mode(48.5, [1, 0.2])], reg.match([mode(48.5, [1, 0.2])]))
    assert back[0].id == newer
