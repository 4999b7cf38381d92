"""Node 2's sample path does per model what it did per sample, with the same outputs.

A gap bridged and a switch's jump measured on the sample path made the model's predictor matrices
(``F``, ``G_u``, ``G_y``) each time, and used none of them: an InnovationPredictor now makes them at
their first use (``okid_ros/core/statespace.py``). The replay below runs node 2's service over a record
with lost samples, a long gap and model switches, as it runs and with every predictor made at once and
stepped as before (the code before the change), and compares every output.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.statespace import InnovationPredictor
from okid_ros.service.estimation import ModalEstimationParams, ModalEstimationService
from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

SAMPLES, EVERY = 4000, 250


def _replay():
    """Node 2's ModalStates (as tuples) and its diagnostics over the paper model's record with gaps."""
    model = paper_model()
    dt = model.sample_time_s
    u = lowpass_input(SAMPLES, 2, 50.0, dt, seed=5)
    y, _ = simulate_innovation(model, u, seed=6)
    lost = np.random.default_rng(7).random(SAMPLES) < 0.02  # gaps bridged
    lost[3800:3820] = True  # a gap longer than max_gap_samples: the estimator restarts
    ident = ArxIdentificationService(ArxIdentificationParams(dt, 40, 2, 2, 2000))
    est = ModalEstimationService(ModalEstimationParams(dt, 2, 2, n_states=6))
    outputs, skipped = [], 0
    for k in np.flatnonzero(~lost):
        skipped = k - (outputs[-1][0] if outputs else k)
        ident.push(k * dt, u[k], y[k])
        r = est.step(k * dt, u[k], y[k], skipped=max(skipped - 1, 0))
        outputs.append((k, None if r is None else (r.model_id, [m.id for m in r.modes], r.coordinates, r.y_estimated,
                                                   r.innovation, r.update is not None)))
        if k % EVERY >= EVERY - 1 and ident.snapshot().valid and not est.busy:
            snap = ident.snapshot()
            est.submit_arx(snap.fit, snap.stamp_s, snap.model_id, snap.window_rows)
            if (job := est.take_job()) is not None:
                est.deliver(est.run_job(job))  # followed, as node 2's pool thread does
    return outputs, est.diagnostics()


def test_modal_states_with_gaps_and_switches_are_those_of_predictors_made_at_once(monkeypatch):
    now, now_diagnostics = _replay()
    made_at_once = InnovationPredictor.__init__
    stepped = InnovationPredictor.step

    def make_at_once(self, model, state=None):
        made_at_once(self, model, state)
        self.F, self.Gu, self.Gy = model.predictor()

    monkeypatch.setattr(InnovationPredictor, "__init__", make_at_once)
    monkeypatch.setattr(InnovationPredictor, "step", lambda self, u, y, advance=True: stepped(self, u, y))
    before, before_diagnostics = _replay()
    published = [r for _, r in now if r is not None]
    assert sum(r[-1] for r in published) >= 3, "too few model switches to compare"
    assert now_diagnostics["gaps_bridged"] > 20 and now_diagnostics["estimator_restarts"] >= 1, now_diagnostics
    assert len(now) == len(before)
    for (k, mine), (_, theirs) in zip(now, before):
        assert (mine is None) == (theirs is None), k
        if mine is not None:
            assert mine[:2] == theirs[:2] and mine[-1] == theirs[-1], k
            for a, b in zip(mine[2:5], theirs[2:5]):
                np.testing.assert_array_equal(a, b)
    timing = {"last_realization_time_s"}
    assert {k: v for k, v in now_diagnostics.items() if k not in timing} == \
        {k: v for k, v in before_diagnostics.items() if k not in timing}
