"""The .csv record format read by :func:`okid_ros.records.load_record` (its rules: that module's docstring).

A header naming the columns, one row a sample, the sample time from a comment line or a
``time_s`` column; every refusal a :class:`~okid_ros.errors.DataError` naming the file, the row
and the column. The result is the record's arrays, checked as a whole by
:meth:`okid_ros.records.Record.validate`.
"""

from __future__ import annotations

import csv
import re
import unicodedata
import warnings
from pathlib import Path

import numpy as np

from okid_ros.core.column_names import repeated_column_names
from okid_ros.core.record_stamps import stamp_jump_problem
from okid_ros.errors import DataError, OkidWarning, os_reason, shown_path
from okid_ros.record_keys import check_csv_extras, comment_hint, decimals_written, named_like_time

__all__ = ["read_csv_record"]


def _plain(text: str) -> bool:
    """Whether a number's text has neither Python's digit separator nor non-ASCII digits.

    float() reads both ("1_000" as 1000, "0_01" as 1, "١٢" as 12), which no CSV writer emits: a
    typo or a locale's grouping, refused.
    """
    return "_" not in text and text.isascii()


def _comment_setting(comment: str) -> tuple[str, str]:
    """The name and value of a ``# name=value`` (or ``# name: value``) comment line."""
    text = comment.lstrip("#")
    name, _, value = text.partition("=") if "=" in text else text.partition(":")
    return name.strip(), value


def _csv_sample_time(path: Path, comment: str) -> float:
    """The value of a ``# sample_time_s=...`` comment line."""
    value = _comment_setting(comment)[1]
    try:
        if not _plain(value):
            raise ValueError(value)
        return float(value)
    except ValueError:
        raise DataError(f"{shown_path(path)}: bad sample_time_s comment {comment!r}") from None


def _csv_rows(path: Path, wanted) -> tuple[float | None, list[str], np.ndarray, dict[int, list[str]], dict[str, str]]:
    """The sample time of the comment (or None), the header, the (N, columns) values and what is not read.

    ``wanted(header)``: the indices of the columns read as numbers; the others are ignored
    (a text column of labels does not stop the record), their values NaN, their texts returned by
    index; last, the other ``# name=value`` comments' values by name.
    """
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{shown_path(path)}: cannot read as UTF-8 text ({os_reason(exc)})") from None
    dt, settings = None, {}
    body, commented = [], []  # commented: (data rows before it, its text) of comment lines among the rows
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("#"):
            if body:
                commented.append((len(body) - 1, stripped.lstrip("#").strip()))
            if _comment_setting(stripped)[0] == "sample_time_s":
                given = _csv_sample_time(path, stripped)
                if dt is not None and given != dt:  # the first must not be silently overridden
                    raise DataError(f"{shown_path(path)}: two different sample_time_s comments "
                                    f"({dt:g} and {given:g} s)")
                dt = given
            elif "=" in stripped or ":" in stripped:
                settings.setdefault(*_comment_setting(stripped))
        elif stripped:
            body.append(line)
    if not body:
        raise DataError(f"{shown_path(path)}: no header line")
    try:
        rows = list(csv.reader(body))
    except csv.Error as exc:  # a field past the csv module's limit (131072 characters), e.g. an unclosed quote
        raise DataError(f"{shown_path(path)}: not a CSV table the reader can take ({exc})") from None
    # Invisible characters (a zero-width space, a NUL, a second BOM) would hide a 'u1' from its prefix.
    header = ["".join(c for c in h if unicodedata.category(c) not in ("Cc", "Cf")).strip() for h in rows[0]]
    for number, row in enumerate(rows[1:], start=1):
        if len(row) != len(header):
            raise DataError(f"{shown_path(path)}: data row {number} has {len(row)} values, the header {len(header)}"
                            f"{_separator_hint(header, body[number] if number < len(body) else body[0])}")
    _warn_commented_rows(path, commented, len(header), len(rows) - 1)
    if names := repeated_column_names(header, wanted(header)):  # read as 2 channels ('y1' and 'Y1' too)
        raise DataError(f"{shown_path(path)}: the header names {names} (a column given twice?): rename or remove one")
    values = np.full((len(rows) - 1, len(header)), np.nan)
    for column in wanted(header):
        texts = [row[column] for row in rows[1:]]
        try:
            values[:, column] = [float(text) for text in texts]
        except ValueError:
            raise DataError(f"{shown_path(path)}: {_not_a_number(header, column, texts)}") from None
        loose = next((number for number, text in enumerate(texts, start=1) if not _plain(text)), None)
        if loose is not None:
            raise DataError(f"{shown_path(path)}: data row {loose}, column {header[column]!r}: "
                            f"{texts[loose - 1].strip()!r} is not a plain decimal number")
    ignored = {column: [row[column] for row in rows[1:]] for column in range(len(header))
               if column not in wanted(header)}
    return dt, header, values, ignored, settings


