"""Structure families no selection rule was tuned on, with exact discrete truth (``--cases new-families``).

Three families, drawn in turn (structure ``index`` is of family ``index % 3``), each a physical
``M q'' + C q' + K q = F d(t)`` like :mod:`okid_bench.physical_cases`, but of kinds the bench's
rules never saw:

* ``plate``: a grid of 2-4 x 2-5 masses moving out of plane, springs to their neighbours along
  both axes (the two directions' stiffnesses within 0-30 % of each other, every spring +-5 %) and
  to the ground at the edges: clusters of close modes where the grid's directions nearly agree;
  Rayleigh or modal damping 0.5-2 %;
* ``torsion-frame``: a building of 2-6 floors with three degrees of freedom each (two sway
  directions and the floor's twist), four corner columns of unequal stiffness (the floors'
  centres of stiffness off their centres of mass: sway and torsion coupled, close sway pairs),
  damped by 1-3 local dashpots between floors plus a light Rayleigh floor: non-proportional
  damping, complex modes, 1-5 % typical;
* ``coloured-building``: a shear building of 3-10 storeys driven by coloured forces (each white
  force through a 2nd-order low-pass with its corner at 0.3-1.2 of the highest mode, or through an
  overdamped band-pass around the modes): the modes above the corner weakly excited. The filter's
  states are part of the simulated system (the record is exactly Gaussian and linear); its poles
  (damping 0.7 or more) are not structural modes: a method listing one is charged a spurious mode.

Record conditions, drawn per structure: sampling rate 3-20 times the highest mode; 300-3000 periods
of the slowest mode (3000-60000 samples: a slow mode far below the highest gets fewer periods);
3-40 sensors (at most the degrees of freedom); 1-3 white forces; sensor noise 1-20 % of each
channel's noise-free RMS. Forces are held over a sample (:func:`okid_ros.sim.models.zero_order_hold`):
the discrete poles are exactly ``exp(s dt)``.

Truth: the structure's discrete modes whose share of some channel's variance is at least
:data:`okid_bench.physical_cases.VISIBLE_SHARE` (:func:`mode_shares`); the others are hidden
(neither found nor missed, nor spurious when listed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, signal

from okid_bench.output_only_cases import system_modes
from okid_bench.physical_cases import VISIBLE_SHARE, PhysicalCase, _chain_stiffness, _modal_damping, _rayleigh
from okid_ros.sim.models import NoisyStateSpace, zero_order_hold

__all__ = ["NEW_FAMILIES", "NEW_FAMILY_CASES", "ShapedCase", "mode_shares", "new_family_case", "shaped_system"]

#: The families, drawn in turn.
NEW_FAMILIES = ("plate", "torsion-frame", "coloured-building")
#: Their name among the bench's ``--cases``.
NEW_FAMILY_CASES = "new-families"
#: Samples of a record: at least, at most.
MIN_SAMPLES, MAX_SAMPLES = 3000, 60000
#: Sensors: at least, at most.
MIN_SENSORS, MAX_SENSORS = 3, 40


@dataclass
class ShapedCase(PhysicalCase):
    """A structure whose record may carry a shaping filter's states; its truth is the structure's modes only.

    Attributes
    ----------
    structural_poles : the structure's own continuous poles (upper half plane), to tell them from
        the filter's in the simulated system.
    """

    structural_poles: np.ndarray | None = None

    def _modes(self) -> list[tuple[dict, float]]:
        """(mode, share) of the structure's own poles (``s = ln z / dt`` is the continuous pole exactly)."""
        poles = np.asarray(self.structural_poles)
        out = []
        for mode, share in zip(system_modes(self.system), mode_shares(self.system)):
            w, zeta = 2 * np.pi * mode["frequency_hz"], mode["damping_ratio"]
            s = w * complex(-zeta, np.sqrt(1 - zeta ** 2))
            if np.min(np.abs(poles - s)) < 1e-6 * w:
                out.append((mode, share))
        return out

    def truth(self) -> list[dict]:
        """The structure's modes the record shows (share at least ``VISIBLE_SHARE`` in a channel), by frequency."""
        return [m for m, share in self._modes() if share >= VISIBLE_SHARE]

    def hidden_hz(self) -> list[float]:
        """Frequencies of the structure's modes the record does not show."""
        return [m["frequency_hz"] for m, share in self._modes() if share < VISIBLE_SHARE]


