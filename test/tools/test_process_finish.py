"""The end of a record in `okid-ros process` (OfflineNodes.finish, WindowedPipeline.finish), without DDS.

A model realized from an ArxModel at the record's last sample has no next sample to take over
at: ``finish()`` switches it in after the last sample, as the live node's idle timer does at the
end of a replay, and writes it as any other (StateSpaceModel, JSON line, counts, final modes).
The paper's structure, a short window and a fixed order keep each run under a second.
"""

from __future__ import annotations

import dataclasses

import pytest

from okid_ros.nodes.conversions import io_sample_msg
from okid_ros.service import realization
from okid_ros.service.grid_samples import GridSample
from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams
from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, resolve_parameters
from okid_ros.service.windowed import WindowedPipeline
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation
from okid_ros.tools.process import OfflineNodes, load_node_parameters

DT = paper_model().sample_time_s
T0 = 50.0
N = 2000  # the second valid ArxModel (one per second of sample time) comes at sample 1250
OVERRIDES = ["arx.order=40", "arx.window_length=2000", "publish_rate_hz=1.0", "realization.n_states=6",
             "realization.refine=false"]
SSM, ARX = "/okid/state_space_model", "/okid/arx_model"


@pytest.fixture(scope="module")
def record():
    u = lowpass_input(N, 2, 50.0, DT, seed=3)
    y, _ = simulate_innovation(paper_model(), u, seed=4)
    return u, y


def _feed_until_second_valid_arx(nodes: OfflineNodes, record) -> tuple[list, int]:
    """Feed samples until the sample at which the second valid ArxModel comes, and stop there.

    Returns the outputs and that ArxModel's id: it is realized at the record's last sample.
    """
    u, y = record
    out, valid = [], []
    for k in range(N):
        t = T0 + k * DT
        step = nodes.feed("/okid/io_sample", io_sample_msg(t, u[k], y[k], nodes.types), t)
        out += step
        valid += [msg.model_id for topic, msg in step if topic == ARX and msg.valid]
        if len(valid) == 2:
            return out, valid[1]
    raise AssertionError(f"fewer than two valid ArxModel in {N} samples")


def test_a_model_realized_at_the_last_sample_is_written_by_finish(record):
    nodes = OfflineNodes(*load_node_parameters(overrides=OVERRIDES))
    out, last_arx = _feed_until_second_valid_arx(nodes, record)
    before = [msg for topic, msg in out if topic == SSM]
    assert [msg.model_id for msg in before] == [1] and nodes.est.diagnostics()["busy"]  # delivered, not applied
    end = nodes.finish()
    assert [topic for topic, _ in end] == [SSM]  # no ModalStates: there is no sample after the last
    (final,) = [msg for _, msg in end]
    assert final.model_id == 2 and final.arx_model_id == last_arx
    summary = nodes.summary
    assert summary.models == 2 == len(summary.updates) == len(before) + 1
    line = summary.updates[-1]
    assert line["model_id"] == 2 and line["arx_model_id"] == last_arx and line["applied_after_last_sample"]
    assert line["applied_at_stamp_s"] == pytest.approx(summary.last_stamp_s)
    assert len(line["fit_one_step_pct"]) == len(line["fit_simulation_pct"]) == 2  # as realize_now prepares them
    assert not summary.updates[0]["applied_after_last_sample"]
    assert summary.final_modes == line["modes"] and [m["id"] for m in line["modes"]] == [m.id for m in final.modes]
    assert nodes.est.model_id == 2 and summary.estimator_diagnostics["models_applied_idle"] == 1
    assert nodes.finish() == [] and summary.models == 2  # applied once


def test_a_model_refused_at_the_end_writes_nothing_and_keeps_the_last_good_one(record, monkeypatch):
    nodes = OfflineNodes(*load_node_parameters(overrides=OVERRIDES))
    identify = realization.identify_from_arx
    calls = []

    def second_unstable(*args, **kwargs):
        model = identify(*args, **kwargs)
        calls.append(model)
        return model if len(calls) == 1 else dataclasses.replace(model, A=1.05 * model.A)

    monkeypatch.setattr(realization, "identify_from_arx", second_unstable)
    out, _ = _feed_until_second_valid_arx(nodes, record)
    assert len(calls) == 2
    assert nodes.finish() == []
    summary = nodes.summary
    assert summary.models == 1 == len(summary.updates) and summary.updates[0]["model_id"] == 1
    d = summary.estimator_diagnostics
    assert nodes.est.current_model is calls[0] and d["model_id"] == 1 and not d["last_model_accepted"]
    assert "unstable" in d["last_reason"], d["last_reason"]
    assert d["models_rejected"] == 1 and d["models_applied_idle"] == 0


def _pipeline() -> WindowedPipeline:
    values = {"sample_time_s": DT, "n_inputs": 2, "n_outputs": 2}
    arx = resolve_parameters(ARX_NODE, {**values, "arx.order": 40, "arx.window_length": 2000})
    est = resolve_parameters(ESTIMATOR_NODE, {**values, "realization.n_states": 6, "realization.refine": False})
    return WindowedPipeline(ArxIdentificationParams.from_parameters(arx), ModalEstimationParams.from_parameters(est))


@pytest.mark.parametrize(("lost", "taken"), [(2, True), (60, False)])
def test_a_request_whose_last_samples_never_reached_node_2_is_taken_at_the_end(record, lost, taken):
    # Node 1 got `lost` samples more than node 2: the request waits for them; at the end of the
    # record it is taken with node 2's newest sample as its end if at most max_gap_samples short.
    u, y = record
    pipe = _pipeline()
    last = 1500
    for k in range(last + lost):
        sample = GridSample(k, T0 + k * DT, u[k], y[k], restart=k == 0)
        if k < last:
            pipe.estimate(sample)
        pipe.identify(sample)
    snapshot = pipe.arx.snapshot()
    assert snapshot.valid
    assert pipe.realize_now(snapshot.fit, snapshot.stamp_s, 7, snapshot.window_rows) is None
    assert pipe.est.has_request
    switches = pipe.finish()
    if not taken:  # further than max_gap_samples short: node 2 lost its input, not a sample or two
        assert switches == [] and pipe.updates == [] and pipe.est.has_request
        return
    (switch,) = switches
    assert switch.update.arx_model_id == 7 and switch.stamp_s == pytest.approx(T0 + (last - 1) * DT)
    (line,) = pipe.updates
    assert line["arx_model_id"] == 7 and line["applied_after_last_sample"] and "fit_one_step_pct" in line
    assert line["stamp_s"] == pytest.approx(T0 + (last - 1) * DT)  # the window ends at node 2's newest