def _warn_commented_rows(path: Path, commented: list[tuple[int, str]], columns: int, n_rows: int) -> None:
    """Warn of comment lines between data rows that read as a row of numbers: a sample left out.

    Without a ``time_s`` column nothing else shows the gap: the samples either side are taken as
    neighbours (``commented``: (data rows before it, its text without the ``#``)).
    """
    dropped = [before for before, text in commented
               if 0 < before < n_rows and len(row := text.split(",")) == columns and all(map(_is_float, row))]
    if dropped:
        where = ", ".join(f"after data row {before}" for before in dropped[:3]) + (", ..." if len(dropped) > 3 else "")
        warnings.warn(f"{shown_path(path)}: {len(dropped)} commented-out data row(s) between the samples ({where}): "
                      "each is a sample missing from the record, its neighbours taken as consecutive; uncomment it or "
                      "give a time_s column to mark the gap", OkidWarning, stacklevel=4)


def _not_a_number(header: list[str], column: int, texts: list[str]) -> str:
    """Where a column of a CSV holds text that is no number, with a hint for a separator not a comma."""
    row = next(number for number, text in enumerate(texts, start=1) if not _is_float(text))
    hint = _separator_hint(header, texts[row - 1])
    return f"non-numeric value in column {header[column]!r} (data row {row}: {texts[row - 1].strip()!r}){hint}"


def _separator_hint(header: list[str], text: str) -> str:
    """A hint when a table's text looks written in another locale (semicolons, tabs, decimal commas), else "".

    ``text``: a data row's raw line (or, for a one-column table, its value). Numbers written with a
    decimal comma split a comma-separated row into about twice the header's values, each an integer.
    """
    if len(header) == 1 and (mark := next((m for m in (";", "\t") if m in text), "")):
        name = "semicolons" if mark == ";" else "tabs"
        comma = ", numbers with decimal commas" if re.search(r"[0-9],[0-9]", text) else ""
        return f" (values separated by {name}{comma}? a CSV here is separated by commas, with decimal points)"
    fields = [field.strip() for field in text.split(",")]
    if len(fields) > len(header) and all(re.fullmatch(r"[-+]?[0-9]+", field) for field in fields):
        return " (numbers written with decimal commas? a CSV here has decimal points: 0.25, not 0,25)"
    return ""


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _csv_columns(header: list[str]) -> tuple[list[int], list[int], list[int]]:
    """Indices of the input, output and time columns (``time_s``, ``stamp_s``) of a CSV header."""
    return ([i for i, h in enumerate(header) if h.lower().startswith("u")],
            [i for i, h in enumerate(header) if h.lower().startswith("y")],
            [i for i, h in enumerate(header) if h in ("time_s", "stamp_s")])


