"""Structure families no selection rule was tuned on, round two, with exact discrete truth (``--cases families-2``).

Three families, drawn in turn (structure ``index`` is of family ``index % 3``), each a physical
``M q'' + C q' + K q = F d(t)`` like :mod:`okid_bench.new_families`, differing from every earlier
set in a way a structure in service does:

* ``damped-building``: a shear building of 3-8 storeys with strong viscous dampers in 1-2 storeys on a
  light 0.3 % Rayleigh floor (damping non-proportional: complex true shapes) and, in half of them,
  a tuned mass damper on the roof (mass 1-4 % of the tuned mode's, Den Hartog's frequency and damping;
  its mass not observed): a pair of strongly complex modes. The true shapes are complex and the MAC is
  scored against them;
* ``tower``: a cantilever tower's (a chimney's) first 3-4 bending modes in each of its two principal
  directions (frequency ratios of a cantilever, a taper's +-10 %), the second direction's modes
  0.2-1 % above the first's (modal damping 0.3-1.5 %), its principal axes turned 0-90 degrees
  from the sensors', 2-4 biaxial accelerometers (4-8 channels) along its height; the wind a
  Kaimal-like force (a rational filter whose spectrum falls as ``f^(-5/3)`` above a corner under the
  slowest mode: real poles, simulated with the structure, not modes) on 2-3 independent gust
  patterns over the height;
* ``deck``: a long-span deck's vertical (``f_n ~ n sqrt(1 + b n^2)``: cables and bending) and
  torsional modes, 9-18 of them, the slowest at 0.3-0.6 % of the sampling rate (about half the
  modes below 2 % of it), 10-15 stations with a vertical accelerometer at each edge (20-30
  channels); traffic: white forces at 2-4 lane points each modulated by the passage of vehicles
  (a Poisson stream, their loads log-normal, crossing in 10-60 s): an amplitude-modulated,
  nonstationary broadband record. Its truth is that of the stationary record of the same mean
  square forces.

Record conditions: sampling 3-20 times the top mode (the deck: as above), 300-3000 periods of the
slowest mode (3000-60000 samples; the deck up to 90000), sensor noise 1-20 % of each channel's
noise-free RMS. Forces are held over a sample: the discrete poles are exactly ``exp(s dt)``. Truth
as :mod:`okid_bench.new_families`: the structure's modes with at least
:data:`okid_bench.physical_cases.VISIBLE_SHARE` of some channel's variance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, signal

from okid_bench.new_families import ShapedCase, shaped_system
from okid_bench.physical_cases import _chain_stiffness, _rayleigh
from okid_ros.sim.models import NoisyStateSpace, zero_order_hold
from okid_ros.sim.simulators import simulate_noisy

__all__ = ["FAMILIES_TWO", "FAMILIES_TWO_CASES", "ModulatedCase", "family_two_case", "true_mpc"]

#: The families, drawn in turn.
FAMILIES_TWO = ("damped-building", "tower", "deck")
#: Their name among the bench's ``--cases``.
FAMILIES_TWO_CASES = "families-2"
#: Samples of a record: at least, at most (the deck: at most ``DECK_MAX_SAMPLES``).
MIN_SAMPLES, MAX_SAMPLES, DECK_MAX_SAMPLES = 3000, 60000, 90000
#: A cantilever's ``beta_n L`` (uniform section, fixed base).
CANTILEVER_BETA = (1.875104069, 4.694091133, 7.854757438, 10.99554073)


@dataclass
class ModulatedCase(ShapedCase):
    """A structure driven by white forces whose amplitudes vary in time; ``system`` is its stationary equivalent.

    Attributes
    ----------
    driven : the same structure with the forces as its input (``B``, ``D``) and no process noise.
    envelope : (n_samples + burn_in, forces) each force's amplitude, mean square 1.
    burn_in : samples simulated from rest and dropped.
    """

    driven: NoisyStateSpace | None = None
    envelope: np.ndarray | None = None
    burn_in: int = 0

    def simulate(self, seed: int, n_samples: int | None = None) -> np.ndarray:
        """(N, p) outputs of one noise seed: the modulated white forces, from rest, the burn-in dropped."""
        n = int(n_samples or self.n_samples)
        total = min(n + self.burn_in, self.envelope.shape[0])
        rng = np.random.default_rng(20_000 + seed)
        forces = rng.standard_normal((total, self.envelope.shape[1])) * self.envelope[:total]
        return simulate_noisy(self.driven, forces, seed=seed, x0=None)[total - n:]


def true_mpc(shape: np.ndarray) -> float:
    """Modal phase collinearity of a complex shape (1: real up to one phase, 0: circular)."""
    shape = np.asarray(shape)
    parts = np.vstack([shape.real, shape.imag])
    low, high = np.linalg.eigvalsh(parts @ parts.T)
    return float(((high - low) / (high + low)) ** 2) if high > 0 else 1.0


def _log_uniform(rng, low, high, size=None):
    return np.exp(rng.uniform(np.log(low), np.log(high), size))


def _storey_damper(storeys: int, storey: int) -> np.ndarray:
    """Unit viscous damper between floor ``storey`` and the one below (the ground for 0)."""
    local = np.zeros((storeys, storeys))
    local[storey, storey] = 1.0
    if storey:
        local[storey - 1, storey - 1] = 1.0
        local[storey, storey - 1] = local[storey - 1, storey] = -1.0
    return local


def _with_tmd(M, C, K, rng, w):
    """The roof carries a tuned mass damper (Den Hartog): the matrices grown by its degree of freedom."""
    n = M.shape[0]
    w2, phi = linalg.eigh(K, M)
    tuned = int(rng.integers(0, min(2, n)))
    shape = phi[:, tuned] / phi[-1, tuned]  # unit at the roof: the modal mass there
    ratio = rng.uniform(0.01, 0.04)
    mass = ratio * shape @ M @ shape
    omega = w[tuned] / (1 + ratio)
    zeta = np.sqrt(3 * ratio / (8 * (1 + ratio) ** 3))
    grow = np.zeros((n + 1, n + 1))
    Mt, Ct, Kt = grow.copy(), grow.copy(), grow.copy()
    Mt[:n, :n], Ct[:n, :n], Kt[:n, :n] = M, C, K
    Mt[n, n] = mass
    for matrix, value in ((Kt, mass * omega ** 2), (Ct, 2 * zeta * mass * omega)):
        matrix[[n - 1, n], [n - 1, n]] += value
        matrix[[n - 1, n], [n, n - 1]] -= value
    return Mt, Ct, Kt, f", a {100 * ratio:.1f} % TMD on mode {tuned + 1}"


def _damped_building(rng, top_hz):
    storeys = int(rng.integers(3, 9))
    M = np.diag(rng.uniform(0.8, 1.2, storeys))
    K = _chain_stiffness(rng.uniform(0.7, 1.3, storeys))
    w2 = linalg.eigh(K, M, eigvals_only=True)
    K = K * (2 * np.pi * top_hz) ** 2 / w2[-1]
    w2, phi = linalg.eigh(K, M)
    w = np.sqrt(w2)
    local = sum(_storey_damper(storeys, int(s)) for s in rng.choice(storeys, int(rng.integers(1, 3)), replace=False))
    first_order = np.einsum("ij,ik,kj->j", phi, local, phi) / (2 * w)
    target = _log_uniform(rng, 0.01, 0.06)
    scale = min(target / np.max(first_order), 0.08 / first_order.max())  # the most damped mode at the target
    C = _rayleigh(M, K, w[0], w[-1], 0.003, 0.003) + scale * local
    description = f"{storeys}-storey building, dampers to {100 * target:.1f} %"
    sensors = np.eye(storeys)
    if rng.random() < 0.5:
        M, C, K, tmd = _with_tmd(M, C, K, rng, w)
        sensors = np.hstack([sensors, np.zeros((storeys, 1))])
        description += tmd
    forces_at = np.arange(storeys)
    return M, C, K, w, sensors, forces_at, description


def _cantilever_shape(beta: float, height: np.ndarray) -> np.ndarray:
    """A uniform cantilever's mode of ``beta L`` at relative heights, 2 at the top (the analytic formula)."""
    sigma = (np.cosh(beta) + np.cos(beta)) / (np.sinh(beta) + np.sin(beta))
    x = beta * np.asarray(height)
    return np.cosh(x) - np.cos(x) - sigma * (np.sinh(x) - np.sin(x))


