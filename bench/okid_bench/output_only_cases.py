"""Ambient-vibration records with known discrete modal truth, for output-only identification.

Each case is a :func:`okid_ros.sim.models.modal_structure` (zero-order-hold discretized, so its
discrete poles are exactly ``exp(s dt)``) driven by unmeasured forces: white disturbance forces
on every mode, plus, for some cases, a coloured force or a harmonic one through the input
matrix. The truth is read from the discrete ``A`` that is simulated (:meth:`OutputOnlyCase.truth`):
frequency, damping and output shape ``C psi`` of each pole pair. The optimal predictor of a
white-noise case is ``system.to_innovation_form()``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, optimize, signal

from okid_bench.cases import random_frequencies
from okid_ros.sim.models import NoisyStateSpace, modal_structure
from okid_ros.sim.simulators import simulate_noisy

__all__ = ["OutputOnlyCase", "output_only_case", "output_only_cases", "random_case", "system_modes", "pair_modes",
           "OUTPUT_ONLY_CASES"]


@dataclass
class OutputOnlyCase:
    """One simulated ambient record.

    Attributes
    ----------
    name : short name; system : the simulated structure (u: the unmeasured coloured/harmonic force);
    n_samples : record length; coloured_cutoff_hz : low-pass corner of the coloured force (None: none);
    harmonic_hz : frequency of a harmonic force (None: none); force_std : its standard deviation.
    """

    name: str
    system: NoisyStateSpace
    n_samples: int
    description: str
    coloured_cutoff_hz: float | None = None
    harmonic_hz: float | None = None
    force_std: float = 0.0

    @property
    def sample_time_s(self) -> float:
        return self.system.sample_time_s

    def force(self, n_samples: int, seed: int) -> np.ndarray:
        """(N, 1) the unmeasured force through ``B``: coloured noise and/or a harmonic."""
        rng = np.random.default_rng(10_000 + seed)
        f = np.zeros((n_samples, 1))
        if self.coloured_cutoff_hz is not None:
            b, a = signal.butter(2, self.coloured_cutoff_hz, fs=1.0 / self.sample_time_s)
            white = rng.standard_normal(n_samples + 2000)
            coloured = signal.lfilter(b, a, white)[2000:]
            f[:, 0] += self.force_std * coloured / coloured.std()
        if self.harmonic_hz is not None:
            t = np.arange(n_samples) * self.sample_time_s
            f[:, 0] += self.force_std * np.sqrt(2.0) * np.sin(2 * np.pi * self.harmonic_hz * t + rng.uniform(0, 6.28))
        return f

    def simulate(self, seed: int, n_samples: int | None = None) -> np.ndarray:
        """(N, p) outputs of one noise seed."""
        n = int(n_samples or self.n_samples)
        return simulate_noisy(self.system, self.force(n, seed), seed=seed)

    def truth(self) -> list[dict]:
        """The discrete system's modes by frequency (:func:`system_modes`)."""
        return system_modes(self.system)


def system_modes(system) -> list[dict]:
    """The modes of a simulated system (``A``, ``C``, ``sample_time_s``) by frequency.

    Each a dict of ``frequency_hz``, ``damping_ratio`` and ``shape`` (p,), unit norm.
    """
    z, psi = linalg.eig(system.A)
    s = np.log(z) / system.sample_time_s
    out = []
    for i in np.flatnonzero(z.imag > 0):
        w = abs(s[i])
        shape = system.C @ psi[:, i]
        out.append({"frequency_hz": w / (2 * np.pi), "damping_ratio": -s[i].real / w,
                    "shape": shape / np.linalg.norm(shape)})
    return sorted(out, key=lambda m: m["frequency_hz"])


def _structure(freqs, damping, p, dt, seed=3, noise=0.05):
    return modal_structure(freqs, damping, 1, p, dt, seed=seed, output="acceleration", disturbance_std=1.0,
                           measurement_noise_ratio=noise)