def read_csv_record(path: Path) -> tuple[np.ndarray, np.ndarray, float]:
    """The inputs ``u`` (N, m), outputs ``y`` (N, p) and sample time of a .csv record, or DataError."""
    dt, header, values, ignored, settings = _csv_rows(path, lambda header: sorted(sum(_csv_columns(header), [])))
    u_cols, y_cols, _ = _csv_columns(header)
    if not y_cols:
        raise DataError(f"{shown_path(path)}: header needs output columns 'y...' (inputs 'u...' optional), "
                        f"got {header}")
    # 'uptime_s' or 'year' is a channel by the format's first-letter rule: say so, the user may not expect it.
    worded = [f"{header[i]!r} ({kind} {j})" for kind, cols in (("input", u_cols), ("output", y_cols))
              for j, i in enumerate(cols) if not re.match(r"[uy]([0-9_.\- ]|$)", header[i], re.IGNORECASE)]
    if worded:
        warnings.warn(f"{shown_path(path)}: columns read as channels by their first letter: {', '.join(worded)}; "
                      f"rename or remove those that are not channels", OkidWarning, stacklevel=3)
    if dt is None and "time_s" not in header:
        hint = _time_hint(header) or comment_hint(settings)
        raise DataError(f"{shown_path(path)}: no '# sample_time_s=...' line and no time_s column{hint}")
    if "time_s" in header:
        times = values[:, header.index("time_s")]
        step, rounding, irregular = _uniform_step(times)
        if irregular:  # also with a sample_time_s comment: the samples either side of a gap are not neighbours
            advice = ("; the identification needs samples on one uniform grid: resample the record onto one, or cut "
                      "it where the step changes" if " follows row " in irregular else "")
            raise DataError(f"{shown_path(path)}: time_s is not uniformly increasing ({irregular}){advice}")
        if dt is not None and abs(step - dt) > max(1e-6 * dt, rounding / max(times.size - 1, 1)):
            raise DataError(f"{shown_path(path)}: the sample_time_s comment says {dt:g} s and the time_s column "
                            f"steps {step:g} s")
        dt = step if dt is None else dt
    if "stamp_s" in header and (jump := stamp_jump_problem(values[:, header.index("stamp_s")], dt,
                                                           n_samples=values.shape[0], rows=True)):
        raise DataError(f"{shown_path(path)}: {jump}")
    check_csv_extras(path, header, ignored, settings, dt)
    return values[:, u_cols], values[:, y_cols], dt


def _time_hint(header: list[str]) -> str:
    """A hint naming a column that looks like the samples' times but is not read as them ("" if none)."""
    named = next((name for name in header if named_like_time(name, in_a_unit=True)), None)
    if named is None:
        return ""
    return (f" (the column {named!r} is not read as the time: name it time_s, in seconds from any start, or give "
            f"the sample time as a first line '# sample_time_s=0.005')")


def _uniform_step(times: np.ndarray) -> tuple[float, float, str]:
    """The step of a time column, the rounding of its times and, if it is not a uniform grid, where not ("" if it is).

    Uniform: every time within 1e-6 of a step of the grid from the first to the last, or within the rounding of
    the times as written (``0.003`` for 1/300 s to 3 decimals) or of float64 (epoch seconds: about 2e-7 s).
    """
    steps = np.diff(times)
    if steps.size == 0 or not np.all(np.isfinite(steps)) or not np.all(steps > 0):
        bad = int(np.argmax(~(steps > 0))) if steps.size and np.isfinite(steps).all() else None
        return 0.0, 0.0, ("fewer than two times" if steps.size == 0 else
                          "NaN/Inf in it" if bad is None else f"data row {bad + 2} is not after row {bad + 1}")
    step = float((times[-1] - times[0]) / steps.size)
    rounding = max(4 * np.finfo(float).eps * np.max(np.abs(times)), 0.5 * 10.0 ** -decimals_written(times))
    off = np.abs(times - (times[0] + step * np.arange(times.size)))
    if np.max(off) <= max(1e-6 * step, 2 * rounding):
        return step, rounding, ""
    row = int(np.argmax(np.abs(steps - step) > max(1e-6 * step, 2 * rounding)))
    return step, rounding, (f"data row {row + 2} follows row {row + 1} by {steps[row]:g} s, the column's mean "
                            f"step is {step:g} s")
