"""The state-jump test (core/state_jump.py) against simulated truth.

A record looped back on itself (a seam, as a bag replayed in a loop) makes the state jump with
the structure unchanged; a structural change (okid_bench.changes, the systems of the change
bench: 250 Hz, 2 inputs, 3 accelerometers) changes the dynamics. The first must be explained
as a jump, the second never.
"""

from __future__ import annotations

import numpy as np
import pytest

from okid_bench.changes import change_case
from okid_ros.core.arx import fit_arx
from okid_ros.core.change_detection import whitening_matrix
from okid_ros.core.change_monitor import StructuralChangeMonitor
from okid_ros.core.noise_change import MIN_JUDGED_SAMPLES
from okid_ros.core.pipeline import identify_from_arx
from okid_ros.core.sample_ring import SampleRing
from okid_ros.core.state_jump import StateJumpTest
from okid_ros.core.statespace import InnovationPredictor

ORDER, WINDOW = 100, 4000
START = WINDOW + ORDER  # the detector is armed here
CHANGE = START + 3000  # the change, or the seam
LOOP_FROM = START + 200  # the seam goes back to this sample


def _model(case, u, y):
    u, y = u[:START], y[:START]
    return identify_from_arx(fit_arx(u, y, ORDER, "ridge", "gcv"), u, y, case.sample_time_s,
                             n_states="auto", max_states=40)


def _looped(u, y):
    u, y = u.copy(), y.copy()
    rest = len(u) - CHANGE
    u[CHANGE:], y[CHANGE:] = u[LOOP_FROM:LOOP_FROM + rest].copy(), y[LOOP_FROM:LOOP_FROM + rest].copy()
    return u, y


@pytest.fixture(scope="module", params=[0, 1])
def structure(request):
    """A reference model of the structure before, the record before, and the changed records."""
    seed = request.param
    u, y = change_case("frequency", 0.06).simulate(CHANGE + 2000, CHANGE, seed)
    model = _model(change_case("frequency", 0.06), u, y)
    changed = {(kind, size): change_case(kind, size).simulate(CHANGE + 2000, CHANGE, seed)
               for kind, size in (("frequency", 0.06), ("frequency", 0.04), ("damping", 3.0), ("stiffness", 0.2))}
    return model, (u, y), changed


def _whitened(model, u, y):
    whiten = whitening_matrix(model.innovation_covariance)
    predictor = InnovationPredictor(model)
    return predictor.run(u, y) @ whiten.T, StateJumpTest(predictor.F, whiten @ predictor.C)


def test_a_seam_is_explained_and_a_structural_change_is_not(structure):
    model, (u, y), changed = structure
    cases = {"seam": _looped(u, y)} | {f"{k} {s:g}": record for (k, s), record in changed.items()}
    for name, (uc, yc) in cases.items():
        z, test = _whitened(model, uc, yc)
        baseline = float(np.mean(z[START:START + 1000] ** 2))
        # From 5 or 40 samples before the change point, as the CUSUM's estimate may be (it is
        # where its statistic last left zero); the first judgement (enough samples after the
        # first loud one) and two later ones.
        for before in (5, 40):
            start = CHANGE - before
            first = next(k for k in range(test.needed_samples, test.needed_samples + 100)
                         if test.judge(z[start:start + k], start, baseline_power=baseline))
            for samples in (first, first + 35, first + 85):  # the loud search up to the first, as the detector does
                jump = test.judge(z[start:start + samples], start, baseline_power=baseline,
                                  loud_until=start + first - 1)
                if name == "seam":
                    assert jump.explained and jump.power_after < 1.2 and jump.power_before > 4, (samples, jump)
                    assert jump.onset_index >= CHANGE  # never before the seam
                else:
                    assert not jump.explained, (name, before, samples, jump.power_before, jump.power_after)


