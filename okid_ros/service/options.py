"""The services' options, derived from the parameter table (:mod:`okid_ros.service.params`).

Each :class:`~okid_ros.service.params.ParamSpec` names the option field that takes its value
(``field``) and whether it may change while a node runs (``runtime``). From that table come,
here, the defaults of :class:`ArxIdentificationParams` (node 1) and
:class:`ModalEstimationParams` (node 2), their ``from_parameters``, and
:func:`check_runtime_change`, the one rule of which option may change on a running service;
the defaults the core defines are read from the core by the table.

>>> ModalEstimationParams().min_mac == option_specs(ESTIMATOR_NODE)["min_mac"].default
True
>>> from okid_ros.service.params import resolve_parameters
>>> ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, {"publish_rate_hz": 4.0})).publish_period_s
0.25
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, Mapping

from okid_ros.core.options import AUTO, ArxOrderOptions, ModeCriteria, RealizationOptions
from okid_ros.core.regressors import regressor_length
from okid_ros.core.window_minimum import window_minimum
from okid_ros.errors import ParameterError
from okid_ros.service.params import (
    ARX_NODE,
    ESTIMATOR_NODE,
    option_specs,
    option_values,
    runtime_fields,
)
from okid_ros.service.sample_buffer import memory_shortfall

__all__ = ["ArxIdentificationParams", "ModalEstimationParams", "check_runtime_change", "HANDOVER_SAMPLES",
           "MAX_ARX_LEAD_S", "MAX_BUFFER_SAMPLES"]

#: Samples :meth:`~okid_ros.service.estimation.ModalEstimationService.follow` leaves to the
#: switch on the sample path (not a parameter).
HANDOVER_SAMPLES = 4
#: How far after node 2's newest sample an ArxModel's window may end [s]. Node 2's samples may lag
#: node 1's by its input queue (``inputs.queue_depth`` 1000 messages: 8 s at 125 Hz) on a loaded
#: machine; a window ending further ahead is of a stream node 2 does not get (a forged or foreign
#: stamp) and held the realization waiting for its end sample until node 1's next model replaced it.
MAX_ARX_LEAD_S = 60.0
#: The most samples node 2 buffers, the limit of ``estimator.buffer_length``; with 0 (the
#: buffer follows the ARX window an ArxModel claims) the buffer grows no further.
MAX_BUFFER_SAMPLES = int(option_specs(ESTIMATOR_NODE)["buffer_length"].high)


def _default(node: str, option: str) -> Any:
    """The table's default of the parameter that sets ``option``, as the option holds it."""
    spec = option_specs(node)[option]
    return spec.field_value(spec.default)


def _arx(option: str) -> Any:
    return _default(ARX_NODE, option)


def _est(option: str) -> Any:
    return _default(ESTIMATOR_NODE, option)


