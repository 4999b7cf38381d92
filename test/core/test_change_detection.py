"""okid_ros/core/change_detection.py: whitening, the CUSUM threshold, change and divergence tests.

Systems of okid_ros/sim at 250 Hz; models identified by the core from a 3000-sample record.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from scipy import signal

from okid_bench.switching import added_mass_structure, simulate_switched
from okid_ros.core.arx import fit_arx
from okid_ros.core.change_detection import (
    ChangeDetector,
    DivergenceMonitor,
    calibration_scale,
    cusum_average_run_length,
    cusum_threshold,
    predictor_spectral_radius,
    whitening_matrix,
)
from okid_ros.core.change_monitor import StructuralChangeMonitor
from okid_ros.core.model_error_check import ModelErrorCheck
from okid_ros.core.noise_change import MIN_JUDGED_SAMPLES
from okid_ros.core.pipeline import identify_from_arx
from okid_ros.core.statespace import InnovationPredictor
from okid_ros.core.window_samples import MAX_SAMPLE_MAGNITUDE
from okid_ros.sim.inputs import lowpass_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation

DT = 1.0 / 250.0
FIT = 3000  # samples the model is identified from


def test_whitening_matrix_gives_unit_covariance_and_refuses_bad_covariances():
    cov = np.array([[4.0, 1.0], [1.0, 2.0]])
    W = whitening_matrix(cov)
    np.testing.assert_allclose(W @ cov @ W.T, np.eye(2), atol=1e-12)
    with pytest.raises(ValueError, match="positive definite"):
        whitening_matrix(np.array([[1.0, 2.0], [2.0, 1.0]]))
    with pytest.raises(ValueError, match="NaN"):
        whitening_matrix(np.array([[np.nan]]))


def test_cusum_threshold_gives_the_requested_false_alarm_rate():
    # Run lengths of the CUSUM on white unit-covariance innovations against the Markov-chain ARL.
    p, target = 2, 400.0
    h = cusum_threshold(target, p, 1.5)
    assert cusum_average_run_length(h, p, 1.5) == pytest.approx(target, rel=1e-3)
    assert cusum_threshold(1e7, p, 1.5) > h  # rarer false alarms need a higher threshold
    rng = np.random.default_rng(0)
    runs = []
    for _ in range(300):
        # The chi-square CUSUM alone: no tracked mean, no correlation factor.
        det = ChangeDetector(p, false_alarm_samples=target, reference_samples=20, mean_tracking_samples=0,
                             batch_samples=0, calibration_confidence=None)
        det.mean, det.rewhiten = np.zeros(p), np.eye(p)  # calibrated to the truth
        index = 0
        while True:
            alarm = det.process(rng.standard_normal((500, p)), index)
            if alarm is not None:
                runs.append(alarm.alarm_index + 1)
                break
            index += 500
    # 300 run lengths, roughly exponential: standard error of the mean about 6 %.
    assert np.mean(runs) == pytest.approx(target, rel=0.2)


def _bursty_innovations(rng, n_samples: int, p: int) -> np.ndarray:
    """Innovations as measured data give them, with no structural change in them.

    Their power varies by about 30 % over ~50 samples and their mean drifts over ~1000 samples.
    """
    a, b = np.exp(-1 / 50), np.exp(-1 / 1000)
    level = signal.lfilter([np.sqrt(1 - a * a)], [1, -a], rng.standard_normal(n_samples))
    drift = signal.lfilter([np.sqrt(1 - b * b)], [1, -b], rng.standard_normal((n_samples, p)), axis=0)
    return np.exp(0.3 * level)[:, None] * rng.standard_normal((n_samples, p)) + 0.3 * drift


def test_correlated_and_drifting_innovations_keep_the_false_alarm_rate():
    # The plain chi-square CUSUM alarms within a few hundred samples on such innovations; the
    # tracked mean and the correlation factor bring the run lengths back near the target.
    p, target, n = 4, 2000.0, 20000
    rng = np.random.default_rng(1)
    plain, robust, factors = [], [], []
    for _ in range(12):
        z = _bursty_innovations(rng, n, p)
        det = ChangeDetector(p, false_alarm_samples=target, mean_tracking_samples=0, batch_samples=0)
        alarm = det.process(z, 0)
        plain.append(n if alarm is None else alarm.alarm_index - det.reference_samples)
        det = ChangeDetector(p, false_alarm_samples=target)
        alarm = det.process(z, 0)
        robust.append(n if alarm is None else alarm.alarm_index - det.reference_samples)
        factors.append(det.correlation_factor)
    assert np.median(plain) < target / 4, plain
    assert np.mean(robust) > target / 2, robust
    assert min(factors) > 1.5, factors  # the correlation was measured, and raised the threshold


def test_white_innovations_give_a_correlation_factor_near_one():
    rng = np.random.default_rng(2)
    det = ChangeDetector(3, false_alarm_samples=1e7)
    assert det.process(rng.standard_normal((1000, 3)), 0) is None
    assert det.calibrated and 1.0 <= det.correlation_factor < 1.6
    assert det.threshold == pytest.approx(det.correlation_factor * det.base_threshold)


@pytest.fixture(scope="module")
def identified():
    """A 2-mode structure, its model and records without and with a change.

    6 and 21 Hz, the model from the first 3000 samples, and records
    without and with a change of the frequencies by `factor` at sample 3000 + 5000.
    """
    before, after = added_mass_structure([6.0, 21.0], [0.01, 0.015], 2, 2, DT, frequency_factor=0.94, seed=1)
    n = FIT + 110_000
    u = lowpass_input(n, 2, 40.0, DT, seed=1)
    y = simulate_switched([before], [], u, seed=2)
    model = identify_from_arx(fit_arx(u[:FIT], y[:FIT], 40, "ridge", "gcv"), u[:FIT], y[:FIT], DT,
                              n_states="auto", max_states=12)
    return before, model, u, y


def _armed(model, u, y, **options) -> StructuralChangeMonitor:
    warm = InnovationPredictor(model)
    warm.run(u[:FIT], y[:FIT])  # the predictor's state at the end of the model's own window
    monitor = StructuralChangeMonitor(2, **options)
    monitor.arm(model, warm.x, reference_rows=FIT)
    return monitor


def test_no_alarm_on_1e5_stationary_samples_of_an_identified_model(identified):
    _, model, u, y = identified
    monitor = _armed(model, u, y)
    assert monitor.state == "calibrating"
    alarm = monitor.process(u[FIT:], y[FIT:], FIT)
    assert alarm is None, alarm
    assert monitor.state == "monitoring" and 0.0 <= monitor.statistic < monitor.threshold


# Declared once the noise-change test has judged MIN_JUDGED_SAMPLES of it (core/noise_change.py).
@pytest.mark.parametrize("factor, max_delay, max_point_error", [(0.94, MIN_JUDGED_SAMPLES + 50, 100), (0.98, 500, 500)])
def test_a_step_change_of_the_frequencies_is_detected_at_once(identified, factor, max_delay, max_point_error):
    before, model, u, _ = identified
    _, after = added_mass_structure([6.0, 21.0], [0.01, 0.015], 2, 2, DT, frequency_factor=factor, seed=1)
    change = FIT + 5000
    n = change + 3000
    y = simulate_switched([before, after], change, u[:n], seed=2)
    monitor = _armed(model, u, y)
    alarm = monitor.process(u[FIT:n], y[FIT:n], FIT)
    assert alarm is not None
    assert change <= alarm.alarm_index <= change + max_delay, alarm
    assert abs(alarm.change_index - change) <= max_point_error, alarm  # change point estimate
    assert alarm.statistic > alarm.threshold and alarm.variance_ratio > 1.2
    assert monitor.state == "disarmed"  # waits for the model of the new structure


def test_a_wrongly_calibrated_power_test_does_alarm(identified):
    # The same stationary data with a reference calibrated on 20 % smaller innovations: the
    # power test must be able to fail. The model-error check then refuses the alarm (the
    # innovations are as unpredictable as at the calibration) and counts it.
    _, model, u, y = identified
    counts = {}
    for check in (False, True):
        monitor = _armed(model, u, y, model_error_check=check)
        monitor.process(u[FIT:FIT + 1000], y[FIT:FIT + 1000], FIT)
        assert monitor.state == "monitoring"
        monitor.detector.rewhiten = monitor.detector.rewhiten / 0.8
        alarm = monitor.process(u[FIT + 1000:FIT + 20_000], y[FIT + 1000:FIT + 20_000], FIT + 1000)
        counts[check] = (alarm is not None, monitor.unconfirmed_alarms)
    assert counts[False] == (True, 0)
    assert counts[True][0] is False and counts[True][1] >= 1, counts


def _noisier(system, factor: float):
    """``system`` with every noise covariance (Q, R, S) times ``factor``: the same structure."""
    return dataclasses.replace(
        system, process_noise_covariance=factor * system.process_noise_covariance,
        measurement_noise_covariance=factor * system.measurement_noise_covariance,
        cross_covariance=None if system.cross_covariance is None else factor * system.cross_covariance)


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_more_noise_alone_is_not_declared_a_change(identified, seed):
    # The disturbances and the sensor noise grow by 60 % in power for 3000 samples and drop
    # back, the structure unchanged: the power test alarms, the model-error check refuses it.
    before, model, u, _ = identified
    rise, end = FIT + 4000, FIT + 7000
    n = FIT + 12_000
    y = simulate_switched([before, _noisier(before, 1.6), before], [rise, end], u[:n], seed=seed)
    declared = {}
    for check in (False, True):
        monitor = _armed(model, u, y, model_error_check=check)
        declared[check] = monitor.process(u[FIT:n], y[FIT:n], FIT)
        if check:
            assert monitor.unconfirmed_alarms >= 1 and not monitor.detector.judgement.last_verdict.confirmed
            assert monitor.state == "monitoring"  # still armed: nothing was declared
    assert declared[False] is not None and rise <= declared[False].alarm_index < end, declared[False]
    assert declared[True] is None, (declared[True], monitor.detector.judgement.last_verdict)


def test_a_change_during_a_noisy_stretch_is_declared(identified):
    # The noise rises first (refused); 1000 samples later the frequencies drop by 6 %.
    before, model, u, _ = identified
    _, after = added_mass_structure([6.0, 21.0], [0.01, 0.015], 2, 2, DT, frequency_factor=0.94, seed=1)
    rise, change = FIT + 4000, FIT + 5000
    n = change + 3000
    y = simulate_switched([before, _noisier(before, 1.6), _noisier(after, 1.6)], [rise, change], u[:n], seed=2)
    monitor = _armed(model, u, y)
    alarm = monitor.process(u[FIT:n], y[FIT:n], FIT)
    assert monitor.unconfirmed_alarms >= 1
    assert alarm is not None and change <= alarm.alarm_index <= change + 300, alarm
    assert monitor.state == "disarmed"


def test_the_check_confirms_a_model_error_and_not_white_residuals():
    # The check alone: white residuals (any power) are refused, residuals that follow the
    # inputs are confirmed; its calibration's own predictable part is allowed for.
    rng = np.random.default_rng(5)
    p, m, n = 4, 2, 6000
    u = rng.standard_normal((n, m))
    w = rng.standard_normal((n, p))
    w[3000:] *= 3.0  # more power, still white
    w[5000:] += 3.0 * np.roll(u, 3, axis=0)[5000:, [0, 1, 0, 1]]  # then a part the inputs 3 samples ago explain
    check = ModelErrorCheck(p, m, capacity=n)
    check.push_inputs(0, u)
    check.push_residuals(0, w)
    check.calibrate(999, 1000)
    assert abs(check.baseline) < 0.02
    assert not check.judge(3100, 3300).confirmed
    verdict = check.judge(5000, 5400)
    assert verdict.confirmed and verdict.excess > 0.1, verdict
    # A calibration whose residuals already follow the inputs as much: nothing in excess.
    check.calibrate(5999, 1000)
    assert not check.judge(5000, 5400).confirmed


def test_divergence_monitor_flags_non_finite_and_huge_innovations():
    mon = DivergenceMonitor(2, window_samples=10, nis_ratio=100.0)
    rng = np.random.default_rng(1)
    assert not any(mon.check(z) for z in rng.standard_normal((200, 2)))
    assert mon.check(np.array([np.nan, 0.0])) and not mon.sustained
    mon.restart()
    flags = [mon.check(z) for z in 1e3 * rng.standard_normal((10, 2))]
    assert all(flags) and mon.sustained
    mon.restart()
    assert not mon.sustained and not mon.check(np.ones(2))


def test_predictor_spectral_radius(identified):
    _, model, _, _ = identified
    assert 0.0 < predictor_spectral_radius(model) < 1.0
    unstable = dataclasses.replace(model, K=np.zeros_like(model.K), A=1.01 * model.A)
    assert predictor_spectral_radius(unstable) > 1.0


def test_the_per_sample_path_gives_the_alarm_of_the_block_path(identified):
    before, model, u, _ = identified
    _, after = added_mass_structure([6.0, 21.0], [0.01, 0.015], 2, 2, DT, frequency_factor=0.98, seed=1)
    change, n = FIT + 3000, FIT + 6000
    y = simulate_switched([before, after], change, u[:n], seed=2)
    block = _armed(model, u, y).process(u[FIT:n], y[FIT:n], FIT)
    monitor = _armed(model, u, y)
    single = None
    for k in range(FIT, n):
        single = monitor.step(u[k], y[k], k)
        if single is not None:
            break
    assert block is not None and single is not None
    assert (single.alarm_index, single.change_index) == (block.alarm_index, block.change_index)
    assert single.statistic == pytest.approx(block.statistic, rel=1e-9)
    assert single.variance_ratio == pytest.approx(block.variance_ratio, rel=1e-9)



def test_the_threshold_allows_for_the_error_of_a_short_calibration():
    # White innovations, 2 outputs, 200 calibration samples, the default 1e7 samples between
    # false alarms: 0.1 % of runs should alarm within 10 000 samples. The threshold of an exact
    # calibration alarms in 10 % (the calibration under-estimates the covariance about half of the
    # time, for every later sample); the allowance keeps the rate for 90 % of the calibrations.
    def alarms(**options) -> int:
        count = 0
        for run in range(60):
            z = np.random.default_rng(run).standard_normal((200 + 10_000, 2))
            count += ChangeDetector(2, reference_samples=200, **options).process(z, 0) is not None
        return count

    exact, allowed = alarms(calibration_confidence=None), alarms()
    assert exact >= 5 and allowed <= exact / 3, (exact, allowed)
    assert calibration_scale(1000, 2) < calibration_scale(200, 2) < 1.15  # fewer samples, more allowance


def _short_window_references(seeds):
    """Models of the paper's structure from 1000-sample windows (node 1's ARX order 20, 6 states).

    With windows that short a model often misses the 7.3 Hz mode (or more): its innovations
    are coloured. Yields the model and 20000 later samples of the same structure.
    """
    from okid_ros.core.pipeline import identify
    from okid_ros.sim import paper_model, simulate_innovation

    truth = paper_model()
    for seed in seeds:
        u = lowpass_input(21_000, 2, 50.0, truth.sample_time_s, seed=seed)
        y, _ = simulate_innovation(truth, u, seed=100 + seed)
        model = identify(u[:1000], y[:1000], truth.sample_time_s, order=20, n_states=6, refine=False)
        warm = InnovationPredictor(model)
        warm.run(u[:1000], y[:1000])
        yield model, warm.x, u[1000:], y[1000:]


def test_references_that_miss_a_mode_keep_the_false_alarm_rate():
    # 20000 stationary samples per reference, 1e7 expected between false alarms: 0.06 alarms
    # expected over 30 references. Without the whitening AR several of them alarm. (The
    # state-jump and noise-change tests, which explain some of those excursions too, are off: the AR alone.)
    plain = whitened = 0
    orders = []
    for model, state, u, y in _short_window_references(range(30)):
        for options in ({"whitening_max_order": 0}, {}):
            monitor = StructuralChangeMonitor(2, state_jump_test=False, noise_change_test=False, **options)
            monitor.arm(model, state)
            alarm = monitor.process(u, y, 0)
            if options:
                plain += alarm is not None
            else:
                whitened += alarm is not None
                orders.append(monitor.detector.whitening_order if alarm is None else -1)
    assert plain >= 3, plain  # the test can fail
    assert whitened == 0, whitened
    assert max(orders) >= 5 and min(orders) == 0, orders  # coloured ones whitened, white ones left


def test_the_whitened_test_still_detects_a_change():
    # References from 1000 samples with 4 states for a 3-mode structure: they miss modes and
    # their innovations are coloured. Without the whitening AR most of them raise a false alarm
    # before the change; with it none does, and the 6 % frequency drop is still found at once:
    # at the noise-change test's first or second judgement (a reference missing modes needs more samples).
    before, after = added_mass_structure([6.0, 21.0, 40.0], [0.01, 0.015, 0.01], 2, 2, DT,
                                         frequency_factor=0.94, seed=1)
    n, change = 8000, 5000
    false_plain, delays = 0, []
    for seed in range(4):
        u = lowpass_input(n, 2, 60.0, DT, seed=3 + seed)
        y = simulate_switched([before, after], change, u, seed=4 + seed)
        model = identify_from_arx(fit_arx(u[:1000], y[:1000], 10, "ridge", "gcv"), u[:1000], y[:1000], DT,
                                  n_states=4)
        for options in ({"whitening_max_order": 0}, {}):
            warm = InnovationPredictor(model)
            warm.run(u[:1000], y[:1000])
            monitor = StructuralChangeMonitor(2, noise_change_test=not options, **options)  # plain: the AR alone
            monitor.arm(model, warm.x)
            false_alarm = monitor.process(u[1000:change], y[1000:change], 1000)
            if options:
                false_plain += false_alarm is not None
                continue
            assert false_alarm is None and monitor.detector.whitening_order > 0
            alarm = monitor.process(u[change:], y[change:], change)
            delays.append(alarm.alarm_index - change if alarm is not None else None)
    assert false_plain >= 2, false_plain  # the test can fail
    assert all(d is not None and d <= 2 * MIN_JUDGED_SAMPLES + 50 for d in delays), delays


def test_the_per_sample_path_equals_the_block_path_with_whitening_and_gaps():
    model, state, u, y = next(_short_window_references([24]))
    block, single = StructuralChangeMonitor(2), StructuralChangeMonitor(2)
    block.arm(model, state)
    single.arm(model, state)
    for lo, hi in ((0, 1500), (1503, 4000)):  # 3 samples lost: both bridge them
        if lo:
            block.gap(u[lo - 4], 3, 10)
            single.gap(u[lo - 4], 3, 10)
        assert block.process(u[lo:hi], y[lo:hi], lo) is None
        for k in range(lo, hi):
            assert single.step(u[k], y[k], k) is None
    assert block.detector.whitening_order > 0
    assert single.statistic == pytest.approx(block.statistic, rel=1e-9, abs=1e-12)


def _glitched(y: np.ndarray, samples, output: int) -> np.ndarray:
    glitched = y.copy()
    glitched[samples, output] += 30 * y[:, output].std()
    return glitched


@pytest.mark.parametrize("size", [30.0, 1e20])
def test_glitches_in_one_output_are_no_change_on_either_path(size):
    # Ten samples of output 0 thirty spreads off (interference, a bit error) in 20000 samples of
    # the paper's structure, the reference model identified from the first 3750 as `track` and
    # node 2 do (its window holds four of them): an alarm at sample 5496, a false change. At 1e20
    # spreads the glitch's prediction, taken as the sample less its innovation, was lost to
    # rounding: no glitch settled, and the squares overflowed (a 1e200 sample in `track`).
    truth, dt, fit = paper_model(), 0.008, 3750
    u = lowpass_input(20_000, 2, 15.0, dt, seed=1)
    y, _ = simulate_innovation(truth, u, seed=2)
    samples = [427, 911, 1589, 3570, 5440, 6193, 10216, 12706, 16202, 16934]
    clean = y.copy()
    y[samples, 0] += size * y[:, 0].std()
    fitted = clean if size > 1e3 else y  # the reference of a window of such samples is not the point here
    model = identify_from_arx(fit_arx(u[:fit], fitted[:fit], 50, center=True), u[:fit], fitted[:fit], dt)
    warm = InnovationPredictor(model)
    warm.run(u[:fit], fitted[:fit])
    block, single = StructuralChangeMonitor(2), StructuralChangeMonitor(2)
    block.arm(model, warm.x, reference_rows=fit)
    single.arm(model, warm.x, reference_rows=fit)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert block.process(u[fit:], y[fit:], fit) is None
        assert all(single.step(u[k], y[k], k) is None for k in range(fit, y.shape[0]))
    assert block.glitches == single.glitches == 6 and block.state == single.state == "monitoring"
    np.testing.assert_allclose(single.predictor.x, block.predictor.x, atol=1e-9 * np.abs(block.predictor.x).max())


def test_a_jump_of_every_output_and_a_change_are_no_glitch(identified):
    before, model, u, _ = identified
    _, after = added_mass_structure([6.0, 21.0], [0.01, 0.015], 2, 2, DT, frequency_factor=0.94, seed=1)
    change = FIT + 5000
    n = change + 3000
    y = simulate_switched([before, after], change, u[:n], seed=2)
    monitor = _armed(model, u, y)
    assert monitor.process(u[FIT:n], y[FIT:n], FIT) is not None and monitor.glitches == 0
    both = _glitched(_glitched(y[:change], [FIT + 2000], 0), [FIT + 2000], 1)  # an unmeasured impact
    monitor = _armed(model, u, both)
    monitor.process(u[FIT:change], both[FIT:change], FIT)
    assert monitor.glitches == 0


@pytest.mark.parametrize("size", [1e140, 1e200])
@pytest.mark.parametrize("at", ["a block's last sample", "the record's last sample"])
def test_a_glitch_at_a_blocks_last_sample_is_judged(identified, at, size):
    # `track` hands the change test a block per update. A glitch candidate at a block's last
    # sample had no next sample to judge it and was tested as it came: 1e200 in one output
    # overflowed the model-error check's squares (RuntimeWarning), 1e140 was declared a change.
    # The next block's first sample judges it now, as the next sample does on the nodes'
    # per-sample path (which never sees a sample beyond MAX_SAMPLE_MAGNITUDE); at the record's
    # last sample (finish: no next sample) it is counted as a glitch.
    _, model, u, y = identified
    n, every = FIT + 4000, 500
    k = FIT + 3 * every - 1 if at == "a block's last sample" else n - 1
    y = y[:n].copy()
    y[k, 0] = size
    block, single = _armed(model, u, y), _armed(model, u, y)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert all(block.process(u[lo:lo + every], y[lo:lo + every], lo) is None for lo in range(FIT, n, every))
        block.finish()
        if size <= MAX_SAMPLE_MAGNITUDE:
            assert all(single.step(u[j], y[j], j) is None for j in range(FIT, n))
            single.finish()
    assert block.glitches == 1 and block.state == "monitoring"
    if size <= MAX_SAMPLE_MAGNITUDE:
        assert single.glitches == 1 and single.state == "monitoring"
        np.testing.assert_allclose(block.predictor.x, single.predictor.x, atol=1e-9 * np.abs(block.predictor.x).max())
        assert block.statistic == pytest.approx(single.statistic, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_rise_of_power_within_the_calibration_is_tested_from_there(seed):
    # split_calibration (measured, not adopted; docs/benchmarks-change.md, forty-sixth session). White unit
    # innovations whose power doubles 600 samples into the 1000 of the calibration: the samples
    # before the rise calibrate, and the CUSUM alarms soon after it (it used to take the doubled power as the
    # baseline and never alarm).
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((5000, 3))
    z[600:] *= np.sqrt(2.0)
    detector = ChangeDetector(3, whitening_max_order=0, split_calibration=True)
    alarm = detector.process(z, 0)
    assert alarm is not None and 600 <= alarm.alarm_index < 1000, alarm
    assert abs(alarm.change_index - 600) <= 50
    assert detector.calibrations_split == 1 and 500 <= detector.calibration_samples <= 650


def test_a_stationary_calibration_is_not_split():
    # 100 calibrations of white innovations, and of innovations 1.3 times as loud as Re says throughout (a
    # reference whose out-of-sample innovations are larger than its Re): none split.
    split = []
    for run in range(100):
        z = np.random.default_rng(run).standard_normal((1000, 3)) * (1.0 if run % 2 else np.sqrt(1.3))
        detector = ChangeDetector(3, split_calibration=True)
        detector.process(z, 0)
        if detector.calibrations_split or detector.calibration_samples != 1000:
            split.append((run, detector.calibration_samples))
    assert split == []


def test_a_change_within_the_calibration_is_declared_on_both_paths(identified):
    before, model, u, _ = identified
    _, after = added_mass_structure([6.0, 21.0], [0.01, 0.015], 2, 2, DT, frequency_factor=0.94, seed=1)
    change, n = FIT + 600, FIT + 3000
    y = simulate_switched([before, after], change, u[:n], seed=2)
    block = _armed(model, u, y, split_calibration=True)
    alarm = block.process(u[FIT:n], y[FIT:n], FIT)
    assert alarm is not None and abs(alarm.change_index - change) <= 50 and alarm.alarm_index < change + 1000
    assert block.detector.calibrations_split == 1
    monitor = _armed(model, u, y, split_calibration=True)
    single = None
    for k in range(FIT, n):
        single = monitor.step(u[k], y[k], k)
        if single is not None:
            break
    assert single is not None
    assert (single.alarm_index, single.change_index) == (alarm.alarm_index, alarm.change_index)
    assert single.statistic == pytest.approx(alarm.statistic, rel=1e-9)
