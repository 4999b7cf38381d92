"""What a record holds beside what its reader reads: .npz keys and CSV columns and comments.

A record is read from ``u``, ``y``, ``sample_time_s`` and ``stamp_s`` (a CSV: ``u...``/``y...``
columns, ``time_s``, ``stamp_s`` and the ``# sample_time_s=`` comment); anything else was passed
over in silence, so a rate stored in Hz under ``fs`` that contradicts ``sample_time_s``, inputs
stored as ``U`` (the record then read as one without inputs) or channels stored one a key went
unsaid. The rules here:

- a sample rate (``fs``, ``sample_rate_hz``, ...), a sample time (``dt``, ``Ts``, ...) or a time
  vector (``t``, ``time_s``, ...) is checked against ``sample_time_s``: agreeing, nothing is said;
  contradicting, the record is refused naming both values; where ``sample_time_s`` is missing,
  the refusal says what to store;
- a key that looks like the inputs or outputs under another spelling (``U``, ``inputs``, ``y1``)
  where the read one is missing is refused, saying what to store;
- any other key (or named CSV column) is one warning naming it.

Only the members named like a sample time or rate are opened (a pickled member is never loaded).
"""

from __future__ import annotations

import difflib
import re
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from okid_ros.core.record_stamps import MAX_STAMP_SLIP
from okid_ros.errors import DataError, OkidWarning, shown_path

__all__ = ["NPZ_KEYS", "check_npz_keys", "missing_key_hint", "check_csv_extras", "comment_hint", "decimals_written",
           "named_like_time"]

#: The keys of an .npz record that are read.
NPZ_KEYS = ("u", "y", "sample_time_s", "stamp_s")
#: Names (lower case, letters and digits only) of a sample rate in Hz.
_RATE_NAMES = {"fs", "fshz", "samplerate", "sampleratehz", "samplingrate", "samplingratehz", "samplingfrequency",
               "samplingfrequencyhz", "samplefrequency", "samplefrequencyhz", "ratehz"}
#: Names of a sample time in seconds (a scalar) or of the samples' times (a vector).
_TIME_NAMES = {"dt", "dts", "ts", "sampletime", "sampletimes", "samplingtime", "samplingtimes", "sampleperiod",
               "sampleperiods", "samplingperiod", "samplingperiods", "timestep", "timesteps", "t", "time", "times",
               "timestamp", "timestamps", "stamps", "stamp", "tvec", "timevector"}
#: A column of the samples' times in some unit, or named by its unit alone (``Time (ms)``, ``seconds``): pointed at
#: where a CSV record has no sample time, never read as one (its unit need not be seconds).
_TIME_IN_A_UNIT = re.compile(r"seconds|sec|s|time[ _\[(].*", re.IGNORECASE)
#: A measured time vector's mean step may differ from the sample time by this share (100 ppm: a logger
#: clock's drift; the frequencies it shifts by as much are far inside any mode's uncertainty).
CLOCK_TOLERANCE = 1e-4
#: A sample_time_s written rounded agrees with an exact rate within its last digit, up to this share of it.
ROUNDED_SAMPLE_TIME = 1e-3
#: Where a CSV record's sample time is read from.
_CSV_TIME = "the sample_time_s comment (or the time_s column)"
#: What each channel array holds, and the keys (any case) that look like it under another name.
_CHANNELS = {"u": ("inputs", r"u|inputs?|u_?[0-9]+|inputs?_?[0-9]+"),
             "y": ("outputs", r"y|outputs?|y_?[0-9]+|outputs?_?[0-9]+")}


def _plain_name(key: str) -> str:
    """``key`` in lower case, letters and digits only: ``Sample_Rate_Hz`` and ``sample rate (Hz)`` alike."""
    return re.sub(r"[^a-z0-9]", "", key.lower())


def named_like_time(key: str, *, in_a_unit: bool = False) -> bool:
    """Whether ``key`` names a sample rate, a sample time or the samples' times (``in_a_unit``: or times in a unit).

    The one rule of both readers: the .npz keys and CSV comments and columns so named are checked against the
    sample time; a CSV without one points at a column so named (or, ``in_a_unit``, named like ``Time (ms)``).
    """
    return _plain_name(key) in _RATE_NAMES | _TIME_NAMES or bool(in_a_unit and _TIME_IN_A_UNIT.fullmatch(key))


def decimals_written(values: np.ndarray) -> int:
    """The fewest decimals (0-9) every value of ``values`` is written with (to float64's rounding), else 12."""
    for decimals in range(10):
        scaled = values * 10.0**decimals
        if np.all(np.abs(scaled - np.round(scaled)) <= 1e-6):
            return decimals
    return 12


