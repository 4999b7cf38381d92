"""Checking what a previous run of `okid-ros batch` left, before it is taken as it is.

A rerun keeps the result of an unchanged bag: for an ok bag its ``bags/LABEL/result.json``,
for a failed one the summary in its manifest entry. Both are JSON that a disk error, an
interrupted copy or a hand edit may have spoilt; what the tables need is checked here, so
that a spoilt result makes the bag run again (with a warning) instead of stopping the
campaign with a Python error. Nothing is deleted here: a good stored result is only ever
replaced by the complete folder of a new run (:func:`okid_ros.tools.campaign.manifest.replace_directory`).
"""

from __future__ import annotations

import json
from pathlib import Path

from okid_ros.errors import one_line, shown_path
from okid_ros.jsonio import NOT_JSON, finite_number
from okid_ros.tools.campaign.manifest import MANIFEST_NAME

__all__ = ["label_problem", "result_problem", "stored_result"]

#: Fields of a stored result that are numbers (or null) when present; the counts among them are finite.
_NUMBERS = ("models", "samples", "input_messages", "duration_s", "start_s", "seconds")
_COUNTS = ("models", "samples", "input_messages")
#: Fields of a stored mode that must be finite numbers (a mode of node 2 always has them), and those
#: that may also be null or NaN (a fresh mode's ``mac_previous``, an ``emac`` without its reference).
_MODE_NUMBERS = ("id", "frequency_rad_s", "frequency_hz", "damping_ratio")
_MODE_OPTIONAL = ("mpc", "msv", "emac", "frequency_hz_std", "damping_ratio_std", "mac_previous")


def _number(value: object) -> bool:
    """A number float64 holds (NaN too, as json reads it); an integer beyond float64 is none (exit 70 before)."""
    return finite_number(value) or isinstance(value, float)


def _finite_problem(what: str, value: object) -> str:
    """Why ``value`` is no finite number ('' when it is one): NaN and Inf read as floats from the JSON."""
    if finite_number(value):
        return ""
    return f"{what} is {value!r}, {'not finite' if _number(value) else 'not a number'}"


def label_problem(label: object) -> str:
    """Why ``label`` cannot name a folder under ``bags/`` ('' when it can)."""
    if not isinstance(label, str) or not label:
        return f"its label is {label!r}, not a folder name"
    if label in (".", "..") or "/" in label or "\\" in label or "\0" in label:
        return f"its label {label!r} is not a plain folder name"
    return ""


def _mode_problem(mode: object) -> str:
    if not isinstance(mode, dict):
        return "a mode is not an object"
    for name in _MODE_NUMBERS:
        if problem := _finite_problem(f"a mode's {name}", mode.get(name)):
            return problem
    for name in _MODE_OPTIONAL:
        if mode.get(name) is not None and not _number(mode[name]):
            return f"a mode's {name} is {mode[name]!r}, not a number"
    for name in ("shape_real", "shape_imag"):
        shape = mode.get(name)
        if shape is not None and not (isinstance(shape, list) and all(map(finite_number, shape))):
            return f"a mode's {name} is not a list of finite numbers"
    real, imag = mode.get("shape_real") or [], mode.get("shape_imag") or []
    if real and imag and len(real) != len(imag):
        return f"a mode's shape_real has {len(real)} entries, its shape_imag {len(imag)}"
    return ""


def _update_problem(update: object) -> str:
    if not isinstance(update, dict):
        return "a model update is not an object"
    if not finite_number(update.get("stamp_s")) or not isinstance(update.get("model_id"), int):
        return "a model update lacks its stamp_s or model_id"
    for name in ("arx_model_id", "n_states"):
        if name in update and not isinstance(update[name], int):
            return f"a model update's {name} is {update[name]!r}, not an integer"
    if not isinstance(update.get("modes"), list):
        return "a model update has no list of modes"
    return next((p for p in map(_mode_problem, update["modes"]) if p), "")


def result_problem(result: object, status: str) -> str:
    """What makes ``result`` unusable as the stored result of a bag of ``status``; '' when it is usable.

    Checked: the fields the tables read (status, label, counts and times as numbers, and for an
    ok bag every model update with its modes); counts, frequencies, damping ratios and shapes finite.
    """
    if not isinstance(result, dict):
        return f"not a JSON object but {type(result).__name__}"
    if result.get("status") != status:
        return f"its status is {result.get('status')!r}, the manifest says {status!r}"
    problem = label_problem(result.get("label"))
    if problem:
        return problem
    for name in _NUMBERS:
        value = result.get(name)
        if value is not None and not finite_number(value) and (name in _COUNTS or not _number(value)):
            return _finite_problem(f"its {name}", value)
    if status == "ok":
        if not isinstance(result.get("updates"), list):
            return "it has no list of model updates"
        return next((p for p in map(_update_problem, result["updates"]) if p), "")
    return ""


def stored_result(entry: dict, out_dir: Path, retry_failed: bool) -> tuple[dict | None, str]:
    """The result kept for an unchanged bag, or None when it must run again; and why, if spoilt.

    Parameters
    ----------
    entry : the bag's manifest entry (its key and fingerprint matched).
    out_dir : the campaign directory.
    retry_failed : run a bag that failed before again.

    Returns
    -------
    (result or None, problem): ``problem`` is '' unless the stored result or the entry is
    spoilt (then the result is None: the bag runs again, and the caller says why).
    """
    status = entry.get("status")
    if status == "failed":
        if retry_failed:
            return None, ""
        summary = entry.get("summary")
        problem = result_problem(summary, "failed")
        return (None, f"{shown_path(out_dir / MANIFEST_NAME)}: the entry of the bag is spoilt ({problem})") if problem \
            else ({**summary, "updates": []}, "")
    if status != "ok":
        return None, f"{shown_path(out_dir / MANIFEST_NAME)}: the entry of the bag has the status {status!r}"
    problem = label_problem(entry.get("label"))
    if problem:
        return None, f"{shown_path(out_dir / MANIFEST_NAME)}: the entry of the bag is spoilt ({problem})"
    path = out_dir / "bags" / entry["label"] / "result.json"
    if not path.is_file():
        return None, ""  # outputs removed by hand: do it again
    try:
        result = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, *NOT_JSON) as exc:
        return None, f"{shown_path(path)}: unreadable ({one_line(exc)[:120]})"
    problem = result_problem(result, "ok")
    return (None, f"{shown_path(path)}: {problem}") if problem else (result, "")
