"""The named benchmark cases: known-truth systems with their inputs and data lengths.

:func:`benchmark_cases` lists them in a fixed order; ``bench/identification_accuracy.py`` runs
every identifier on each.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np

from okid_bench.oracle import kalman_predictor
from okid_ros.sim.inputs import lowpass_input, white_input
from okid_ros.sim.models import TrueSystem, modal_structure
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_noisy

__all__ = ["BenchmarkCase", "suggested_arx_order", "benchmark_cases", "benchmark_case", "random_case", "random_record",
           "random_frequencies"]


@dataclass
class BenchmarkCase:
    """One known-truth identification problem for the benchmark.

    Attributes
    ----------
    name : short identifier (used on the command line and in tables).
    description : one-paragraph description for the report.
    system : the true system (``InnovationModel`` or ``NoisyStateSpace``).
    make_input : ``make_input(n_samples, seed) -> u`` of shape (n_samples, m).
    n_samples : data lengths to run (identification data).
    arx_order : suggested ARX order ``q`` for ARX-based methods: ``5 / -ln rho(A - L C)``
        of the true predictor (the lag after which its memory has decayed to e^-5), rounded
        up to a multiple of 20 and capped at 200 (:func:`suggested_arx_order`); 100 for the
        paper case as in the paper.  A property of the system, not tuned per method.
    max_physical_damping : damping-ratio cut for "physical" modes when scoring.
    """

    name: str
    description: str
    system: TrueSystem
    make_input: Callable[[int, int], np.ndarray]
    n_samples: tuple = (3750, 15000)
    arx_order: int = 100
    max_physical_damping: float = 0.2
    tags: tuple = field(default_factory=tuple)

    @property
    def sample_time_s(self) -> float:
        return self.system.sample_time_s

    @property
    def n_states(self) -> int:
        return self.system.n_states


def suggested_arx_order(system: TrueSystem, decay: float = 5.0, step: int = 20,
                        cap: int = 200) -> int:
    """ARX order covering the memory of the true one-step predictor.

    ``q = decay / -ln rho(A - L C)`` with ``L`` the oracle predictor gain, rounded up to a
    multiple of ``step`` and capped at ``cap``.
    """
    K, _ = kalman_predictor(system)
    rho = float(np.max(np.abs(np.linalg.eigvals(system.A - system.A @ K @ system.C))))
    q = decay / -np.log(rho)
    return int(min(cap, step * np.ceil(q / step)))


def _paper_case(cutoff_hz: Optional[float]) -> BenchmarkCase:
    model = paper_model()
    dt = model.sample_time_s
    if cutoff_hz is None:
        name = "paper-white"
        desc = ("Published model of Chen, Huang & Juang (1991) at 125 Hz (3 modes: 37.10 rad/s "
                "0.28 %, 46.13 rad/s 2.87 %, 304.49 rad/s 0.40 %), 2 white unit-variance inputs, "
                "innovation covariance I.")

        def make_input(N, seed):
            return white_input(N, model.n_inputs, seed)
    else:
        name = f"paper-lp{cutoff_hz:g}"
        desc = (f"Published model of Chen, Huang & Juang (1991) at 125 Hz (3 modes: 37.10 rad/s "
                f"0.28 %, 46.13 rad/s 2.87 %, 304.49 rad/s 0.40 %), 2 random inputs through a "
                f"4th-order Butterworth low-pass at {cutoff_hz:g} Hz (unit variance), innovation "
                f"covariance I.")

        def make_input(N, seed):
            return lowpass_input(N, model.n_inputs, cutoff_hz, dt, seed)
    return BenchmarkCase(name, desc, model, make_input, (3750, 15000), 100, tags=("paper",))


def paper_lowpass15_case() -> BenchmarkCase:
    """(a) Paper model, inputs low-passed at 15 Hz (the experiment-like case)."""
    return _paper_case(15.0)


def paper_lowpass50_case() -> BenchmarkCase:
    """(b) Paper model, inputs low-passed at 50 Hz (nearly broadband at 125 Hz)."""
    return _paper_case(50.0)


def paper_white_case() -> BenchmarkCase:
    """Paper model with white inputs."""
    return _paper_case(None)


def light_damping_case() -> BenchmarkCase:
    """(c) Three modes at 0.3 % damping, acceleration outputs, white input, 50 Hz sampling."""
    dt = 1.0 / 50.0
    f = [1.9, 4.4, 8.1]
    sys_ = modal_structure(f, 0.003, n_inputs=2, n_outputs=2, sample_time_s=dt, seed=11,
                           output="acceleration", disturbance_std=0.3, measurement_noise_ratio=0.05)
    desc = ("Lightly damped structure: modes at 1.9, 4.4, 8.1 Hz, all 0.3 % damping "
            "(decay time constants 28, 12, 6.5 s, i.e. 3750 samples span 75 s), 2 force inputs, "
            "2 accelerometers (D != 0), 50 Hz sampling, white input; disturbance forces "
            "(std 0.3 of the input) and 5 % measurement noise (correlated S through D).")
    return BenchmarkCase("light-damping", desc, sys_,
                         lambda N, seed: white_input(N, 2, seed), (3750, 15000),
                         suggested_arx_order(sys_))


def close_pair_case() -> BenchmarkCase:
    """(d) A close pair 1.6 % apart plus two other modes, band-limited input, 100 Hz."""
    dt = 1.0 / 100.0
    f = [3.10, 3.15, 7.3, 12.6]
    zeta = [0.01, 0.008, 0.02, 0.015]
    sys_ = modal_structure(f, zeta, n_inputs=2, n_outputs=3, sample_time_s=dt, seed=7,
                           output="acceleration", disturbance_std=0.3, measurement_noise_ratio=0.05)
    desc = ("Close pair: modes at 3.10 and 3.15 Hz (1.6 % apart; 1.0 % and 0.8 % damping) plus "
            "7.3 Hz (2 %) and 12.6 Hz (1.5 %), 2 inputs, 3 accelerometers, 100 Hz sampling, "
            "inputs low-passed at 20 Hz; disturbance forces (std 0.3) and 5 % measurement noise.")
    return BenchmarkCase("close-pair", desc, sys_,
                         lambda N, seed: lowpass_input(N, 2, 20.0, dt, seed), (3750, 15000),
                         suggested_arx_order(sys_))


def more_outputs_case() -> BenchmarkCase:
    """(e) 2 inputs, 6 outputs, 4 modes, band-limited input, 100 Hz."""
    dt = 1.0 / 100.0
    f = [2.4, 5.2, 9.7, 16.5]
    zeta = [0.005, 0.01, 0.015, 0.02]
    sys_ = modal_structure(f, zeta, n_inputs=2, n_outputs=6, sample_time_s=dt, seed=3,
                           output="acceleration", disturbance_std=0.3, measurement_noise_ratio=0.05)
    desc = ("More outputs than inputs: 4 modes at 2.4, 5.2, 9.7, 16.5 Hz (0.5-2 % damping), "
            "2 inputs, 6 accelerometers, 100 Hz sampling, inputs low-passed at 25 Hz; "
            "disturbance forces (std 0.3) and 5 % measurement noise.")
    return BenchmarkCase("more-outputs", desc, sys_,
                         lambda N, seed: lowpass_input(N, 2, 25.0, dt, seed), (3750, 15000),
                         suggested_arx_order(sys_))


def many_outputs_case() -> BenchmarkCase:
    """(g) 2 inputs, 16 outputs, 6 modes, band-limited input, 100 Hz: the jackknife's standard deviations."""
    dt = 1.0 / 100.0
    f = [2.4, 5.2, 9.7, 16.5, 23.0, 31.0]
    zeta = [0.005, 0.01, 0.015, 0.02, 0.01, 0.015]
    sys_ = modal_structure(f, zeta, n_inputs=2, n_outputs=16, sample_time_s=dt, seed=13,
                           output="acceleration", disturbance_std=0.3, measurement_noise_ratio=0.05)
    desc = ("Many outputs: 6 modes at 2.4-31 Hz (0.5-2 % damping), 2 inputs, 16 accelerometers, "
            "100 Hz sampling, inputs low-passed at 40 Hz; disturbance forces (std 0.3) and 5 % "
            "measurement noise. Too many predictor parameters for the prediction-error covariance: "
            "the modes' standard deviations come from the jackknife.")
    return BenchmarkCase("many-outputs", desc, sys_,
                         lambda N, seed: lowpass_input(N, 2, 40.0, dt, seed), (6000, 15000),
                         suggested_arx_order(sys_))