@dataclass
class ArxIdentificationParams:
    """Settings of the identification (the ROS names and meanings: ``okid_ros/service/params.py``).

    Attributes
    ----------
    sample_time_s : dt [s].
    order : ARX order q.
    n_inputs, n_outputs : m and p.
    window_length : regressor rows in the sliding window; 0 for infinite history with
        ``forgetting_factor``.
    forgetting_factor : lambda in (0, 1] (only with ``window_length`` 0).
    regularization : "none", "ridge" or "tc".
    penalty_by_gcv : choose the penalty (and TC decay) by GCV at every solve.
    penalty : fixed penalty otherwise.
    tc_decay : fixed TC decay otherwise.
    min_window_fill : snapshots of a window filled less than this are invalid.
    max_condition_number : condition number of the column-scaled normal equations above which
        the window is unexcited (snapshot invalid, last good fit kept) when a cause is found: no
        input varying, one varying in part of the window only, dead or dependent outputs, or the
        inputs' columns beyond it too; else only the outputs' lags are collinear (a response far above
        its noise) and the window is identified (:mod:`okid_ros.core.window_conditioning`). An input
        silent over the whole window is left out before (:func:`~okid_ros.service.arx_solve.silent_inputs`).
    publish_period_s : period of the snapshots by sample time (offline processing), 1 /
        ``publish_rate_hz``.
    restart_min_fill : after a restart at a structural change, snapshots are valid from this
        window fill on (instead of ``min_window_fill``).
    offsets : "remove" (the fit has an intercept: signals with non-zero means, as node 2 and
        the batch ``identify`` remove them) or "none".
    """

    sample_time_s: float = _arx("sample_time_s")
    order: int = _arx("order")
    n_inputs: int = _arx("n_inputs")
    n_outputs: int = _arx("n_outputs")
    window_length: int = _arx("window_length")
    forgetting_factor: float = _arx("forgetting_factor")
    regularization: str = _arx("regularization")
    penalty_by_gcv: bool = _arx("penalty_by_gcv")
    penalty: float = _arx("penalty")
    tc_decay: float = _arx("tc_decay")
    min_window_fill: float = _arx("min_window_fill")
    max_condition_number: float = _arx("max_condition_number")
    publish_period_s: float = _arx("publish_period_s")
    restart_min_fill: float = _arx("restart_min_fill")
    offsets: str = _arx("offsets")

    @classmethod
    def from_parameters(cls, values: Mapping[str, Any]) -> "ArxIdentificationParams":
        """From the resolved node parameters (dotted names, :func:`okid_ros.service.params.resolve_parameters`).

        Raises ParameterError when the ARX regressor does not fit (:meth:`size_problem`).
        """
        params = cls(**option_values(ARX_NODE, values))
        problem = params.size_problem()
        if problem:
            raise ParameterError(problem)
        return params

    def fill_needed(self, restarted: bool) -> float:
        """The window fill from which a snapshot is valid (after a restart at a change: the smaller of two).

        ``min_window_fill``; after a restart at a change the smaller of it and ``restart_min_fill``.
        """
        return min(self.min_window_fill, self.restart_min_fill) if restarted else self.min_window_fill

    def rows_needed(self, restarted: bool) -> int:
        """:meth:`fill_needed` in rows of a window of ``window_length`` rows (at least 1): fewer are refused."""
        return max(math.ceil(self.fill_needed(restarted) * self.window_length), 1)

    def first_model_samples(self) -> float:
        """Samples node 1 takes in before its first valid model: ``min_window_fill`` of its window, plus ``order``.

        With forgetting (``window_length`` 0) the window's fill after n rows is 1 - lambda^n (1 from the
        first row on without forgetting, :class:`~okid_ros.core.recursive.SlidingWindowArx`); inf when the
        fill asked for is never reached.
        """
        fill, lam = self.min_window_fill, self.forgetting_factor
        if self.window_length > 0:
            rows = math.ceil(fill * self.window_length)
        elif lam >= 1.0:
            rows = 1
        elif fill >= 1.0:
            return math.inf
        else:
            rows = math.ceil(math.log1p(-fill) / math.log(lam))
        return max(rows, 1) + self.order  # a solve needs a row; each row its order lags before it

    def full_window_rows(self) -> float:
        """Regressor rows of a full window: ``window_length``, or with forgetting its effective memory 1 / (1 - lambda).

        As node 1's window reports them (:attr:`~okid_ros.core.recursive.SlidingWindowArx.status`, rounded) and node
        2 sizes its realization's window by; inf for an infinite history without forgetting.
        """
        if self.window_length > 0:
            return self.window_length
        if self.forgetting_factor >= 1.0:
            return math.inf
        return round(1.0 / (1.0 - self.forgetting_factor))

    def size_problem(self) -> str:
        """Why the regressor of ``order`` is too long for the window or the live update, or ""."""
        q, p, m = self.order, self.n_outputs, self.n_inputs
        d = regressor_length(q, p, m)
        # The core's bound on the automatic order: the window's d x d normal equations are updated
        # at every sample and solved at every publication (order 5000 with p = m = 2 meant a
        # 3.2 GB matrix, and `process` never finished).
        limit = ArxOrderOptions.max_coefficients
        if d > limit:
            return (f"arx.order {q} with {m} inputs and {p} outputs gives regressors of d = m + q (p + m) = {d} "
                    f"coefficients; at most {limit} (the window's normal equations are d x d, updated at every "
                    f"sample)")
        if m > 0 and q < 2:  # else every model would be refused, with nothing said at the start
            return (f"arx.order {q}: node 2 realizes models from an ARX order of at least 2 (its ERA Hankel needs "
                    f"two blocks of Markov parameters)")
        # Output-only (m = 0) too: a window under its 200 samples had every model refused, exit 0 (`process`).
        rows = self.full_window_rows()
        minimum = window_minimum(q, rows + q, m) if math.isfinite(rows) else 0
        if 0 < self.window_length and self.window_length + q < minimum:
            return (f"arx.window_length {self.window_length} with arx.order {q}: node 2's realization needs at least "
                    f"{minimum} samples of a window (arx.window_length at least {minimum - q})")
        if rows + q < minimum:  # forgetting: arx.forgetting_factor 0.99 at order 100 had every window refused
            lam, least = self.forgetting_factor, math.ceil((1.0 - 1.0 / (minimum - q)) * 1e5) / 1e5
            return (f"arx.forgetting_factor {lam:g} with arx.window_length 0 and arx.order {q}: the window's "
                    f"effective memory, 1 / (1 - {lam:g}) = {rows} rows, plus the order is {rows + q} samples; node "
                    f"2's realization needs at least {minimum} (arx.forgetting_factor at least {least:.5f}, or "
                    f"arx.window_length at least {minimum - q} with arx.forgetting_factor 1.0)")
        if self.regularization == "none" and 0 < self.window_length < d:
            return (f"arx.window_length {self.window_length} is smaller than the d = {d} coefficients of arx.order "
                    f"{q}: unregularized least squares (arx.regularization none) needs at least d rows")
        # numpy's zeroed buffers take memory only as samples fill them: 1e8 rows started, then failed days
        # later (or at once under ulimit -v with a message that did not name the parameter).
        shortfall = memory_shortfall(self.window_bytes())
        if shortfall:
            return (f"arx.window_length {self.window_length}: buffering the window's samples {shortfall} (estimated "
                    f"at {self.window_bytes() / self.window_length:.0f} bytes a row: the window's two-fold ring, "
                    f"node 1's replay ring and node 2's)")
        return ""

    def window_bytes(self) -> int:
        """Memory the buffers sized by a full ``window_length`` take [bytes] (0 for an infinite history).

        The sliding window's ring of twice the window of (p + m) samples with two flags each
        (:class:`~okid_ros.core.recursive.SlidingWindowArx`), node 1's ring of the samples it replays
        after a change and node 2's of the window (stamp, skipped flag, u, y: both
        :class:`~okid_ros.service.sample_buffer.SampleBuffer`; `process` runs both nodes in one process).
        """
        if self.window_length <= 0:
            return 0
        samples = self.n_inputs + self.n_outputs
        return self.window_length * (2 * (8 * samples + 2) + 2 * 8 * (2 + samples))

    @property
    def n_params(self) -> int:
        """D = m + q (p + m), coefficients per output."""
        return regressor_length(self.order, self.n_outputs, self.n_inputs)