def _cases() -> dict[str, OutputOnlyCase]:
    return {
        "close-pair": OutputOnlyCase(
            "close-pair", _structure([3.0, 7.0, 7.07, 12.0], 0.005, 6, 1 / 50), 30_000,
            "4 modes at 0.5 % damping, 7.00 / 7.07 Hz 1 % apart, fs 50 Hz, 6 outputs, 600 s"),
        "low-modes": OutputOnlyCase(
            "low-modes", _structure([0.8, 1.6, 6.0, 15.0], [0.02, 0.01, 0.01, 0.01], 4, 1 / 100), 60_000,
            "modes at 0.8 % and 1.6 % of fs (100 Hz), 4 outputs, 600 s"),
        "coloured": OutputOnlyCase(
            "coloured", _structure([2.0, 5.0, 9.0, 14.0], 0.01, 5, 1 / 50, seed=5), 30_000,
            "a low-passed force (corner 6 Hz, 5x the white forces) on top of white forces, fs 50 Hz, 600 s",
            coloured_cutoff_hz=6.0, force_std=5.0),
        "harmonic": OutputOnlyCase(
            "harmonic", _structure([3.0, 6.0, 10.0], 0.01, 5, 1 / 50, seed=7), 30_000,
            "a harmonic force at 6.3 Hz (5 % above mode 2, 3x the white forces), fs 50 Hz, 600 s",
            harmonic_hz=6.3, force_std=3.0),
        "one-channel": OutputOnlyCase(
            "one-channel", _structure([3.0, 7.0, 12.0], 0.01, 1, 1 / 50, seed=1), 6_000,
            "3 modes at 1 %, one accelerometer, fs 50 Hz, 120 s (a short record: the lags and the jackknife "
            "compete for it)"),
    }


OUTPUT_ONLY_CASES = tuple(_cases())


def output_only_case(name: str) -> OutputOnlyCase:
    """The case called ``name`` (one of :data:`OUTPUT_ONLY_CASES`)."""
    cases = _cases()
    if name not in cases:
        raise ValueError(f"unknown output-only case {name!r}; known: {', '.join(cases)}")
    return cases[name]


def output_only_cases() -> list[OutputOnlyCase]:
    """Every case."""
    return list(_cases().values())


def random_case(index: int) -> OutputOnlyCase:
    """Structure number ``index`` of a family drawn at random: records no selection rule was tuned on.

    2-8 modes between 1 % and 35 % of the sampling rate (50-1000 Hz), at least 3 % apart, and in
    three structures of ten one pair 1-2 % apart; damping 0.3-4 % (log-uniform, each mode its
    own); 1-16 outputs, accelerations (two in three) or displacements; 300-3000 periods of the
    slowest mode (3000-60000 samples); sensor noise 1-15 % of each output; random shapes and
    white forces (:func:`okid_ros.sim.models.modal_structure`). Some draws are beyond any method
    (two modes closer than their bandwidths, a mode a displacement sensor barely sees): they
    score every method alike.
    """
    rng = np.random.default_rng(1000 + index)
    fs, f = random_frequencies(rng, max_modes=8)
    n_modes = f.size
    if n_modes >= 3 and rng.random() < 0.3:
        j = int(rng.integers(0, n_modes - 1))
        f[j + 1] = f[j] * (1 + rng.uniform(0.01, 0.02))
        f = np.sort(f)
    zeta = np.exp(rng.uniform(np.log(0.003), np.log(0.04), n_modes))
    p = int(rng.choice([1, 2, 3, 4, 6, 8, 12, 16]))
    n_samples = int(min(max(rng.uniform(300, 3000) * fs / f[0], 3000), 60000))
    noise = float(rng.uniform(0.01, 0.15))
    output = str(rng.choice(["acceleration", "acceleration", "displacement"]))
    system = modal_structure(list(f), list(zeta), 1, p, 1.0 / fs, seed=int(rng.integers(1e6)), output=output,
                             disturbance_std=1.0, measurement_noise_ratio=noise)
    return OutputOnlyCase(f"random-{index}", system, n_samples,
                          f"{n_modes} modes, {p} {output} outputs, fs {fs:g} Hz, {n_samples / fs:.0f} s")


