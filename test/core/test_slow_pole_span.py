"""An ARX order spanning the slowest mode's period, for models the refinement did not correct."""

from types import SimpleNamespace

import numpy as np
import pytest

from okid_ros.core.identified_model import IdentificationError
from okid_ros.core.options import ArxOrderOptions
from okid_ros.core.pipeline import identify
from okid_ros.core.slow_pole_span import arx_order_spanning_slowest_pole, spanning_slowest_pole

DT = 0.01  # 100 Hz


def _modal_A(*modes: tuple[float, float]) -> np.ndarray:
    """Block-diagonal discrete ``A`` of (frequency Hz, damping ratio) pairs."""
    blocks = []
    for f, zeta in modes:
        s = 2 * np.pi * f * (-zeta + 1j * np.sqrt(1 - zeta**2))
        lam = np.exp(s * DT)
        blocks.append(np.array([[lam.real, -lam.imag], [lam.imag, lam.real]]))
    A = np.zeros((2 * len(blocks), 2 * len(blocks)))
    for i, block in enumerate(blocks):
        A[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = block
    return A


def _longer(A: np.ndarray, order: int, **changes) -> tuple[int, float]:
    size = {"n_outputs": 16, "n_inputs": 2, "n_samples": 6000, "max_damping": 0.1} | changes
    return arx_order_spanning_slowest_pole(A, DT, order, **size)


def test_the_order_spans_one_period_of_the_slowest_light_pole() -> None:
    # 2.4 Hz at 100 Hz: 41.7 samples; the next candidate order is 50.
    longer, slowest = _longer(_modal_A((2.4, 0.005), (9.7, 0.015)), 20)
    assert longer == 50 and slowest == pytest.approx(2.4, rel=1e-9)
    assert _longer(_modal_A((2.4, 0.005)), 50)[0] == 0  # already spanned


def test_heavily_damped_poles_do_not_count() -> None:
    # 1 Hz at 30 % damping is no mode; the slowest light pole is 9.7 Hz (10.3 samples).
    longer, slowest = _longer(_modal_A((1.0, 0.3), (9.7, 0.015)), 20)
    assert longer == 0 and slowest == pytest.approx(9.7, rel=1e-9)
    assert _longer(_modal_A((1.0, 0.3)), 20) == (0, pytest.approx(np.nan, nan_ok=True))


def test_a_pole_with_few_periods_in_the_record_is_no_mode_to_span() -> None:
    # 0.015 Hz over 6000 samples (60 s): 0.9 periods, a drift; 2.4 Hz sets the order.
    assert _longer(_modal_A((0.015, 0.01), (2.4, 0.005)), 20)[0] == 50


def test_the_longer_order_stays_within_the_cost_limit_and_the_record() -> None:
    slow = _modal_A((0.2, 0.01))  # 500 samples
    assert _longer(slow, 20)[0] == (2500 - 2) // 18  # the cost limit: 2500 coefficients per output
    assert _longer(slow, 20, n_samples=5000)[0] == longest_fit(5000, 16, 2) < (2500 - 2) // 18
    assert _longer(slow, 200, n_samples=5000)[0] == 0  # nothing longer fits
    assert arx_order_spanning_slowest_pole(slow, DT, 20, n_outputs=1, n_inputs=1, n_samples=100000, max_damping=0.1,
                                           arx_orders=ArxOrderOptions(candidates=(10, 600)))[0] == 600


def longest_fit(n_samples: int, p: int, m: int) -> int:
    return int((n_samples - 2 * m) // (1 + 2 * (p + m)))


def test_a_refused_second_identification_keeps_the_first_model() -> None:
    model = SimpleNamespace(arx=SimpleNamespace(order=20), A=_modal_A((2.4, 0.005)), n_outputs=16, n_inputs=2,
                            warnings=[])

    def refuse(q: int):
        raise IdentificationError(f"refused at {q}")

    kept = spanning_slowest_pole(model, refuse, DT, max_damping=0.1, n_samples=6000)
    assert kept is model
    assert "ARX order 50" in model.warnings[0] and "refused at 50" in model.warnings[0]


def test_many_outputs_list_the_mode_the_short_arx_order_lost() -> None:
    """``many-outputs`` (16 accelerometers, 6000 samples): GCV picks ARX order 20, 0.2 s.

    The 2.4 Hz mode's period is 0.42 s; at 16 outputs the refinement is beyond its cost bound.
    From order 20 the 5.2 Hz mode was never listed (10 of 10 seeds) and the 2.4 Hz mode's damping
    came out 0.6-1.2 points high (true 0.5 %); from order 50 every mode is listed.
    """
    from okid_bench.cases import benchmark_case
    from okid_bench.scoring import assign_by_frequency, modes_of
    from okid_ros.sim.simulators import simulate

    case = benchmark_case("many-outputs")
    u = case.make_input(6000, 1001)
    model = identify(u, simulate(case.system, u, 1002), case.sample_time_s)
    assert model.arx.order == 50 and not model.refined
    assert any("instead of 20 (chosen by GCV)" in warning for warning in model.warnings), model.warnings
    truth = modes_of(case.system.A, case.sample_time_s)
    listed = [mode.frequency_hz for mode in model.modes]
    pairs = assign_by_frequency(listed, [mode.frequency_hz for mode in truth], 0.005)
    assert None not in pairs, (listed, [mode.frequency_hz for mode in truth])
    slowest = int(np.argmin([mode.frequency_hz for mode in truth]))
    assert abs(model.modes[pairs[slowest]].damping_ratio - truth[slowest].damping_ratio) < 0.002
