"""Piecewise-constant structures: a modal structure that changes during the record.

Used to test tracking (``okid-ros track``): the identified modes of a sliding window must follow
a sudden change of the structure.

:func:`added_mass_structure` builds the structure before and after a uniform added mass, in
the same state coordinates so that the state carries over the change; :func:`simulate_switched`
simulates a list of :class:`~okid_ros.sim.models.NoisyStateSpace` systems one after the other
with a continuous state.

The added mass
--------------
A mass change that scales *every* natural frequency by the same factor ``f`` without changing
the mode shapes is a mass matrix scaled as a whole, ``M' = M / f^2`` (the added mass is
distributed like the structure's own mass). Stiffness and mode shapes ``Phi`` stay; with the
shapes kept normalized to the original mass the modal mass becomes ``1 / f^2``, so in the
modal coordinates ``q`` of :func:`~okid_ros.sim.models.modal_structure` (``x = Phi q``)::

    q_i'' + 2 z_i (f w_i) q_i' + (f w_i)^2 q_i = f^2 (phi_in_i^T u + phi_w_i^T d)

with the damping ratios ``z_i`` kept (modal damping). The displacement ``q`` and the velocity
``q'`` are continuous at the change, so the state ``[q_1, q_1', ...]`` carries over as it is.
The accelerometers are the same sensors: ``y = Phi_out q''`` with the same ``Phi_out``, so
``C`` follows the new frequencies, ``D = f^2 Phi_out Phi_in``, and the sensor noise (the
measurement-noise part of ``R``) is unchanged; the disturbance forces keep their statistics
(their share of ``Q``, ``S`` and ``R`` scales with ``f^2`` and ``f^4``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from okid_ros.sim.inputs import lowpass_input
from okid_ros.sim.models import NoisyStateSpace, modal_structure
from okid_ros.sim.simulators import initial_state, propagate_states, sqrt_psd

__all__ = [
    "SwitchedCase",
    "ModeSettling",
    "added_mass_structure",
    "added_mass_case",
    "simulate_switched",
    "settling",
]


def added_mass_structure(
    frequencies_hz: Sequence[float],
    damping_ratios: Sequence[float] | float,
    n_inputs: int,
    n_outputs: int,
    sample_time_s: float,
    frequency_factor: float = 0.94,
    seed: int = 0,
    output: str = "acceleration",
    disturbance_std: float = 0.3,
    n_disturbances: Optional[int] = None,
    measurement_noise_ratio: float = 0.05,
) -> tuple[NoisyStateSpace, NoisyStateSpace]:
    """A modal structure before and after a uniform added mass (see the module docstring).

    Parameters are those of :func:`~okid_ros.sim.models.modal_structure` (the *before* system
    is exactly ``modal_structure(frequencies_hz, damping_ratios, ...)``), plus

    frequency_factor : ``f``, every natural frequency is multiplied by it (0.94: a 6 % drop,
        i.e. 13.2 % more mass).

    Returns
    -------
    (before, after) : two NoisyStateSpace systems in the same state coordinates
    ``[q_1, q_1', q_2, q_2', ...]``; the true modes of ``after`` are at
    ``frequency_factor * frequencies_hz`` with the same damping ratios.
    """
    f = float(frequency_factor)
    if not 0.0 < f:
        raise ValueError(f"frequency_factor must be positive, got {f}")
    common = dict(
        damping_ratios=damping_ratios, n_inputs=n_inputs, n_outputs=n_outputs,
        sample_time_s=sample_time_s, seed=seed, output=output, disturbance_std=disturbance_std,
        n_disturbances=n_disturbances,
    )
    freqs = np.asarray(frequencies_hz, dtype=float)
    before = modal_structure(freqs, measurement_noise_ratio=measurement_noise_ratio, **common)
    # The sensor-noise part of R (R minus the disturbances' share through D_w).
    sensor_noise = before.measurement_noise_covariance - modal_structure(
        freqs, measurement_noise_ratio=0.0, **common
    ).measurement_noise_covariance
    # Same seed: same mode shapes and input/disturbance participation, new frequencies.
    raw = modal_structure(f * freqs, measurement_noise_ratio=0.0, **common)
    g = f * f  # modal forces over the new modal mass 1 / f^2
    after = NoisyStateSpace(
        A=raw.A,
        B=g * raw.B,
        C=raw.C,
        D=g * raw.D,
        process_noise_covariance=g * g * raw.process_noise_covariance,
        measurement_noise_covariance=g * g * raw.measurement_noise_covariance + sensor_noise,
        sample_time_s=sample_time_s,
        cross_covariance=g * g * raw.cross_covariance,
    )
    return before, after


def simulate_switched(
    systems: Sequence[NoisyStateSpace],
    switch_indices: Sequence[int] | int,
    u: np.ndarray,
    seed: Optional[int] = None,
    x0="stationary",
    return_states: bool = False,
):
    """Simulate systems one after the other, with the state carried over each switch.

    ``systems[j]`` produces the samples ``switch_indices[j-1] <= k < switch_indices[j]``
    (``switch_indices[-1]`` is the first sample of the last system): for those samples
    ``x_{k+1} = A_j x_k + B_j u_k + w_k``, ``y_k = C_j x_k + D_j u_k + v_k`` with
    ``[w_k; v_k] ~ N(0, [[Q_j, S_j], [S_j^T, R_j]])``. So the first sample of a new system,
    ``x_s``, is the last old system's step from ``x_{s-1}``; from there the new system runs.
    All systems must have the same state, input and output dimensions (the same coordinates).

    Parameters
    ----------
    systems : J >= 1 systems.
    switch_indices : J - 1 increasing sample indices in (0, N), or one int for J = 2.
    u : (N, m) input.
    seed : noise seed (one standard normal draw per sample, coloured per segment).
    x0 : initial state of ``systems[0]``: ``"stationary"`` (default), ``None`` or an array.
    return_states : also return the states ``X`` (N, n).

    Returns
    -------
    y : (N, p); and ``X`` (N, n) if ``return_states``.
    """
    systems = list(systems)
    switches = [int(switch_indices)] if np.isscalar(switch_indices) else [int(s) for s in switch_indices]
    u = np.asarray(u, dtype=float).reshape(len(u), -1)
    N = u.shape[0]
    if len(switches) != len(systems) - 1:
        raise ValueError(f"{len(systems)} systems need {len(systems) - 1} switch indices, got {len(switches)}")
    bounds = [0, *switches, N]
    if any(b >= c for b, c in zip(bounds[:-1], bounds[1:])):
        raise ValueError(f"switch indices must increase strictly inside (0, {N}), got {switches}")
    first = systems[0]
    n, m, p = first.n_states, first.n_inputs, first.n_outputs
    for s in systems:
        if (s.n_states, s.n_inputs, s.n_outputs) != (n, m, p):
            raise ValueError("all systems need the same numbers of states, inputs and outputs")
    if u.shape[1] != m:
        raise ValueError(f"u has {u.shape[1]} columns, the systems have {m} inputs")
    rng = np.random.default_rng(seed)
    white = rng.standard_normal((N, n + p))
    x = initial_state(first.A, first.process_noise_covariance, x0, rng)
    X = np.empty((N, n))
    y = np.empty((N, p))
    for s, lo, hi in zip(systems, bounds[:-1], bounds[1:]):
        wv = white[lo:hi] @ sqrt_psd(s.joint_noise_covariance()).T
        w, v = wv[:, :n], wv[:, n:]
        forcing = u[lo:hi] @ s.B.T + w
        X[lo:hi] = propagate_states(s.A, forcing, x)
        x = s.A @ X[hi - 1] + forcing[-1]
        y[lo:hi] = X[lo:hi] @ s.C.T + u[lo:hi] @ s.D.T + v
    return (y, X) if return_states else y


# ---------------------------------------------------------------------------
# The tracking case of issue 4 and its score
# ---------------------------------------------------------------------------


@dataclass
class SwitchedCase:
    """A structure that changes once during the record, with its known truth.

    Attributes
    ----------
    name, description : identifier and one-paragraph description.
    before, after : the systems before and after the change (same state coordinates).
    frequencies_hz : (n_modes,) true natural frequencies before the change.
    frequency_factor : the frequencies after the change are ``frequency_factor * frequencies_hz``.
    damping_ratios : (n_modes,) true damping ratios (unchanged).
    make_input : ``make_input(n_samples, seed) -> u`` (n_samples, m).
    arx_order : ARX order q for tracking (covers the true predictor's memory, see
        :func:`~okid_bench.cases.suggested_arx_order`).
    """

    name: str
    description: str
    before: NoisyStateSpace
    after: NoisyStateSpace
    frequencies_hz: np.ndarray
    frequency_factor: float
    damping_ratios: np.ndarray
    make_input: Callable[[int, int], np.ndarray]
    arx_order: int

    @property
    def sample_time_s(self) -> float:
        return self.before.sample_time_s

    @property
    def new_frequencies_hz(self) -> np.ndarray:
        return self.frequency_factor * self.frequencies_hz

    def simulate(self, n_samples: int, change_index: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """``(u, y)`` of ``n_samples`` with the change at ``change_index``.

        ``change_index`` is the first sample of the new structure; input seed ``100 + seed``,
        noise seed ``200 + seed``.
        """
        u = self.make_input(n_samples, 100 + seed)
        return u, simulate_switched([self.before, self.after], change_index, u, seed=200 + seed)


def added_mass_case(frequency_factor: float = 0.94) -> SwitchedCase:
    """Issue 4's tracking case: three modes, all frequencies drop by 6 % (an added mass).

    Modes at 1.8, 4.2 and 7.9 Hz with 0.8, 1.0 and 1.5 % damping (after the change 1.692,
    3.948, 7.426 Hz), 2 force inputs low-passed at 10 Hz, 3 accelerometers, 25 Hz sampling (a
    window of 4000 samples is 160 s, 288 periods of the lowest mode); disturbance forces (std
    0.3 of the input) and 5 % sensor noise. Mode-shape seed 6: every mode is excited by both
    inputs and seen by all sensors (participation norms 1.7-2.6 of the inputs, 1.2-1.6 of the
    sensors). The true predictor's memory (``5 / -ln rho(A - L C)``) is 33 samples; q = 40.
    """
    dt = 1.0 / 25.0
    f = np.array([1.8, 4.2, 7.9])
    z = np.array([0.008, 0.01, 0.015])
    before, after = added_mass_structure(
        f, z, n_inputs=2, n_outputs=3, sample_time_s=dt, frequency_factor=frequency_factor, seed=6,
        output="acceleration", disturbance_std=0.3, measurement_noise_ratio=0.05,
    )
    desc = (
        f"Added mass: modes at 1.8, 4.2, 7.9 Hz (0.8, 1.0, 1.5 % damping) drop to "
        f"{', '.join(f'{x:.3f}' for x in frequency_factor * f)} Hz; 2 inputs low-passed at 10 Hz, "
        f"3 accelerometers, 25 Hz sampling; disturbance forces (std 0.3) and 5 % sensor noise."
    )
    return SwitchedCase(
        "added-mass", desc, before, after, f, float(frequency_factor), z,
        lambda N, seed: lowpass_input(N, 2, 10.0, dt, seed), arx_order=40,
    )


@dataclass
class ModeSettling:
    """How one true mode's identified frequency settled after the change.

    Attributes
    ----------
    truth_hz : the true frequency after the change.
    settle_index : ``sample_index`` of the first update at or after the change from which on
        the identified frequency (of the identified mode nearest to ``truth_hz``) stays within
        the tolerance for every later update; None if it never does.
    settle_samples : ``settle_index - change_index`` (None if it never settles).
    max_error_after : largest relative error over the updates from ``settle_index`` on.
    max_error_before : largest relative error of the nearest identified mode to the *old* truth
        over the updates whose window ends before the change.
    """

    truth_hz: float
    settle_index: Optional[int]
    settle_samples: Optional[int]
    max_error_after: float
    max_error_before: float


def _nearest_error(modes: Sequence[dict], truth_hz: float) -> float:
    if not modes:
        return float("inf")
    freqs = np.array([m["frequency_hz"] for m in modes])
    return float(np.min(np.abs(freqs / truth_hz - 1.0)))


def settling(
    updates: Sequence[dict],
    change_index: int,
    old_hz: Sequence[float],
    new_hz: Sequence[float],
    tolerance: float = 0.005,
) -> tuple[list[ModeSettling], Optional[int]]:
    """Settling of each true mode in a list of ``okid-ros track`` updates (one dict per line).

    Each true mode is matched, at every update, to the identified mode nearest in frequency.

    Returns
    -------
    per_mode : one :class:`ModeSettling` per true mode.
    clean_index : ``sample_index`` of the first update at or after the change from which on the
        identified modes are exactly one per true mode, each within the tolerance of the new
        truth (no mode of the old structure or spurious mode left); None if never.
    """
    updates = sorted(updates, key=lambda e: e["sample_index"])
    before = [e for e in updates if e["sample_index"] < change_index]
    after = [e for e in updates if e["sample_index"] >= change_index]
    per_mode = []
    for old, new in zip(old_hz, new_hz):
        errors = np.array([_nearest_error(e["modes"], new) for e in after])
        bad = np.flatnonzero(~(errors <= tolerance))
        start = 0 if bad.size == 0 else int(bad[-1]) + 1
        settled = start < len(after)
        index = int(after[start]["sample_index"]) if settled else None
        per_mode.append(ModeSettling(
            truth_hz=float(new),
            settle_index=index,
            settle_samples=None if index is None else index - int(change_index),
            max_error_after=float(errors[start:].max()) if settled else float("nan"),
            max_error_before=max((_nearest_error(e["modes"], old) for e in before), default=float("nan")),
        ))
    clean = np.array([
        len(e["modes"]) == len(new_hz) and all(_nearest_error(e["modes"], f) <= tolerance for f in new_hz)
        for e in after
    ], dtype=bool)
    bad = np.flatnonzero(~clean)
    start = 0 if bad.size == 0 else int(bad[-1]) + 1
    clean_index = int(after[start]["sample_index"]) if start < len(after) else None
    return per_mode, clean_index