def pair_modes(found: list[dict], truth: list[dict], tolerance: float) -> dict[int, int]:
    """One-to-one pairing of found with true modes by frequency and shape: the found index of each paired true mode.

    The most pairs within ``tolerance`` (relative frequency) are kept, and among them the assignment
    (Hungarian algorithm) of least total ``|f - f_true| / (f_true tolerance) + (1 - MAC)``: two modes
    whose frequencies cross within a close pair are paired by shape, so neither takes the other's
    damping. The shape term is 0 where either shape is unknown (frequency alone).
    """
    if not found or not truth:
        return {}
    ft = np.array([t["frequency_hz"] for t in truth], float)
    ff = np.array([f["frequency_hz"] for f in found], float)
    distance = np.abs(ff[None, :] - ft[:, None]) / ft[:, None]
    macs = np.array([[_mac(t.get("shape"), f.get("shape"), 1.0) for f in found] for t in truth])
    unlikeness = 1.0 - np.nan_to_num(macs, nan=0.0)  # a zero shape is like nothing
    admissible = distance <= tolerance
    # A cost above any sum of admissible ones: every extra admissible pair outweighs any cost of the others.
    excluded = 2.0 * min(ft.size, ff.size) + 1.0
    cost = np.where(admissible, distance / tolerance + unlikeness, excluded)
    rows, cols = optimize.linear_sum_assignment(cost)
    return {int(j): int(i) for j, i in zip(rows, cols) if admissible[j, i]}


def _mac(a, b, unknown: float = float("nan")) -> float:
    """Modal assurance criterion of two (complex) shapes; ``unknown`` where either is missing."""
    if a is None or b is None:
        return unknown
    a, b = np.asarray(a), np.asarray(b)
    with np.errstate(invalid="ignore"):  # a zero shape: NaN
        return float(abs(np.vdot(a, b)) ** 2 / (np.vdot(a, a).real * np.vdot(b, b).real))


def score_modes(found: list[dict], truth: list[dict], *, match_tolerance: float = 0.02) -> dict:
    """Match identified modes to the true ones and score them.

    Parameters
    ----------
    found : identified modes, each with ``frequency_hz``, ``damping_ratio``, ``shape`` (p,) and
        optionally ``frequency_hz_std``, ``damping_ratio_std``.
    truth : true modes (:meth:`OutputOnlyCase.truth`, or ``shape`` None when unknown).
    match_tolerance : a found mode within this relative frequency of a true mode is its candidate;
        the pairs are :func:`pair_modes` (frequency and shape, one each); found modes left over are spurious.

    Returns
    -------
    dict with per true mode ``frequency_error`` (relative, NaN if missed), ``damping_error``
    (relative), ``mac``, ``frequency_covered`` / ``damping_covered`` (within 2 std, NaN without a
    std), and ``spurious`` (count).
    """
    match = pair_modes(found, truth, match_tolerance)
    rows = []
    for j, t in enumerate(truth):
        if j not in match:
            rows.append({k: float("nan") for k in ("frequency_error", "damping_error", "mac",
                                                    "frequency_covered", "damping_covered")})
            continue
        f = found[match[j]]
        f_err = (f["frequency_hz"] - t["frequency_hz"]) / t["frequency_hz"]
        z_err = (f["damping_ratio"] - t["damping_ratio"]) / t["damping_ratio"]
        f_std, z_std = f.get("frequency_hz_std", np.nan), f.get("damping_ratio_std", np.nan)
        rows.append({
            "frequency_error": f_err, "damping_error": z_err, "mac": _mac(t.get("shape"), f.get("shape")),
            "frequency_covered": _covered(f["frequency_hz"] - t["frequency_hz"], f_std),
            "damping_covered": _covered(f["damping_ratio"] - t["damping_ratio"], z_std),
        })
    return {"modes": rows, "spurious": len(found) - len(match)}


def _covered(error: float, std: float) -> float:
    """1.0 when ``|error| <= 2 std``, 0.0 when not, NaN without a std."""
    return float(abs(error) <= 2 * std) if std == std else float("nan")
