"""Strict JSON for every file and line `okid-ros` writes: ``null``, never ``NaN`` or ``Infinity``.

Python's ``json`` writes the non-standard tokens ``NaN``, ``Infinity`` and ``-Infinity`` for
non-finite floats, which strict parsers (JavaScript's ``JSON.parse``, ``jq`` with some options,
Go, Rust's serde_json) reject. Every output goes through :func:`dumps`, which turns non-finite
numbers into ``null`` and numpy scalars and arrays into plain JSON, and refuses anything else
that is not JSON (``allow_nan=False`` as a last guard).
"""

from __future__ import annotations

import contextlib
import math
from pathlib import Path
from typing import Any

import numpy as np

from okid_ros.errors import replacing, write_atomically, writing

__all__ = ["NOT_JSON", "finite_number", "to_strict", "dumps", "write_json"]

#: What ``json.loads`` raises for a text that is no JSON: ValueError (UnicodeDecodeError among them),
#: and RecursionError for arrays or objects nested some thousands deep (an internal error, exit 70, before).
NOT_JSON = (ValueError, RecursionError)


def finite_number(value: Any) -> bool:
    """Whether a value read from JSON is a number float64 holds: an int or a finite float, not a bool.

    JSON's integers have no bound: one beyond float64 (a 1 and 400 zeros) made math.isfinite raise
    OverflowError, and numpy's isfinite TypeError from 2**64 on (an internal error, exit 70).
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def to_strict(value: Any) -> Any:
    """A copy of ``value`` that strict JSON can hold.

    Non-finite floats become None; numpy scalars become Python numbers, numpy arrays nested
    lists; tuples become lists; dict keys become strings. Other objects are returned as they are
    (``json`` then raises on them, or applies the caller's ``default``).
    """
    kind = type(value)
    if kind is float:  # the common leaves first: a model's JSON has tens of thousands of them
        return value if math.isfinite(value) else None
    if kind is str or kind is int or value is None:
        return value
    if isinstance(value, dict):
        return {str(k): to_strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_strict(v) for v in value]
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "biu" or (value.dtype.kind == "f" and np.isfinite(value).all()):
            return value.tolist()  # already plain Python numbers, nothing to replace
        return to_strict(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    return value


def dumps(value: Any, **kwargs: Any) -> str:
    """``json.dumps`` of :func:`to_strict` ``(value)`` with ``allow_nan=False``."""
    import json

    kwargs.setdefault("allow_nan", False)
    return json.dumps(to_strict(value), **kwargs)


def write_json(path: str | Path, value: Any, *, indent: int | None = 1) -> None:
    """Write one strict JSON document to ``path`` (callers check ``--force`` first).

    The document is made first and written atomically: a failure leaves no truncated file.
    """
    text = (dumps(value, indent=indent) + "\n").encode()
    write_atomically(path, lambda stream: stream.write(text))


class JsonLines:
    """A JSON lines output written as its lines come (``track``, ``process --jsonl``).

    One strict JSON object per line, flushed each time; failing to open or write it (a full
    disk) is an :class:`~okid_ros.errors.OutputError` naming the file. A context manager.

    ``replace``: the lines go to a temporary file beside ``path``, renamed over it by
    :meth:`close` (:func:`okid_ros.errors.replacing`, the rule of every other file output):
    leaving the ``with`` block by an error removes them and leaves ``path`` as it was; by Ctrl-C
    (or SIGTERM, which the CLI turns into it) the lines so far replace it, as the user stopped the
    run, not the run itself (what is identified is kept). Without it (``process``, whose lines go
    with its bag and stay when it is interrupted) the file is opened in place, so the caller
    removes an old one first (``prepare_output``).
    """

    def __init__(self, path: str | Path, *, replace: bool = False) -> None:
        self.path = Path(path)
        self._open = contextlib.ExitStack()
        with writing(self.path, "JSON lines file"):
            self.stream = self._open.enter_context(replacing(self.path) if replace else open(self.path, "wb"))

    def write(self, line: Any) -> None:
        with writing(self.path, "JSON lines file"):
            self.stream.write((dumps(line) + "\n").encode())
            self.stream.flush()

    def close(self) -> None:
        with writing(self.path, "JSON lines file"):
            self._open.close()

    def __enter__(self) -> JsonLines:
        return self

    def __exit__(self, kind, value, traceback) -> None:
        if kind is not None and not issubclass(kind, KeyboardInterrupt):  # temporary file removed; the error stands
            with contextlib.suppress(Exception):
                self._open.__exit__(kind, value, traceback)
            return
        self.close()
