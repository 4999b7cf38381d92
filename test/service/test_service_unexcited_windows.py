"""Node 1's windows beyond the condition bound: identified when only the outputs' lags are collinear, or refused, why.

Truth: the paper's structure struck by an impact hammer (blows of 1e6 over a force of 0.01, the
innovations of unit variance), node 1 as the live fault rig runs it (ARX order 20, window 800).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from okid_ros.core.markov import markov_from_arx, markov_from_state_space
from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
from okid_ros.service.params import ARX_NODE, resolve_parameters
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

LIVE = {"arx.order": 20, "arx.window_length": 800, "arx.min_window_fill": 0.25, "publish_rate_hz": 2.0}
Q = LIVE["arx.order"]


def _service(dt: float) -> ArxIdentificationService:
    return ArxIdentificationService(ArxIdentificationParams.from_parameters(
        resolve_parameters(ARX_NODE, {"sample_time_s": dt, **LIVE})))


def _struck(blows: list[tuple[int, int]], n: int, seed: int = 4) -> tuple[float, np.ndarray, np.ndarray]:
    """A quiet force (0.01) on both inputs, blows of 1e6 at ``(sample, input)``; the structure's outputs."""
    truth = paper_model()
    u = 0.01 * np.random.default_rng(seed).standard_normal((n, 2))
    for sample, channel in blows:
        u[sample, channel] += 1e6
    y, _ = simulate_innovation(truth, u, seed=seed + 1)
    return truth.sample_time_s, u, y


def _reason(dt: float, u: np.ndarray, y: np.ndarray) -> str:
    service = _service(dt)
    service.push_block(dt * np.arange(u.shape[0]), u, y)
    return service.snapshot().reason


def test_a_window_of_blows_far_above_the_noise_is_identified_and_its_markov_parameters_are_the_truths():
    # Blows of 1e6 on both inputs well inside the window: the outputs' free decays stand 1e5 above
    # their noise and their 20 lags repeat them (condition number 4e12 here, 1e12-2e13 over the
    # tests' hammer record), which node 1 refused as an unexcited window naming no cause.
    dt, u, y = _struck([(300, 1), (500, 0), (620, 1)], 1000)
    service = _service(dt)
    service.push_block(dt * np.arange(u.shape[0]), u, y)
    snapshot = service.snapshot()
    assert snapshot.condition_number > service.params.max_condition_number
    assert snapshot.valid, snapshot.reason
    truth = paper_model()
    markov = markov_from_arx(snapshot.fit, Q + 1)
    true_markov = markov_from_state_space(truth.A, truth.B, truth.C, truth.D, Q + 1)
    assert np.linalg.norm(markov - true_markov) < 1e-4 * np.linalg.norm(true_markov)


def test_every_window_of_the_hammer_record_beyond_the_bound_is_identified_or_names_its_cause():
    # The tests' impact-hammer record (test_service_input_glitches) with blows of 1e6: 51 of its 63
    # windows were refused with the condition number alone.
    truth, rng = paper_model(), np.random.default_rng(4)
    u = 0.01 * rng.standard_normal((4000, 2))
    u[rng.choice(np.arange(300, 3900), 12, replace=False), rng.integers(0, 2, 12)] += 1e6
    (y, _), dt = simulate_innovation(truth, u, seed=5), truth.sample_time_s
    service, refused = _service(dt), []
    for k in range(u.shape[0]):
        service.push(k * dt, u[k], y[k])
        if service.due(k * dt):
            snapshot = service.snapshot()
            if snapshot.reason.startswith("unexcited window"):
                refused.append(snapshot.reason)
            else:
                assert snapshot.valid or snapshot.reason.startswith("window fill"), snapshot.reason
    assert service.diagnostics()["valid_snapshots"] >= 55
    assert refused and all(re.search(r"; input \d varies only ", reason) for reason in refused), refused


@pytest.mark.parametrize("age", [0, 7])
def test_a_blow_in_the_windows_newest_samples_over_a_quiet_force_is_named(age):
    # Its lags but the newest age + 1 hold only the quiet force, 1e-13 of the blow's mean square:
    # the window has the force and not yet its response. Input 1's blow well inside.
    dt, u, y = _struck([(300, 1), (999 - age, 0)], 1000)
    reason = _reason(dt, u, y)
    assert reason.startswith("unexcited window: condition number"), reason
    assert (f"; input 0 varies only in the newest {age + 1} samples of this window" in reason
            and f"it will {Q - age} samples on" in reason), reason


@pytest.mark.parametrize("quiet", [0.01, 0.0])
def test_a_blow_leaving_the_windows_lags_is_named(quiet):
    # The window's rows begin at sample 200; a blow at 195 is in the lags 5-20 of its oldest rows only.
    # Over a force of exactly 0 the input was named dead: "check the sensor or actuator".
    dt, u, y = _struck([(195, 0), (600, 1)], 1000)
    u[:, 0] *= quiet / 0.01
    u[195, 0] = 1e6
    y, _ = simulate_innovation(paper_model(), u, seed=5)
    reason = _reason(dt, u, y)
    own = "hold 8e-14 of that mean square" if quiet else "are all zeros"  # the quiet force's mean square, or none
    assert (f"; input 0 varies only 5 or more samples before this window's oldest row (in its lags 5-20 alone; the "
            f"window's own samples {own}: a hammer's blow leaving the window): its response is in the window, the "
            f"force at lags 0-4 is not; it will be past the ARX order's 20 lags 16 samples on" in reason), reason


def test_one_force_on_two_inputs_and_a_sinusoid_are_named():
    truth = paper_model()
    dt = truth.sample_time_s
    u = lowpass_input(1000, 2, 15.0, dt, seed=3)
    u[:, 1] = 0.5 * u[:, 0]  # one command sent to two actuators
    y, _ = simulate_innovation(truth, u, seed=4)
    assert "; inputs 0, 1 are linearly dependent" in _reason(dt, u, y)
    u[:, 0] = np.sin(2 * np.pi * 5.0 * dt * np.arange(1000))  # a shaker's single tone
    u[:, 1] = lowpass_input(1000, 1, 15.0, dt, seed=5)[:, 0]
    y, _ = simulate_innovation(truth, u, seed=4)
    reason = _reason(dt, u, y)
    assert "; input 0 does not vary independently over the ARX order's 20 lags" in reason, reason
