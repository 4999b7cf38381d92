"""Topic names in the rig namespace, and parameter files read as rcl reads them (no ROS)."""

from __future__ import annotations

import pytest
import yaml

from okid_ros.errors import ParameterError
from okid_ros.service.param_files import file_report, params_files_from_args, section_matches
from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, load_parameters, node_params
from okid_ros.service.topics import output_topics, resolve_topic, rig_namespace, validate_namespace
from okid_ros.tools.process import load_node_parameters


def test_relative_names_resolve_in_the_rig_namespace_and_absolute_ones_stay():
    assert resolve_topic("io_sample") == "/okid/io_sample"
    assert resolve_topic("io_sample", "/") == "/okid/io_sample"
    assert resolve_topic("io_sample", "/rig1") == "/rig1/io_sample"
    assert resolve_topic("sensors/imu", "/plant/rig2/") == "/plant/rig2/sensors/imu"
    assert resolve_topic("/my/imu", "/rig1") == "/my/imu"
    assert rig_namespace("rig3") == "/rig3"
    assert set(output_topics("/rig1")) == {"/rig1/arx_model", "/rig1/state_space_model", "/rig1/modal_states",
                                          "/rig1/structural_change"}
    for bad in ("/rig 1", "/1rig", "//rig", "/rig-1"):
        with pytest.raises(ValueError, match="namespace"):
            validate_namespace(bad)


@pytest.mark.parametrize("key, fqn, matches", [
    ("/**", "/rig1/okid_arx_identifier", True),
    ("/**/okid_arx_identifier", "/okid_arx_identifier", True),
    ("/**/okid_arx_identifier", "/a/b/okid_arx_identifier", True),
    ("okid_arx_identifier", "/okid_arx_identifier", True),
    ("okid_arx_identifier", "/rig1/okid_arx_identifier", False),
    ("/rig1/okid_arx_identifier", "/rig1/okid_arx_identifier", True),
    ("/rig1/okid_arx_identifier", "/rig2/okid_arx_identifier", False),
    ("/*/okid_arx_identifier", "/rig2/okid_arx_identifier", True),
    ("/*/okid_arx_identifier", "/okid_arx_identifier", False),
    ("/**/okid_modal_estimator", "/okid_arx_identifier", False),
])
def test_sections_match_nodes_as_rcl_does(key, fqn, matches):
    assert section_matches(key, fqn) is matches


def test_unknown_names_and_sections_that_do_not_apply_are_reported(tmp_path):
    tree = yaml.safe_load("""
/**:
  ros__parameters:
    sample_time_s: 0.01
    use_sim_time: true
    qos_overrides:
      /okid/io_sample:
        subscription: {depth: 10}
    publish_rate_hz: 2.0          # node 1 only, fine in the shared section
    sampel_time_s: 0.01           # typo
okid_arx_identifier:
  ros__parameters:
    arx: {ordr: 50}
/**/okid_modal_estimator:
  ros__parameters:
    tracking: {min_mac: 0.8}
""")
    names = {n: [s.name for s in node_params(n)] for n in (ARX_NODE, ESTIMATOR_NODE)}
    root = file_report(tree, "f.yaml", names)
    assert len(root) == 2
    assert "sampel_time_s" in root[0] and "publish_rate_hz" not in root[0] and "use_sim_time" not in root[0]
    assert "arx.ordr" in root[1]
    in_ns = file_report(tree, "f.yaml", names, "/rig1")
    assert any("'okid_arx_identifier' does not apply to /rig1/okid_arx_identifier" in p for p in in_ns)
    only_est = file_report(tree, "f.yaml", names, for_node=ESTIMATOR_NODE)
    assert len(only_est) == 1 and "sampel_time_s" in only_est[0]

    path = tmp_path / "typo.yaml"
    path.write_text(yaml.safe_dump(tree))
    reported: list[str] = []
    arx, est = load_node_parameters([path], report=reported.append)
    assert arx["sample_time_s"] == 0.01 and est["tracking.min_mac"] == 0.8 and len(reported) == 2
    with pytest.raises(ParameterError, match="arx.ordr"):
        load_node_parameters([path], strict=True)
    arx_ns, _ = load_node_parameters([path], namespace="/rig1", report=reported.append)
    assert arx_ns["publish_rate_hz"] == 2.0


