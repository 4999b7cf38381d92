"""okid_ros/service/options.py and the parameter table: one default and one run-time rule each."""

from __future__ import annotations

import dataclasses
import math
import re

import pytest
from ros_helpers import REPO_ROOT

from okid_ros.core.change_detection import DEFAULT_FALSE_ALARM_SAMPLES, DivergenceMonitor
from okid_ros.core.options import RealizationOptions
from okid_ros.errors import ParameterError
from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams, check_runtime_change
from okid_ros.service.params import (
    ARX_NODE,
    ESTIMATOR_NODE,
    RUNTIME_PARAMS,
    load_parameters,
    node_params,
    option_specs,
    read_only_reason,
    resolve_parameters,
)

CONFIG = REPO_ROOT / "config" / "okid.yaml"
OPTIONS = {ARX_NODE: ArxIdentificationParams, ESTIMATOR_NODE: ModalEstimationParams}


@pytest.mark.parametrize("node", [ARX_NODE, ESTIMATOR_NODE])
def test_every_default_is_the_same_in_the_table_the_options_and_okid_yaml(node):
    # Every parameter is listed in okid.yaml (test_nodes_config.py); the values it gives:
    listed = load_parameters(CONFIG, node)
    options = OPTIONS[node]()
    specs = option_specs(node)
    for spec in node_params(node):
        assert listed[spec.name] == spec.default, f"{spec.name}: okid.yaml {listed[spec.name]!r}"
        if spec.field:
            value = getattr(options, spec.field)
            assert value == spec.field_value(spec.default), f"{spec.name}: option {spec.field} = {value!r}"
            assert type(value) is type(spec.field_value(spec.default))
    # Every option field but the internal hand-over count comes from a parameter.
    assert {f.name for f in dataclasses.fields(options)} - set(specs) <= {"handover_samples"}
    # The options built from the file's values are the default options.
    assert OPTIONS[node].from_parameters(resolve_parameters(node, {})) == options


def test_defaults_the_core_defines_are_the_cores():
    est = ModalEstimationParams()
    core = RealizationOptions()
    assert (est.max_states, est.gain, est.min_msv) == (core.max_states, core.gain, core.modes.min_msv)
    assert est.change_false_alarm_samples == DEFAULT_FALSE_ALARM_SAMPLES
    import inspect

    signature = inspect.signature(DivergenceMonitor).parameters
    assert est.divergence_nis_ratio == signature["nis_ratio"].default
    assert est.divergence_window_samples == signature["window_samples"].default


def test_the_runtime_list_and_the_read_only_reasons_come_from_the_table():
    for node in (ARX_NODE, ESTIMATOR_NODE):
        for spec in node_params(node):
            assert (spec.name in RUNTIME_PARAMS) == spec.runtime
            assert bool(read_only_reason(spec.name)) == (not spec.runtime), spec.name
    assert "structural" in read_only_reason("arx.order")
    assert "subscriptions" in read_only_reason("inputs.sources")
    assert "worker" in read_only_reason("realization.worker")
    # The six that used to wait for a reset, and the gain that used to be refused.
    for name in ("tracking.max_frequency_change", "tracking.min_mac", "tracking.mode_memory",
                 "change.false_alarm_samples", "change.variance_ratio", "estimator.divergence_nis_ratio",
                 "realization.gain"):
        assert name in RUNTIME_PARAMS


def test_a_structural_option_may_not_change_on_a_running_service():
    old = ModalEstimationParams()
    assert check_runtime_change(old, dataclasses.replace(old, min_mac=0.9, gain="riccati")) == ["gain", "min_mac"]
    with pytest.raises(ValueError, match="buffer_length"):
        check_runtime_change(old, dataclasses.replace(old, buffer_length=100))
    arx = ArxIdentificationParams()
    with pytest.raises(ValueError, match="order"):
        check_runtime_change(arx, dataclasses.replace(arx, order=10))
    assert check_runtime_change(arx, dataclasses.replace(arx, publish_period_s=0.5)) == ["publish_period_s"]


def test_a_limit_of_the_order_search_below_its_start_is_refused_with_both_names():
    # It was raised to realization.max_states without a word: node 2 started, and took the value
    # at run time, while it searched up to another limit than the one it reported.
    values = resolve_parameters(ESTIMATOR_NODE, {"realization.max_states": 40, "realization.max_states_limit": 10})
    with pytest.raises(ValueError, match=r"realization\.max_states_limit 10 is below realization\.max_states 40"):
        ModalEstimationParams.from_parameters(values).realization_options()
    equal = ModalEstimationParams(max_states=40, max_states_limit=40).realization_options()
    assert (equal.max_states, equal.max_states_limit) == (40, 40)


