"""Output spikes (a glitch in a channel) found, left out of `identify` as missing samples, and named."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from okid_ros.core.output_spikes import most_spikes, output_spikes
from okid_ros.core.pipeline import identify
from okid_ros.core.sensor_faults import record_fault_warnings, record_faults
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation

DT = 0.008


def _spiked(y: np.ndarray, samples, output: int = 0, height: float = 30.0) -> np.ndarray:
    spiked = y.copy()
    spiked[list(samples), output] += height * y[:, output].std()
    return spiked


def test_a_clean_record_holds_no_spike(paper_record) -> None:
    u, y = paper_record
    spikes, by_output = output_spikes(u, y)
    assert not spikes.any() and by_output == {}


def test_spikes_in_one_output_are_found_at_their_samples(paper_record) -> None:
    u, y = paper_record
    spikes, by_output = output_spikes(u, _spiked(y, [400, 1777, 3001], output=1))
    assert list(by_output) == [1] and by_output[1].tolist() == [400, 1777, 3001]
    assert np.flatnonzero(spikes).tolist() == [400, 1777, 3001]


def test_an_impact_hammer_record_holds_no_spike() -> None:
    # Sparse impulses into the structure: its lightly damped ringing has second differences far
    # from their median (a second-difference rule alone flagged 5 to 10 samples per record).
    truth = paper_model()
    for seed in range(3):
        rng = np.random.default_rng(seed)
        u = 0.01 * rng.standard_normal((6000, 2))
        u[rng.choice(np.arange(100, 5900), 6, replace=False), rng.integers(0, 2, 6)] += 50.0
        y, _ = simulate_innovation(truth, u, seed=seed)
        assert not output_spikes(u, y)[0].any()  # the hammer measured
        assert not output_spikes(np.zeros((6000, 0)), y)[0].any()  # unmeasured


def test_a_jump_of_every_output_at_once_or_one_an_input_makes_is_no_glitch(paper_record) -> None:
    u, y = paper_record
    both = _spiked(_spiked(y, [900], output=0), [900], output=1)
    assert not output_spikes(u, both)[0].any()  # an unmeasured impact, or the whole acquisition
    kicked = u.copy()
    kicked[1200, 0] += 100.0 * u[:, 0].std()
    assert not output_spikes(kicked, _spiked(y, [1201], output=0))[0].any()  # its response


def test_missing_samples_are_bridged_not_taken_for_spikes(paper_record) -> None:
    u, y = paper_record
    valid = np.ones(y.shape[0], bool)
    valid[[500, 501, 2200]] = False
    holed = np.where(valid[:, None], y, 0.0)
    assert not output_spikes(u, holed, valid=valid)[0].any()
    assert output_spikes(u, _spiked(holed, [503]), valid=valid)[1] == {0: [503]}


def test_identify_leaves_a_spike_out_and_finds_the_clean_modes(paper_record) -> None:
    # One spike of 50 output spreads: the paper structure's 7.3 Hz mode was lost (21 of 30 modes
    # over 10 seeds), nothing said.
    # Here the 48.5 Hz mode was lost (the paper's three modes: 5.9, 7.3, 48.5 Hz).
    u, y = paper_record
    clean = sorted(m.frequency_hz for m in identify(u, y, DT).modes)
    assert len(clean) == 3
    model = identify(u, _spiked(y, [1900], output=1, height=50.0), DT)
    assert [w for w in model.warnings if "jumps far beyond" in w] == [
        "output 1 jumps far beyond its neighbours at 1 sample(s) (1900): a spike or glitch, not the structure's "
        "response; left out as missing samples, filled by the model's prediction as a record's gaps are"]
    found = np.array([m.frequency_hz for m in model.modes])
    for f in clean:  # (a sample left out, even without a spike, lists a 53 Hz pole beside 48.5 Hz here)
        assert np.min(np.abs(found / f - 1)) < 3e-3, (f, found)


def test_spikes_are_kept_and_named_where_they_cannot_be_left_out(paper_record) -> None:
    u, y = paper_record
    _, spiked, valid, warnings = record_faults(u, _spiked(y, [1000]), leave_out_spikes=False)  # method "paper"
    assert valid is None and spiked[1000, 0] > 10 * y[:, 0].std()
    assert len(warnings) == 1 and warnings[0].endswith("kept; the model may list spurious modes from them")
    _, _, valid, _ = record_faults(u, _spiked(y, [3748]), leave_out_spikes=True)  # the last sample but one
    assert np.flatnonzero(~valid).tolist() == [3748]
    many = _spiked(y, range(100, 3700, 300))  # 12 spikes: more than a record of 3750 samples may hold
    assert most_spikes(3750) == 10
    warnings = identify(u, many, DT, order=20).warnings
    assert any("12 such samples (0.3 % of the record) are a heavy-tailed signal" in w for w in warnings), warnings


def test_track_names_spikes_and_keeps_them(paper_record) -> None:
    u, y = paper_record
    warnings = record_fault_warnings(u, _spiked(y, [2500]), sample_time_s=DT)
    assert len(warnings) == 1 and warnings[0].startswith("output 0 jumps far beyond its neighbours at 1 sample(s)")
    assert "judged as the nodes judge them live: a glitch in some outputs goes into track's windows as the last " \
        "fit's prediction (node 1's gate)" in warnings[0]


def test_a_spike_within_a_few_channel_spreads_is_named_and_kept(paper_record) -> None:
    # One such glitch on DaISy's winding record (4 spreads): left out, its ARX rows cost more than
    # it weighed (held-out one-step prediction 1-2 % worse).
    u, y = paper_record
    small = y.copy()
    small[2000, 1] = np.median(y[1975:2026, 1]) + 7.0 * y[:, 1].std()
    spikes, by_output = output_spikes(u, small)
    assert by_output == {1: [2000]}
    _, _, valid, warnings = record_faults(u, small, leave_out_spikes=True)
    assert valid is None and len(warnings) == 1
    assert warnings[0].endswith("kept: within 8 standard deviations of the channel, such a sample weighs less than "
                                "the ARX rows leaving it out costs")
    _, _, valid, warnings = record_faults(u, _spiked(small, [3000], output=1), leave_out_spikes=True)  # and a large one
    assert np.flatnonzero(~valid).tolist() == [3000] and len(warnings) == 2


@pytest.mark.parametrize("units", [1e300, 1e308])
def test_the_faults_of_a_record_near_the_float_limits_are_those_in_ordinary_units(paper_record, units) -> None:
    # `okid-ros track` names a record's faults in its own units (its windows see them scaled), as
    # identify does. 8644b37: numpy's overflow warnings (the spikes' spread by np.std at 1e300, a
    # second difference and the harmonics' mean at 1e308) and the spikes called small, kept.
    u, y = paper_record
    y = _spiked(y, [700, 1900])
    y = 0.9 + y / (16 * np.abs(y).max())  # 0.84 to 0.96: times 1e308 still finite
    ordinary = record_faults(u, y, sample_time_s=0.008, leave_out_spikes=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        far = record_faults(u, y * units, sample_time_s=0.008, leave_out_spikes=True)
    np.testing.assert_array_equal(far[2], ordinary[2])
    assert not ordinary[2][[700, 1900]].any()
    assert [w.split(" ")[:4] for w in far[3]] == [w.split(" ")[:4] for w in ordinary[3]]
    assert len(far[3]) == 1 and "(700, 1900)" in far[3][0] and "left out as missing samples" in far[3][0], far[3]