def test_a_section_without_ros_parameters_is_reported():
    # rcl refuses such a file; offline (process, identify, batch) it was passed over in silence.
    names = {n: [s.name for s in node_params(n)] for n in (ARX_NODE, ESTIMATOR_NODE)}
    for tree, key in (({"/**": {"sample_time_s": 0.01}}, "/**"),
                      ({"/**": {"ros_parameters": {"sample_time_s": 0.01}}}, "/**/ros_parameters")):
        report = file_report(tree, "f.yaml", names)
        assert len(report) == 1 and f"section '{key}' holds no 'ros__parameters'" in report[0], report
    assert file_report({"/**": {"ros__parameters": {"sample_time_s": 0.01}}}, "f.yaml", names) == []
    # rcl's nested form, a namespace holding node sections, is no problem of the file, and the
    # offline tools read it as the nodes do (they read nothing of it before).
    nested = {"rig1": {"okid_arx_identifier": {"ros__parameters": {"sample_time_s": 0.01}}}}
    assert not any("holds no" in line for line in file_report(nested, "f.yaml", names))


def test_the_nested_namespace_form_is_read_as_rcl_reads_it(tmp_path):
    path = tmp_path / "nested.yaml"
    path.write_text("/**:\n  okid_arx_identifier:\n    ros__parameters:\n      publish_rate_hz: 5.0\n"
                    "rig1:\n  okid_modal_estimator:\n    ros__parameters:\n      tracking:\n        min_mac: 0.55\n")
    reported: list[str] = []
    arx, est = load_node_parameters([path], report=reported.append)
    assert arx["publish_rate_hz"] == 5.0 and est["tracking.min_mac"] != 0.55  # rig1's is not the root node's
    assert len(reported) == 1 and "'rig1/okid_modal_estimator' does not apply to /okid_modal_estimator" in reported[0]
    _, est_rig1 = load_node_parameters([path], namespace="/rig1", strict=True)
    assert est_rig1["tracking.min_mac"] == 0.55


def test_params_files_are_found_among_ros_arguments():
    argv = ["node", "--ros-args", "--params-file", "a.yaml", "-r", "__ns:=/x", "--params-file", "b.yaml",
            "--", "--params-file", "not_ros.yaml"]
    assert params_files_from_args(argv) == ["a.yaml", "b.yaml"]
    assert params_files_from_args(["node", "--params-file", "x.yaml"]) == []


def test_namespaced_parameter_file_sections(tmp_path):
    path = tmp_path / "rigs.yaml"
    path.write_text("/rig1/okid_arx_identifier:\n  ros__parameters:\n    arx: {order: 20}\n"
                    "/rig2/okid_arx_identifier:\n  ros__parameters:\n    arx: {order: 30}\n")
    assert load_parameters(path, ARX_NODE, namespace="/rig1")["arx.order"] == 20
    assert load_parameters(path, ARX_NODE, namespace="/rig2")["arx.order"] == 30
    assert load_parameters(path, ARX_NODE)["arx.order"] == 100


def test_a_key_given_twice_is_reported_and_the_last_value_counts(tmp_path):
    # rcl keeps the last value of a key given twice, as YAML loaders do; nothing said so before.
    path = tmp_path / "twice.yaml"
    path.write_text("/**:\n  ros__parameters:\n    publish_rate_hz: 1.0\n    arx: {order: 20}\n"
                    "    publish_rate_hz: 4.0\n"
                    "/**/okid_modal_estimator:\n  ros__parameters:\n    tracking: {min_mac: 0.8, min_mac: 0.7}\n")
    reported: list[str] = []
    arx, est = load_node_parameters([path], report=reported.append)
    assert arx["publish_rate_hz"] == 4.0 and est["tracking.min_mac"] == 0.7
    assert reported == [
        f"{path}: key 'publish_rate_hz' is given twice in one mapping (lines 3 and 5): the last value counts, "
        "as rcl reads it",
        f"{path}: key 'min_mac' is given twice in one mapping (line 8): the last value counts, as rcl reads it",
    ], reported
    with pytest.raises(ParameterError, match="given twice"):
        load_node_parameters([path], strict=True)


