"""Parameters of both nodes: one declaration each (name, default, unit, range, meaning).

The nodes declare their ROS parameters from these specifications (descriptors with ranges),
and the offline tools (``okid-ros process``) read the same YAML file through
:func:`load_parameters`, so that a parameter means the same thing live and offline.

YAML layout (``config/okid.yaml``)::

    /**:                          # parameters shared by both nodes
      ros__parameters:
        sample_time_s: 0.008
        inputs:
          sources: ["io_sample /okid/io_sample"]
    okid_arx_identifier:
      ros__parameters:
        arx:
          order: 100
    okid_modal_estimator:
      ros__parameters:
        realization:
          n_states: 0

Nested keys become dotted names (``arx.order``). A node-specific value overrides a ``/**`` one.
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from okid_ros.core.divergence import DivergenceMonitor
from okid_ros.core.modal import match_modes
from okid_ros.core.options import (
    DEFAULT_FALSE_ALARM_SAMPLES,
    DEFAULT_REFERENCE_SAMPLES,
    DEFAULT_VARIANCE_RATIO,
    GAINS,
    MAX_GAP_SAMPLES,
    OFFSETS,
    OUTPUT_ONLY_METHODS,
    SAMPLE_TIME_RANGE_S,
    RealizationOptions,
)
from okid_ros.errors import ParameterError, shown_path
from okid_ros.service.param_files import node_fqn, node_values_from_tree, read_parameter_file
from okid_ros.service.topics import ARX_MODEL, IO_SAMPLE, MODAL_STATES, STATE_SPACE_MODEL, STRUCTURAL_CHANGE

__all__ = [
    "ARX_NODE",
    "ESTIMATOR_NODE",
    "ParamSpec",
    "SHARED_PARAMS",
    "ARX_PARAMS",
    "ESTIMATOR_PARAMS",
    "node_params",
    "default_value",
    "RUNTIME_PARAMS",
    "read_only_reason",
    "option_specs",
    "option_values",
    "runtime_fields",
    "read_parameter_file",
    "validate_value",
    "resolve_parameters",
    "load_parameters",
]

# The core's defaults, defined there once.
_REALIZATION = RealizationOptions()
_MODES = _REALIZATION.modes


def _keyword_default(function: Callable, name: str) -> Any:
    """The default of keyword ``name`` of a core function (defined there, not copied here)."""
    return inspect.signature(function).parameters[name].default


_MATCH_FREQUENCY = _keyword_default(match_modes, "max_frequency_change")
_MATCH_MAC = _keyword_default(match_modes, "min_mac")
_DIVERGENCE_WINDOW = _keyword_default(DivergenceMonitor, "window_samples")
_DIVERGENCE_RATIO = _keyword_default(DivergenceMonitor, "nis_ratio")

#: Why a parameter is read at the start only (``ParamSpec.fixed``; the default: ``AT_START``).
SIZES = "structural: it sizes the window, the buffers and the model; restart the node to change it"
WIRING = "the subscriptions and publishers are created at the start; restart the node to change it"
WORKER = "the worker and the node's threads are started with the node; restart the node to change it"
AT_START = "read at the start only; restart the node to change it"


def _period(rate_hz: float) -> float:
    return 1.0 / float(rate_hz)

ARX_NODE = "okid_arx_identifier"
ESTIMATOR_NODE = "okid_modal_estimator"


@dataclass(frozen=True)
class ParamSpec:
    """One parameter.

    Attributes
    ----------
    name : dotted name, e.g. ``arx.order``.
    default : bool, int, float, str or list of str (its type is the parameter's type).
    description : meaning, one sentence.
    unit : physical unit ('' for none).
    low, high : inclusive range of a number (None: unbounded on that side).
    choices : allowed values of a string parameter.
    field : the field of the node's service options (:mod:`okid_ros.service.options`) that
        takes the value ('' when the service does not use it: the node itself does).
    runtime : may change while the node runs (the service applies it at once).
    fixed : why it may not (when not ``runtime``), for the refusal of a run-time change.
    convert : value -> field value when they differ (``publish_rate_hz`` -> a period).
    """

    name: str
    default: Any
    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    field: str = ""
    runtime: bool = False
    fixed: str = ""
    convert: Callable[[Any], Any] | None = None

    def field_value(self, value: Any) -> Any:
        """The service option's value for the parameter value ``value``."""
        return self.convert(value) if self.convert is not None else value

    @property
    def kind(self) -> type:
        if isinstance(self.default, bool):
            return bool
        if isinstance(self.default, list):
            return list
        return type(self.default)

    def range_text(self) -> str:
        """'[1, 2000]', 'one of none, ridge, tc', or '' when anything of the type goes."""
        if self.choices:
            return "one of " + ", ".join(self.choices)
        if self.low is None and self.high is None:
            return ""
        lo = "-inf" if self.low is None else _fmt(self.low)
        hi = "inf" if self.high is None else _fmt(self.high)
        return f"[{lo}, {hi}]"

    def full_description(self) -> str:
        """Description with unit, range and default, for ROS descriptors and --help texts."""
        text = self.description
        if self.unit:
            text += f" [{self.unit}]"
        if self.range_text():
            text += f"; valid: {self.range_text()}"
        return text + f"; default: {self.default!r}"


def _fmt(x: float) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


# Shared by both nodes (YAML section "/**").
SHARED_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("sample_time_s", 0.008, "sample time of the input/output samples (paper: 0.008 s)", "s", *SAMPLE_TIME_RANGE_S, field="sample_time_s", fixed=SIZES),
    ParamSpec("n_inputs", 2, "number of inputs m (channels u0..u{m-1}); 0: output-only (ambient) identification from the outputs alone", "", 0, 64, field="n_inputs", fixed=SIZES),
    ParamSpec("n_outputs", 2, "number of outputs p (channels y0..y{p-1})", "", 1, 64, field="n_outputs", fixed=SIZES),
    ParamSpec(
        "inputs.sources", [f"io_sample {IO_SAMPLE}"],
        "input topics, one 'KIND TOPIC [FIELD=CHANNEL ...]' string each (see okid_ros/service/inputs.py); "
        "a relative TOPIC is in the rig namespace (/okid, or the node's namespace)", fixed=WIRING,
    ),
    ParamSpec("inputs.queue_depth", 1000, "subscription queue depth of each input topic (sensor-data QoS); covers stalls of the node of depth / rate seconds", "messages", 1, 100000, fixed=WIRING),
    ParamSpec("inputs.stamp_tolerance", 0.25, "largest distance of a stamp from its grid slot", "sample times", 0.01, 0.49, runtime=True),
    ParamSpec("inputs.latency_samples", 5, "slots newer data may be ahead before an incomplete slot is dropped as missing", "samples", 0, 100000, runtime=True),
    ParamSpec("inputs.time_jump_s", 1.0, "a stamp more than this before the newest one is a time jump (re-anchors the grid), more than this after it a step forward (a gap); never less than inputs.latency_samples + 2 sample times (a lower value is raised to that, with a warning)", "s", 1e-3, 1e6, runtime=True),
    ParamSpec("inputs.stale_timeout_s", 1.0, "an input with no message for this long is reported stale", "s", 1e-3, 1e6, runtime=True),
    ParamSpec("diagnostics_rate_hz", 1.0, "rate of the DiagnosticArray on /diagnostics", "Hz", 0.01, 100.0, runtime=True),
    ParamSpec("offsets", "remove", "remove: the ARX window fits the signals' offsets as an intercept and each realization removes the window's means (kept with the model, subtracted from live samples); none: raw signals", choices=OFFSETS, field="offsets"),
    ParamSpec("reset_on_time_jump", True, "when the stamps jump back by more than inputs.time_jump_s (at least inputs.latency_samples + 2 sample times; a looped bag, a restarted simulation), forget the window / model and start again as at the first start (false: keep them; the window then holds data from before the jump)", runtime=True),
    ParamSpec("frame_id", "base_link", "frame_id of the headers of the output messages (the structure the modes belong to)", runtime=True),
    ParamSpec("strict_parameters", False, "refuse to start when a parameter file sets a name this node does not declare, or has a section naming it that does not apply (false: a warning)"),
)

