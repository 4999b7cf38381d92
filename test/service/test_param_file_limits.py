"""Parameter files that would expand without end: YAML alias bombs, recursive aliases, deep nesting.

A 1 KB "billion laughs" file (aliases nested 9 deep, 9**9 values) once hung `process`, `plot`
and `batch` past a minute while its sections were flattened; a recursive alias ended them in a
RecursionError (exit 70). Each is now one ParameterError naming the file, before any walk.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, run_cli

from okid_ros.errors import ParameterError
from okid_ros.service.param_files import MAX_ALIAS_EXPANSION, flatten, load_yaml_as_rcl, read_parameter_file
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
    with pytest.raises(ParameterError, match=f"parameter file {path}: its YAML aliases expand it") as raised:
        read_parameter_file(path)
    assert time.monotonic() - started < 2.0
    assert "\n" not in str(raised.value)
    with pytest.raises(ParameterError, match="bomb.yaml"):  # the path `process` takes
        load_parameters(path, ARX_NODE)


def test_a_recursive_alias_is_refused(tmp_path):
    path = tmp_path / "loop.yaml"
    path.write_text("/**:\n  ros__parameters:\n    a: &a {b: *a}\n")
    with pytest.raises(ParameterError, match="loop.yaml: a YAML alias refers to a mapping or list that contains it"):
        read_parameter_file(path)
    with pytest.raises(ParameterError, match="contains it"):
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
    assert flatten(read_parameter_file(path)["/**"]["ros__parameters"])["<<.arx.order"] == 20


def test_a_value_nested_too_deeply_is_a_parameter_error():
    # `okid-ros process --param NAME=VALUE` parses VALUE here (RecursionError: exit 70 before)
    with pytest.raises(ParameterError, match="the YAML text is nested too deeply"):
        load_yaml_as_rcl("[" * 5000 + "]" * 5000)


def test_a_few_aliases_still_load():
    text = ("common: &common {order: 20, window_length: 800}\n"
            "/**/okid_arx_identifier:\n  ros__parameters:\n    arx: *common\n"
            "other:\n  ros__parameters:\n    arx: *common\n")
    tree = load_yaml_as_rcl(text)
    assert tree["/**/okid_arx_identifier"]["ros__parameters"]["arx"] == {"order": 20, "window_length": 800}
    # just within the limit: one list of MAX_ALIAS_EXPANSION / 10 aliases to a 9-value list
    many = "x: &x [1, 2, 3, 4, 5, 6, 7, 8, 9]\ny: [" + ", ".join(["*x"] * (MAX_ALIAS_EXPANSION // 10)) + "]\n"
    assert len(load_yaml_as_rcl(many)["y"]) == MAX_ALIAS_EXPANSION // 10


@pytest.mark.parametrize("path", sorted((REPO_ROOT / "config").glob("*.yaml")), ids=lambda p: p.name)
def test_the_shipped_config_files_load(path):
    assert read_parameter_file(path)
    load_parameters(path, ARX_NODE)
