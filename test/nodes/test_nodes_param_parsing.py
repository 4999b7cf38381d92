"""Parameter files and --param values are typed as rcl types them for a node.

`okid-ros process`/`batch` read the nodes' parameter YAML without ROS
(:func:`okid_ros.service.param_files.load_yaml_as_rcl`); the nodes get the same file through
rcl's C parser. A value must mean the same to both: ``1e-3`` is a double to rcl and was a
string to PyYAML's YAML 1.1 rules ("publish_rate_hz must be a number, got '1e-3'").
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from okid_ros.errors import ParameterError
from okid_ros.service.param_files import flatten, load_yaml_as_rcl
from okid_ros.tools.node_parameters import load_node_parameters

pytestmark = [pytest.mark.dds, pytest.mark.dds_startup]  # start-ups and exits only: `make test` runs it in parallel

SCALARS = {
    "exponent": "1e-3", "exponent_upper": "2E+2", "decimal": "0.25", "leading_dot": ".5", "trailing_dot": "3.",
    "integer": "42", "negative": "-7", "octal": "010", "hex": "0x1F", "not_octal": "08", "big": "99999999999999999999",
    "underscore": "1_000", "word_true": "yes", "letter_y": "y", "word_off": "Off", "inf": ".inf", "minus_inf": "-.Inf",
    "bare_inf": "inf", "text": "abc", "quoted_number": "'1e-3'", "double_quoted": '"7"',
}

PROBE = """
import json, sys, math
import rclpy
from rclpy.node import Node
rclpy.init(args=["--ros-args", "--params-file", sys.argv[1]])
node = Node("probe", automatically_declare_parameters_from_overrides=True)
out = {}
for name, p in node.get_parameters_by_prefix("").items():
    v = p.value
    out[name] = [type(v).__name__, "inf" if isinstance(v, float) and math.isinf(v) and v > 0
                 else "-inf" if isinstance(v, float) and math.isinf(v) else v]
print("PARAMS " + json.dumps(out), flush=True)
"""


def _typed(value) -> list:
    if isinstance(value, float) and value in (float("inf"), float("-inf")):
        return [type(value).__name__, "inf" if value > 0 else "-inf"]
    return [type(value).__name__, value]


def test_a_parameter_file_means_to_okid_ros_what_it_means_to_rcl(tmp_path: Path, spawn_ros) -> None:
    path = tmp_path / "params.yaml"
    path.write_text("/**:\n  ros__parameters:\n" + "".join(f"    {k}: {v}\n" for k, v in SCALARS.items()))
    probe = spawn_ros("-c", PROBE, str(path))
    rcl = json.loads(probe.wait_for_output(r"^PARAMS (.*)$", timeout_s=60).group(1))
    rcl = {k: v for k, v in rcl.items() if k not in ("use_sim_time", "start_type_description_service")}
    ours = {k: _typed(v) for k, v in flatten(load_yaml_as_rcl(path.read_text())["/**"]["ros__parameters"]).items()}
    assert ours == rcl
    assert ours["exponent"] == ["float", 0.001] and ours["octal"] == ["int", 8] and ours["letter_y"] == ["bool", True]


@pytest.mark.parametrize("text, expected", [("5e-1", 0.5), ("2.0", 2.0)])
def test_a_number_in_exponent_form_is_a_number_in_files_and_overrides(tmp_path: Path, text: str,
                                                                       expected: float) -> None:
    path = tmp_path / "rate.yaml"
    path.write_text(f"/**:\n  ros__parameters:\n    publish_rate_hz: {text}\n")
    from_file, _ = load_node_parameters([path])
    from_override, _ = load_node_parameters(overrides=[f"publish_rate_hz={text}"])
    assert from_file["publish_rate_hz"] == from_override["publish_rate_hz"] == expected


def test_a_value_the_nodes_refuse_for_its_type_is_refused_from_a_file_and_from_param(tmp_path: Path) -> None:
    # rclpy's typed parameters refuse 8 for sample_time_s and 20.0 for arx.order (node 1 stops with
    # "parameter sample_time_s must be a floating-point number (e.g. 1.0, not 1)"); the offline path
    # read them silently, then with a warning from a file only (and none for --param sample_time_s=8),
    # so a file or an option `process` took could not start `up`. Refused on every path, as the nodes do.
    path = tmp_path / "loose.yaml"
    path.write_text("/**:\n  ros__parameters:\n    sample_time_s: 8\n"
                    "/**/okid_arx_identifier:\n  ros__parameters:\n    arx: {order: 20.0}\n")
    said: list[str] = []
    for strict in (False, True):
        with pytest.raises(ParameterError) as refused:
            load_node_parameters([path], report=said.append, strict=strict)
        assert str(refused.value) == (
            f"{path}: parameter sample_time_s = 8 is an integer: the nodes refuse it for a floating-point parameter "
            f"and do not start (write 8.0); {path}: parameter arx.order = 20.0 is a floating-point number: the "
            "nodes refuse it for an integer parameter and do not start")
    for override in ("sample_time_s=8", "sample_time_s:=8"):  # NAME:=VALUE as ros2 run -p writes it
        with pytest.raises(ParameterError, match=f"^--param {override}: parameter sample_time_s = 8 is an integer: "
                           r"the nodes refuse it for a floating-point parameter and do not start \(write 8\.0\)$"):
            load_node_parameters(overrides=[override], report=said.append)
    with pytest.raises(ParameterError, match=r"^--param arx\.order=20\.0: parameter arx\.order = 20\.0 is a "):
        load_node_parameters(overrides=["arx.order=20.0"], report=said.append)
    assert said == []
    arx, _ = load_node_parameters(overrides=["sample_time_s:=8.0", "arx.order=20"])
    assert arx["sample_time_s"] == 8.0 and arx["arx.order"] == 20


def test_the_commands_say_a_files_problems_as_their_own_warning_lines(tmp_path: Path, capsys) -> None:
    # Each command's other warnings read "okid-ros COMMAND: warning: ..."; a parameter file's were
    # "warning: FILE: ..." alone, and identify's "ignored" note ended in "(UserWarning at identify.py:105)".
    from okid_ros.cli import main

    bag, loose = tmp_path / "run", tmp_path / "loose.yaml"
    loose.write_text("/**:\n  ros__parameters:\n    publish_rate_hz: 1.0\n    no_such_thing: 3\n")
    assert main(["simulate", "--out", str(bag), "--duration", "2"]) == 0
    capsys.readouterr()
    for command, args in [("export", ["--npz", str(tmp_path / "run.npz")]),
                          ("batch", ["--plan"]), ("process", ["--out", str(tmp_path / "out"), "--no-progress"])]:
        main([command, str(bag), *args, "--params", str(loose)])
        said = [line for line in capsys.readouterr().err.splitlines() if str(loose) in line]
        assert said == [
            f"okid-ros {command}: warning: {loose}: section '/**': unknown parameter(s) no_such_thing (not declared "
            "by okid_arx_identifier, okid_modal_estimator)"], said
    assert main(["identify", str(tmp_path / "run.npz"), "--json", str(tmp_path / "m.json"), "--order", "10",
                 "--params", str(loose)]) == 0
    assert capsys.readouterr().err.splitlines()[0] == (
        f"okid-ros identify: warning: {tmp_path / 'run.npz'}: --params, --param and --source say how to read a bag's "
        "topics; a record file holds its channels and sample time itself: ignored")


RCL_VERDICTS = """
import json, sys
import rclpy
out = {}
for path in sys.argv[1:]:
    try:
        rclpy.init(args=["--ros-args", "--params-file", path])
    except Exception as exc:
        out[path] = " ".join(str(exc).split())
    else:
        out[path] = None
        rclpy.shutdown()