ARX_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("arx.order", 100, "ARX order q, past samples of y and u in each regressor (paper: 100)", "samples", 1, 5000, field="order", fixed=SIZES),
    ParamSpec("arx.window_length", 4000, "regressor rows in the sliding window; 0: infinite history with arx.forgetting_factor", "samples", 0, 100_000_000, field="window_length", fixed=SIZES),
    ParamSpec("arx.forgetting_factor", 1.0, "exponential forgetting per sample when arx.window_length is 0 (1.0: none)", "", 0.5, 1.0, field="forgetting_factor", fixed=SIZES),
    ParamSpec("arx.regularization", "ridge", "prior of the ARX coefficients", choices=("none", "ridge", "tc"), field="regularization", runtime=True),
    ParamSpec("arx.penalty_by_gcv", True, "choose the regularization penalty (and TC decay) by generalized cross-validation at each solve", field="penalty_by_gcv", runtime=True),
    ParamSpec("arx.penalty", 1.0, "regularization penalty when arx.penalty_by_gcv is false", "", 0.0, 1e15, field="penalty", runtime=True),
    ParamSpec("arx.tc_decay", 0.95, "TC kernel decay per lag when arx.regularization is tc and arx.penalty_by_gcv is false", "", 0.01, 0.9999, field="tc_decay", runtime=True),
    ParamSpec("arx.min_window_fill", 0.5, "window fill below which published models are marked invalid", "", 0.0, 1.0, field="min_window_fill", runtime=True),
    ParamSpec("arx.max_condition_number", 1e12, "condition number of the column-scaled normal equations above which the window counts as unexcited (last good model kept) when its inputs' columns exceed it too, an output is dead, no input varies, or one varies in part of the window only (an input silent over the whole window is left out, its effect zero, as identify and track leave it out; only the outputs' lags collinear: a response far above its noise, identified)", "", 1.0, 1e300, field="max_condition_number", runtime=True),
    ParamSpec("publish_rate_hz", 1.0, "rate at which ArxModel is solved and published (node clock)", "Hz", 1e-3, 1000.0, field="publish_period_s", runtime=True, convert=_period),
    ParamSpec("arx_model_topic", ARX_MODEL, "output topic of okid_msgs/msg/ArxModel (relative: in the rig namespace, /okid/arx_model by default)", fixed=WIRING),
    ParamSpec("arx.restart_min_fill", 0.25, "after a structural change the window restarts at the change point, and models are valid from this fill on (instead of arx.min_window_fill) until the window is full again", "", 0.0, 1.0, field="restart_min_fill", runtime=True),
    ParamSpec("structural_change_topic", STRUCTURAL_CHANGE, "input topic of okid_msgs/msg/StructuralChange: the window restarts at each change (relative: in the rig namespace, /okid/structural_change by default)", fixed=WIRING),
)