def _rounding(value: float) -> float:
    """Half a unit of the last decimal ``value`` is written with; 0 for an integer (a rate of 200 Hz is 200)."""
    decimals = decimals_written(np.asarray([value]))
    return 0.0 if decimals == 0 else 0.5 * 10.0**-decimals


def _implied_sample_time(key: str, value: object, n_samples: int) -> tuple[float, str] | None:
    """The sample time [s] a key named like a rate, sample time or time vector gives, and its wording; else None.

    None too where the value is no such thing (text, a matrix, a vector of another length): the key is not read.
    """
    name = _plain_name(key)
    if not named_like_time(key):
        return None
    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf":
        return None
    with np.errstate(all="ignore"):
        arr = arr.astype(float)
    if arr.size == 1:
        number = float(arr.reshape(()))
        if not 0.0 < number < np.inf:
            return None
        if name in _RATE_NAMES:
            return 1.0 / number, f"{key} = {number:g} Hz (a sample time of {1.0 / number:.6g} s)"
        return number, f"{key} = {number:g} s"
    if arr.ndim != 1 or arr.size != n_samples or n_samples < 2 or name in _RATE_NAMES or not np.isfinite(arr).all():
        return None
    step = float((arr[-1] - arr[0]) / (n_samples - 1))
    return step, f"{key} steps {step:.6g} s a sample ({arr[0]:g} to {arr[-1]:g} s over {n_samples} samples)"


def _agrees(key: str, value: object, implied: float, sample_time_s: float, n_samples: int) -> bool:
    """Whether the sample time a key gives is ``sample_time_s``: to the digits a number is written with.

    Times may be measured ones (a logger's clock): they agree when their span is the grid's within
    :data:`~okid_ros.core.record_stamps.MAX_STAMP_SLIP` sample times (jitter at either end) or
    :data:`CLOCK_TOLERANCE` of it (a clock's drift), whichever is more.
    """
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.size == 1:
        written = _rounding(float(arr[0]))
        slack = written / float(arr[0]) ** 2 if _plain_name(key) in _RATE_NAMES else written
    else:
        slack = max(MAX_STAMP_SLIP / (n_samples - 1), CLOCK_TOLERANCE) * sample_time_s
    # sample_time_s to the digits it is written with too (0.0833 beside fs = 12), at most 0.1 % of it (0.001
    # beside fs = 1024 still contradicts)
    rounded = min(_rounding(sample_time_s), ROUNDED_SAMPLE_TIME * sample_time_s)
    return abs(implied - sample_time_s) <= max(1e-6 * sample_time_s, slack, rounded)


def _contradiction(path: Path, key: str, found: tuple[float, str], sample_time_s: float, *,
                   read: str = "sample_time_s") -> DataError:
    """The refusal of a record whose ``key`` gives another sample time (``found``) than ``sample_time_s``.

    ``read``: what the sample time is read from.
    """
    ratio = found[0] / sample_time_s
    units = ((1e3, " (in milliseconds, or a rate in kHz?)"), (1e-3, " (sample_time_s in milliseconds?)"))
    unit = next((what for factor, what in units if abs(ratio / factor - 1) < 1e-3), "")
    return DataError(f"{shown_path(path)}: {found[1]}, and sample_time_s = {sample_time_s:g} s{unit}: they contradict; "
                     f"a record has one sample time and only {read} is read: correct the wrong one, or leave "
                     f"{key} out")


def check_npz_keys(path: Path, files: Sequence[str], member: Callable[[str], np.ndarray], *, n_samples: int,
                   sample_time_s: float) -> None:
    """Refuse an .npz whose keys contradict ``sample_time_s`` or hold its channels under another name; warn of the rest.

    ``member(key)``: the array stored under ``key`` (opened only for keys named like a rate or time).
    """
    for channel, (_, pattern) in _CHANNELS.items():
        if channel not in files and (alike := [k for k in files if re.fullmatch(pattern, k, re.IGNORECASE)]):
            outputs_only = f" (for a record of outputs only, leave {', '.join(alike)} out)" if channel == "u" else ""
            raise DataError(f"{shown_path(path)}: no key {channel}, but {', '.join(alike)}: "
                            f"{_store_as(channel, alike)}{outputs_only}")
    unread = []
    for key in (k for k in files if k not in NPZ_KEYS):
        value = _opened(member, key)
        found = None if value is None else _implied_sample_time(key, value, n_samples)
        if found is None:
            unread.append(key)
        elif not _agrees(key, value, found[0], sample_time_s, n_samples):
            raise _contradiction(path, key, found, sample_time_s)
    if unread:
        warnings.warn(f"{shown_path(path)}: not read: {_listed(unread, files)}; an .npz record is read from "
                      f"{', '.join(NPZ_KEYS)} alone", OkidWarning, stacklevel=3)