def _tower(rng, top_hz):
    modes = int(rng.integers(3, 5))
    beta = np.array(CANTILEVER_BETA[:modes])
    ratios = (beta / beta[0]) ** 2 * np.concatenate([[1.0], rng.uniform(0.9, 1.1, modes - 1)])
    split = _log_uniform(rng, 0.002, 0.01)
    wx = 2 * np.pi * top_hz / ratios[-1] / (1 + split) * ratios
    wy = wx * (1 + split * rng.uniform(0.7, 1.3, modes))
    w = np.concatenate([wx, wy])
    zeta = np.repeat(_log_uniform(rng, 0.003, 0.015, modes), 2).reshape(modes, 2).T.ravel()
    zeta[modes:] *= rng.uniform(0.8, 1.25, modes)
    levels = np.sort(rng.choice([0.4, 0.55, 0.7, 0.85, 1.0], int(rng.integers(2, 5)), replace=False))
    angle = rng.uniform(0, np.pi / 2)
    rows = []
    for level in levels:
        phi = np.array([_cantilever_shape(b, level) for b in beta])
        rows += [np.concatenate([np.cos(angle) * phi, np.sin(angle) * phi]),
                 np.concatenate([-np.sin(angle) * phi, np.cos(angle) * phi])]
    heights = np.linspace(0.1, 1.0, 10)
    at = np.array([_cantilever_shape(b, heights) for b in beta])  # (modes, heights)
    patterns = []
    for _ in range(int(rng.integers(2, 4))):  # gusts: a mean-profile part and an incoherent part over the height
        load = heights ** 0.3 * (1.0 + rng.normal(0, 0.7, heights.size))
        direction = rng.uniform(0, 2 * np.pi)
        patterns.append(np.concatenate([np.cos(direction) * at @ load, np.sin(direction) * at @ load]))
    M = np.eye(2 * modes)
    description = (f"tower, {modes} bending modes a direction {100 * split:.2f} % apart, axes at "
                   f"{np.degrees(angle):.0f} deg, {levels.size} biaxial levels")
    return M, np.diag(2 * zeta * w), np.diag(w ** 2), np.sort(w), np.array(rows), np.column_stack(patterns), \
        description