ESTIMATOR_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("arx_model_topic", ARX_MODEL, "input topic of okid_msgs/msg/ArxModel (relative: in the rig namespace, /okid/arx_model by default)", fixed=WIRING),
    ParamSpec("state_space_model_topic", STATE_SPACE_MODEL, "output topic of okid_msgs/msg/StateSpaceModel (relative: in the rig namespace, /okid/state_space_model by default)", fixed=WIRING),
    ParamSpec("modal_states_topic", MODAL_STATES, "output topic of okid_msgs/msg/ModalStates (relative: in the rig namespace, /okid/modal_states by default)", fixed=WIRING),
    ParamSpec("realization.n_states", 0, "model order n of the ERA realization; 0: lowest BIC over the orders up to realization.max_states", "states", 0, 400, field="n_states", runtime=True),
    ParamSpec("realization.max_states", _REALIZATION.max_states, "largest order tried first when realization.n_states is 0; while BIC is lowest there the search doubles it, up to realization.max_states_limit", "states", 2, 400, field="max_states", runtime=True),
    ParamSpec("realization.max_states_limit", _REALIZATION.max_states_limit, "hard upper limit of the automatic order search, at least realization.max_states (reaching it is reported in the diagnostics)", "states", 2, 1000, field="max_states_limit", runtime=True),
    ParamSpec("realization.refine", True, "finish each realization with the prediction-error refinement of the core (skipped for large models)", field="refine", runtime=True),
    ParamSpec("realization.jackknife_segments", 0, "modes' standard deviations where the prediction-error covariance is out of reach (tens of outputs): a jackknife over this many segments of the window (8 as identify and track do; it adds about 60 % to each realization at 28 outputs); 0: left NaN, or at least 2", "segments", 0, 64, field="jackknife_segments", runtime=True),
    ParamSpec("realtime_priority", 0, "SCHED_FIFO priority of the node's own threads (samples, executor, DDS), not of the realization worker: at 1 kHz on a loaded machine they then get a core first (needs CAP_SYS_NICE or ulimit -r; refused: a warning, ordinary scheduling); 0: ordinary scheduling", "", 0, 99, fixed=WORKER),
    ParamSpec("realization.worker", "process", "where realizations run: a worker process (never competes with the per-sample path for the interpreter lock) or a thread", choices=("process", "thread"), fixed=WORKER),
    ParamSpec("realization.gain", _REALIZATION.gain, "estimator gain: refit (least squares where the predictor is stable by construction, else the Riccati gain), riccati (always the Kalman gain of the Riccati equation on the residual covariances) or whitening (the paper's)", choices=GAINS, field="gain", runtime=True),
    ParamSpec("realization.output_only_method", OUTPUT_ONLY_METHODS[0], "with n_inputs 0 (output-only): how each window's model is realized from its outputs: ssi-cva (covariance-driven SSI with a canonical-variate weighting, the measured winner), ssi-cov (unweighted NExT-ERA: up to 4 times faster on long lag windows, fewer modes found) or var (a vector AR and the OKID recursion, the paper's route); docs/benchmarks-output-only.md; see okid_ros/core/output_only.py", choices=OUTPUT_ONLY_METHODS, field="output_only_method", runtime=True),
    ParamSpec("modes.max_damping", _MODES.max_damping, "largest damping ratio of a physical mode", "", 1e-6, 1.0, field="max_damping", runtime=True),
    ParamSpec("modes.min_msv", _MODES.min_msv, "smallest relative modal singular value of a physical mode", "", 0.0, 1.0, field="min_msv", runtime=True),
    ParamSpec("modes.max_nyquist_fraction", _MODES.max_nyquist_fraction, "physical modes lie below this fraction of the Nyquist frequency", "", 0.01, 1.0, field="max_nyquist_fraction", runtime=True),
    ParamSpec("modes.min_mpc", _MODES.min_mpc, "smallest modal phase collinearity of a physical mode (with 3 or more outputs)", "", 0.0, 1.0, field="min_mpc", runtime=True),
    ParamSpec("modes.min_dominance", _MODES.min_dominance, "smallest share of the model's frequency response at a physical mode's frequency that its pole pair makes up, along its shape (input-output models)", "", 0.0, 1.0, field="min_dominance", runtime=True),
    ParamSpec("modes.min_stable_fraction", _MODES.min_stable_fraction, "a physical mode is found in at least this fraction of the neighbouring model orders (stabilization; 0: off)", "", 0.0, 1.0, field="min_stable_fraction", runtime=True),
    ParamSpec("tracking.max_frequency_change", _MATCH_FREQUENCY, "relative frequency change up to which a mode keeps its id", "", 1e-6, 1.0, field="max_frequency_change", runtime=True),
    ParamSpec("tracking.min_mac", _MATCH_MAC, "smallest MAC of the shapes for a mode to keep its id", "", 0.0, 1.0, field="min_mac", runtime=True),
    ParamSpec("tracking.min_matched_fraction", 0.5, "a new model is rejected if fewer than this fraction of the current model's modes are found in it", "", 0.0, 1.0, field="min_matched_fraction", runtime=True),
    ParamSpec("tracking.max_consecutive_rejections", 3, "after this many models rejected in a row for lost modes the next stable one is accepted (0: never)", "models", 0, 1_000_000, field="max_consecutive_rejections", runtime=True),
    ParamSpec("tracking.mode_memory", 10, "model updates a mode that disappeared keeps its id for", "models", 0, 1_000_000, field="mode_memory", runtime=True),
    ParamSpec("estimator.buffer_length", 0, "samples kept for realization and warm start; 0: ARX window + order + 10 %", "samples", 0, 100_000_000, field="buffer_length", fixed=SIZES),
    ParamSpec("estimator.max_gap_samples", MAX_GAP_SAMPLES, "missing samples the estimator bridges by prediction; a longer gap restarts it", "samples", 0, 1_000_000, field="max_gap_samples", runtime=True),
    ParamSpec("estimator.divergence_window_samples", _DIVERGENCE_WINDOW, "samples of the moving mean of the normalized innovation squared that detects divergence, and samples of divergence in a row that restart the estimator from the buffer", "samples", 1, 100_000, field="divergence_window_samples"),
    ParamSpec("estimator.divergence_nis_ratio", _DIVERGENCE_RATIO, "the estimator diverged when the moving mean of the normalized innovation squared exceeds this many times its expectation p (or an innovation is not finite); diverged samples are not published", "", 2.0, 1e12, field="divergence_nis_ratio", runtime=True),
    ParamSpec("change.enabled", True, "detect structural changes from the innovations of a reference model (CUSUM, see okid_ros/core/change_detection.py)", field="change_detection", runtime=True),
    ParamSpec("change.false_alarm_samples", DEFAULT_FALSE_ALARM_SAMPLES, "expected number of samples between false alarms of the change test on a stationary structure (sets the CUSUM threshold)", "samples", 100.0, 1e15, field="change_false_alarm_samples", runtime=True),
    ParamSpec("change.variance_ratio", DEFAULT_VARIANCE_RATIO, "increase of the innovation covariance the CUSUM is tuned to; increases above ratio ln(ratio) / (ratio - 1) are detected", "", 1.01, 100.0, field="change_variance_ratio", runtime=True),
    ParamSpec("change.noise_test", True, "judge an alarm that no jump of the state explains as a change of the noise model (the unmeasured excitation louder or quieter against the sensor noise, core/noise_change.py) before declaring it; false: a change is declared ~250 samples sooner, and so is every such change of the excitation", field="change_noise_test"),
    ParamSpec("change.mode_confirmation", True, "hold an output-only reference's alarm that no jump of the state or noise change explains until the modes of the samples after it are identified (core/mode_confirmation.py): declared when a mode moved beyond its jackknife uncertainty, else a change of the ambient excitation; false: declared at once, and so is every such change of the excitation", field="change_mode_confirmation"),
    ParamSpec("change.reference_samples", DEFAULT_REFERENCE_SAMPLES, "samples after each new reference model that calibrate the change test (no detection meanwhile)", "samples", 100, 10_000_000, field="change_reference_samples"),
    ParamSpec("structural_change_topic", STRUCTURAL_CHANGE, "output topic of okid_msgs/msg/StructuralChange (relative: in the rig namespace, /okid/structural_change by default)", fixed=WIRING),
)


