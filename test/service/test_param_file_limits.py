"""Parameter YAML that rcl does not read: aliases, merge keys; files that would expand without end; deep nesting.

rcl refuses every YAML alias ("Will not support aliasing at line N", checked with rclpy's
``--params-file`` and ``-p``) and reads an anchor alone. So does every command here, naming the
file and the line, before a node starts. A 1 KB "billion laughs" file (aliases nested 9 deep,
9**9 values) once hung `process`, `plot` and `batch` past a minute while its sections were
flattened; a recursive alias ended them in a RecursionError (exit 70): both are refused at their
first alias now, before anything is expanded.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.errors import ParameterError
from okid_ros.service.param_files import files_for_nodes, flatten, load_yaml_as_rcl, read_parameter_file
from okid_ros.service.params import ARX_NODE, load_parameters

REPO_ROOT = Path(__file__).resolve().parents[2]


def billion_laughs(levels: int = 9, fan_out: int = 9) -> str:
    lines = ["a0: &a0 {x: 1}"]
    for level in range(1, levels + 1):
        items = ", ".join(f"k{i}: *a{level - 1}" for i in range(fan_out))
        lines.append(f"a{level}: &a{level} {{{items}}}")
    lines += ["/**:", "  ros__parameters:", f"    deep: *a{levels}"]
    return "\n".join(lines) + "\n"


def test_an_alias_bomb_is_refused_at_once_naming_the_file(tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(billion_laughs())
    started = time.monotonic()
    expected = f"parameter file {path}: line 2: the YAML alias '*a0'"  # the first alias: nothing expanded
    with pytest.raises(ParameterError, match=re.escape(expected)) as raised:
        read_parameter_file(path)
    assert time.monotonic() - started < 2.0
    assert "\n" not in str(raised.value)
    with pytest.raises(ParameterError, match="bomb.yaml"):  # the path `process` takes
        load_parameters(path, ARX_NODE)


def test_a_recursive_alias_is_refused(tmp_path):
    path = tmp_path / "loop.yaml"
    path.write_text("/**:\n  ros__parameters:\n    a: &a {b: *a}\n")
    with pytest.raises(ParameterError, match=re.escape("loop.yaml: line 3: the YAML alias '*a' is not read by rcl")):
        read_parameter_file(path)
    with pytest.raises(ParameterError, match=re.escape("the YAML text: line 1: the YAML alias '*l'")):
        load_yaml_as_rcl("&l [1, *l]")


@pytest.mark.parametrize("section, line", [
    ("base: &base\n  arx: {order: 20}\n/**:\n  ros__parameters:\n    <<: *base\n    sample_time_s: 0.01\n", 5),
    ("/**:\n  ros__parameters:\n    sample_time_s: 0.01\n    <<: {arx: {order: 20}}\n", 4),
], ids=["alias", "inline"])
def test_a_yaml_merge_key_is_refused_naming_the_file_and_line(tmp_path, capsys, section, line):
    # '<<: *base' was read as a parameter named '<<' ('<<.arx.order', an unknown parameter's warning) while rcl
    # refuses the file ("Will not support aliasing at line 5"); rcl reads the inline form as '<<.arx.order' too.
    path = tmp_path / "merge.yaml"
    path.write_text(section)
    with pytest.raises(ParameterError, match=re.escape(f"parameter file {path}: line {line}: the YAML merge key '<<' "
                                                       "is not read by rcl")):
        read_parameter_file(path)
    code, _, err = run_cli(capsys, "process", tmp_path / "no_bag", "--params", path, "--out", tmp_path / "out")
    assert_one_line_error(code, err, f"merge.yaml: line {line}: the YAML merge key '<<'")
    assert not (tmp_path / "out").exists()
    path.write_text(section.replace("<<:", "'<<':"))  # quoted: a name, no merge key (rcl reads the inline one so)
    if "*base" in section:  # still an alias, which rcl refuses
        with pytest.raises(ParameterError, match=re.escape(f"line {line}: the YAML alias '*base'")):
            read_parameter_file(path)
    else:
        assert flatten(read_parameter_file(path)["/**"]["ros__parameters"])["<<.arx.order"] == 20


def test_a_value_nested_too_deeply_is_a_parameter_error():
    # `okid-ros process --param NAME=VALUE` parses VALUE here (RecursionError: exit 70 before)
    with pytest.raises(ParameterError, match="the YAML text is nested too deeply"):
        load_yaml_as_rcl("[" * 5000 + "]" * 5000)


# (file, line of the alias): each refused by rclpy.init(args=["--ros-args", "--params-file", FILE]) with
# "Will not support aliasing at line LINE".
ALIASES = {
    "scalar": ("/**:\n  ros__parameters:\n    a: &x 5\n    b: *x\n", 4),
    "list": ("/**:\n  ros__parameters:\n    a: &x [1, 2]\n    b: *x\n", 4),
    "mapping": ("/**:\n  ros__parameters:\n    arx: &x {order: 20}\n    arma: *x\n", 4),
    "list_item": ("/**:\n  ros__parameters:\n    a: [&x 1, *x]\n", 3),
    "key": ("/**:\n  ros__parameters:\n    &k a: 1\n    *k : 2\n", 4),
    "across_sections": ("/**/okid_arx_identifier:\n  ros__parameters:\n    arx: &common {order: 20}\n"
                        "/**/okid_estimator:\n  ros__parameters:\n    arx: *common\n", 6),
    "whole_section": ("/**/okid_arx_identifier: &s\n  ros__parameters:\n    sample_time_s: 0.01\n"
                      "/**/okid_estimator: *s\n", 4),
}


@pytest.mark.parametrize("case", sorted(ALIASES))
def test_an_alias_is_refused_naming_the_file_and_line(tmp_path, capsys, case):
    # Was read, its values copied (test_a_few_aliases_still_load): `process`, `batch` and `up`'s check
    # took the file, then each node refused it at start.
    text, line = ALIASES[case]
    path = tmp_path / "alias.yaml"
    path.write_text(text)
    expected = f"parameter file {path}: line {line}: the YAML alias '*"
    with pytest.raises(ParameterError, match=re.escape(expected)) as raised:
        read_parameter_file(path)
    assert "write the values out" in str(raised.value)
    with pytest.raises(ParameterError, match=re.escape(expected)):
        files_for_nodes([path])  # `up` and `demo`, before a node starts
    process = ["process", tmp_path / "no_bag", "--params", path, "--out", tmp_path / "out"]
    for argv in (process, ["up", "--params", path]):
        code, _, err = run_cli(capsys, *argv)
        assert_one_line_error(code, err, f"alias.yaml: line {line}: the YAML alias '*")
    assert not (tmp_path / "out").exists()


def test_an_alias_in_a_param_value_is_refused(tmp_path, capsys):
    # rcl's `-p a:=[&x 1, *x]` fails ("Unknown YAML event"); `--param` read it as [1, 1]
    code, _, err = run_cli(capsys, "process", tmp_path / "no_bag", "--param", "inputs.sources=[&s a, *s]",
                           "--out", tmp_path / "out")
    assert_one_line_error(code, err, "--param 'inputs.sources=[&s a, *s]': line 1: the YAML alias '*s'")


def test_an_anchor_alone_is_read_as_rcl_reads_it(tmp_path):
    # rclpy read each of these (an anchor on a value, a key, a list item, ros__parameters, a section, the document)
    path = tmp_path / "anchors.yaml"
    path.write_text("&doc\n/**/okid_arx_identifier: &section\n  &params ros__parameters: &values\n"
                    "    a: &x 5\n    &k b: [&item 1, 2]\n    arx: &arx {order: 20}\n")
    assert flatten(read_parameter_file(path)["/**/okid_arx_identifier"]["ros__parameters"]) == {
        "a": 5, "b": [1, 2], "arx.order": 20}


@pytest.mark.parametrize("path", sorted((REPO_ROOT / "config").glob("*.yaml")), ids=lambda p: p.name)
def test_the_shipped_config_files_load(path):
    assert read_parameter_file(path)
    load_parameters(path, ARX_NODE)


# Each refused by rclpy.init(args=["--ros-args", "--params-file", FILE]): "Cannot have a value before ros__parameters".
NOT_SECTIONS = {
    "flat_section": ("/**: {sample_time_s: 0.01}\n", "/**"),
    "typo": ("/**:\n  ros_parameters:\n    sample_time_s: 0.01\n", "/**/ros_parameters"),
    "top_level_value": ("/**:\n  ros__parameters:\n    sample_time_s: 0.01\nnote: 5\n", "note"),
}


@pytest.mark.parametrize("case", sorted(NOT_SECTIONS))
def test_up_refuses_a_file_with_a_key_no_node_reads_before_a_node_starts(tmp_path, capsys, case):
    # Were started: each node then failed in rcl's parser ("Cannot have a value before ros__parameters").
    text, key = NOT_SECTIONS[case]
    path = tmp_path / "bare.yaml"
    path.write_text(text)
    with pytest.raises(ParameterError, match=re.escape(f"section {key!r} holds no 'ros__parameters' mapping: "
                                                       "a node refuses the file")):
        files_for_nodes([path])
    code, out, err = run_cli(capsys, "up", "--params", path)
    assert_one_line_error(code, err, "bare.yaml: section")
    assert "started" not in out + err
    assert read_parameter_file(path) is not None  # the commands that read it themselves warn (file_report)


# The first keys of an `identify --json` model (IdentifiedModel.to_json_dict) and a YAML of plain settings.
NOT_PARAMETER_FILES = {
    "identify_model": ('{"sample_time_s": 0.008, "n_states": 2, "n_inputs": 1, "n_outputs": 1, "A": [[0.5, 0], '
                       '[0, 0.4]], "C": [[1, 0]], "modes": [], "warnings": []}\n',
                       "none of its 8 top-level key(s) ('sample_time_s', 'n_states', 'n_inputs', ...)",
                       "looks like a model written by `okid-ros identify --json`"),
    "plain_settings": ("rate: 5\nsolver: {order: 50}\n", "none of its 2 top-level key(s) ('rate', 'solver')",
                       "is a node section"),
}


@pytest.mark.parametrize("command", ["process", "up"])
@pytest.mark.parametrize("case", sorted(NOT_PARAMETER_FILES))
def test_a_file_with_no_node_section_is_refused_in_one_line_by_process_as_by_up(tmp_path, capsys, case, command):
    # process warned once per key (37 lines for a model JSON) and ran on the defaults; up refused it.
    text, *fragments = NOT_PARAMETER_FILES[case]
    path = tmp_path / "model.json"
    path.write_text(text)
    args = ["--params", path] + (["--out", tmp_path / "out"] if command == "process" else [])
    code, out, err = run_cli(capsys, command, *([tmp_path / "no_bag"] if command == "process" else []), *args)
    assert_one_line_error(code, err, f"{path} is not a parameter file: ", *fragments)
    assert "started" not in out + err and not (tmp_path / "out").exists()


def test_a_file_with_a_section_and_a_stray_key_is_still_read_with_a_warning(tmp_path):
    from okid_ros.tools.node_parameters import load_node_parameters

    path = tmp_path / "okid.yaml"
    path.write_text("/**:\n  ros__parameters:\n    publish_rate_hz: 2.0\nnote: 5\n")
    reported: list[str] = []
    arx, _ = load_node_parameters([path], report=reported.append)
    assert arx["publish_rate_hz"] == 2.0
    assert len(reported) == 1 and "section 'note' holds no 'ros__parameters'" in reported[0], reported