def mode_shares(system: NoisyStateSpace) -> np.ndarray:
    """Each complex pole pair's largest share of one channel's variance, by frequency (as ``system_modes``).

    As :func:`okid_bench.physical_cases.variance_shares`, with the real poles of a shaping filter
    as 1x1 blocks of the real modal coordinates.
    """
    z, psi = linalg.eig(system.A)
    upper = np.flatnonzero(z.imag > 0)
    real = np.flatnonzero(z.imag == 0)
    order = upper[np.argsort(np.abs(np.log(z[upper])))]
    T = np.hstack([np.column_stack([psi[:, i].real, psi[:, i].imag]) for i in order] + [psi[:, real].real])
    T_inv = np.linalg.inv(T)
    P = linalg.solve_discrete_lyapunov(T_inv @ system.A @ T, T_inv @ system.process_noise_covariance @ T_inv.T)
    C_modal = system.C @ T
    total = np.diag(C_modal @ P @ C_modal.T + system.measurement_noise_covariance)
    parts = np.column_stack([np.einsum("jk,kl,jl->j", C_modal[:, 2 * i:2 * i + 2], P[2 * i:2 * i + 2, 2 * i:2 * i + 2],
                                       C_modal[:, 2 * i:2 * i + 2]) for i in range(order.size)])
    return (parts / total[:, None]).max(axis=0)


def shaped_system(M: np.ndarray, C: np.ndarray, K: np.ndarray, *, forces: np.ndarray, sensors: np.ndarray,
                  sample_time_s: float, noise_ratio: float, shaping=None) -> NoisyStateSpace:
    """Accelerations of ``M q'' + C q' + K q = forces f`` at ``sensors``, ``f`` white or shaped white noise.

    Parameters
    ----------
    M, C, K : (n, n); forces : (n, f) where each force acts; sensors : (p, n).
    sample_time_s : sample period; noise_ratio : sensor noise std over each noise-free channel's.
    shaping : None (unit white forces) or the continuous state space ``(a, b, c, d)`` of one
        single-input single-output filter each white force goes through.

    Returns
    -------
    NoisyStateSpace with state ``[q; q'; filter states]``, one zero input, the white forces held
    over a sample.
    """
    n, n_forces = forces.shape
    a, b, c, d = (np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.ones((1, 1))) if shaping is None \
        else (np.atleast_2d(x) for x in shaping)
    eye = np.eye(n_forces)
    Af, Bf, Cf, Df = np.kron(eye, a), np.kron(eye, b), np.kron(eye, c), np.kron(eye, d)
    M_inv_K, M_inv_C, M_inv_F = np.linalg.solve(M, K), np.linalg.solve(M, C), np.linalg.solve(M, forces)
    m = Af.shape[0]
    Ac = np.block([[np.zeros((n, n)), np.eye(n), np.zeros((n, m))], [-M_inv_K, -M_inv_C, M_inv_F @ Cf],
                   [np.zeros((m, 2 * n)), Af]])
    Bc = np.vstack([np.zeros((n, n_forces)), M_inv_F @ Df, Bf])
    A, Bw = zero_order_hold(Ac, Bc, sample_time_s)
    C_out = sensors @ np.hstack([-M_inv_K, -M_inv_C, M_inv_F @ Cf])
    Dw = sensors @ M_inv_F @ Df
    Q, S = Bw @ Bw.T, Bw @ Dw.T
    noise_free = np.diag(C_out @ linalg.solve_discrete_lyapunov(A, Q) @ C_out.T + Dw @ Dw.T)
    R = Dw @ Dw.T + np.diag(noise_ratio ** 2 * noise_free)
    p = sensors.shape[0]
    return NoisyStateSpace(A, np.zeros((2 * n + m, 1)), C_out, np.zeros((p, 1)), Q, R, sample_time_s,
                           cross_covariance=S)


def _scaled(M, K, top_hz):
    """K scaled so the highest natural frequency is ``top_hz``; the natural frequencies [rad/s]."""
    w2 = linalg.eigh(K, M, eigvals_only=True)
    scale = (2 * np.pi * top_hz) ** 2 / w2[-1]
    return K * scale, np.sqrt(w2 * scale)


