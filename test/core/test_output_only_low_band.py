"""The decimated band's frequency replaces a slow mode's full-rate one only where it is the more certain.

Random records 82, 91 and 38 of ``bench/output_only.py --cases random`` (ssi-cva) lost a slow mode
found within 0.5 % at the full rate to a decimated estimate 0.56-0.63 % off with a larger
jackknife frequency standard deviation (docs/benchmarks-output-only.md, forty-third session).

A tuned mass damper's pair of modes, which the full rate reads as one pole between them and the
decimated record's longer lags resolve, is not listed (forty-ninth session).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from ros_helpers import REPO_ROOT

import okid_ros.core.output_only as oo
from okid_bench.families_two import family_two_case
from okid_bench.output_only_cases import random_case
from okid_ros.core.modal import Mode
from okid_ros.core.output_only import identify_output_only
from okid_ros.core.output_only_low_band import refine_low_modes

KOMA = REPO_ROOT.parent / "shared" / "data" / "oma" / "koma-shear-frame"


@pytest.mark.parametrize("finer_std", [None, (3e-3, 4e-3)])
@pytest.mark.parametrize(("decimated_std", "frequency_replaced"), [(0.5e-3, True), (2e-3, False)])
def test_a_slow_mode_takes_the_decimated_frequency_only_with_a_smaller_std_and_its_damping_always(
        decimated_std: float, frequency_replaced: bool, finer_std: tuple | None) -> None:
    # The choice is by the screening jackknife's deviations; a second jackknife's (okid_ros/core/output_only_std.py,
    # here larger than the full rate's) are the ones listed where given.
    y = np.random.default_rng(0).standard_normal((20000, 2))
    mode = Mode(2 * np.pi, 1.0, 0.02, 0.99 + 0.06j, np.ones(2, complex) / np.sqrt(2), 1.0, 1.0, 1.0, True, True,
                frequency_hz_std=1e-3, damping_ratio_std=2e-3)
    decimated = {"frequency_hz": 1.004, "damping_ratio": 0.025, "frequency_hz_std": decimated_std,
                 "damping_ratio_std": 1e-3} | ({} if finer_std is None else {"finer_std": finer_std})
    refine_low_modes(SimpleNamespace(modes=[mode]), y, 0.01, lambda low, dt, rows: [decimated])
    listed_f_std, listed_z_std = finer_std or (decimated_std, 1e-3)
    frequency = (1.004, listed_f_std) if frequency_replaced else (1.0, 1e-3)
    assert (mode.frequency_hz, mode.frequency_hz_std, mode.frequency_rad_s) == (*frequency, 2 * np.pi * frequency[0])
    assert (mode.damping_ratio, mode.damping_ratio_std) == (0.025, listed_z_std)
    assert (mode.extras["full_rate_frequency_hz"], mode.extras["full_rate_damping_ratio"]) == (1.0, 0.02)


@pytest.mark.parametrize("index", [38, 82])
def test_a_slow_mode_found_at_the_full_rate_is_kept(index: int) -> None:
    case = random_case(index)
    model = identify_output_only(case.simulate(index), case.sample_time_s, method="ssi-cva")
    listed = np.array([m.frequency_hz for m in model.modes])
    for true in case.truth():
        assert np.min(np.abs(listed / true["frequency_hz"] - 1)) <= 0.005, f"{true['frequency_hz']:.3f} Hz missed"


def test_a_decimated_record_too_short_for_a_jackknife_is_not_decomposed(monkeypatch) -> None:
    # The koma frame's decimated record holds 2 segments of its lags: a selection without a jackknife, whose
    # modes _mode_values discards (no standard deviations to weigh them by), so it is not made at all.
    record = np.load(KOMA / "shear_frame.npz")
    selections, decompositions = [], []
    select, decompose = oo._select_modes, oo.canonical_decomposition

    def counted_select(*args, **options):
        selections.append(options.get("once", True))
        return select(*args, **options)

    monkeypatch.setattr(oo, "_select_modes", counted_select)
    monkeypatch.setattr(oo, "canonical_decomposition", lambda *args: decompositions.append(args[2]) or decompose(*args))
    model = identify_output_only(record["y"], float(record["sample_time_s"]))
    assert selections == [True, False]  # the full rate's, then the decimated band's was asked for
    assert len(decompositions) == 1  # the record's alone (its replicates are canonical_replicates')
    assert len(model.modes) == 5 and not any("decimation" in mode.extras for mode in model.modes)


def _slow_mode(frequency_hz: float, damping_ratio: float) -> Mode:
    pole = np.exp(0.01 * 2 * np.pi * frequency_hz * (-damping_ratio + 1j * np.sqrt(1 - damping_ratio ** 2)))
    return Mode(2 * np.pi * frequency_hz, frequency_hz, damping_ratio, pole, np.ones(2, complex) / np.sqrt(2),
                1.0, 1.0, 1.0, True, True, frequency_hz_std=1e-3, damping_ratio_std=2e-3)


@pytest.mark.parametrize(("decimated_hz", "other_hz", "pair"), [
    ((0.95, 1.07, 3.0), 1.2, (0.95, 1.07)),  # one on each side, within one bandwidth (0.1 Hz): a pair
    ((0.95, 1.12, 3.0), 1.2, None),  # the upper one beyond a bandwidth
    ((0.95, 1.07, 3.0), 1.12, None),  # the upper one nearer the other listed mode
    ((0.95, 1.005, 1.07), 1.2, None),  # found again within 1 %: refined, not a pair
    ((0.92, 0.95, 3.0), 1.2, None),  # both below
])
def test_a_slow_mode_the_decimated_record_resolves_into_a_pair_is_returned(decimated_hz, other_hz, pair) -> None:
    y = np.random.default_rng(0).standard_normal((20000, 2))
    modes = [_slow_mode(1.0, 0.05), _slow_mode(other_hz, 0.01)]
    decimated = [{"frequency_hz": f, "damping_ratio": 0.05, "frequency_hz_std": 1e-3, "damping_ratio_std": 1e-3}
                 for f in decimated_hz]
    merged = refine_low_modes(SimpleNamespace(modes=modes), y, 0.01, lambda low, dt, rows: decimated)
    assert [(m.mode.frequency_hz, m.below_hz, m.above_hz) for m in merged] == ([] if pair is None else [(1.0, *pair)])


def test_a_tuned_mass_dampers_pair_read_as_one_pole_is_not_listed() -> None:
    case = family_two_case(87)  # a 3 % TMD on mode 1: 21.68 and 25.04 Hz, both about 5.4 % damped
    model = identify_output_only(case.simulate(87, 35000), case.sample_time_s)
    structural = np.sort(np.abs(case.structural_poles)) / (2 * np.pi)
    listed = np.array([m.frequency_hz for m in model.modes])
    off = np.min(np.abs(listed[:, None] / structural[None, :] - 1), axis=1)
    assert np.all(off <= 0.02), f"{listed[off > 0.02]} Hz: not a mode of the structure"
    assert any("resolve at 21.7" in w and "and 24.6" in w for w in model.warnings), model.warnings
