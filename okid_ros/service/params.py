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

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from okid_ros.core.options import GAINS, OFFSETS, RealizationOptions
from okid_ros.errors import ParameterError
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
    "RUNTIME_PARAMS",
    "read_only_reason",
    "read_parameter_file",
    "validate_value",
    "resolve_parameters",
    "load_parameters",
]

# The core's defaults, defined there once.
_REALIZATION = RealizationOptions()
_MODES = _REALIZATION.modes

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
    """

    name: str
    default: Any
    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None

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
    ParamSpec("sample_time_s", 0.008, "sample time of the input/output samples (paper: 0.008 s)", "s", 1e-6, 3600.0),
    ParamSpec("n_inputs", 2, "number of inputs m (channels u0..u{m-1})", "", 1, 64),
    ParamSpec("n_outputs", 2, "number of outputs p (channels y0..y{p-1})", "", 1, 64),
    ParamSpec(
        "inputs.sources", [f"io_sample {IO_SAMPLE}"],
        "input topics, one 'KIND TOPIC [FIELD=CHANNEL ...]' string each (see okid_ros/service/inputs.py); "
        "a relative TOPIC is in the rig namespace (/okid, or the node's namespace)",
    ),
    ParamSpec("inputs.queue_depth", 1000, "subscription queue depth of each input topic (sensor-data QoS); covers stalls of the node of depth / rate seconds", "messages", 1, 100000),
    ParamSpec("inputs.stamp_tolerance", 0.25, "largest distance of a stamp from its grid slot", "sample times", 0.01, 0.49),
    ParamSpec("inputs.latency_samples", 5, "slots newer data may be ahead before an incomplete slot is dropped as missing", "samples", 0, 100000),
    ParamSpec("inputs.time_jump_s", 1.0, "a stamp this much older than the newest one is a time jump (re-anchors the grid)", "s", 1e-3, 1e6),
    ParamSpec("inputs.stale_timeout_s", 1.0, "an input with no message for this long is reported stale", "s", 1e-3, 1e6),
    ParamSpec("diagnostics_rate_hz", 1.0, "rate of the DiagnosticArray on /diagnostics", "Hz", 0.01, 100.0),
    ParamSpec("offsets", "remove", "remove: the ARX window fits the signals' offsets as an intercept and each realization removes the window's means (kept with the model, subtracted from live samples); none: raw signals", choices=OFFSETS),
    ParamSpec("reset_on_time_jump", True, "when the stamps jump back by more than inputs.time_jump_s (a looped bag, a restarted simulation), forget the window / model and start again as at the first start (false: keep them; the window then holds data from before the jump)"),
    ParamSpec("frame_id", "base_link", "frame_id of the headers of the output messages (the structure the modes belong to)"),
    ParamSpec("strict_parameters", False, "refuse to start when a parameter file sets a name this node does not declare, or has a section naming it that does not apply (false: a warning)"),
)

ARX_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("arx.order", 100, "ARX order q, past samples of y and u in each regressor (paper: 100)", "samples", 1, 5000),
    ParamSpec("arx.window_length", 4000, "regressor rows in the sliding window; 0: infinite history with arx.forgetting_factor", "samples", 0, 100_000_000),
    ParamSpec("arx.forgetting_factor", 1.0, "exponential forgetting per sample when arx.window_length is 0 (1.0: none)", "", 0.5, 1.0),
    ParamSpec("arx.regularization", "ridge", "prior of the ARX coefficients", choices=("none", "ridge", "tc")),
    ParamSpec("arx.penalty_by_gcv", True, "choose the regularization penalty (and TC decay) by generalized cross-validation at each solve"),
    ParamSpec("arx.penalty", 1.0, "regularization penalty when arx.penalty_by_gcv is false", "", 0.0, 1e15),
    ParamSpec("arx.tc_decay", 0.95, "TC kernel decay per lag when arx.regularization is tc and arx.penalty_by_gcv is false", "", 0.01, 0.9999),
    ParamSpec("arx.min_window_fill", 0.5, "window fill below which published models are marked invalid", "", 0.0, 1.0),
    ParamSpec("arx.max_condition_number", 1e12, "condition number of the column-scaled normal equations above which the window counts as unexcited (last good model kept)", "", 1.0, 1e300),
    ParamSpec("publish_rate_hz", 1.0, "rate at which ArxModel is solved and published (node clock)", "Hz", 1e-3, 1000.0),
    ParamSpec("arx_model_topic", ARX_MODEL, "output topic of okid_msgs/msg/ArxModel (relative: in the rig namespace, /okid/arx_model by default)"),
    ParamSpec("arx.restart_min_fill", 0.25, "after a structural change the window restarts at the change point, and models are valid from this fill on (instead of arx.min_window_fill) until the window is full again", "", 0.0, 1.0),
    ParamSpec("structural_change_topic", STRUCTURAL_CHANGE, "input topic of okid_msgs/msg/StructuralChange: the window restarts at each change (relative: in the rig namespace, /okid/structural_change by default)"),
)

ESTIMATOR_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("arx_model_topic", ARX_MODEL, "input topic of okid_msgs/msg/ArxModel (relative: in the rig namespace, /okid/arx_model by default)"),
    ParamSpec("state_space_model_topic", STATE_SPACE_MODEL, "output topic of okid_msgs/msg/StateSpaceModel (relative: in the rig namespace, /okid/state_space_model by default)"),
    ParamSpec("modal_states_topic", MODAL_STATES, "output topic of okid_msgs/msg/ModalStates (relative: in the rig namespace, /okid/modal_states by default)"),
    ParamSpec("realization.n_states", 0, "model order n of the ERA realization; 0: lowest BIC over the orders up to realization.max_states", "states", 0, 400),
    ParamSpec("realization.max_states", _REALIZATION.max_states, "largest order tried first when realization.n_states is 0; while BIC is lowest there the search doubles it, up to realization.max_states_limit", "states", 2, 400),
    ParamSpec("realization.max_states_limit", _REALIZATION.max_states_limit, "hard upper limit of the automatic order search (reaching it is reported in the diagnostics)", "states", 2, 1000),
    ParamSpec("realization.refine", True, "finish each realization with the prediction-error refinement of the core (skipped for large models)"),
    ParamSpec("realization.worker", "process", "where realizations run: a worker process (never competes with the per-sample path for the interpreter lock) or a thread", choices=("process", "thread")),
    ParamSpec("realization.gain", _REALIZATION.gain, "estimator gain: refit (least squares where the predictor is stable by construction, else the Riccati gain), riccati (always the Kalman gain of the Riccati equation on the residual covariances) or whitening (the paper's)", choices=GAINS),
    ParamSpec("modes.max_damping", _MODES.max_damping, "largest damping ratio of a physical mode", "", 1e-6, 1.0),
    ParamSpec("modes.min_msv", _MODES.min_msv, "smallest relative modal singular value of a physical mode", "", 0.0, 1.0),
    ParamSpec("modes.max_nyquist_fraction", _MODES.max_nyquist_fraction, "physical modes lie below this fraction of the Nyquist frequency", "", 0.01, 1.0),
    ParamSpec("modes.min_mpc", _MODES.min_mpc, "smallest modal phase collinearity of a physical mode (with 3 or more outputs)", "", 0.0, 1.0),
    ParamSpec("modes.min_stable_fraction", _MODES.min_stable_fraction, "a physical mode is found in at least this fraction of the neighbouring model orders (stabilization; 0: off)", "", 0.0, 1.0),
    ParamSpec("tracking.max_frequency_change", 0.05, "relative frequency change up to which a mode keeps its id", "", 1e-6, 1.0),
    ParamSpec("tracking.min_mac", 0.7, "smallest MAC of the shapes for a mode to keep its id", "", 0.0, 1.0),
    ParamSpec("tracking.min_matched_fraction", 0.5, "a new model is rejected if fewer than this fraction of the current model's modes are found in it", "", 0.0, 1.0),
    ParamSpec("tracking.max_consecutive_rejections", 3, "after this many models rejected in a row for lost modes the next stable one is accepted (0: never)", "models", 0, 1_000_000),
    ParamSpec("tracking.mode_memory", 10, "model updates a mode that disappeared keeps its id for", "models", 0, 1_000_000),
    ParamSpec("estimator.buffer_length", 0, "samples kept for realization and warm start; 0: ARX window + order + 10 %", "samples", 0, 100_000_000),
    ParamSpec("estimator.max_gap_samples", 10, "missing samples the estimator bridges by prediction; a longer gap restarts it", "samples", 0, 1_000_000),
    ParamSpec("estimator.divergence_window_samples", 25, "samples of the moving mean of the normalized innovation squared that detects divergence, and samples of divergence in a row that restart the estimator from the buffer", "samples", 1, 100_000),
    ParamSpec("estimator.divergence_nis_ratio", 100.0, "the estimator diverged when the moving mean of the normalized innovation squared exceeds this many times its expectation p (or an innovation is not finite); diverged samples are not published", "", 2.0, 1e12),
    ParamSpec("change.enabled", True, "detect structural changes from the innovations of a reference model (CUSUM, see okid_ros/core/change_detection.py)"),
    ParamSpec("change.false_alarm_samples", 1e7, "expected number of samples between false alarms of the change test on a stationary structure (sets the CUSUM threshold)", "samples", 100.0, 1e15),
    ParamSpec("change.variance_ratio", 1.5, "increase of the innovation covariance the CUSUM is tuned to; increases above ratio ln(ratio) / (ratio - 1) are detected", "", 1.01, 100.0),
    ParamSpec("change.reference_samples", 1000, "samples after each new reference model that calibrate the change test (no detection meanwhile)", "samples", 100, 10_000_000),
    ParamSpec("structural_change_topic", STRUCTURAL_CHANGE, "output topic of okid_msgs/msg/StructuralChange (relative: in the rig namespace, /okid/structural_change by default)"),
)


#: Parameters that may change while the node runs (``ros2 param set``, the SetParameters
#: service), checked like at the start. All others are read-only: see :func:`read_only_reason`.
RUNTIME_PARAMS: frozenset[str] = frozenset({
    "diagnostics_rate_hz", "reset_on_time_jump", "frame_id",
    "inputs.stamp_tolerance", "inputs.latency_samples", "inputs.time_jump_s", "inputs.stale_timeout_s",
    # node 1: the solve of each window
    "publish_rate_hz", "arx.regularization", "arx.penalty_by_gcv", "arx.penalty", "arx.tc_decay",
    "arx.min_window_fill", "arx.max_condition_number",
    # node 2: the next realization, mode filters and tracking
    "realization.n_states", "realization.max_states", "realization.max_states_limit", "realization.refine",
    "realization.gain", "modes.max_damping", "modes.min_msv", "modes.max_nyquist_fraction", "modes.min_mpc",
    "modes.min_stable_fraction",
    # node 1: the restart after a change; node 2: the change test and the divergence watchdog
    "arx.restart_min_fill", "change.enabled", "change.false_alarm_samples", "change.variance_ratio",
    "estimator.divergence_nis_ratio",
    "tracking.max_frequency_change", "tracking.min_mac", "tracking.min_matched_fraction",
    "tracking.max_consecutive_rejections", "tracking.mode_memory", "estimator.max_gap_samples",
})


def read_only_reason(name: str) -> str:
    """Why a parameter cannot change while the node runs ('' when it can)."""
    if name in RUNTIME_PARAMS:
        return ""
    if name in ("sample_time_s", "n_inputs", "n_outputs", "arx.order", "arx.window_length",
                "arx.forgetting_factor", "estimator.buffer_length"):
        return "structural: it sizes the window, the buffers and the model; restart the node to change it"
    if name.endswith("_topic") or name in ("inputs.sources", "inputs.queue_depth"):
        return "the subscriptions and publishers are created at the start; restart the node to change it"
    if name == "realization.worker":
        return "the worker is started with the node; restart the node to change it"
    return "read at the start only; restart the node to change it"


def node_params(node: str) -> tuple[ParamSpec, ...]:
    """All parameters of a node: the shared ones, then its own."""
    if node == ARX_NODE:
        return SHARED_PARAMS + ARX_PARAMS
    if node == ESTIMATOR_NODE:
        return SHARED_PARAMS + ESTIMATOR_PARAMS
    raise ValueError(f"unknown node {node!r}; nodes are {ARX_NODE}, {ESTIMATOR_NODE}")


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
        raise ParameterError(f"{path}: {exc}") from None