def _damping(rng, M, K, w, *, top=0.03):
    """Rayleigh or modal damping, the ratios log-uniform in 0.5 % .. ``top``."""
    z_ends = np.exp(rng.uniform(np.log(0.005), np.log(top), 2))
    if rng.random() < 0.5:
        return _rayleigh(M, K, w[0], w[-1], *z_ends), "Rayleigh"
    return _modal_damping(M, K, np.exp(rng.uniform(np.log(0.005), np.log(top), w.size))), "modal"


def _plate(rng, top_hz):
    nx, ny = int(rng.integers(2, 5)), int(rng.integers(2, 6))
    n = nx * ny
    index = np.arange(n).reshape(nx, ny)
    ratio = 1 + rng.uniform(0, 0.3)  # the y springs over the x springs
    K = np.zeros((n, n))
    links = [(index[i, j], index[i + 1, j], 1.0) for i in range(nx - 1) for j in range(ny)]
    links += [(index[i, j], index[i, j + 1], ratio) for i in range(nx) for j in range(ny - 1)]
    for a, b, k in links:
        k *= rng.uniform(0.95, 1.05)
        K[[a, b], [a, b]] += k
        K[[a, b], [b, a]] -= k
    edge = np.zeros((nx, ny))
    edge[[0, -1], :] += 1.0
    edge[:, [0, -1]] += ratio
    K += np.diag(edge.ravel() * rng.uniform(0.95, 1.05, n))
    M = np.diag(rng.uniform(0.97, 1.03, n))
    K, w = _scaled(M, K, top_hz)
    C, damping = _damping(rng, M, K, w, top=0.02)
    return M, C, K, w, np.eye(n), f"{nx} x {ny} plate grid, y/x stiffness {ratio:.3f}, {damping} damping"