#: Parameters that may change while the node runs (``ros2 param set``, the SetParameters
#: service), checked like at the start: those declared ``runtime`` in the tables above, the one
#: rule. All others are read-only: see :func:`read_only_reason`.
RUNTIME_PARAMS: frozenset[str] = frozenset(
    spec.name for spec in SHARED_PARAMS + ARX_PARAMS + ESTIMATOR_PARAMS if spec.runtime)

_SPECS: dict[str, ParamSpec] = {spec.name: spec for spec in SHARED_PARAMS + ARX_PARAMS + ESTIMATOR_PARAMS}


def read_only_reason(name: str) -> str:
    """Why a parameter cannot change while the node runs ('' when it can)."""
    spec = _SPECS.get(name)
    if spec is None:
        return AT_START
    return "" if spec.runtime else spec.fixed or AT_START


def node_params(node: str) -> tuple[ParamSpec, ...]:
    """All parameters of a node: the shared ones, then its own."""
    if node == ARX_NODE:
        return SHARED_PARAMS + ARX_PARAMS
    if node == ESTIMATOR_NODE:
        return SHARED_PARAMS + ESTIMATOR_PARAMS
    raise ValueError(f"unknown node {node!r}; nodes are {ARX_NODE}, {ESTIMATOR_NODE}")