def separate_noise_case() -> BenchmarkCase:
    """(f) Displacement sensors, separate (uncorrelated) process and measurement noise."""
    dt = 1.0 / 100.0
    f = [1.5, 4.0, 6.8]
    zeta = [0.01, 0.02, 0.01]
    sys_ = modal_structure(f, zeta, n_inputs=1, n_outputs=3, sample_time_s=dt, seed=5,
                           output="displacement", disturbance_std=0.5, measurement_noise_ratio=0.2)
    desc = ("Separate process and measurement noise: 3 modes at 1.5, 4.0, 6.8 Hz (1-2 % "
            "damping), 1 input, 3 displacement sensors (D = 0, S = 0), 100 Hz sampling, white "
            "input; disturbance forces std 0.5 and 20 % measurement noise (noisy sensors).")
    return BenchmarkCase("separate-noise", desc, sys_,
                         lambda N, seed: white_input(N, 1, seed), (3750, 15000),
                         suggested_arx_order(sys_))


def random_frequencies(rng: np.random.Generator, *, max_modes: int) -> tuple[float, np.ndarray]:
    """A sampling rate (50-1000 Hz) and 2..``max_modes`` natural frequencies [Hz], ascending.

    Log-uniform between 1 % and 35 % of the sampling rate, redrawn until every two are at least
    3 % apart (the random cases of this module and of :mod:`okid_bench.output_only_cases`).
    """
    n_modes = int(rng.integers(2, max_modes + 1))
    fs = float(rng.choice([50, 100, 200, 256, 512, 1000]))
    while True:
        f = np.sort(np.exp(rng.uniform(np.log(0.01), np.log(0.35), n_modes))) * fs
        if np.all(np.diff(f) / f[:-1] > 0.03):
            return fs, f


