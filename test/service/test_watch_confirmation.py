"""Node 2's watch (service/watch.py) while an output-only reference's alarm waits for its modes.

The change bench's 4-mode structure (okid_bench.changes: 250 Hz, 3 accelerometers, its forces
unmeasured) loses 20 % of a stiffness at CHANGE; the change test's reference is identified from
the outputs before WINDOW (core/mode_confirmation.py holds its alarm until the modes after the
change point are identified). What node 2 and ``track`` do meanwhile goes through
:class:`~okid_ros.service.watch.InnovationWatch`: a model of a longer window accepted then, its
diagnostics, its divergence record at a new model.
"""

from __future__ import annotations

import numpy as np
import pytest

from okid_bench.changes import change_case
from okid_ros.core.change_detection import whitening_matrix
from okid_ros.core.estimator import ModalStateEstimator
from okid_ros.core.output_only import identify_output_only
from okid_ros.core.statespace import InnovationPredictor
from okid_ros.service.options import ModalEstimationParams
from okid_ros.service.results import ActiveModel, EstimationStats
from okid_ros.service.sample_buffer import SampleBuffer
from okid_ros.service.watch import InnovationWatch, is_new_reference

WINDOW = 4100  # the reference's samples
CHANGE = 2 * WINDOW + 1000  # a window twice the reference's fits before it
N = CHANGE + 6000


def _identified(y: np.ndarray, dt: float) -> tuple[object, np.ndarray]:
    """The output-only model of ``y`` and its predicted state for the sample after it."""
    model = identify_output_only(y, dt)
    warm = InnovationPredictor(model)
    warm.run(np.zeros((y.shape[0], 0)), y)
    return model, warm.x


@pytest.fixture(scope="module")
def stiffness_loss():
    case = change_case("stiffness", 0.2)
    y = case.simulate(N, CHANGE, 0)[1]
    return y, case.sample_time_s, _identified(y[:WINDOW], case.sample_time_s)


def _watch(dt: float, p: int) -> InnovationWatch:
    params = ModalEstimationParams(dt, 0, p)
    return InnovationWatch(params, SampleBuffer(4 * WINDOW, 0, p), EstimationStats())


def _until_held(watch: InnovationWatch, y: np.ndarray) -> int:
    """Samples from WINDOW on through the change test until it holds an alarm; the last sample taken."""
    no_inputs = np.zeros(0)
    for k in range(WINDOW, y.shape[0]):
        assert watch.monitor.step(no_inputs, y[k], k) is None
        if watch.monitor.holding:
            return k
    raise AssertionError("no alarm held")


def test_a_longer_window_accepted_while_an_alarm_is_held_keeps_the_hold_to_its_verdict(stiffness_loss):
    y, dt, (reference, state) = stiffness_loss
    watch = _watch(dt, y.shape[1])
    watch.new_model(reference, state, WINDOW)
    held = _until_held(watch, y)
    diagnostics = watch.diagnostics()
    assert diagnostics["change_monitor"] == "confirming"  # said "monitoring" while it waited
    assert watch.monitor.state == "confirming" and CHANGE <= held < CHANGE + 2000
    # Node 2 accepts the model of a window twice the reference's, ending at this sample (its last
    # tenth after the change): on main it became the reference, and the change was never declared.
    longer, longer_state = _identified(y[held + 1 - 2 * WINDOW:held + 1], dt)
    assert not is_new_reference(watch.monitor, 2 * WINDOW)
    watch.new_model(longer, longer_state, 2 * WINDOW)
    assert watch.monitor.model is reference and watch.monitor.holding
    no_inputs, alarm = np.zeros(0), None
    for k in range(held + 1, y.shape[0]):
        alarm = watch.monitor.step(no_inputs, y[k], k)
        if alarm is not None:
            break
    assert alarm is not None and CHANGE - 300 <= alarm.change_index <= held  # the held alarm, declared
    assert watch.monitor.excitation_changes == 0 and watch.monitor.state == "disarmed"
    # After the change the next model is the first of the new structure: it arms the test.
    assert is_new_reference(watch.monitor, WINDOW)


def test_a_new_models_restart_predicts_over_its_own_diverged_samples_only(stiffness_loss):
    # The samples the last model diverged on stayed listed after a new model was accepted: a restart of
    # the new model (its warm start over the buffer) ran open loop over them, though it was warm-started
    # over them when accepted, and ran from further back (up to the whole buffer) on the sample path.
    y, dt, (reference, state) = stiffness_loss
    p, no_inputs = y.shape[1], np.zeros(0)
    buffer = SampleBuffer(2 * WINDOW, 0, p)
    watch = InnovationWatch(ModalEstimationParams(dt, 0, p, change_detection=False), buffer, EstimationStats())
    watch.new_model(reference, state, WINDOW)
    active = ActiveModel(reference, ModalStateEstimator.from_model(reference), 1, reference.modes,
                         len(reference.modes), whitening_matrix(reference.innovation_covariance), WINDOW)
    diverged_at = WINDOW - 40  # the old model's last diverged sample, shortly before the new model came
    for k in range(WINDOW):
        index = buffer.append(k * dt, no_inputs, y[k], 0)
        innovation = np.full(p, np.nan) if k == diverged_at else np.zeros(p)  # a non-finite innovation: diverged
        assert watch.observe(active, k * dt, index, no_inputs, y[k], innovation)[0] == (k == diverged_at)
    new, new_state = _identified(y[:WINDOW], dt)
    watch.new_model(new, new_state, WINDOW)
    x, _ = watch.warm_state(new, index)  # what a restart of the new model at this sample starts from
    predictor = InnovationPredictor(new)
    first = index + 1 - predictor.settle_samples
    predictor.run(np.zeros((index + 1 - first, 0)), y[first:index + 1])
    np.testing.assert_allclose(x, predictor.x, rtol=1e-9, atol=1e-12 * np.abs(predictor.x).max())


def test_an_alarm_the_samples_end_before_its_verdict_is_said_never_judged(stiffness_loss):
    # Was: a record (process, track) ending while an alarm waited for its modes left it so, and nothing said it.
    y, dt, (reference, state) = stiffness_loss
    p, no_inputs = y.shape[1], np.zeros(0)
    buffer = SampleBuffer(4 * WINDOW, 0, p)
    watch = InnovationWatch(ModalEstimationParams(dt, 0, p), buffer, EstimationStats())
    for k in range(WINDOW):
        buffer.append(k * dt, no_inputs, y[k], 0)
    watch.new_model(reference, state, WINDOW)
    assert watch.unjudged_alarm() == ""
    for k in range(WINDOW, y.shape[0]):
        assert watch.monitor.step(no_inputs, y[k], buffer.append(k * dt, no_inputs, y[k], 0)) is None
        if watch.monitor.holding:
            break
    alarm, need = watch.monitor.held_alarm
    have = k + 1 - alarm.change_index
    assert 0 < have < need and alarm.alarm_index == k
    assert watch.unjudged_alarm() == (
        f"the change test's alarm at {k * dt:.3f} s (change point {alarm.change_index * dt:.3f} s, statistic "
        f"{alarm.statistic:.1f} > {alarm.threshold:.1f}) was never judged: the samples end {have} after its change "
        f"point, and its modes' identification needs {need}; neither declared a structural change nor dismissed as "
        "a change of the excitation")