def _floor_element(x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
    """How a point ``(x, y)`` of a floor moves along x and along y per floor degree of freedom (x, y, twist)."""
    return np.array([1.0, 0.0, -y]), np.array([0.0, 1.0, x])


def _storey_chain(storey_blocks: list[np.ndarray]) -> np.ndarray:
    """Assemble 3x3 storey blocks (relative motion of floor j over floor j-1, j=0 over the ground)."""
    floors = len(storey_blocks)
    K = np.zeros((3 * floors, 3 * floors))
    for j, block in enumerate(storey_blocks):
        K[3 * j:3 * j + 3, 3 * j:3 * j + 3] += block
        if j:
            K[3 * j - 3:3 * j, 3 * j - 3:3 * j] += block
            K[3 * j:3 * j + 3, 3 * j - 3:3 * j] -= block
            K[3 * j - 3:3 * j, 3 * j:3 * j + 3] -= block
    return K


def _torsion_frame(rng, top_hz):
    floors = int(rng.integers(2, 7))
    width, depth = 1.0, rng.uniform(0.6, 1.0)
    corners = [(sx * width / 2, sy * depth / 2) for sx in (-1, 1) for sy in (-1, 1)]
    blocks = []
    for _ in range(floors):
        block = np.zeros((3, 3))
        for x, y in corners:
            ax, ay = _floor_element(x, y)
            block += rng.uniform(0.7, 1.3) * np.outer(ax, ax) + rng.uniform(0.7, 1.3) * np.outer(ay, ay)
        blocks.append(block)
    mass = rng.uniform(0.8, 1.2, floors)
    inertia = mass * (width ** 2 + depth ** 2) / 12
    M = np.diag(np.column_stack([mass, mass, inertia]).ravel())
    K, w = _scaled(M, _storey_chain(blocks), top_hz)
    dashpots = []
    for _ in range(int(rng.integers(1, 4))):
        storey = int(rng.integers(0, floors))
        x, y = corners[int(rng.integers(0, 4))]
        direction = _floor_element(x, y)[int(rng.integers(0, 2))]
        block = np.zeros((3, 3))
        block += np.outer(direction, direction)
        dashpots.append(_storey_chain([block if j == storey else np.zeros((3, 3)) for j in range(floors)]))
    local = sum(dashpots)
    w2, phi = linalg.eigh(K, M)
    first_order = np.einsum("ij,ik,kj->j", phi, local, phi) / (2 * np.sqrt(w2))  # each mode's damping per unit
    target = np.exp(rng.uniform(np.log(0.01), np.log(0.05)))
    light = _rayleigh(M, K, w[0], w[-1], 0.003, 0.003)  # a light proportional floor under the dashpots
    scale = min(target / np.median(first_order), 0.04 / first_order.max())  # no mode near the 10 % cut
    sensors = np.zeros((8 * floors, 3 * floors))  # each floor corner along x and along y
    for floor in range(floors):
        rows = np.vstack([direction for corner in corners for direction in _floor_element(*corner)])
        sensors[8 * floor:8 * floor + 8, 3 * floor:3 * floor + 3] = rows
    return M, light + scale * local, K, w, sensors, (f"{floors}-floor torsion frame, {len(dashpots)} dashpot(s), "
                                                     f"median dashpot damping {100 * target:.1f} %")


def _coloured_building(rng, top_hz):
    storeys = int(rng.integers(3, 11))
    M = np.diag(rng.uniform(0.8, 1.2, storeys))
    K, w = _scaled(M, _chain_stiffness(rng.uniform(0.7, 1.3, storeys)), top_hz)
    C, damping = _damping(rng, M, K, w)
    return M, C, K, w, np.eye(storeys), f"{storeys}-storey shear building, {damping} damping"


def _shaping(rng, w):
    """A force filter: 2nd-order Butterworth low-pass, or an overdamped band-pass around the modes."""
    if rng.random() < 0.5:
        corner = rng.uniform(0.3, 1.2) * w[-1]
        low_pass = signal.zpk2ss(*signal.butter(2, corner, analog=True, output="zpk"))
        return low_pass, f"low-pass at {corner / w[-1]:.2f} f_top"
    low, high = w[0] * rng.uniform(0.2, 0.8), w[-1] * rng.uniform(1.0, 3.0)
    high = max(high, 6 * low)  # band-pass poles overdamped: (high - low) / 2 sqrt(high low) >= 1
    return signal.tf2ss([high - low, 0.0], [1.0, high - low, high * low]), "band-pass"


def new_family_case(index: int) -> ShapedCase:
    """Structure number ``index`` of :data:`NEW_FAMILIES`, drawn at random (one record each, seed ``index``).

    See the module's docstring for the families and the record conditions.
    """
    family = NEW_FAMILIES[index % len(NEW_FAMILIES)]
    rng = np.random.default_rng(45_000 + index)
    fs = float(np.exp(rng.uniform(np.log(50.0), np.log(2000.0))))
    top_hz = fs / float(np.exp(rng.uniform(np.log(3.0), np.log(20.0))))
    build = {"plate": _plate, "torsion-frame": _torsion_frame, "coloured-building": _coloured_building}[family]
    M, C, K, w, candidates, description = build(rng, top_hz)
    n = M.shape[0]
    n_forces = int(rng.integers(1, 4))
    p = int(rng.integers(MIN_SENSORS, min(MAX_SENSORS, candidates.shape[0]) + 1))
    sensors = candidates[np.sort(rng.choice(candidates.shape[0], size=p, replace=False))]
    forces = np.eye(n)[:, np.sort(rng.choice(n, size=min(n_forces, n), replace=False))]
    shaping, shaped = (None, "white") if family != "coloured-building" else _shaping(rng, w)
    noise = float(rng.uniform(0.01, 0.2))
    system = shaped_system(M, C, K, forces=forces, sensors=sensors, sample_time_s=1.0 / fs, noise_ratio=noise,
                           shaping=shaping)
    periods = float(np.exp(rng.uniform(np.log(300.0), np.log(3000.0))))
    n_samples = int(min(max(periods * fs / (w[0] / (2 * np.pi)), MIN_SAMPLES), MAX_SAMPLES))
    Ac = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
    poles = np.linalg.eigvals(Ac)
    return ShapedCase(f"{family}-{index}", system, n_samples,
                      f"{description}, {shaped} forces at {n_forces} point(s), {p} sensors, fs {fs:.0f} Hz "
                      f"({fs / top_hz:.1f} x the top mode), noise {100 * noise:.0f} %, {n_samples / fs:.0f} s",
                      family=family, structural_poles=poles[poles.imag > 0])
