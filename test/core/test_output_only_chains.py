"""One mode's chain of poles cut into pieces by its turning shape is one mode (ssi-cva, issue 18).

Twin chains 34 (bench/okid_bench/physical_cases.py): the 148.04 Hz member of a close pair held a
stable pole within 0.5 % at 43 orders, but its estimated shape turned with the order (its partner's
mixed in), and the linkage's shape distance cut the chain into seven clusters of 4-10 orders, each
too short to be a mode (docs/benchmarks-output-only.md, "Resolvable close modes kept apart by the
clustering (forty-sixth session)").
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.output_only_modes import PoleSet, cluster_modes


def _turning_chain(frequencies_hz, damping_ratios, orders, *, turn_per_order: float, seed: int = 3) -> PoleSet:
    """One pole per order of each mode, each mode's real shape turning by ``turn_per_order`` rad an order step."""
    dt, rng = 0.01, np.random.default_rng(seed)
    order = np.tile(orders, len(frequencies_hz))
    f = np.repeat(frequencies_hz, orders.size) * (1 + 2e-4 * rng.standard_normal(order.size))
    z = np.repeat(damping_ratios, orders.size) * (1 + 0.03 * rng.standard_normal(order.size))
    angle = turn_per_order * np.tile(np.arange(orders.size), len(frequencies_hz))
    base = np.repeat(np.arange(len(frequencies_hz)), orders.size)  # each mode turns in a plane of its own
    shape = np.zeros((order.size, 4), complex)
    shape[np.arange(order.size), 2 * base] = np.cos(angle)
    shape[np.arange(order.size), 2 * base + 1] = np.sin(angle)
    s = 2 * np.pi * f * (-z + 1j * np.sqrt(1 - z ** 2))
    return PoleSet(order, f, z, np.exp(s * dt), shape, np.ones(f.size), np.ones(f.size, bool))


def test_a_mode_whose_shape_turns_with_the_order_is_one_mode() -> None:
    orders = np.arange(10, 102, 2)
    modes, _ = cluster_modes(_turning_chain([10.0], [0.01], orders, turn_per_order=0.03))
    assert [round(m.frequency_hz, 2) for m in modes] == [10.0]
    assert len(modes[0].members) >= 0.9 * orders.size


def test_two_turning_chains_side_by_side_stay_two_modes() -> None:
    """Two modes 0.6 % apart (a third of a half-power width), both turning, hold poles at the same orders: two modes."""
    orders = np.arange(10, 102, 2)
    modes, _ = cluster_modes(_turning_chain([10.0, 10.06], [0.01, 0.01], orders, turn_per_order=0.03))
    assert [round(m.frequency_hz, 2) for m in modes] == [10.0, 10.06]
