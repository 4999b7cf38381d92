"""The shipped parameter files and the launch file agree with the nodes' declarations.

The declarations are those of okid_ros/service/params.py; no ROS is started.
"""

from __future__ import annotations

import ast
import re

import pytest
import yaml
from ros_helpers import REPO_ROOT

from okid_ros.service.inputs import parse_sources
from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, load_parameters, node_params
from okid_ros.service.topics import resolve_topic

CONFIG = REPO_ROOT / "config" / "okid.yaml"


def flatten(tree: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


@pytest.mark.parametrize("node", [ARX_NODE, ESTIMATOR_NODE])
def test_okid_yaml_lists_every_parameter_with_its_default(node):
    tree = yaml.safe_load(CONFIG.read_text())
    listed = {**flatten(tree["/**"]["ros__parameters"]), **flatten(tree[f"/**/{node}"]["ros__parameters"])}
    specs = {spec.name: spec for spec in node_params(node)}
    assert set(listed) == set(specs), "config/okid.yaml and params.py list different parameters"
    for name, spec in specs.items():
        assert listed[name] == spec.default, f"{name}: YAML {listed[name]!r}, declared default {spec.default!r}"
    values = load_parameters(CONFIG, node)
    assert values["sample_time_s"] == 0.008 and values["n_inputs"] == values["n_outputs"] == 2
    # Topic names are relative: /okid/... in the root namespace, NAMESPACE/... otherwise.
    if node == ARX_NODE:
        assert values["arx.order"] == 100
        assert resolve_topic(values["arx_model_topic"]) == "/okid/arx_model"
        assert resolve_topic(values["arx_model_topic"], "/rig1") == "/rig1/arx_model"
    else:
        assert resolve_topic(values["modal_states_topic"]) == "/okid/modal_states"
        assert resolve_topic(values["state_space_model_topic"]) == "/okid/state_space_model"
        assert resolve_topic(values["modal_states_topic"], "/plant/rig2") == "/plant/rig2/modal_states"
    assert values["inputs.sources"] == ["io_sample io_sample"]
    # The sections are keyed /**/NODE: the same values apply to the node in a namespace.
    assert load_parameters(CONFIG, node, namespace="/rig1") == values


def test_every_parameter_in_okid_yaml_is_commented_with_its_default():
    text = CONFIG.read_text()
    lines = text.splitlines()
    for i, line in enumerate(lines):
        match = re.match(r"^\s+([a-z_]+):\s*\S", line)
        if not match or line.strip().startswith("#") or match.group(1) == "ros__parameters":
            continue
        comment = []
        j = i - 1
        while j >= 0 and lines[j].strip().startswith("#"):
            comment.insert(0, lines[j])
            j -= 1
        assert "Default" in " ".join(comment), (
            f"config/okid.yaml line {i + 1} ({match.group(1)}) has no comment with its default"
        )


def test_the_sensor_example_maps_every_channel_once():
    values = load_parameters(REPO_ROOT / "config" / "okid_imu_wrench.yaml", ESTIMATOR_NODE)
    specs = parse_sources(values["inputs.sources"], values["n_inputs"], values["n_outputs"])
    assert sorted(s.kind for s in specs) == ["imu", "imu", "wrench", "wrench"]


def test_launch_file_starts_both_console_scripts_under_their_node_names():
    tree = ast.parse((REPO_ROOT / "launch" / "okid.launch.py").read_text())
    nodes = {}
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and getattr(call.func, "id", "") == "Node":
            kw = {k.arg: k.value.value for k in call.keywords if isinstance(k.value, ast.Constant)}
            nodes[kw["name"]] = kw["executable"]
    assert nodes == {ARX_NODE: "arx_identifier", ESTIMATOR_NODE: "modal_estimator"}
    setup = (REPO_ROOT / "setup.py").read_text()
    for executable, module in (("arx_identifier", "arx_identifier_node"), ("modal_estimator", "modal_estimator_node")):
        assert f'"{executable} = okid_ros.nodes.{module}:main"' in setup
    assert "params_file" in (REPO_ROOT / "launch" / "okid.launch.py").read_text()
