"""The JSON documents `plot` reads from a bag's metadata, checked before any figure is drawn.

A bag's ``metadata.yaml`` is a text file anyone can edit, and its ``custom_data`` entries
(:data:`~okid_ros.tools.bagio.TRUTH_KEY`, ``STABILIZATION_KEY``, ``PROCESS_KEY``) may parse as
JSON and still not have the shape `simulate` and `process` write. Each check returns the
document when every part a figure reads is there with the right type and size, else None (the
process record: without the parts it cannot use) and the reason; `plot` then draws without it
and says so, instead of stopping half way through the figures.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from okid_ros.jsonio import finite_number

__all__ = ["check_plot_metadata", "usable_process_info", "usable_stabilization", "usable_truth"]

_TRUTH_MATRICES = ("A", "B", "C", "D", "K")


def _matrix(value: Any, name: str) -> np.ndarray:
    finite = f"{name} is not a finite 2-D matrix"
    try:
        array = np.asarray(value, dtype=float)
    except OverflowError:  # a JSON integer beyond float64 (exit 70 before)
        raise ValueError(finite) from None
    except (TypeError, ValueError):
        raise ValueError(f"{name} is not a matrix of numbers") from None
    if array.ndim != 2 or not np.all(np.isfinite(array)):
        raise ValueError(finite)
    return array


def _number(value: Any, name: str) -> float:
    if not finite_number(value):
        raise ValueError(f"{name} is not a finite number")
    return float(value)


def usable_truth(truth: Any) -> tuple[dict | None, str]:
    """The simulated truth if its matrices and modes are usable: ``(truth, "")`` or ``(None, reason)``.

    Matrices ``A`` (n, n), ``B`` (n, m), ``C`` (p, n), ``D`` (p, m), ``K`` (n, p) finite when
    given (all or none), ``sample_time_s`` positive, ``modes`` a list of mappings with a finite
    ``frequency_hz`` and ``damping_ratio``.
    """
    if truth is None:
        return None, ""
    try:
        if not isinstance(truth, dict):
            raise ValueError("not a JSON object")
        given = [name for name in _TRUTH_MATRICES if name in truth]
        if given:
            A, B, C, D, K = (_matrix(truth.get(name), name) for name in _TRUTH_MATRICES)
            n, m, p = A.shape[0], B.shape[1], C.shape[0]
            shapes = {"A": (n, n), "B": (n, m), "C": (p, n), "D": (p, m), "K": (n, p)}
            wrong = [f"{k} {v.shape}" for k, v in zip(_TRUTH_MATRICES, (A, B, C, D, K)) if v.shape != shapes[k]]
            if wrong:
                raise ValueError(f"matrix sizes do not fit together ({', '.join(wrong)})")
        if "sample_time_s" in truth and not _number(truth["sample_time_s"], "sample_time_s") > 0:
            raise ValueError("sample_time_s is not positive")
        modes = truth.get("modes", [])
        if not isinstance(modes, list) or not all(isinstance(mode, dict) for mode in modes):
            raise ValueError("modes is not a list of objects")
        for mode in modes:
            _number(mode.get("frequency_hz"), "a mode's frequency_hz")
            _number(mode.get("damping_ratio"), "a mode's damping_ratio")
    except ValueError as exc:
        return None, str(exc)
    return truth, ""


def usable_stabilization(stabilization: Any) -> tuple[list | None, str]:
    """The stabilization data of `process` if usable: a list of ``{"n_states", "poles": [...]}``."""
    if stabilization is None:
        return None, ""
    try:
        if not isinstance(stabilization, list):
            raise ValueError("not a JSON list")
        for entry in stabilization:
            if not isinstance(entry, dict) or not isinstance(entry.get("poles", []), list):
                raise ValueError("an entry is not an object with a list of poles")
            if isinstance(entry.get("n_states"), bool) or not isinstance(entry.get("n_states"), int):
                raise ValueError("an entry's n_states is not an integer")
            for pole in entry.get("poles", []):
                if not isinstance(pole, dict):
                    raise ValueError("a pole is not an object")
                _number(pole.get("frequency_hz"), "a pole's frequency_hz")
    except ValueError as exc:
        return None, str(exc)
    return stabilization, ""


def usable_process_info(info: Any, estimator_node: str) -> tuple[dict | None, str]:
    """What `process` recorded of its run, without the parts plot cannot use: ``(info, "")`` or ``(info, reason)``.

    Not an object: ``(None, reason)``. A ``first_stamp_s`` that is no ROS 2 time in seconds and
    ``parameters`` whose estimator node's values the node would refuse are dropped from the
    copy returned (the input bag is then read with ``--params`` or the built-in defaults); the
    estimator's values kept are those :func:`~okid_ros.service.params.resolve_parameters` gives.
    """
    from okid_ros.errors import ParameterError
    from okid_ros.service.inputs import parse_sources
    from okid_ros.service.params import node_params, resolve_parameters
    from okid_ros.service.stamp_steps import MAX_STAMP_S

    if info is None:
        return None, ""
    if not isinstance(info, dict):
        return None, "not a JSON object"
    info, problems = dict(info), []
    if "first_stamp_s" in info and not (finite_number(info["first_stamp_s"])
                                        and abs(float(info["first_stamp_s"])) <= MAX_STAMP_S):
        problems.append(f"its first_stamp_s is not a ROS 2 time (seconds up to {MAX_STAMP_S})")
        del info["first_stamp_s"]
    parameters = info.get("parameters")
    if parameters is not None:
        try:
            if not (isinstance(parameters, dict) and isinstance(parameters.get(estimator_node), dict)):
                raise ParameterError("no object")
            known = {spec.name for spec in node_params(estimator_node)}
            values = resolve_parameters(estimator_node, {k: v for k, v in parameters[estimator_node].items()
                                                         if k in known})
            parse_sources(values["inputs.sources"], values["n_inputs"], values["n_outputs"])
            info["parameters"] = {**parameters, estimator_node: values}
        except (ParameterError, ValueError) as exc:
            problems.append(f"its parameters of {estimator_node}: {exc}; the input bag read with --params or the "
                            "built-in defaults")
            del info["parameters"]
    return info, "; ".join(problems)


def check_plot_metadata(path: Any, data: Any) -> None:
    """Leave out of ``data`` (a ``PlotData``) each metadata document a figure could not read, with a warning."""
    import warnings

    from okid_ros.errors import OkidWarning, shown_path
    from okid_ros.service.params import ESTIMATOR_NODE
    from okid_ros.tools.bagio import PROCESS_KEY, STABILIZATION_KEY, TRUTH_KEY

    data.truth, why_truth = usable_truth(data.truth)
    data.stabilization, why_stabilization = usable_stabilization(data.stabilization)
    data.process_info, why_process = usable_process_info(data.process_info, ESTIMATOR_NODE)
    for key, why in ((TRUTH_KEY, why_truth), (STABILIZATION_KEY, why_stabilization), (PROCESS_KEY, why_process)):
        if why:
            warnings.warn(f"{shown_path(path)}: metadata.yaml's {key} is not what plot can draw ({why}): left out",
                          OkidWarning, stacklevel=3)
