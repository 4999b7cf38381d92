"""The resolved parameters of both nodes, read as the nodes read them (``okid-ros process``, ``track``, ...)."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from math import isclose
from pathlib import Path
from typing import Any

from okid_ros.errors import OkidWarning, ParameterError, shown_path

__all__ = ["load_node_parameters"]


def load_node_parameters(param_files: Sequence[str | Path] = (), overrides: Sequence[str] = (),
                         sources: Sequence[str] = (), *, namespace: str | None = None,
                         strict: bool = False, report: Callable[[str], None] | None = None) -> tuple[dict, dict]:
    """Resolved parameters of both nodes, as the nodes would read them.

    Parameters
    ----------
    param_files : ROS parameter YAML files, later ones override earlier ones (as several
        ``--params-file`` do); none: the defaults (equal to config/okid.yaml).
    overrides : ``NAME=VALUE`` (dotted name, YAML value), applied to each node that has
        the parameter, after the files.
    sources : if given, replaces ``inputs.sources`` of both nodes.
    namespace : the nodes' namespace (None: the root namespace); decides which sections of
        the files apply, as for the live nodes.
    strict : unknown parameter names (or sections naming a node that do not apply) in the
        files are an error instead of a report. A value the nodes refuse for its type (``8`` for a
        floating-point parameter: rclpy's typed parameters; the nodes do not start) is an error
        always, in a file or an override, as it is for the nodes (:func:`~okid_ros.service.params.rcl_type_problem`).
    report : called with each such problem when not ``strict``, and with an ``inputs.time_jump_s``
        the sample grid raises (:func:`okid_ros.service.inputs.time_jump_note`) (default: an
        :class:`~okid_ros.errors.OkidWarning`, which `okid-ros` prints as its command's warning line).

    Returns
    -------
        (identification node values, estimation node values), dotted names.

    Raises
    ------
    ParameterError
        unreadable file, bad value, an override no node knows, or (``strict``) an unknown
        name in a file.
    """
    from okid_ros.service.inputs import time_jump_note
    from okid_ros.service.param_files import file_report, node_fqn, node_values_from_tree
    from okid_ros.service.params import (
        ARX_NODE,
        ESTIMATOR_NODE,
        node_params,
        read_parameter_file,
        resolve_parameters,
    )

    names = {node: {s.name for s in node_params(node)} for node in (ARX_NODE, ESTIMATOR_NODE)}
    layered = _overrides(overrides, names)
    # Where each value given on the command line came from: a bad one is blamed on its option, not a file.
    given = {name: f"--param {item.strip()}" for (name, _), item in zip(layered, overrides)}
    if sources:
        layered.append(("inputs.sources", list(sources)))
        given["inputs.sources"] = "--source"
    trees = [(shown_path(path), read_parameter_file(path)) for path in param_files]  # labels of messages
    problems = [p for label, tree in trees for p in file_report(tree, label, names, namespace)]
    if problems and strict:
        raise ParameterError("; ".join(problems))
    say = report or (lambda text: warnings.warn(text, OkidWarning, stacklevel=3))
    for problem in problems:
        say(problem)
    # The nodes do not start on such a value (rclpy's typed parameters), strict or not: nor does this.
    if typed := _typed_problems(trees, namespace) + _typed_override_problems(layered, given):
        raise ParameterError("; ".join(typed))
    values, origins = [], []
    for node in (ARX_NODE, ESTIMATOR_NODE):
        merged: dict[str, Any] = {}
        origins.append(origin := {})  # parameter -> the file or option that gave it
        for label, tree in trees:
            found = node_values_from_tree(tree, node_fqn(node, namespace))
            merged.update(found)
            origin.update({name: label for name in found})
        merged.update((name, value) for name, value in layered if name in names[node])
        origin.update((name, given[name]) for name, _ in layered if name in names[node])
        merged = {k: v for k, v in merged.items() if k in names[node]}
        try:
            values.append(resolve_parameters(node, merged))
        except ParameterError as exc:
            label = next((origin[n] for n in origin if f"parameter {n} " in str(exc)), None)
            raise ParameterError(f"{label}: {exc}" if label else str(exc)) from None
    _check_sizes_agree(values, origins)
    for note in dict.fromkeys(time_jump_note(v) for v in values):  # a section of each node: said once
        if note:
            say(note)
    return values[0], values[1]


def _check_sizes_agree(values: list[dict], origins: list[dict[str, str]]) -> None:
    """Raise ParameterError where the nodes' values of a shared parameter that sizes the model differ.

    Node 2 refuses every ArxModel of another sample time or other dimensions than its own
    (``estimator_arx_fit``, ``RealizationHandoff.arrival``): with such values no model ever comes.
    """
    from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, SHARED_PARAMS, SIZES

    for spec in SHARED_PARAMS:
        ours, theirs = (v[spec.name] for v in values)
        if spec.fixed != SIZES or ours == theirs or isclose(ours, theirs, rel_tol=1e-9):  # the node's tolerance
            continue
        where = " and ".join(f"{node} {value!r} ({origin.get(spec.name, 'default')})" for node, value, origin
                             in zip((ARX_NODE, ESTIMATOR_NODE), (ours, theirs), origins))
        raise ParameterError(f"parameter {spec.name} differs between the nodes: {where}; node 2 refuses every "
                             f"ArxModel of another sample time or size than its own, so no model would come: set "
                             f"{spec.name} once, in the '/**' section both nodes read")


def _overrides(overrides: Sequence[str], names: dict[str, set[str]]) -> list[tuple[str, Any]]:
    """``(name, value)`` of each ``NAME=VALUE`` override, its value typed as rcl types it; ParameterError if bad."""
    import yaml

    from okid_ros.service.param_files import load_yaml_as_rcl

    layered: list[tuple[str, Any]] = []
    for item in overrides:
        name, sep, text = item.partition("=")
        name = name.strip().removesuffix(":")  # NAME:=VALUE as ros2 run's -p writes it, too
        if not sep or not name:
            raise ParameterError(f"--param {item!r} must be NAME=VALUE, e.g. publish_rate_hz=0.5")
        try:
            value = load_yaml_as_rcl(text, f"--param {item!r}")
        except yaml.YAMLError:
            raise ParameterError(f"--param {item!r}: the value is not valid YAML") from None
        if not any(name in known for known in names.values()):
            raise ParameterError(f"--param {name}: no such parameter of {' or '.join(names)}")
        layered.append((name, value))
    return layered


def _typed_override_problems(layered: list[tuple[str, Any]], given: dict[str, str]) -> list[str]:
    """Values of ``--param`` that the nodes refuse for their type (``-p sample_time_s:=1`` does not start them)."""
    from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, node_params, rcl_type_problem

    specs = {spec.name: spec for node in (ARX_NODE, ESTIMATOR_NODE) for spec in node_params(node)}
    found = {}
    for name, value in layered:
        if name in specs and name in given and (why := rcl_type_problem(specs[name], value)):
            found[name] = f"{given[name]}: parameter {name} = {value!r} {why}"
    return list(found.values())


def _typed_problems(trees: list[tuple[str, Any]], namespace: str | None) -> list[str]:
    """Values of the files that the nodes refuse for their type, one sentence each."""
    from okid_ros.service.param_files import node_fqn, node_values_from_tree
    from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, node_params, rcl_type_problem

    specs = {node: {spec.name: spec for spec in node_params(node)} for node in (ARX_NODE, ESTIMATOR_NODE)}
    found: dict[tuple[str, str], str] = {}  # a value of a section both nodes read is said once
    for label, tree in trees:
        for node, by_name in specs.items():
            for name, value in node_values_from_tree(tree, node_fqn(node, namespace)).items():
                why = rcl_type_problem(by_name[name], value) if name in by_name else ""
                if why:
                    found.setdefault((label, name), f"{label}: parameter {name} = {value!r} {why}")
    return list(found.values())