def test_a_parameter_given_dotted_and_nested_in_one_section_is_refused(tmp_path, capsys):
    # Hostile sweep of session 31: `inputs.sources: [...]` and `inputs: {sources: [...]}` in one
    # section; the later one won in silence (as in rcl: a node took it too), the other was lost.
    from cli_helpers import assert_one_line_error, run_cli

    path = tmp_path / "both.yaml"
    path.write_text('/**:\n  ros__parameters:\n    inputs.sources: ["io_sample /okid/io_sample"]\n'
                    '    inputs:\n      sources: ["imu /accel/tip1/imu linear_acceleration.x=y0"]\n')
    message = (f"parameter file {path}: section '/**': parameter inputs.sources is given twice, as "
               "'inputs.sources' and as 'inputs: {sources}': give it once")
    for read in (lambda: load_node_parameters([path]), lambda: load_parameters(path, ARX_NODE)):
        with pytest.raises(ParameterError) as refused:
            read()
        assert str(refused.value) == message
    code, _, err = run_cli(capsys, "batch", tmp_path, "--plan", "--params", path)
    assert_one_line_error(code, err, message)
    # Any pair, at any depth, in a node's own section too; names that only share a prefix are fine.
    path.write_text("/**/okid_arx_identifier:\n  ros__parameters:\n    arx: {order: 30, window_length: 500}\n"
                    "    a.b: {c: 1}\n    a: {b.c: 2}\n")
    with pytest.raises(ParameterError, match=r"section '/\*\*/okid_arx_identifier': parameter a.b.c is given "
                                             r"twice, as 'a.b: \{c\}' and as 'a: \{b.c\}'"):
        load_node_parameters([path])
    path.write_text("/**:\n  ros__parameters:\n    arx.order: 30\n    arx: {window_length: 500}\n")
    arx, _ = load_node_parameters([path], strict=True)
    assert (arx["arx.order"], arx["arx.window_length"]) == (30, 500)


def test_a_section_that_applies_to_no_node_is_reported_with_the_closest_node_name(tmp_path):
    # A misspelt node name applies to no node: the run used the defaults, in silence, even with --strict-params.
    path = tmp_path / "misspelt.yaml"
    path.write_text("/**/okid_arx_identifer:\n  ros__parameters:\n    arx: {order: 20}\n"
                    "/**/some_other_node:\n  ros__parameters:\n    rate: 5\n")
    reported: list[str] = []
    arx, _ = load_node_parameters([path], report=reported.append)
    assert arx["arx.order"] == 100 and len(reported) == 2
    assert "section '/**/okid_arx_identifer' applies to no node" in reported[0]
    assert "did you mean '/**/okid_arx_identifier'?" in reported[0]
    assert "'/**/some_other_node' applies to no node" in reported[1] and "did you mean" not in reported[1]
    with pytest.raises(ParameterError, match="okid_arx_identifer' applies to no node"):
        load_node_parameters([path], strict=True)
    names = {n: [s.name for s in node_params(n)] for n in (ARX_NODE, ESTIMATOR_NODE)}
    tree = yaml.safe_load(path.read_text())
    # A node reports the near miss of its own name only (a shared file holds other nodes' sections).
    assert len(file_report(tree, "f.yaml", names, for_node=ARX_NODE)) == 1
    assert file_report(tree, "f.yaml", names, for_node=ESTIMATOR_NODE) == []


def test_a_bad_param_value_names_the_option_not_the_last_file(tmp_path):
    path = tmp_path / "small.yaml"
    path.write_text("/**/okid_arx_identifier:\n  ros__parameters:\n    arx: {order: 20}\n")
    with pytest.raises(ParameterError, match=r"^--param arx.order=abc: parameter arx.order must be a number"):
        load_node_parameters([path], ["arx.order=abc"])
    with pytest.raises(ParameterError, match=r"^--param arx.window_length=-5: parameter arx.window_length"):
        load_node_parameters([path], ["arx.window_length=-5"])
    bad = tmp_path / "bad.yaml"
    bad.write_text("/**/okid_arx_identifier:\n  ros__parameters:\n    arx: {order: abc}\n")
    with pytest.raises(ParameterError, match=rf"^{bad}: parameter arx.order must be a number"):  # a file's own
        load_node_parameters([path, bad], ["arx.window_length=500"])
