"""Node 2's idle switch without ROS: a model delivered after the last sample (end of a bag, a pause).

``ModalEstimationService.apply_ready_if_idle`` (okid_ros/service/estimation.py) and its idle
criterion (okid_ros/service/idle.py), on the paper's structure as in test_service_estimation.py.
"""

from __future__ import annotations

import copy
import dataclasses
import threading

import numpy as np
import pytest

from okid_ros.service import realization
from okid_ros.service.estimation import ModalEstimationParams, ModalEstimationService
from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
from okid_ros.service.idle import IdleWatch, idle_after_s
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

Q, W = 40, 2000
FIRST_WINDOW = W + Q + 60  # samples until node 1's first window is full
T0 = 50.0
DT = paper_model().sample_time_s


def as_outcome_of(job, outcome):
    """A copy of ``outcome`` as the outcome of ``job``: the same window realized by another service.

    A service takes only the outcomes of its own jobs (their generation).
    """
    copied = copy.deepcopy(outcome)
    copied.job.generation = job.generation
    return copied


@pytest.fixture(scope="module")
def record():
    u = lowpass_input(2600, 2, 50.0, DT, seed=3)
    y, _ = simulate_innovation(paper_model(), u, seed=4)
    return u, y


def _services(n: int = 1) -> tuple[ArxIdentificationService, list[ModalEstimationService]]:
    ident = ArxIdentificationService(ArxIdentificationParams(DT, Q, 2, 2, W))
    return ident, [ModalEstimationService(ModalEstimationParams(DT, 2, 2, n_states=6)) for _ in range(n)]


def _feed(record, ident, services, lo: int, hi: int) -> list[list]:
    """Samples lo..hi-1 into node 1 (if given) and each service; each service's results."""
    u, y = record
    results: list[list] = [[] for _ in services]
    for k in range(lo, hi):
        t = T0 + k * DT
        if ident is not None:
            ident.push(t, u[k], y[k])
        for est, out in zip(services, results):
            out.append(est.step(t, u[k], y[k]))
    return results


def _submit(ident, services, arx_model_id: int) -> None:
    snap = ident.snapshot()
    assert snap.valid
    for est in services:
        assert est.submit_arx(snap.fit, snap.stamp_s, arx_model_id, snap.window_rows)


def _realized(est: ModalEstimationService):
    """Take the waiting request and realize it (as the node's worker, with the follow-up)."""
    job = est.take_job()
    assert job is not None
    return est.run_job(job)


def test_the_idle_criterion_waits_half_a_second_or_five_sample_periods():
    watch = IdleWatch()
    assert not watch.idle(10, 0.0, 0.01)  # first look at this count
    assert not watch.idle(10, 0.49, 0.01)
    assert watch.idle(10, 0.5, 0.01)
    assert not watch.idle(11, 0.6, 0.01)  # a sample came: quiet again from here
    assert not watch.idle(11, 1.0, 0.01) and watch.idle(11, 1.1, 0.01)
    assert idle_after_s(1.0) == 5.0 and not watch.idle(11, 5.0, 1.0) and watch.idle(11, 6.1, 1.0)


def test_a_model_delivered_after_the_last_sample_is_applied_once_the_stream_is_idle(record):
    ident, (est,) = _services()
    _feed(record, ident, [est], 0, FIRST_WINDOW)
    _submit(ident, [est], 1)
    est.deliver(_realized(est))
    assert est.apply_ready_if_idle(now_s=10.0) is None  # the first look: the quiet time starts
    assert est.apply_ready_if_idle(now_s=10.4) is None and est.model_id == 0
    switch = est.apply_ready_if_idle(now_s=10.6)
    assert switch is not None and switch.change is None
    assert switch.update.model_id == est.model_id == 1 and switch.update.arx_model_id == 1
    assert switch.stamp_s == pytest.approx(T0 + (FIRST_WINDOW - 1) * DT)
    d = est.diagnostics()
    assert d["models_applied_idle"] == 1 and d["models_accepted"] == 1 and not d["busy"]
    assert est.apply_ready_if_idle(now_s=20.0) is None  # applied once
    (after,) = _feed(record, None, [est], FIRST_WINDOW, FIRST_WINDOW + 5)
    assert all(r is not None and r.model_id == 1 and r.update is None for r in after)