def default_value(node: str, name: str) -> Any:
    """The default of ``node``'s parameter ``name`` (KeyError for a name it does not declare)."""
    return {s.name: s for s in node_params(node)}[name].default


def option_specs(node: str) -> dict[str, ParamSpec]:
    """Service option field -> its parameter, for the parameters of ``node`` a service takes."""
    return {spec.field: spec for spec in node_params(node) if spec.field}


def runtime_fields(node: str) -> frozenset[str]:
    """The service option fields of ``node`` that may change while it runs."""
    return frozenset(field for field, spec in option_specs(node).items() if spec.runtime)


def option_values(node: str, values: Mapping[str, Any]) -> dict[str, Any]:
    """Service option field -> value, from resolved parameters (dotted names) of ``node``."""
    return {field: spec.field_value(values[spec.name]) for field, spec in option_specs(node).items()}


def validate_value(spec: ParamSpec, value: Any) -> Any:
    """Return ``value`` converted to the parameter's type, or raise ParameterError naming it.

    Integers are accepted for float parameters; nothing else is converted.
    """
    kind = spec.kind
    where = f"parameter {spec.name}"
    if kind is bool:
        if not isinstance(value, bool):
            raise ParameterError(f"{where} must be true or false, got {value!r}")
        return value
    if kind is list:
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise ParameterError(f"{where} must be a list of strings, got {value!r}")
        return [str(v) for v in value]
    if kind is str:
        if not isinstance(value, str):
            raise ParameterError(f"{where} must be a string, got {value!r}")
        if spec.choices and value not in spec.choices:
            raise ParameterError(f"{where} = {value!r} is not valid; valid: {spec.range_text()}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{where} must be a number, got {value!r}")
    if kind is int:
        if isinstance(value, float):
            if not value.is_integer():
                raise ParameterError(f"{where} must be an integer, got {value!r}")
            value = int(value)
    else:
        value = float(value)
        if not math.isfinite(value):
            raise ParameterError(f"{where} = {value!r} is not valid; valid range {spec.range_text()} {spec.unit}".rstrip())
    if (spec.low is not None and value < spec.low) or (spec.high is not None and value > spec.high):
        unit = f" {spec.unit}" if spec.unit else ""
        raise ParameterError(f"{where} = {value!r} is out of range; valid range {spec.range_text()}{unit}")
    return value