def test_the_jackknife_is_off_in_the_windowed_service_and_passed_on_when_asked():
    # The live realization's budget (docs/benchmarks-uncertainty.md): identify's core default is 8.
    assert ModalEstimationParams().realization_options().jackknife_segments == 0
    assert RealizationOptions().jackknife_segments == 8
    values = resolve_parameters(ESTIMATOR_NODE, {"realization.jackknife_segments": 8})
    assert ModalEstimationParams.from_parameters(values).realization_options().jackknife_segments == 8
    one = resolve_parameters(ESTIMATOR_NODE, {"realization.jackknife_segments": 1})
    with pytest.raises(ValueError, match="jackknife_segments must be 0 or at least 2"):
        ModalEstimationParams.from_parameters(one).realization_options()


def test_a_core_rule_the_parameter_table_lets_through_names_the_parameter():
    """``process --param realization.jackknife_segments=1`` said only "jackknife_segments must be ..."."""
    one = resolve_parameters(ESTIMATOR_NODE, {"realization.jackknife_segments": 1})
    with pytest.raises(ValueError, match=r"^parameter realization\.jackknife_segments: .* 0 or at least 2, got 1"):
        ModalEstimationParams.from_parameters(one).realization_options()


@pytest.mark.parametrize("values, text", [
    ({"arx.order": 5000}, "d = m + q (p + m) = 20002 coefficients; at most 2500"),
    ({"arx.order": 150, "arx.regularization": "none", "arx.window_length": 500},
     "arx.window_length 500 is smaller than the d = 602 coefficients"),
    # No model could ever come out: `process` ran to the end and said so only then.
    ({"arx.order": 1}, "arx.order 1: node 2 realizes models from an ARX order of at least 2"),
    ({"arx.window_length": 10}, "arx.window_length 10 with arx.order 100: node 2's realization needs at least 400"),
    # Output-only: was taken, then every model refused ("too few samples for output-only identification: 160 <
    # 200", or at 50 rows "unexcited window: condition number inf"), `process` exit 0.
    ({"n_inputs": 0, "arx.order": 10, "arx.window_length": 150},
     "arx.window_length 150 with arx.order 10: node 2's realization needs at least 200 samples of a window "
     "(arx.window_length at least 190)"),
    # Forgetting: node 1's windows were refused as unexcited (0.5), or node 2 refused every one as shorter
    # than a realization needs (0.99 at order 100: 200 of 400 samples), exit 0 and nothing said at the start.
    ({"arx.window_length": 0, "arx.forgetting_factor": 0.5},
     "arx.forgetting_factor 0.5 with arx.window_length 0 and arx.order 100: the window's effective memory, "
     "1 / (1 - 0.5) = 2 rows, plus the order is 102 samples; node 2's realization needs at least 400 "
     "(arx.forgetting_factor at least 0.99667, or arx.window_length at least 300 with arx.forgetting_factor 1.0)"),
    ({"arx.window_length": 0, "arx.forgetting_factor": 0.99}, "= 100 rows, plus the order is 200 samples"),
    ({"n_inputs": 0, "arx.order": 10, "arx.window_length": 0, "arx.forgetting_factor": 0.99},
     "needs at least 200 (arx.forgetting_factor at least 0.99474, or arx.window_length at least 190"),
])
def test_an_arx_regressor_too_long_for_the_window_or_the_live_update_is_refused(values, text):
    with pytest.raises(ParameterError, match=re.escape(text)):
        ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, values))
    # The same order regularized, or with 28 outputs at the live configuration's order, is taken.
    ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, {"arx.order": 150, "arx.window_length": 500}))
    ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, {"arx.order": 20, "n_outputs": 28}))
    ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, {"arx.order": 1, "n_inputs": 0}))
    ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, {"n_inputs": 0, "arx.order": 10,
                                                                          "arx.window_length": 190}))
    # The least forgetting factor it names is taken; no forgetting with an infinite history too.
    for values in ({"arx.window_length": 0, "arx.forgetting_factor": 0.99667},
                   {"n_inputs": 0, "arx.order": 10, "arx.window_length": 0, "arx.forgetting_factor": 0.99474},
                   {"arx.window_length": 0, "arx.forgetting_factor": 1.0}):
        ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, values))