def _opened(member: Callable[[str], np.ndarray], key: str) -> np.ndarray | None:
    """The member ``key`` where it is named like a sample rate or time and readable as an array, else None."""
    if not named_like_time(key):
        return None
    try:
        return member(key)
    except DataError:  # stored as Python objects: never loaded
        return None


def _store_as(channel: str, alike: Sequence[str]) -> str:
    """What to store where ``channel`` is missing and the keys ``alike`` seem to hold it."""
    kind = _CHANNELS[channel][0]
    if len(alike) > 1:
        return (f"{channel} is read alone, as one array (samples, {kind}): store them as {channel}, "
                f"np.column_stack([{', '.join(alike)}]) in the order of the channels")
    case = " (keys are case-sensitive)" if alike[0].lower() == channel else ""
    return f"the {kind} are read from {channel} alone{case}: store {alike[0]} as {channel}"


def _listed(keys: Sequence[str], files: Sequence[str]) -> str:
    """The keys, each one spelt like a read key followed by that key."""
    named = []
    for key in keys:
        near = difflib.get_close_matches(key, NPZ_KEYS, n=1, cutoff=0.75) or [k for k in NPZ_KEYS if k == key.lower()]
        if near:
            key = f"{key} (beside {near[0]}, which is read)" if near[0] in files else f"{key} (a misspelt {near[0]}?)"
        named.append(key)
    return ", ".join(named)


def missing_key_hint(files: Sequence[str], member: Callable[[str], np.ndarray], missing: Sequence[str],
                     n_samples: int) -> str:
    """What the keys of an .npz without ``missing`` (``y``, ``sample_time_s``) seem to hold instead, or ""."""
    hints = []
    for channel, (_, pattern) in _CHANNELS.items():
        if channel not in files and (alike := [k for k in files if re.fullmatch(pattern, k, re.IGNORECASE)]):
            hints.append(_store_as(channel, alike))
    if "sample_time_s" in missing:
        for key in files:
            value = _opened(member, key)
            if value is not None and (found := _implied_sample_time(key, value, n_samples)):
                hints.append(f"{found[1]}: if that is the sample time, store sample_time_s={found[0]:.6g} (only "
                             f"sample_time_s is read)")
                break
        else:
            if near := difflib.get_close_matches("sample_time_s", list(files), n=1, cutoff=0.75):
                hints.append(f"{near[0]}: a misspelt sample_time_s? store it as sample_time_s")
    return "; ".join(hints)


def check_csv_extras(path: Path, header: Sequence[str], ignored: Mapping[int, Sequence[str]],
                     settings: Mapping[str, str], sample_time_s: float) -> None:
    """Refuse a CSV whose time column or comment contradicts its sample time; warn of the named columns not read.

    ``ignored``: the texts of each column the reader does not read, by index; ``settings``: the
    ``# name=value`` comments other than sample_time_s.
    """
    n_samples = len(next(iter(ignored.values()), ()))
    unread = []
    for column, texts in ignored.items():
        values = _numbers(texts)
        found = None if values is None else _implied_sample_time(header[column], values, n_samples)
        if found is not None and not _agrees(header[column], values, found[0], sample_time_s, n_samples):
            raise _contradiction(path, f"the column {header[column]!r}", (found[0], f"the column {found[1]}"),
                                 sample_time_s, read=_CSV_TIME)
        if found is None and (header[column] or any(text.strip() for text in texts)):  # not a trailing comma
            unread.append(repr(header[column]) if header[column] else f"the unnamed column {column + 1}")
    for name, text in settings.items():
        values = _numbers([text])
        found = None if values is None else _implied_sample_time(name, values, 1)
        if found is not None and not _agrees(name, values, found[0], sample_time_s, 1):
            raise _contradiction(path, f"the comment {name}", (found[0], f"the comment {found[1]}"), sample_time_s,
                                 read=_CSV_TIME)
    if unread:
        warnings.warn(f"{shown_path(path)}: column(s) not read: {', '.join(dict.fromkeys(unread))}; a CSV record is "
                      f"read from its u... and y... columns, time_s and stamp_s alone", OkidWarning, stacklevel=4)


def comment_hint(settings: Mapping[str, str]) -> str:
    """For a CSV without a sample time: what a comment named like a sample rate or time says to write, or ""."""
    for name, text in settings.items():
        values = _numbers([text])
        if values is not None and (found := _implied_sample_time(name, values, 1)):
            return (f" (the comment {found[1]} is not read: if that is the sample time, write "
                    f"'# sample_time_s={found[0]:.6g}')")
    return ""


def _numbers(texts: Sequence[str]) -> np.ndarray | None:
    """The texts as numbers, or None where one is not a plain number."""
    try:
        return np.array([float(text) for text in texts])
    except ValueError:
        return None