def rcl_type_problem(spec: ParamSpec, value: Any) -> str:
    """Why the nodes refuse ``value`` for ``spec`` although :func:`validate_value` converts it, or "".

    rclpy's typed parameters take no integer for a floating-point parameter and no floating-point
    number for an integer one (the node does not start); the offline path converts both.
    """
    if spec.kind is float and isinstance(value, int) and not isinstance(value, bool):
        return (f"is an integer: the nodes refuse it for a floating-point parameter and do not start "
                f"(write {float(value)!r})")
    if spec.kind is int and isinstance(value, float):
        return "is a floating-point number: the nodes refuse it for an integer parameter and do not start"
    return ""


def resolve_parameters(node: str, values: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Defaults of ``node`` overridden by ``values`` (dotted names), validated.

    Raises ParameterError for an unknown name or a bad value.
    """
    specs = {s.name: s for s in node_params(node)}
    values = dict(values or {})
    unknown = sorted(set(values) - set(specs))
    if unknown:
        raise ParameterError(f"unknown parameter(s) for {node}: {', '.join(unknown)}")
    return {name: validate_value(spec, values.get(name, spec.default)) for name, spec in specs.items()}


def load_parameters(path: str | Path, node: str, strict: bool = False, namespace: str | None = None) -> dict[str, Any]:
    """Read a ROS parameter YAML file the way the node would and return its resolved parameters.

    The sections that apply to the node ``NAMESPACE/NODE`` as rcl matches them (``/**``,
    ``/**/NODE``, ``NODE`` in the root namespace, ...; :mod:`okid_ros.service.param_files`) are
    merged, wildcard sections first; parameters that do not belong to ``node`` are ignored
    unless ``strict``.

    Raises
    ------
    ParameterError on an unreadable file or an invalid value (the message names the file).
    """
    tree = read_parameter_file(path)
    merged = node_values_from_tree(tree, node_fqn(node, namespace))
    known = {s.name for s in node_params(node)}
    if not strict:
        merged = {k: v for k, v in merged.items() if k in known and k != "use_sim_time"}
    try:
        return resolve_parameters(node, merged)
    except ParameterError as exc:
        raise ParameterError(f"{shown_path(path)}: {exc}") from None