def random_case(index: int) -> BenchmarkCase:
    """Structure number ``index`` of a family drawn at random, with a measured white input.

    2-7 modes between 1 % and 35 % of the sampling rate (50-1000 Hz), at least 3 % apart;
    damping 0.3-4 % per mode (log-uniform); 1 or 2 inputs, 1-8 accelerometers (two in three) or
    displacement sensors; 100-1000 periods of the slowest mode (2000-20000 samples); random
    shapes, disturbance forces 0.05-0.5 of the input, sensor noise 1-15 %. Records no
    threshold was tuned on (``bench/random_structures.py``).
    """
    rng = np.random.default_rng(5000 + index)
    fs, f = random_frequencies(rng, max_modes=7)
    n_modes = f.size
    zeta = np.exp(rng.uniform(np.log(0.003), np.log(0.04), n_modes))
    p, m = int(rng.choice([1, 2, 3, 4, 6, 8])), int(rng.choice([1, 1, 2]))
    n_samples = int(min(max(rng.uniform(100, 1000) * fs / f[0], 2000), 20000))
    noise = float(rng.uniform(0.01, 0.15))
    output = str(rng.choice(["acceleration", "acceleration", "displacement"]))
    system = modal_structure(list(f), list(zeta), m, p, 1.0 / fs, seed=int(rng.integers(1e6)), output=output,
                             disturbance_std=float(rng.uniform(0.05, 0.5)), measurement_noise_ratio=noise)
    desc = f"{n_modes} modes, {m} white input(s), {p} {output} outputs, fs {fs:g} Hz, {n_samples / fs:.0f} s"
    return BenchmarkCase(f"random-{index}", desc, system, lambda N, seed: white_input(N, m, seed), (n_samples,),
                         suggested_arx_order(system))


def random_record(index: int) -> tuple[BenchmarkCase, np.ndarray, np.ndarray]:
    """Structure ``index`` of :func:`random_case` and its record: ``u`` (N, m), ``y`` (N, p).

    The input's and the noise's seeds are the index (``bench/random_structures.py``).
    """
    case = random_case(index)
    u = case.make_input(case.n_samples[0], index)
    return case, u, simulate_noisy(case.system, u, seed=index)


_CASES = {
    "paper-lp15": paper_lowpass15_case,
    "paper-lp50": paper_lowpass50_case,
    "paper-white": paper_white_case,
    "light-damping": light_damping_case,
    "close-pair": close_pair_case,
    "more-outputs": more_outputs_case,
    "separate-noise": separate_noise_case,
    "many-outputs": many_outputs_case,
}
#: The cases of the accuracy tables (docs/benchmarks.md); ``many-outputs`` serves the calibration.
DEFAULT_CASE_NAMES = ("paper-lp15", "paper-lp50", "paper-white", "light-damping", "close-pair", "more-outputs",
                      "separate-noise")


def benchmark_case(name: str) -> BenchmarkCase:
    """The named benchmark case (see :func:`benchmark_cases` for the names)."""
    try:
        return _CASES[name]()
    except KeyError:
        raise KeyError(f"unknown case {name!r}; known: {', '.join(_CASES)}") from None


def benchmark_cases(names: Optional[Sequence[str]] = None) -> list[BenchmarkCase]:
    """All named benchmark cases (or the listed ones), in a fixed order."""
    names = list(DEFAULT_CASE_NAMES) if names is None else list(names)
    return [benchmark_case(n) for n in names]