def _kaimal_filter(corner_hz: float, top_hz: float):
    """A force filter whose spectrum is flat below ``corner_hz`` and falls as ``f^(-5/3)`` up to ``top_hz`` and more.

    One real pole a decade and a zero 5/6 of a decade after it: the amplitude falls on average by
    5/6 of a decade per decade; real poles, so none is a mode.
    """
    decades = int(np.ceil(np.log10(3 * top_hz / corner_hz)))
    poles = -2 * np.pi * corner_hz * 10.0 ** np.arange(decades)
    zeros = poles * 10 ** (5 / 6)
    return signal.zpk2ss(zeros, poles, 1.0)


def _deck(rng, fs):
    vertical, torsional = int(rng.integers(6, 13)), int(rng.integers(3, 7))
    cable = _log_uniform(rng, 0.001, 0.02)
    n = np.arange(1, vertical + 1)
    m = np.arange(1, torsional + 1)
    f1 = fs * _log_uniform(rng, 0.003, 0.006)
    fv = f1 * n * np.sqrt(1 + cable * n ** 2) / np.sqrt(1 + cable)
    ft = f1 * rng.uniform(1.5, 3.0) * m * np.sqrt(1 + cable * m ** 2) / np.sqrt(1 + cable)
    w = 2 * np.pi * np.concatenate([fv, ft])
    zeta = _log_uniform(rng, 0.003, 0.02, w.size)
    stations = np.sort(np.clip(np.linspace(0, 1, int(rng.integers(10, 16)) + 2)[1:-1]
                               + rng.uniform(-0.02, 0.02, 1), 0.02, 0.98))
    half_width = rng.uniform(0.5, 1.0)
    rows = []
    for x in stations:
        bend, twist = np.sin(np.pi * n * x), np.sin(np.pi * m * x)
        rows += [np.concatenate([bend, half_width * twist]), np.concatenate([bend, -half_width * twist])]
    lanes = rng.uniform(0.1, 0.9, int(rng.integers(2, 5)))
    offsets = half_width * rng.uniform(0.3, 0.9, lanes.size) * rng.choice([-1, 1], lanes.size)
    forces = np.array([np.concatenate([np.sin(np.pi * n * x), e * np.sin(np.pi * m * x)])
                       for x, e in zip(lanes, offsets)]).T
    description = (f"deck, {vertical} vertical and {torsional} torsional modes, {stations.size} stations, "
                   f"{lanes.size} lane points")
    return np.eye(w.size), np.diag(2 * zeta * w), np.diag(w ** 2), np.sort(w), np.array(rows), forces, \
        lanes, description


