"""Stabilization across model orders: which poles are structural modes.

Modal analysts identify a structure at a range of model orders and keep the poles that stay
put as the order grows (the stabilization diagram of ``modalsd``, PolyMAX and pyOMA): a
structural mode appears at every order above the one that first resolves it, with the same
frequency, damping and mode shape, while poles that fit noise wander from order to order.

Here each order tried by the order search contributes its completed model's poles (complex
pairs of ``A`` below Nyquist). A pole of order n is marked against the poles of the previous
order tried:

- ``stable_frequency``: a pole within ``stability_frequency`` (relative) in frequency;
- ``stable_damping``: that pole also within ``stability_damping`` (relative) in damping;
- ``stable_shape``: that pole also with MAC >= ``stability_mac`` between the output shapes.

A mode of the chosen model is *stable* when a pole with about its frequency and damping
(:func:`stable_fraction`) is found in at least ``min_stable_fraction`` of the neighbouring
orders tried (up to ``NEIGHBOURS`` on each side), and only stable modes are listed as
physical; a mode of a refined model also by its pole before the refinement
(:func:`refined_stable_fraction`: the orders' models are not refined). The tolerances are
looser than the diagram's criteria and the shape is not required: the damping of a lightly
damped mode and the shapes of a close pair (which mix from order to order) scatter more than
a structural mode's frequency, while a pole that fits noise does not keep its frequency.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import linalg

from okid_ros.core.modal import Mode, continuous_poles, mac
from okid_ros.core.options import ModeCriteria
from okid_ros.core.statespace import InnovationModel

__all__ = ["NEIGHBOURS", "StabilizationPole", "StabilizationOrder", "stabilization_diagram", "stable_fraction",
           "refined_stable_fraction", "stability_judge"]

#: Neighbouring orders (on each side of the chosen one) a mode is looked for in.
NEIGHBOURS = 4
#: Largest relative frequency change by the refinement for which a refined mode is also judged by
#: its pole before it (:func:`refined_stable_fraction`): 5 %, the benchmarks' match tolerance.
MAX_REFINEMENT_SHIFT = 0.05
#: The frequency tolerance grows with a mode's damping up to this (a heavily damped pole would
#: otherwise find a partner anywhere near).
MAX_FREQUENCY_TOLERANCE = 0.03
#: Damping ratios of the same pole agree within this factor, or within DAMPING_TOLERANCE.
DAMPING_FACTOR = 3.0
DAMPING_TOLERANCE = 0.005


@dataclass
class StabilizationPole:
    """One complex pole pair of the model of one order, with the criteria it meets."""

    frequency_hz: float
    damping_ratio: float
    shape: np.ndarray  # (p,) complex output shape, unit norm
    stable_frequency: bool = False
    stable_damping: bool = False
    stable_shape: bool = False

    def as_dict(self) -> dict:
        """JSON-ready (no shape)."""
        return {
            "frequency_hz": float(self.frequency_hz),
            "damping_ratio": float(self.damping_ratio),
            "stable_frequency": bool(self.stable_frequency),
            "stable_damping": bool(self.stable_damping),
            "stable_shape": bool(self.stable_shape),
        }


@dataclass
class StabilizationOrder:
    """The poles of the model of one order."""

    n_states: int
    poles: list[StabilizationPole]

    def as_dict(self) -> dict:
        return {"n_states": int(self.n_states), "poles": [pole.as_dict() for pole in self.poles]}


def _poles(model: InnovationModel, sample_time_s: float, criteria: ModeCriteria,
           eigen: tuple[np.ndarray, np.ndarray] | None = None) -> list[StabilizationPole]:
    """Stable complex pole pairs below the Nyquist limit of the criteria, by frequency.

    Only what the diagram compares: frequency, damping and the output shape ``C psi`` (MAC
    ignores its scale), from one eigendecomposition of ``A`` (given, or computed here); the
    indicators of :func:`identify_modes` (MSV, MPC, EMAC need ``inv(psi)``) are not needed.
    """
    z, psi = linalg.eig(model.A) if eigen is None else eigen
    upper = np.flatnonzero(z.imag > 1e-12 * max(1.0, np.abs(z).max()))
    s = continuous_poles(z[upper], sample_time_s)
    omega = np.abs(s)
    zeta = np.where(omega > 0, -s.real / np.where(omega > 0, omega, 1.0), 1.0)
    frequency_hz = omega / (2 * np.pi)
    nyquist_hz = 0.5 / sample_time_s
    below_nyquist = frequency_hz < criteria.max_nyquist_fraction * nyquist_hz
    keep = (np.abs(z[upper]) < 1.0) & (zeta >= 0.0) & (zeta < 1.0) & below_nyquist
    shapes = model.C @ psi[:, upper[keep]]
    norms = np.linalg.norm(shapes, axis=0)
    shapes = shapes / np.where(norms > 0, norms, 1.0)
    poles = [StabilizationPole(float(f), float(d), shapes[:, i])
             for i, (f, d) in enumerate(zip(frequency_hz[keep], zeta[keep]))]
    return sorted(poles, key=lambda pole: pole.frequency_hz)


def _match(pole, others: list[StabilizationPole], criteria: ModeCriteria) -> tuple[bool, bool, bool]:
    """(frequency, + damping, + shape) criteria of ``pole`` against the closest of ``others``."""
    best = (False, False, False)
    for other in others:
        df = abs(other.frequency_hz - pole.frequency_hz) / max(pole.frequency_hz, 1e-300)
        if df > criteria.stability_frequency:
            continue
        dz = abs(other.damping_ratio - pole.damping_ratio) / max(pole.damping_ratio, 1e-300)
        damping_ok = dz <= criteria.stability_damping
        same_size = pole.shape.size == other.shape.size
        shape_ok = same_size and mac(pole.shape, other.shape) >= criteria.stability_mac
        candidate = (True, damping_ok, damping_ok and shape_ok)
        if sum(candidate) > sum(best):
            best = candidate
    return best


def _near_in_frequency(poles: list[StabilizationPole], previous: list[StabilizationPole],
                       criteria: ModeCriteria) -> list[list[StabilizationPole]]:
    """For each pole, the previous order's poles within the frequency tolerance (in order).

    One array comparison per order instead of a Python loop over every pair; :func:`_match`
    then visits only these (the others fail its first test).
    """
    if not poles or not previous:
        return [[] for _ in poles]
    current = np.array([pole.frequency_hz for pole in poles])
    others = np.array([pole.frequency_hz for pole in previous])
    relative = np.abs(others[None, :] - current[:, None]) / np.maximum(current, 1e-300)[:, None]
    near = relative <= criteria.stability_frequency
    return [[previous[j] for j in np.flatnonzero(row)] if row.any() else [] for row in near]


def stabilization_diagram(
    models: dict[int, InnovationModel],
    sample_time_s: float,
    criteria: ModeCriteria,
    *,
    eigen: dict[int, tuple[np.ndarray, np.ndarray]] | None = None,
) -> list[StabilizationOrder]:
    """The poles of every order's model, marked against the previous order tried.

    Parameters
    ----------
    models : completed model of each order tried (order -> model).
    sample_time_s : sample time [s].
    criteria : tolerances of the three criteria.
    eigen : optional eigendecomposition ``(lambda, V)`` of some orders' ``A`` already computed
        (by the order search), used where that order's model has the same ``A``.

    Returns
    -------
    One :class:`StabilizationOrder` per order, increasing.
    """
    diagram: list[StabilizationOrder] = []
    previous: list[StabilizationPole] = []
    for n in sorted(models):
        known = (eigen or {}).get(n)
        if known is not None and known[1].shape[0] != models[n].A.shape[0]:
            known = None
        poles = _poles(models[n], sample_time_s, criteria, known)
        for pole, near in zip(poles, _near_in_frequency(poles, previous, criteria)):
            pole.stable_frequency, pole.stable_damping, pole.stable_shape = _match(pole, near, criteria)
        diagram.append(StabilizationOrder(n, poles))
        previous = poles
    return diagram


def stability_judge(diagram: list[StabilizationOrder], n_states: int, criteria: ModeCriteria,
                    refined_models: dict[int, InnovationModel], sample_time_s: float) -> Callable[[Mode], float]:
    """The stable fraction of each mode of the chosen model of order ``n_states``, as a function.

    Parameters
    ----------
    diagram : the diagram of the models before the refinement (:func:`stabilization_diagram`).
    refined_models : every refined model by order (empty: the chosen model is not refined); a
        refined model's mode is judged by :func:`refined_stable_fraction`, with the other orders'.
    """
    if not refined_models:
        return lambda mode: stable_fraction(mode, diagram, n_states, criteria)
    others = {n: model for n, model in refined_models.items() if n != n_states}
    refined = stabilization_diagram(others, sample_time_s, criteria) if others else []
    return lambda mode: refined_stable_fraction(mode, diagram, n_states, criteria, refined=refined)


def refined_stable_fraction(
    mode: Mode, diagram: list[StabilizationOrder], n_states: int, criteria: ModeCriteria, *,
    refined: list[StabilizationOrder] | None = None,
) -> float:
    """:func:`stable_fraction` of a mode of the refined model of order ``n_states``.

    The diagram holds the models before the prediction-error refinement, which moves a weakly
    excited mode most (separate-noise case: 6.60 -> 6.77 Hz, true 6.8 Hz, 2.5 % from its own pole
    of every other order). Such a mode is judged by its pole before the refinement too (the
    diagram's pole of order ``n_states`` nearest in frequency, within :data:`MAX_REFINEMENT_SHIFT`),
    and by ``refined``, the refined models of the other orders refined (as a diagram): the
    refinement also corrects what the models before it get wrong at every order alike (a slow
    mode, random structure 36: 4.34 Hz at 1.0 % in each refined model, 4.15 Hz at 8.7 % or 4.4 Hz
    at 5-6 % before the refinement from order 10 on). Found in every one of them, the mode counts
    as stable (fraction 1); in some, not at all: they are one or two, and half of them (one) let
    noise poles through (docs/benchmarks-realization.md). The largest fraction counts, so no
    mode stable by itself is refused.
    """
    fractions = [stable_fraction(mode, diagram, n_states, criteria)]
    own = next((entry.poles for entry in diagram if entry.n_states == n_states), [])
    if own and mode.frequency_hz > 0:
        before = min(own, key=lambda pole: abs(pole.frequency_hz - mode.frequency_hz))
        if abs(before.frequency_hz / mode.frequency_hz - 1) <= MAX_REFINEMENT_SHIFT:
            fractions.append(stable_fraction(before, diagram, n_states, criteria))
    if refined and stable_fraction(mode, refined, n_states, criteria) == 1.0:
        fractions.append(1.0)
    judged = [fraction for fraction in fractions if not np.isnan(fraction)]
    return max(judged) if judged else float("nan")


def stable_fraction(
    mode: Mode | StabilizationPole, diagram: list[StabilizationOrder], n_states: int, criteria: ModeCriteria
) -> float:
    """Fraction of the neighbouring orders in whose model the same pole is found.

    The same pole: frequency within ``stability_frequency`` or, for a more damped mode, within
    its damping ratio up to :data:`MAX_FREQUENCY_TOLERANCE` (the frequency of a mode is known
    to about its half-power bandwidth, so a
    1 %-damped mode of a short record scatters by about 1 %), and damping within a factor
    :data:`DAMPING_FACTOR` or :data:`DAMPING_TOLERANCE` (a heavily damped pole next to a lightly
    damped mode is not that mode), and itself below ``max_damping``. Neighbours: up to
    :data:`NEIGHBOURS` orders tried on each side of
    ``n_states``. NaN when no neighbouring order was tried (nothing to judge by).
    """
    below = [entry for entry in diagram if entry.n_states < n_states][-NEIGHBOURS:]
    above = [entry for entry in diagram if entry.n_states > n_states][:NEIGHBOURS]
    neighbours = below + above
    if not neighbours:
        return float("nan")
    tolerance = max(criteria.stability_frequency, min(mode.damping_ratio, MAX_FREQUENCY_TOLERANCE))
    found = 0
    for entry in neighbours:
        for pole in entry.poles:
            df = abs(pole.frequency_hz - mode.frequency_hz) / max(mode.frequency_hz, 1e-300)
            if (df <= tolerance and pole.damping_ratio < criteria.max_damping
                    and _same_damping(pole.damping_ratio, mode.damping_ratio)):
                found += 1
                break
    return found / len(neighbours)


def _same_damping(a: float, b: float) -> bool:
    """Damping ratios close enough for the same pole (see :func:`stable_fraction`)."""
    if abs(a - b) <= DAMPING_TOLERANCE:
        return True
    low, high = sorted((a, b))
    return low > 0 and high <= DAMPING_FACTOR * low