def test_a_window_whose_buffers_do_not_fit_in_the_available_memory_is_refused(monkeypatch):
    """``arx.window_length`` 1e8 started (numpy's zeroed buffers take memory as they fill) and failed later."""
    from okid_ros.service import sample_buffer

    monkeypatch.setattr(sample_buffer, "available_memory_bytes", lambda: 2**30, raising=False)  # 1 GiB
    with pytest.raises(ParameterError, match=r"^arx\.window_length 100000000: buffering the window's samples needs "
                       r"about 15\.3 GiB, only 1 GiB available \(estimated at 164 bytes a row"):
        ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, {"arx.window_length": 100_000_000}))
    # A window of a million rows (164 MB) fits.
    ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, {"arx.window_length": 1_000_000}))


def test_node_1s_first_model_takes_its_window_fill_plus_its_order():
    arx = ArxIdentificationParams(0.008, 100, 2, 2, 4000)  # config/okid.yaml: min_window_fill 0.5
    assert arx.first_model_samples() == 2000 + 100
    forgetting = dataclasses.replace(arx, window_length=0, forgetting_factor=0.99)
    assert forgetting.first_model_samples() == math.ceil(math.log(0.5) / math.log(0.99)) + 100  # 1 - 0.99^n >= 0.5
    assert dataclasses.replace(forgetting, forgetting_factor=1.0).first_model_samples() == 1 + 100
    assert math.isinf(dataclasses.replace(forgetting, min_window_fill=1.0).first_model_samples())
    assert dataclasses.replace(arx, min_window_fill=0.0).first_model_samples() == 1 + 100  # a solve needs a row


def test_input_output_realization_parameters_set_for_an_output_only_rig_are_named():
    """``process --param realization.n_states=2`` with n_inputs 0 gave models of 8 states, in silence."""
    values = {"n_inputs": 0, "realization.n_states": 2, "modes.max_damping": 0.05}
    params = ModalEstimationParams.from_parameters(resolve_parameters(ESTIMATOR_NODE, values))
    assert params.output_only_ignored() == (
        "realization.n_states, modes.max_damping apply to input-output realization; ignored with n_inputs 0 "
        "(output-only: realization.output_only_method chooses the model)")
    def said(values: dict) -> str:
        return ModalEstimationParams.from_parameters(resolve_parameters(ESTIMATOR_NODE, values)).output_only_ignored()

    assert said({"n_inputs": 0, "realization.gain": "riccati"}).startswith(
        "realization.gain applies to input-output realization")
    # Defaults, the output-only route's own parameter, or a rig with inputs: nothing to say.
    for quiet in ({"n_inputs": 0}, {"n_inputs": 0, "realization.output_only_method": "var"},
                  {"n_inputs": 2, "realization.n_states": 2}):
        assert said(quiet) == ""
    # Each parameter the input-output realization reads is named, set alone; the rest of node 2's are not.
    off_default = {"realization.n_states": 4, "realization.max_states": 30, "realization.max_states_limit": 300,
                   "realization.gain": "whitening", "realization.refine": False, "realization.jackknife_segments": 8,
                   "modes.max_damping": 0.05, "modes.min_msv": 0.2, "modes.max_nyquist_fraction": 0.5,
                   "modes.min_mpc": 0.1, "modes.min_dominance": 0.05, "modes.min_stable_fraction": 0.2}
    for name, value in off_default.items():
        assert said({"n_inputs": 0, name: value}).startswith(f"{name} applies to input-output realization")
    for name, value in {"tracking.min_mac": 0.5, "estimator.max_gap_samples": 3, "change.enabled": False,
                        "offsets": "none"}.items():
        assert said({"n_inputs": 0, name: value}) == ""


def test_a_parameter_the_realization_comes_to_read_is_named_for_an_output_only_rig(monkeypatch):
    """The names came from a list kept by hand beside ``realization_options``: a new one was not named."""
    reads = ModalEstimationParams.realization_options

    def reading_min_mac(self):  # as if a new realization option took tracking.min_mac
        options = reads(self)
        return dataclasses.replace(options, modes=dataclasses.replace(options.modes, min_mpc=self.min_mac))

    monkeypatch.setattr(ModalEstimationParams, "realization_options", reading_min_mac)
    params = ModalEstimationParams.from_parameters(resolve_parameters(
        ESTIMATOR_NODE, {"n_inputs": 0, "tracking.min_mac": 0.5}))
    assert params.output_only_ignored().startswith("tracking.min_mac applies to input-output realization")