@dataclass
class ModalEstimationParams:
    """Settings of the realization, mode tracking and estimator (ROS names in params.py)."""

    sample_time_s: float = _est("sample_time_s")
    n_inputs: int = _est("n_inputs")
    n_outputs: int = _est("n_outputs")
    n_states: int = _est("n_states")  # 0: automatic (BIC)
    max_states: int = _est("max_states")
    max_states_limit: int = _est("max_states_limit")
    gain: str = _est("gain")
    refine: bool = _est("refine")
    jackknife_segments: int = _est("jackknife_segments")  # 0: off (the live realization's budget)
    output_only_method: str = _est("output_only_method")  # with n_inputs 0
    max_damping: float = _est("max_damping")
    min_msv: float = _est("min_msv")
    max_nyquist_fraction: float = _est("max_nyquist_fraction")
    min_mpc: float = _est("min_mpc")
    min_dominance: float = _est("min_dominance")
    min_stable_fraction: float = _est("min_stable_fraction")
    offsets: str = _est("offsets")
    max_frequency_change: float = _est("max_frequency_change")
    min_mac: float = _est("min_mac")
    min_matched_fraction: float = _est("min_matched_fraction")
    max_consecutive_rejections: int = _est("max_consecutive_rejections")
    mode_memory: int = _est("mode_memory")
    buffer_length: int = _est("buffer_length")  # 0: sized from the ARX window
    max_gap_samples: int = _est("max_gap_samples")
    handover_samples: int = HANDOVER_SAMPLES
    change_detection: bool = _est("change_detection")
    change_false_alarm_samples: float = _est("change_false_alarm_samples")
    change_variance_ratio: float = _est("change_variance_ratio")
    change_reference_samples: int = _est("change_reference_samples")
    change_noise_test: bool = _est("change_noise_test")
    change_mode_confirmation: bool = _est("change_mode_confirmation")
    divergence_window_samples: int = _est("divergence_window_samples")
    divergence_nis_ratio: float = _est("divergence_nis_ratio")

    @classmethod
    def from_parameters(cls, values: Mapping[str, Any]) -> "ModalEstimationParams":
        """From the resolved node parameters (dotted names)."""
        return cls(**option_values(ESTIMATOR_NODE, values))

    def output_only_ignored(self) -> str:
        """With ``n_inputs`` 0, a sentence naming the input-output realization's parameters set off defaults, or "".

        An output-only window is realized by ``realization.output_only_method`` alone
        (:func:`~okid_ros.service.realization.identify_window`): ``realization.n_states`` 2 gave models of
        8 states, and the mode criteria did nothing, in silence.
        """
        names = self.output_only_ignored_names()
        if not names:
            return ""
        return (f"{', '.join(names)} appl{'ies' if len(names) == 1 else 'y'} to input-output realization; ignored "
                f"with n_inputs 0 (output-only: realization.output_only_method chooses the model)")

    def output_only_ignored_names(self) -> list[str]:
        """The parameters :meth:`output_only_ignored` names (none with inputs), in the table's order."""
        if self.n_inputs:
            return []
        specs = option_specs(ESTIMATOR_NODE)
        return [spec.name for field, spec in specs.items()
                if getattr(self, field) != spec.field_value(spec.default)
                and self._realization_reads(field, spec.field_value(spec.default))]

    def _realization_reads(self, field: str, other: Any) -> bool:
        """Whether :meth:`realization_options` depends on ``field``: its value and ``other`` give different options.

        Asked of the method itself, so that a parameter it comes to read is named without a list kept by hand.
        """
        def options(params: ModalEstimationParams) -> RealizationOptions | str:
            try:
                return params.realization_options()
            except ValueError as exc:  # a refusal depends on the field too when only one value has it
                return str(exc)

        return options(self) != options(replace(self, **{field: other}))

    def realization_options(self) -> RealizationOptions:
        """The core's options of the realization (:class:`okid_ros.core.options.RealizationOptions`).

        Raises ValueError with the reason, in the parameters' names, when they do not fit together.
        """
        if self.max_states_limit < self.max_states:
            # Refused, not raised to max_states: the node ran with a limit other than the one
            # it reported, and a run-time change that says it succeeded did nothing.
            specs = option_specs(ESTIMATOR_NODE)
            limit, start = specs["max_states_limit"].name, specs["max_states"].name
            raise ValueError(
                f"{limit} {self.max_states_limit} is below {start} {self.max_states}: the automatic order "
                f"search starts at {start} and may only grow up to {limit}; set {limit} >= {start} (at run "
                "time: one at a time in an order that keeps it so, or both with SetParametersAtomically)"
            )
        try:
            return RealizationOptions(
                n_states=self.n_states if self.n_states > 0 else AUTO,
                max_states=self.max_states,
                max_states_limit=self.max_states_limit,
                gain=self.gain,
                refine=self.refine,
                jackknife_segments=self.jackknife_segments,
                modes=ModeCriteria(
                    max_damping=self.max_damping, max_nyquist_fraction=self.max_nyquist_fraction,
                    min_msv=self.min_msv, min_mpc=self.min_mpc, min_dominance=self.min_dominance,
                    min_stable_fraction=self.min_stable_fraction,
                ),
            )
        except ValueError as exc:
            # The core's rules name its fields ("jackknife_segments must be 0 or at least 2"); the
            # node's user sets parameters (realization.jackknife_segments 1 passed the table's range).
            spec = option_specs(ESTIMATOR_NODE).get(str(exc).split(" ", 1)[0])
            raise ValueError(f"parameter {spec.name}: {exc}" if spec else str(exc)) from None


_NODES = {ArxIdentificationParams: ARX_NODE, ModalEstimationParams: ESTIMATOR_NODE}


def check_runtime_change(old: Any, new: Any) -> list[str]:
    """The option fields that differ between ``old`` and ``new``; ValueError if one may not change.

    What may change on a running service is what the parameter table declares ``runtime``.
    """
    allowed = runtime_fields(_NODES[type(old)])
    changed = [f.name for f in fields(old) if getattr(old, f.name) != getattr(new, f.name)]
    fixed = [name for name in changed if name not in allowed]
    if fixed:
        raise ValueError(f"{', '.join(fixed)} cannot change while the service runs (structural); reset it "
                         "with the new options instead")
    return changed