def test_the_next_sample_after_an_idle_switch_is_stepped_once_as_after_a_switch_at_it(record):
    # Two services with the same history and the same outcome: one switches while idle, the
    # other at the next sample (the sample path). Every sample after must come out the same:
    # a sample stepped twice or skipped by the idle switch's catch-up would show here.
    ident, (idle, reference) = _services(2)
    _feed(record, ident, [idle, reference], 0, FIRST_WINDOW)
    _submit(ident, [idle, reference], 1)
    for est in (idle, reference):
        assert est.process_pending()
    _feed(record, ident, [idle, reference], FIRST_WINDOW, FIRST_WINDOW + 300)  # model 1 at the first
    _submit(ident, [idle, reference], 2)
    job = idle.take_job()
    reference_job = reference.take_job()
    assert reference_job is not None
    lo = FIRST_WINDOW + 350
    _feed(record, ident, [idle, reference], FIRST_WINDOW + 300, lo)  # samples go on during the realization
    outcome = idle.run_job(job)
    assert outcome.last_index < lo - 1  # follow() leaves at least the newest sample to the catch-up
    idle.deliver(outcome)
    reference.deliver(as_outcome_of(reference_job, outcome))
    assert idle.apply_ready_if_idle(now_s=0.0) is None
    switch = idle.apply_ready_if_idle(now_s=1.0)
    assert switch is not None and switch.update.model_id == 2 and idle.model_id == 2 and reference.model_id == 1
    after_idle, after_reference = _feed(record, None, [idle, reference], lo, lo + 50)
    assert after_reference[0].update is not None and after_reference[0].update.model_id == 2
    assert all(r.update is None for r in after_idle)
    for a, b in zip(after_idle, after_reference):
        assert a.model_id == b.model_id == 2
        np.testing.assert_allclose(a.coordinates, b.coordinates, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(a.innovation, b.innovation, rtol=1e-12, atol=1e-12)
    d_idle, d_reference = idle.diagnostics(), reference.diagnostics()
    assert d_idle["switches_measured"] == d_reference["switches_measured"] == 1  # measured at the next sample
    assert d_idle["last_switch_jump"] == pytest.approx(d_reference["last_switch_jump"], rel=1e-9)
    assert d_idle["models_applied_idle"] == 1 and d_reference["models_applied_idle"] == 0


def test_a_request_that_waited_during_the_job_is_taken_after_the_idle_switch(record):
    ident, (est,) = _services()
    _feed(record, ident, [est], 0, FIRST_WINDOW)
    _submit(ident, [est], 1)
    job = est.take_job()
    _feed(record, ident, [est], FIRST_WINDOW, FIRST_WINDOW + 100)  # the replay goes on during the job
    _submit(ident, [est], 2)
    assert est.take_job() is None and est.has_request and est.busy
    est.deliver(est.run_job(job))  # the replay has ended
    est.apply_ready_if_idle(now_s=0.0)
    first = est.apply_ready_if_idle(now_s=1.0)
    assert first is not None and first.update.arx_model_id == 1
    est.deliver(_realized(est))  # the waiting request: its window ends at the newest sample
    second = est.apply_ready_if_idle(now_s=2.0)  # still idle: applied at the next look
    assert second is not None and second.update.arx_model_id == 2 and est.model_id == 2
    assert not est.has_request and not est.busy and est.diagnostics()["models_applied_idle"] == 2


def _lost_modes(good):
    return dataclasses.replace(good, modes=[dataclasses.replace(m, frequency_rad_s=2 * m.frequency_rad_s,
                                                                frequency_hz=2 * m.frequency_hz)
                                            for m in good.modes])


@pytest.mark.parametrize(("bad_model", "reason"), [
    (lambda good: dataclasses.replace(good, A=1.05 * good.A), "unstable"),
    (_lost_modes, "modes lost"),
])
def test_a_model_refused_in_an_idle_switch_keeps_the_last_good_one(record, monkeypatch, bad_model, reason):
    ident, (est,) = _services()
    _feed(record, ident, [est], 0, FIRST_WINDOW)
    _submit(ident, [est], 1)
    assert est.process_pending()
    _feed(record, ident, [est], FIRST_WINDOW, FIRST_WINDOW + 100)
    good = est.current_model
    bad = bad_model(good)
    monkeypatch.setattr(realization, "identify_from_arx", lambda *args, **kwargs: bad)
    _submit(ident, [est], 2)
    est.deliver(_realized(est))
    est.apply_ready_if_idle(now_s=0.0)
    assert est.apply_ready_if_idle(now_s=1.0) is None
    d = est.diagnostics()
    assert est.model_id == 1 and est.current_model is good and not d["last_model_accepted"]
    assert reason in d["last_reason"], d["last_reason"]
    assert d["models_rejected"] == 1 and d["models_applied_idle"] == 0 and not d["busy"]  # the next job may start
    (after,) = _feed(record, None, [est], FIRST_WINDOW + 100, FIRST_WINDOW + 105)
    assert all(r.model_id == 1 and r.update is None for r in after)


def test_a_sample_arriving_during_the_idle_check_gets_the_outcome_once(record):
    # The idle path made to see the stream idle at any count, so that only the lock keeps it
    # from applying the outcome before a sample that is being appended and stepped.
    ident, (est,) = _services()
    _feed(record, ident, [est], 0, FIRST_WINDOW)
    _submit(ident, [est], 1)
    est.deliver(_realized(est))
    est._idle.idle = lambda *args: True
    appended, go = threading.Event(), threading.Event()
    append = est._buffer.append

    def append_then_wait(*args):
        index = append(*args)
        appended.set()
        go.wait(5.0)
        return index

    est._buffer.append = append_then_wait
    u, y = record
    results, switches = [], []
    sample = threading.Thread(target=lambda: results.append(
        est.step(T0 + FIRST_WINDOW * DT, u[FIRST_WINDOW], y[FIRST_WINDOW])))
    sample.start()
    assert appended.wait(5.0)
    idle = threading.Thread(target=lambda: switches.append(est.apply_ready_if_idle()))
    idle.start()
    idle.join(0.2)
    assert idle.is_alive()  # waits for the sample's step
    go.set()
    sample.join(5.0)
    idle.join(5.0)
    assert results[0].update is not None and results[0].update.model_id == 1  # applied at the sample
    assert switches == [None] and est.model_id == 1 and est.diagnostics()["models_applied_idle"] == 0


def test_a_sample_arriving_during_an_idle_switch_is_stepped_after_it_once(record, monkeypatch):
    ident, (est, reference) = _services(2)
    _feed(record, ident, [est, reference], 0, FIRST_WINDOW)
    _submit(ident, [est, reference], 1)
    outcome = _realized(est)
    reference_job = reference.take_job()
    assert reference_job is not None
    est.deliver(outcome)
    reference.deliver(as_outcome_of(reference_job, outcome))
    assert est.apply_ready_if_idle(now_s=0.0) is None
    in_switch, go = threading.Event(), threading.Event()
    catch_up = realization.catch_up

    def catch_up_then_wait(*args, **kwargs):
        in_switch.set()
        go.wait(5.0)
        return catch_up(*args, **kwargs)

    monkeypatch.setattr(realization, "catch_up", catch_up_then_wait)
    switches, results = [], []
    idle = threading.Thread(target=lambda: switches.append(est.apply_ready_if_idle(now_s=1.0)))
    idle.start()
    assert in_switch.wait(5.0)
    u, y = record
    k = FIRST_WINDOW
    sample = threading.Thread(target=lambda: results.append(est.step(T0 + k * DT, u[k], y[k])))
    sample.start()
    sample.join(0.2)
    assert sample.is_alive()  # waits for the switch
    go.set()
    idle.join(5.0)
    sample.join(5.0)
    monkeypatch.undo()
    assert switches[0] is not None and switches[0].update.model_id == 1 and results[0].update is None
    (expected,) = _feed(record, None, [reference], k, k + 1)  # the reference switches at the sample
    np.testing.assert_allclose(results[0].coordinates, expected[0].coordinates, rtol=1e-12, atol=1e-12)


def test_a_window_whose_last_samples_never_came_is_taken_once_the_stream_is_idle(record):
    # Node 1 got two samples more than node 2 (lost at the end of the stream: sensor QoS): the
    # request waits for them while samples may come, and ends at node 2's newest once idle.
    ident, (est,) = _services()
    _feed(record, ident, [est], 0, FIRST_WINDOW)
    _feed(record, ident, [], FIRST_WINDOW, FIRST_WINDOW + 2)
    _submit(ident, [est], 1)
    assert est.take_job() is None and est.has_request
    assert est.apply_ready_if_idle(now_s=0.0) is None and est.take_job() is None
    assert est.apply_ready_if_idle(now_s=1.0) is None  # idle, nothing delivered
    job = est.take_job()
    assert job is not None and job.stamp_end_s == pytest.approx(T0 + (FIRST_WINDOW - 1) * DT)
    est.deliver(est.run_job(job))
    switch = est.apply_ready_if_idle(now_s=1.5)
    assert switch is not None and switch.update.arx_model_id == 1
    # Further than max_gap_samples short: not a loss at the end (node 2 lost its input); it waits.
    _feed(record, ident, [], FIRST_WINDOW + 2, FIRST_WINDOW + 60)
    _submit(ident, [est], 2)
    est.apply_ready_if_idle(now_s=5.0)
    assert est.take_job() is None and est.has_request


def test_at_the_end_of_the_stream_the_delivered_model_is_applied_at_once(record):
    # What offline processing does after a record's last sample: the idle switch without the
    # quiet time, and a request a sample short taken at once too (the stream has ended).
    ident, (est,) = _services()
    _feed(record, ident, [est], 0, FIRST_WINDOW)
    _submit(ident, [est], 1)
    est.deliver(_realized(est))
    _feed(record, ident, [], FIRST_WINDOW, FIRST_WINDOW + 1)  # node 2 never gets this one
    _submit(ident, [est], 2)
    assert est.take_job() is None  # busy until the outcome is applied
    switch = est.apply_ready_at_end()
    assert switch is not None and switch.update.arx_model_id == 1 and est.model_id == 1
    assert switch.stamp_s == pytest.approx(T0 + (FIRST_WINDOW - 1) * DT)
    job = est.take_job()  # one sample short: taken, the stream having ended
    assert job is not None and job.stamp_end_s == pytest.approx(T0 + (FIRST_WINDOW - 1) * DT)
    est.deliver(est.run_job(job))
    assert est.apply_ready_if_idle(now_s=0.0) is not None  # still idle at the first look: ended
    assert est.model_id == 2 and est.apply_ready_at_end() is None  # applied once
    assert est.diagnostics()["models_applied_idle"] == 2
    (after,) = _feed(record, None, [est], FIRST_WINDOW, FIRST_WINDOW + 3)  # samples after all: stepped as usual
    assert all(r.model_id == 2 and r.update is None for r in after)
