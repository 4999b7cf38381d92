"""Options of the identification chain, with every default defined once.

:class:`RealizationOptions` carries what turns an ARX model (and the samples of its window)
into an innovation model: the model order or the automatic search and its limits, the Hankel
sizes, the gain, the completion, the refinement and the criteria of a physical mode
(:class:`ModeCriteria`). :func:`okid_ros.core.pipeline.identify`,
:func:`okid_ros.core.pipeline.identify_from_arx`, the estimation service, ``okid-ros track``
and the nodes' parameter table all take their defaults from here.

>>> RealizationOptions(n_states=8).max_states
40
>>> RealizationOptions(gain="magic")
Traceback (most recent call last):
...
ValueError: gain must be one of ('refit', 'riccati', 'whitening'), got 'magic'
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, Mapping

__all__ = [
    "AUTO",
    "GAINS",
    "COMPLETIONS",
    "OFFSETS",
    "OUTPUT_ONLY_METHODS",
    "ModeCriteria",
    "RealizationOptions",
    "ArxOrderOptions",
    "SAMPLE_TIME_RANGE_S",
    "HIGHEST_FREQUENCY_HZ",
    "sample_time_problem",
    "MAX_GAP_SAMPLES",
    "DEFAULT_FALSE_ALARM_SAMPLES",
    "DEFAULT_VARIANCE_RATIO",
    "DEFAULT_REFERENCE_SAMPLES",
]

AUTO = "auto"
GAINS = ("refit", "riccati", "whitening")
COMPLETIONS = ("auto", "predictor", "states")
OFFSETS = ("remove", "none")
#: How an output-only model is realized from its outputs (the first the default, the measured
#: winner: docs/benchmarks-output-only.md, forty-second session; :mod:`.output_only`).
OUTPUT_ONLY_METHODS = ("ssi-cva", "ssi-cov", "var")
#: Sample times the chain accepts [s], from 1 MHz to one sample an hour: every structural record
#: lies inside, and the frequencies (1 / dt) and their squares stay far inside float64 (a record
#: at 1e-300 s gave frequencies of 1e299 Hz and NaN standard deviations).
SAMPLE_TIME_RANGE_S = (1e-6, 3600.0)
#: The highest frequency a record read can hold [Hz]: the Nyquist frequency of the shortest sample time.
HIGHEST_FREQUENCY_HZ = 0.5 / SAMPLE_TIME_RANGE_S[0]
#: Longest run of missing samples bridged by prediction (node 2's ``estimator.max_gap_samples``
#: default; a whole record in ``identify``; :mod:`.gap_fill`): the prediction of a lightly
#: damped structure stays close over a few samples, not over a decay time.
MAX_GAP_SAMPLES = 10
# The change test's defaults (:mod:`.change_detection`, :mod:`.cusum`), here so that the nodes'
# parameter table reads them without importing the test's numerical modules (scipy.stats).
DEFAULT_FALSE_ALARM_SAMPLES = 1e7  # expected samples between false alarms (11 h at 250 Hz)
DEFAULT_VARIANCE_RATIO = 1.5  # gamma, the covariance increase the CUSUM is tuned to
DEFAULT_REFERENCE_SAMPLES = 1000  # calibration samples after each (re)arming


def sample_time_problem(sample_time_s: Any) -> str | None:
    """Why ``sample_time_s`` is not a usable sample time (one line), or None when it is."""
    low, high = SAMPLE_TIME_RANGE_S
    try:  # text ("0.008") passed float() and failed later in numpy's division (TypeError)
        if isinstance(sample_time_s, (str, bytes, bool)):
            raise TypeError
        dt = float(sample_time_s)
    except (TypeError, ValueError):
        return f"sample_time_s must be a number of seconds, got {sample_time_s!r}"
    if not low <= dt <= high:  # NaN fails too
        return f"sample_time_s must be between {low:g} and {high:g} s, got {dt!r}"  # :g said 3600.0000001 as 3600
    return None


@dataclass(frozen=True)
class ModeCriteria:
    """What makes a complex pole pair a physical mode (reported to users, modal coordinates).

    Attributes
    ----------
    max_damping : largest damping ratio (fraction).
    max_nyquist_fraction : the mode lies below this fraction of the Nyquist frequency.
    min_msv : smallest modal singular value relative to the largest mode (input reaches it,
        output sees it).
    min_mpc : smallest modal phase collinearity of the output shape (1: a real normal mode).
        Applied only with at least ``3`` outputs, where the MPC of a shape means something.
    min_dominance : smallest share of the model's frequency response at the mode's own
        frequency that its pole pair makes up, along its output shape
        (:func:`okid_ros.core.modal.response_dominance`). A pole pair that does not stand out of
        the response at its own frequency models no resonance of its own: broad poles that fit
        noise or nonlinearity under stronger modes. Measured (docs/benchmarks-realization.md):
        the true modes of the simulated cases 0.37-1.0 (the lowest: the weaker mode of a pair
        1.6 % apart), the two spurious modes of the whole steel-subframe record 0.08 and 0.04.
    stability_frequency : relative frequency change within which a pole of a neighbouring
        model order is "the same pole" (stabilization diagram, first criterion).
    stability_damping : relative damping change of the second criterion.
    stability_mac : smallest MAC of the third criterion (mode shape).
    min_stable_fraction : a mode is physical only if the same pole (frequency and shape
        criteria) is found in at least this fraction of the neighbouring orders tried
        (0 turns the stability criterion off).
    """

    max_damping: float = 0.1
    max_nyquist_fraction: float = 0.95
    min_msv: float = 1e-3
    min_mpc: float = 0.5
    min_dominance: float = 0.2
    stability_frequency: float = 0.01
    stability_damping: float = 0.05
    stability_mac: float = 0.9
    min_stable_fraction: float = 0.5

    def __post_init__(self) -> None:
        for name in ("max_damping", "max_nyquist_fraction", "stability_frequency", "stability_damping"):
            value = getattr(self, name)
            if not 0.0 < value <= 1.0:
                raise ValueError(f"{name} must be in (0, 1], got {value}")
        for name in ("min_msv", "min_mpc", "min_dominance", "stability_mac", "min_stable_fraction"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value}")


@dataclass(frozen=True)
class ArxOrderOptions:
    """The automatic choice of the ARX order q (:func:`okid_ros.core.arx.select_arx_order`).

    Attributes
    ----------
    candidates : ARX orders tried, increasing.
    max_coefficients : largest regressor length ``d = m + q (p + m)`` tried (bounds the cost:
        one symmetric eigendecomposition of ``d x d`` per order).
    min_rows_per_coefficient : a candidate needs at least this many regressor rows per
        coefficient.
    """

    candidates: tuple[int, ...] = (5, 10, 15, 20, 30, 40, 50, 60, 80, 100, 120, 150, 200)
    max_coefficients: int = 2500
    min_rows_per_coefficient: float = 2.0


@dataclass(frozen=True)
class RealizationOptions:
    """How an ARX model is realized and completed into an innovation model.

    Attributes
    ----------
    n_states : model order n, or ``"auto"`` (lowest BIC of the completed predictor).
    max_states : upper limit of the automatic search. When BIC is lowest at the limit the
        search goes on to ``max_states_limit`` (doubling), and says so when it stops there.
    max_states_limit : hard upper limit of the automatic search.
    hankel_rows, hankel_cols : ERA block rows and columns (None: split the ARX lag blocks).
    gain : ``"refit"`` (least squares where the predictor is stable by construction, the
        Riccati gain otherwise), ``"riccati"`` (always the Kalman gain of the discrete Riccati
        equation on the residual covariances of the state-sequence regressions) or
        ``"whitening"`` (the paper's AR whitening, Eqs. 36-45).
    completion : ``"predictor"`` (least-squares refit of the predictor), ``"states"``
        (regressions on the state sequence; fast with many outputs) or ``"auto"``.
    state_passes : re-estimations of the state sequence with the completed model's own Kalman
        predictor (each kept only if it lowers the one-step prediction error).
    refine : finish with the prediction-error refinement when it is affordable.
    refined_orders : in an automatic search, the refinement runs on this many orders (the BIC
        winner and the next best completed ones) and the lowest BIC after refinement wins: the
        refinement moves each order's fit by a different amount (1: the winner only, about half
        the time at the paper's size; docs/benchmarks-realization.md, ninth session).
    max_radius : eigenvalues of ``A`` on or outside the unit circle are moved inside, to at
        most this modulus (unstable poles of a realization are not structural modes).
    ar_order : AR order of the whitening gain (None: the ARX order).
    jackknife_segments : where the prediction-error covariance of the modes is out of reach (tens
        of outputs), their standard deviations come from a jackknife over this many segments of
        the window (:mod:`okid_ros.core.mode_jackknife`); 0: left NaN.
    modes : :class:`ModeCriteria`.
    """

    n_states: int | str = AUTO
    max_states: int = 40
    max_states_limit: int = 160
    hankel_rows: int | None = None
    hankel_cols: int | None = None
    gain: str = "refit"
    completion: str = "auto"
    state_passes: int = 2
    refine: bool = True
    refined_orders: int = 3
    max_radius: float = 0.9999
    ar_order: int | None = None
    jackknife_segments: int = 8
    modes: ModeCriteria = field(default_factory=ModeCriteria)

    def __post_init__(self) -> None:
        if self.gain not in GAINS:
            raise ValueError(f"gain must be one of {GAINS}, got {self.gain!r}")
        if self.completion not in COMPLETIONS:
            raise ValueError(f"completion must be one of {COMPLETIONS}, got {self.completion!r}")
        if self.n_states != AUTO and (not isinstance(self.n_states, int) or self.n_states < 1):
            raise ValueError(f"n_states must be a positive integer or {AUTO!r}, got {self.n_states!r}")
        if self.max_states < 1 or self.max_states_limit < self.max_states:
            raise ValueError(
                f"need 1 <= max_states <= max_states_limit, got {self.max_states} and {self.max_states_limit}"
            )
        if not 0.0 < self.max_radius < 1.0:
            raise ValueError(f"max_radius must be in (0, 1), got {self.max_radius}")
        if self.state_passes < 0:
            raise ValueError(f"state_passes must be >= 0, got {self.state_passes}")
        if self.jackknife_segments < 0 or self.jackknife_segments == 1:
            raise ValueError(f"jackknife_segments must be 0 or at least 2, got {self.jackknife_segments}")
        if self.refined_orders < 1:
            raise ValueError(f"refined_orders must be >= 1, got {self.refined_orders}")
        for name in ("ar_order", "hankel_rows", "hankel_cols"):  # 0 was taken for None in silence, 5.5 a TypeError
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not hasattr(value, "__index__") or value < 1):
                raise ValueError(f"{name} must be a positive integer or None, got {value!r}")
        if self.refine not in (True, False):  # "no" was taken for True
            raise ValueError(f"refine must be True or False, got {self.refine!r}")

    @property
    def automatic_order(self) -> bool:
        return self.n_states == AUTO

    def with_changes(self, **changes: Any) -> "RealizationOptions":
        """A copy with some options changed (``modes`` whole, or mode criteria by their own names)."""
        mode_names = {f.name for f in fields(ModeCriteria)}
        mode_changes = {k: changes.pop(k) for k in list(changes) if k in mode_names}
        modes = changes.pop("modes", self.modes)
        return replace(self, modes=replace(modes, **mode_changes) if mode_changes else modes, **changes)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> "RealizationOptions":
        """From a flat mapping of option names (mode criteria included); unknown names raise."""
        known = {f.name for f in fields(cls)} | {f.name for f in fields(ModeCriteria)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown realization option(s): {', '.join(unknown)}")
        return cls().with_changes(**dict(values))