print("VERDICTS " + json.dumps(out), flush=True)
"""

ALIAS_FILES = {
    "alias_scalar": "/**:\n  ros__parameters:\n    a: &x 5\n    b: *x\n",
    "alias_in_list": "/**:\n  ros__parameters:\n    a: [&x 1, *x]\n",
    "alias_key": "/**:\n  ros__parameters:\n    &k a: 1\n    *k : 2\n",
    "alias_across_sections": "/**/okid_arx_identifier:\n  ros__parameters:\n    arx: &common {order: 20}\n"
                             "/**/okid_estimator:\n  ros__parameters:\n    arx: *common\n",
    "alias_section": "/**/a: &s\n  ros__parameters:\n    b: 1\n/**/c: *s\n",
    "anchors_alone": "&doc\n/**/okid_arx_identifier: &section\n  &params ros__parameters: &values\n"
                     "    a: &x 5\n    &k b: [&item 1, 2]\n    arx: &arx {order: 20}\n",
}


def test_rcl_and_okid_ros_refuse_the_same_aliases_and_read_the_same_anchors(tmp_path: Path, spawn_ros) -> None:
    # The nodes' contract: rcl refuses every alias at its line and reads an anchor alone; okid_ros
    # read aliases (their values copied), so `process` took a file no node would start with.
    from okid_ros.service.param_files import read_parameter_file

    paths = {case: tmp_path / f"{case}.yaml" for case in ALIAS_FILES}
    for case, path in paths.items():
        path.write_text(ALIAS_FILES[case])
    probe = spawn_ros("-c", RCL_VERDICTS, *map(str, paths.values()))
    rcl = json.loads(probe.wait_for_output(r"^VERDICTS (.*)$", timeout_s=60).group(1))
    for case, path in paths.items():
        rcl_line = re.search(r"Will not support aliasing at line (\d+)", rcl[str(path)] or "")
        try:
            read_parameter_file(path)
            ours_line = None
        except ParameterError as exc:
            ours_line = re.search(r": line (\d+): the YAML alias '\*", str(exc))
        assert (rcl[str(path)] is None) == (ours_line is None), (case, rcl[str(path)])
        assert (rcl_line and rcl_line.group(1)) == (ours_line and ours_line.group(1)), (case, rcl[str(path)])
    assert rcl[str(paths["anchors_alone"])] is None and sum(v is None for v in rcl.values()) == 1
