"""The warm-started order search (core/order_search.py): a band around the previous order.

The nodes, ``process`` and ``track`` pass the order of the model in use; the search screens the
orders around it and widens the band until BIC has its minimum inside, with the winner's
stabilization neighbours. Where the minimum is the full search's, the model is the same. The
least-squares refit stops a few orders past its own minimum: the same model again.
"""

from __future__ import annotations

import numpy as np
import pytest

from okid_ros.core import order_search
from okid_ros.core.pipeline import identify, identify_from_arx
from okid_ros.service import realization
from okid_ros.service.estimation import ModalEstimationParams, ModalEstimationService
from okid_ros.sim import lowpass_input, modal_structure, simulate


def _record(n_outputs: int, seed: int):
    dt = 0.01
    system = modal_structure([2.1, 5.3, 9.8, 14.2, 21.0], 0.02, 2, n_outputs, dt, seed=seed)
    u = lowpass_input(4000, 2, 30.0, dt, seed=seed + 1)
    return u, simulate(system, u, seed + 2), dt


@pytest.mark.parametrize("n_outputs, completion", [(3, "predictor"), (16, "states")])
def test_a_hint_near_or_far_gives_the_full_searchs_model_from_fewer_orders(n_outputs, completion):
    u, y, dt = _record(n_outputs, seed=3)
    arx = identify(u, y, dt, order=20 if n_outputs > 3 else 40).arx
    full = identify_from_arx(arx, u, y, dt)
    assert full.completion == completion
    screened_full = len(full.order_scores)
    for hint in (full.n_states, full.n_states + 6, full.n_states - 6, 2, 150):
        warm = identify_from_arx(arx, u, y, dt, order_hint=hint)
        assert warm.n_states == full.n_states, hint
        np.testing.assert_allclose(warm.A, full.A, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose([m.frequency_hz for m in warm.modes], [m.frequency_hz for m in full.modes],
                                   rtol=1e-12)
        assert set(warm.order_scores) <= set(full.order_scores), hint
    at_the_order = identify_from_arx(arx, u, y, dt, order_hint=full.n_states)
    assert len(at_the_order.order_scores) < screened_full


def test_the_service_hints_the_order_of_the_model_in_use(monkeypatch):
    hints = []
    original = realization.identify_from_arx

    def spy(*args, **kwargs):
        hints.append(kwargs.get("order_hint"))
        return original(*args, **kwargs)

    monkeypatch.setattr(realization, "identify_from_arx", spy)
    u, y, dt = _record(3, seed=5)
    from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService

    ident = ArxIdentificationService(ArxIdentificationParams(dt, 40, 2, 3, 2000))
    est = ModalEstimationService(ModalEstimationParams(dt, 2, 3))
    in_use = []
    for k in range(u.shape[0]):
        ident.push(10.0 + k * dt, u[k], y[k])
        est.step(10.0 + k * dt, u[k], y[k])
        if k % 500 == 499:
            snap = ident.snapshot()
            if snap.valid:
                in_use.append(None if est.current_model is None else est.current_model.n_states)
                est.submit_arx(snap.fit, snap.stamp_s, snap.model_id, snap.window_rows)
                est.process_pending()
    assert len(hints) >= 3
    assert hints[0] is None and hints == in_use


def test_the_refit_stops_past_its_minimum_with_the_model_of_every_order_refitted(monkeypatch):
    # 6 outputs: the Gram screening prefers orders above the refit's minimum (14 states here).
    u, y, dt = _record(6, seed=3)
    arx = identify(u, y, dt, order=40).arx
    stopped = identify_from_arx(arx, u, y, dt)
    monkeypatch.setattr(order_search, "REFIT_PATIENCE", 10**6)  # every order up to the screening's choice
    every = identify_from_arx(arx, u, y, dt)
    assert set(stopped.completed_orders) < set(every.completed_orders)
    assert stopped.n_states == every.n_states
    np.testing.assert_array_equal(stopped.A, every.A)
    assert [m.frequency_hz for m in stopped.modes] == [m.frequency_hz for m in every.modes]