def _traffic(rng, lanes: np.ndarray, n_samples: int, fs: float) -> tuple[np.ndarray, str]:
    """(n_samples, lanes) amplitudes: a Poisson stream of vehicles crossing the deck, mean square 1 per lane."""
    duration = n_samples / fs
    crossing = rng.uniform(10.0, 60.0)
    rate = _log_uniform(rng, 0.5, 6.0) / 60.0  # vehicles a second
    arrivals = np.sort(rng.uniform(-crossing, duration, rng.poisson(rate * (duration + crossing)) + 1))
    loads = rng.lognormal(0.0, 0.8, arrivals.size)
    t = np.arange(n_samples) / fs
    width = 0.08 * crossing  # the time a vehicle is near a lane point
    power = np.full((n_samples, lanes.size), rng.uniform(0.05, 0.3))  # the ambient floor
    for start, load in zip(arrivals, loads):
        for lane, passing in enumerate(start + lanes * crossing):
            near = slice(*np.searchsorted(t, [passing - 4 * width, passing + 4 * width]))
            power[near, lane] += load * np.exp(-0.5 * ((t[near] - passing) / width) ** 2)
    envelope = np.sqrt(power / power.mean(axis=0))
    return envelope, f"{arrivals.size} vehicles crossing in {crossing:.0f} s"


def _driven(M, C, K, *, forces, sensors, sample_time_s, noise_ratio) -> tuple[NoisyStateSpace, NoisyStateSpace]:
    """(stationary equivalent, driven) systems of white forces: the first with them as process noise."""
    stationary = shaped_system(M, C, K, forces=forces, sensors=sensors, sample_time_s=sample_time_s,
                               noise_ratio=noise_ratio)
    n = M.shape[0]
    M_inv_K, M_inv_C, M_inv_F = np.linalg.solve(M, K), np.linalg.solve(M, C), np.linalg.solve(M, forces)
    Ac = np.block([[np.zeros((n, n)), np.eye(n)], [-M_inv_K, -M_inv_C]])
    A, Bw = zero_order_hold(Ac, np.vstack([np.zeros_like(M_inv_F), M_inv_F]), sample_time_s)
    Dw = sensors @ M_inv_F
    R = stationary.measurement_noise_covariance - Dw @ Dw.T  # the sensor noise alone
    driven = NoisyStateSpace(A, Bw, stationary.C, Dw, np.zeros_like(A), R, sample_time_s)
    return stationary, driven


