"""A close pair's member whose complex shape lies in its complex partner's real plane: kept below the MPC floor."""

from __future__ import annotations

import numpy as np
import pytest

from okid_ros.core.modal import mpc
from okid_ros.core.output_only_modes import PoleSet, cluster_modes, mpc_floor
from okid_ros.core.output_only_pair_plane import pair_plane_floor, share_in_real_plane

DT = 1e-3
# A tower's two bending directions seen by two biaxial levels (4 outputs): orthogonal real shapes.
_X = np.array([0.5, 0.8, 0.3, 0.6])
_Y = np.array([0.8, -0.5, 0.6, -0.3])
_Y = _Y - _X * (_X @ _Y) / (_X @ _X)
_X, _Y = _X / np.linalg.norm(_X), _Y / np.linalg.norm(_Y)
_OFF_PLANE = np.linalg.qr(np.column_stack([_X, _Y, [0.3, 0.1, -0.9, 0.2]]))[0][:, 2]
_PARTNER = _X + 0.5j * _Y  # the stronger member: a complex mix of both, MPC 0.36 (above the floor at 4 outputs)


def _poles(shape: np.ndarray, frequency_hz: float, seed: int, n_orders: int = 30) -> PoleSet:
    """One mode's pole at every order from 10 on, its shape with a little scatter from order to order."""
    rng = np.random.default_rng(seed)
    orders = np.arange(10, 10 + 2 * n_orders, 2)
    f = frequency_hz * (1 + 1e-4 * rng.standard_normal(n_orders))
    z = 0.01 * (1 + 0.02 * rng.standard_normal(n_orders))
    s = 2 * np.pi * f * (-z + 1j * np.sqrt(1 - z ** 2))
    shapes = shape[None, :] * (1 + 0.01 * (rng.standard_normal((n_orders, shape.size))
                                           + 1j * rng.standard_normal((n_orders, shape.size))))
    shapes /= np.linalg.norm(shapes, axis=1, keepdims=True)
    return PoleSet(orders, f, z, np.exp(s * DT), shapes, np.ones(n_orders), np.ones(n_orders, bool))


def _pair(own: np.ndarray) -> list[float]:
    """The frequencies of the modes clustered from ``own`` at 10.0 Hz beside the partner at 10.02 Hz (0.2 widths)."""
    first, second = _poles(own / np.linalg.norm(own), 10.0, seed=1), _poles(_PARTNER / np.linalg.norm(_PARTNER),
                                                                            10.02, seed=2)
    fields = ("order", "frequency_hz", "damping_ratio", "eigenvalue", "shape", "energy", "stable")
    modes, _ = cluster_modes(PoleSet(*(np.concatenate([getattr(first, k), getattr(second, k)]) for k in fields)))
    return [round(m.frequency_hz, 2) for m in modes]


def test_a_pair_member_mixed_within_its_partners_real_plane_is_kept() -> None:
    """Tower 4's 16.83 Hz (4 outputs, MPC 0.10 at 45 orders, its partner 0.37): both members mix the plane's two shapes.

    With the partner's shape projected out the rest is as complex as the partner (MPC 0.36, under the
    0.5 of noise at 3 outputs): refused before; it lies wholly in the partner's real plane.
    """
    own = _Y + 0.9j * _X
    assert mpc(own / np.linalg.norm(own)) < mpc_floor(4) <= mpc(_PARTNER / np.linalg.norm(_PARTNER))
    assert _pair(own) == [10.0, 10.02]


def test_a_complex_shape_out_of_its_partners_plane_is_rejected() -> None:
    """Half its imaginary part off the plane: no mix of the pair's two real shapes."""
    own = _Y + 0.9j * (_X + _OFF_PLANE) / np.sqrt(2)
    assert mpc(own / np.linalg.norm(own)) < mpc_floor(4)
    assert share_in_real_plane(own / np.linalg.norm(own), _PARTNER) < pair_plane_floor(4)
    assert _pair(own) == [10.02]


@pytest.mark.parametrize("n_outputs", [3, 4, 8])
def test_the_plane_floor_is_what_noise_shapes_exceed_one_time_in_a_hundred(n_outputs: int) -> None:
    rng = np.random.default_rng(n_outputs)
    partner = rng.standard_normal(n_outputs) + 1j * rng.standard_normal(n_outputs)
    noise = rng.standard_normal((40000, n_outputs)) + 1j * rng.standard_normal((40000, n_outputs))
    shares = [share_in_real_plane(shape, partner) for shape in noise[:200]]
    basis, _ = np.linalg.qr(np.column_stack([partner.real, partner.imag]))
    every = np.sum(np.abs(noise @ basis) ** 2, axis=1) / np.sum(np.abs(noise) ** 2, axis=1)
    assert np.allclose(shares, every[:200])
    assert np.mean(every > pair_plane_floor(n_outputs)) == pytest.approx(0.01, abs=0.002)
    assert pair_plane_floor(2) == 1.0