def test_the_fitted_jump_corrects_the_predictor(structure):
    model, (u, y), _ = structure
    u, y = _looped(u, y)
    whiten = whitening_matrix(model.innovation_covariance)
    predictor = InnovationPredictor(model)
    test = StateJumpTest(predictor.F, whiten @ predictor.C)
    z = predictor.run(u[:CHANGE], y[:CHANGE]) @ whiten.T
    jump = None
    while jump is None:  # judged as soon as the test can
        z = np.vstack([z, predictor.run(u[len(z):len(z) + 1], y[len(z):len(z) + 1]) @ whiten.T])
        jump = test.judge(z[CHANGE - 5:], CHANGE - 5)
    judged = len(z)
    corrected = InnovationPredictor(model, predictor.x + jump.correction(predictor.F, judged))
    uncorrected = InnovationPredictor(model, predictor.x)
    after = slice(judged, judged + 20)  # the uncorrected excess decays with the predictor's poles
    power = {name: float(np.mean((p.run(u[after], y[after]) @ whiten.T) ** 2))
             for name, p in (("corrected", corrected), ("uncorrected", uncorrected))}
    baseline = float(np.mean(z[START:CHANGE] ** 2))
    assert power["corrected"] < 1.3 * baseline < power["uncorrected"], (power, baseline)


@pytest.mark.parametrize("block", [False, True])
def test_the_monitor_takes_a_seam_as_a_jump_and_still_declares_a_change(structure, block):
    model, (u, y), changed = structure
    warm = InnovationPredictor(model)
    warm.run(u[:START], y[:START])

    def first_alarm(uc, yc, **options):
        monitor = StructuralChangeMonitor(model.C.shape[0], **options)
        monitor.arm(model, warm.x, reference_rows=WINDOW)
        if block:
            return monitor.process(uc[START:], yc[START:], START), monitor
        for k in range(START, len(uc)):
            alarm = monitor.step(uc[k], yc[k], k)
            if alarm is not None:
                return alarm, monitor
        return None, monitor

    alarm, monitor = first_alarm(*_looped(u, y))
    assert alarm is None and monitor.state_jumps == 1
    # The test can fail: the seam alone declares (a change of the noise model explains it too: off).
    alarm, _ = first_alarm(*_looped(u, y), state_jump_test=False, noise_change_test=False)
    assert alarm is not None and alarm.alarm_index >= CHANGE
    alarm, monitor = first_alarm(*changed[("frequency", 0.06)])
    assert alarm is not None and 0 <= alarm.alarm_index - CHANGE <= MIN_JUDGED_SAMPLES + 50  # noise_change.py
    assert monitor.state_jumps == 0


def test_the_ring_returns_the_run_of_samples_up_to_the_last():
    ring = SampleRing(2, 8)
    ring.push(0, np.arange(12.0).reshape(6, 2))
    z, first = ring.since(2, 5)
    assert first == 2 and z[:, 0].tolist() == [4.0, 6.0, 8.0, 10.0]
    ring.push(10, np.ones((3, 2)))  # samples 6-9 missing: a gap
    z, first = ring.since(0, 12)
    assert first == 10 and z.shape == (3, 2)
    ring.push(11, np.full((1, 2), 5.0))  # written again: replaced
    assert ring.since(11, 11)[0][0, 0] == 5.0
    ring.push(13, np.arange(40.0).reshape(20, 2))  # more than it holds: the newest 8
    z, first = ring.since(0, 32)
    assert first == 25 and z.shape == (8, 2)


def test_a_seam_after_a_noisier_stretch_of_the_same_excursion_is_found(structure):
    # The CUSUM's excursion may have begun long before the jump, in a noisier stretch that the
    # model-error check refused: the onsets are sought where the loudest samples begin.
    model, (u, y), _ = structure
    z, test = _whitened(model, *_looped(u, y))
    baseline = float(np.mean(z[START:START + 1000] ** 2))
    z[CHANGE - 600:CHANGE - 400] *= 2.0  # four times the power for 200 samples
    start = CHANGE - 700
    jump = test.judge(z[start:CHANGE + 100], start, baseline_power=baseline, loud_until=CHANGE + 10)
    assert jump.explained and jump.onset_index >= CHANGE, jump