def _record_length(rng, slowest_hz: float, fs: float, most: int) -> int:
    periods = _log_uniform(rng, 300.0, 3000.0)
    return int(min(max(periods * fs / slowest_hz, MIN_SAMPLES), most))


def _structural_poles(M, C, K) -> np.ndarray:
    n = M.shape[0]
    Ac = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
    poles = np.linalg.eigvals(Ac)
    return poles[poles.imag > 0]


def _deck_case(index: int, rng) -> ModulatedCase:
    fs = float(_log_uniform(rng, 20.0, 200.0))
    M, C, K, w, sensors, forces, lanes, description = _deck(rng, fs)
    noise = float(rng.uniform(0.01, 0.2))
    stationary, driven = _driven(M, C, K, forces=forces, sensors=sensors, sample_time_s=1.0 / fs, noise_ratio=noise)
    n_samples = _record_length(rng, w[0] / (2 * np.pi), fs, DECK_MAX_SAMPLES)
    poles = _structural_poles(M, C, K)
    burn_in = int(min(5 * fs / np.min(-poles.real), 5 * n_samples))  # five decay times of the slowest mode
    envelope, traffic = _traffic(rng, lanes, n_samples + burn_in, fs)
    return ModulatedCase(f"deck-{index}", stationary, n_samples,
                         f"{description}, {sensors.shape[0]} sensors, {traffic}, fs {fs:.0f} Hz, noise "
                         f"{100 * noise:.0f} %, {n_samples / fs:.0f} s", family="deck",
                         structural_poles=poles, driven=driven, envelope=envelope,
                         burn_in=burn_in)


def family_two_case(index: int) -> ShapedCase:
    """Structure number ``index`` of :data:`FAMILIES_TWO`, drawn at random (one record each, seed ``index``).

    See the module's docstring for the families and the record conditions.
    """
    family = FAMILIES_TWO[index % len(FAMILIES_TWO)]
    rng = np.random.default_rng(48_000 + index)
    if family == "deck":
        return _deck_case(index, rng)
    if family == "tower":
        fs = float(_log_uniform(rng, 10.0, 200.0))
        top_hz = fs / float(_log_uniform(rng, 3.0, 20.0))
        M, C, K, w, sensors, forces, description = _tower(rng, top_hz)
        shaping, forcing = _kaimal_filter(w[0] / (2 * np.pi) * rng.uniform(0.05, 0.5), top_hz), "Kaimal-like gusts"
    else:
        fs = float(_log_uniform(rng, 50.0, 2000.0))
        top_hz = fs / float(_log_uniform(rng, 3.0, 20.0))
        M, C, K, w, sensors, at, description = _damped_building(rng, top_hz)
        picks = np.sort(rng.choice(at, size=min(int(rng.integers(1, 4)), at.size), replace=False))
        forces, shaping, forcing = np.eye(M.shape[0])[:, picks], None, f"white forces at {picks.size} floor(s)"
        keep = int(rng.integers(min(3, sensors.shape[0]), sensors.shape[0] + 1))
        sensors = sensors[np.sort(rng.choice(sensors.shape[0], size=keep, replace=False))]
    noise = float(rng.uniform(0.01, 0.2))
    system = shaped_system(M, C, K, forces=forces, sensors=sensors, sample_time_s=1.0 / fs, noise_ratio=noise,
                           shaping=shaping)
    poles = _structural_poles(M, C, K)
    n_samples = _record_length(rng, np.min(np.abs(poles)) / (2 * np.pi), fs, MAX_SAMPLES)
    return ShapedCase(f"{family}-{index}", system, n_samples,
                      f"{description}, {forcing}, {sensors.shape[0]} sensors, fs {fs:.0f} Hz "
                      f"({fs / top_hz:.1f} x the top mode), noise {100 * noise:.0f} %, {n_samples / fs:.0f} s",
                      family=family, structural_poles=poles)
