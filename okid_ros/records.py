"""Input/output records on disk: the .npz and .csv formats read by `identify` and `track`.

.npz
    Arrays ``u`` (N, m), ``y`` (N, p) and a scalar ``sample_time_s``. One-dimensional ``u`` or
    ``y`` are read as a single channel. Without ``u`` (or with an empty one) the record has no inputs
    (``u`` (N, 0), for output-only identification). Arrays must be real numbers (bool, integer or float);
    pickled objects are never loaded. Stamps ``stamp_s`` (N,), as `export` writes them, may come too.
    Other keys are not read (:mod:`okid_ros.record_keys`): one named like a sample rate (``fs``),
    a sample time (``dt``) or the samples' times (``t``, ``time_s``) must agree with ``sample_time_s``;
    the inputs or outputs under another spelling (``U``, ``inputs``, ``y1``) where ``u`` or ``y`` is
    missing are refused, saying what to store; any other key is named in one warning.

.csv
    A header line naming the columns, then one row per sample. Columns whose names start with
    ``u`` (``u1``, ``u_2``) are inputs, those starting with ``y`` are outputs, in the order they
    appear (no ``u`` column: a record without inputs; a name such as ``uptime_s`` is a channel
    too, with a warning); other columns are ignored (text too; named in one warning, and one named
    like the time, ``t``, must agree with the sample time, as a ``# fs=`` comment must), and a name read (a channel,
    ``time_s``, ``stamp_s``) given twice is refused. The sample time comes from a
    comment line ``# sample_time_s=0.008`` (or ``: 0.008``; two that differ are refused, and so
    is one that a ``time_s`` column contradicts) or, failing that, from a ``time_s`` column. A
    ``time_s`` column must be a uniform grid (to the rounding of the times as written), with a
    comment too: a gap is refused with its row; stamps (``stamp_s``, here or in an .npz) must step
    by about the sample time (a jump: records glued). Invisible characters in names are dropped::

        # sample_time_s=0.008
        u1,u2,y1,y2
        0.12,-0.3,0.004,0.001
        ...

The .csv reader is :mod:`okid_ros.record_csv`; the checks of a whole record, :meth:`Record.validate`, are here.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from okid_ros.core.gap_fill import MAX_FILLED_FRACTION, MAX_GAP_SAMPLES
from okid_ros.core.options import sample_time_problem
from okid_ros.core.record_stamps import stamp_jump_problem
from okid_ros.core.regressors import real_array
from okid_ros.errors import DataError, OkidWarning, one_line, shown_path, special_file_kind, write_atomically
from okid_ros.record_csv import read_csv_record
from okid_ros.record_keys import check_npz_keys, missing_key_hint

__all__ = ["Record", "load_record", "require_inputs", "save_record", "transposed_problem"]


def _as_real_array(name: str, value: object) -> np.ndarray:
    """``value`` as a float64 array, or DataError saying why it is not a real numeric array."""
    try:
        return real_array(name, value)
    except ValueError as exc:
        raise DataError(str(exc)) from None


@dataclass
class Record:
    """A uniformly sampled record: ``u`` (N, m), ``y`` (N, p), seconds per sample.

    ``m = 0`` (``u`` of shape (N, 0)) is a record without inputs, for output-only identification;
    commands that need inputs call :func:`require_inputs`.
    """

    u: np.ndarray
    y: np.ndarray
    sample_time_s: float

    @property
    def has_inputs(self) -> bool:
        """Whether the record has at least one input channel."""
        return np.ndim(self.u) == 2 and np.shape(self.u)[1] > 0

    def validate(self, *, allow_nonfinite: bool = False) -> "Record":
        """Check types, shapes, lengths, finiteness and the sample time; raise DataError with the reason.

        ``allow_nonfinite``: NaN/Inf samples are kept (missing samples, for ``track``).
        """
        u, y = (arr[:, None] if arr.ndim == 1 else arr for arr in map(_as_real_array, ("u", "y"), (self.u, self.y)))
        if u.ndim != 2 or y.ndim != 2:
            raise DataError(f"u and y must be 2-D arrays (N, channels); got u{u.shape}, y{y.shape}")
        if u.size == 0:  # u saved empty ((0,), (0, 0), (M, 0)): no inputs, as a record without u
            u = np.zeros((y.shape[0], 0))
        if u.shape[0] != y.shape[0]:
            raise DataError(f"length mismatch: u has {u.shape[0]} samples, y has {y.shape[0]}: a row of u and y is "
                            f"one sample, so both must hold the same samples (for y alone, output-only, store no u)")
        if y.shape[0] == 0:
            raise DataError("the record has no samples")
        if y.shape[1] == 0:
            raise DataError(f"need at least one output channel; got y{y.shape}")
        for name, arr in (("u", u), ("y", y)) if not allow_nonfinite else ():
            bad = ~np.isfinite(arr)
            if bad.any():
                k, c = np.argwhere(bad)[0]
                raise DataError(f"{name} holds {int(bad.sum())} NaN/Inf values (first at sample {k}, channel {c}; "
                                f"values beyond +-1.8e308 read as Inf)")
        return Record(u, y, _sample_time(self.sample_time_s))


def channel_without_values(u: np.ndarray, y: np.ndarray) -> str:
    """Why a channel of ``u`` (N, m) or ``y`` (N, p) holds no finite sample, or "".

    Such a channel makes every sample missing: the commands said "no two samples in a row are
    free of NaN/Inf", or waited for rows on every update, without naming it.
    """
    for kind, values in (("output", y), ("input", u)):
        empty = np.flatnonzero(~np.isfinite(values).any(axis=0))
        if empty.size:
            return (f"{kind} channel {int(empty[0])} holds no value (NaN/Inf in every sample): check its column or "
                    f"topic mapping, or leave the channel out")
    return ""


def transposed_problem(y: np.ndarray) -> str:
    """Why ``y`` (N, p) looks stored transposed for an identification (fewer samples than channels), or "".

    `identify` said "too few samples for output-only identification: 3 < 200" of a (3, 6000) ``y``
    of 3 channels, and `track` "3 samples of 6000 outputs". Other commands load such records as they are.
    """
    n, p = np.shape(y)
    if n >= p:
        return ""
    samples = f"{n} sample{'s' if n != 1 else ''}"
    return (f"y holds {samples} of {p} channels: fewer samples than channels, an array stored transposed? A "
            f"record's arrays are (samples, channels): store y.T; read as it is stored, {samples} "
            f"{'are' if n != 1 else 'is'} too few to identify {p} channels from")


def present_runs(present: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The runs of True in ``present`` (N,): their starts and their ends (exclusive), in order."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], np.asarray(present, dtype=np.int8), [0]])))
    return edges[::2], edges[1::2]


def first_present_run(present: np.ndarray, length: int) -> int | None:
    """Where the first run of ``length`` True in ``present`` (N,) begins; None where there is none."""
    if present[:length].all():
        return 0
    starts, ends = present_runs(present)
    long = np.flatnonzero(ends - starts >= length)
    return int(starts[long[0]]) if long.size else None


def _present(record: Record, use_inputs: bool) -> np.ndarray:
    """(N,) True at the samples without NaN/Inf (in ``y``, and in ``u`` when ``use_inputs``)."""
    present = np.isfinite(record.y).all(axis=1)
    return present & np.isfinite(record.u).all(axis=1) if use_inputs else present


def longest_present_run(record: Record, *, use_inputs: bool = True) -> tuple[Record, str]:
    """The longest run of samples without NaN/Inf, and a sentence on what was left out ("" if nothing).

    For the batch identification, which needs contiguous samples (as a bag's longest run of
    samples, :mod:`okid_ros.tools.bag_record`). ``use_inputs`` False: only ``y`` counts
    (output-only identification ignores ``u``).

    Raises
    ------
    DataError
        no two samples in a row are free of NaN/Inf.
    """
    present = _present(record, use_inputs)
    n = present.size
    if present.all():
        return record, ""
    starts, ends = present_runs(present)
    if not starts.size or (ends - starts).max() < 2:
        raise DataError(f"no two samples in a row are free of NaN/Inf ({n - int(present.sum())} of {n} hold them)")
    best = int(np.argmax(ends - starts))
    lo, hi = int(starts[best]), int(ends[best])
    note = (f"{n - int(present.sum())} of the {n} samples hold NaN/Inf: identified on the longest run without "
            f"them, samples {lo} to {hi - 1} ({hi - lo} samples)")
    return Record(record.u[lo:hi], record.y[lo:hi], record.sample_time_s), note


def bridged_bounds(present: np.ndarray) -> tuple[int, int]:
    """Bounds ``lo, hi`` of the longest stretch of ``present`` (N,) whose missing samples can be filled.

    A stretch ends at a run of more than :data:`~okid_ros.core.gap_fill.MAX_GAP_SAMPLES` missing
    samples; one with more than :data:`~okid_ros.core.gap_fill.MAX_FILLED_FRACTION` of them
    missing is not used. Where the longest run without a missing sample is as long, its bounds
    (so ``present[lo:hi].all()``); ``(0, 0)`` where nothing is present.
    """
    starts, ends = present_runs(present)
    if not starts.size:
        return 0, 0
    joined = np.flatnonzero(starts[1:] - ends[:-1] > MAX_GAP_SAMPLES) + 1  # the first run of each stretch
    first, last = np.concatenate([[0], joined]), np.concatenate([joined, [starts.size]]) - 1
    spans = ends[last] - starts[first]
    spans[spans - np.add.reduceat(ends - starts, first) > MAX_FILLED_FRACTION * spans] = 0
    best, run = int(np.argmax(spans)), int(np.argmax(ends - starts))
    if spans[best] <= ends[run] - starts[run]:
        return int(starts[run]), int(ends[run])
    return int(starts[first[best]]), int(ends[last[best]])


def bridged_run(record: Record, *, use_inputs: bool = True) -> tuple[Record, np.ndarray | None, str]:
    """The longest stretch whose missing samples (NaN/Inf) the identification can fill (:func:`bridged_bounds`).

    The core's ``identify(valid=...)`` fills them by the ARX prediction, as node 2 fills its
    window; a record whose longest run without them is as long gets :func:`longest_present_run`.
    ``use_inputs`` False: only ``y`` counts (output-only identification ignores ``u``).

    Returns
    -------
    record : the stretch (NaN/Inf kept at the missing samples); valid : (N,) bool, False at them,
    or None when none is missing; note : a sentence on what was filled or left out ("" if nothing).

    Raises
    ------
    DataError as :func:`longest_present_run`.
    """
    present = _present(record, use_inputs)
    n = present.size
    if present.all():
        return record, None, ""
    lo, hi = bridged_bounds(present)
    if present[lo:hi].all():
        run, note = longest_present_run(record, use_inputs=use_inputs)  # DataError where nothing is measured
        return run, None, note
    filled = int(hi - lo - present[lo:hi].sum())
    where = "the whole record" if (lo, hi) == (0, n) else (
        f"samples {lo} to {hi - 1} (the longest stretch without a gap of more than {MAX_GAP_SAMPLES} of them)")
    # Output-only, the core fills them by a vector autoregression (gap_fill.fill_missing_outputs), not an ARX model.
    predictor = "the ARX prediction" if use_inputs else "a vector autoregression's prediction"
    note = (f"{n - int(present.sum())} of the {n} samples hold NaN/Inf: identified on {where}, its {filled} missing "
            f"samples filled by {predictor} (as node 2 fills its window)")
    return Record(record.u[lo:hi], record.y[lo:hi], record.sample_time_s), present[lo:hi].copy(), note


def _sample_time(value: object) -> float:
    """The sample time as a positive finite float, or DataError."""
    arr = np.asarray(value)
    if arr.size != 1 or arr.dtype.kind not in "iuf":
        raise DataError(f"sample_time_s must be one positive number of seconds, got {arr.dtype} of shape {arr.shape}")
    dt = float(arr.reshape(()))
    if problem := sample_time_problem(dt):
        raise DataError(problem)
    if arr.dtype.kind == "f" and arr.dtype.itemsize < 4:  # float16: every frequency off by up to 5e-4
        warnings.warn(f"sample_time_s is stored as {arr.dtype} ({dt!r} s, about 3 significant digits): the frequencies "
                      f"are as wrong as it is; store it as float64", OkidWarning, stacklevel=2)
    return dt


def require_inputs(record: Record, source: str | Path, command: str = "this command") -> Record:
    """Return ``record`` if it has input channels, else DataError pointing to output-only identification.

    Parameters
    ----------
    record : a validated record; source : the file it came from (for the message);
    command : what needs the inputs, e.g. "identify".
    """
    if not record.has_inputs:
        raise DataError(f"{shown_path(source)}: the record has no input channels (no 'u'); {command} needs the "
                        f"measured inputs. For a record of outputs only use output-only identification "
                        f"(identify --output-only)")
    return record


def _not_an_archive(path: Path) -> str:
    """Why ``path`` is neither a zip archive nor a .npy array ("" if it begins as one).

    np.load takes any other bytes for a pickle and refused them by suggesting allow_pickle
    (a CSV renamed .npz, random bytes): misleading, as pickles are never loaded here.
    """
    with open(path, "rb") as stream:
        head = stream.read(512)
    if head[:4] in (b"PK\x03\x04", b"PK\x05\x06") or head[:6] == b"\x93NUMPY":  # a zip (empty too), a .npy
        return ""
    if not head:
        return "not an .npz (zip) archive: the file is empty"
    if all(32 <= byte < 127 or byte in b"\t\r\n" for byte in head):
        return "not an .npz (zip) archive: it begins as text, a CSV named .npz?"
    return "not an .npz (zip) archive"


#: What each member of an .npz record holds, for the message refusing one stored as Python objects.
_MEMBER_FORMS = {"u": "(samples, inputs)", "y": "(samples, channels)", "sample_time_s": "(one number of seconds)",
                 "stamp_s": "(one time a sample)"}


def _member(data, key: str, path: Path) -> np.ndarray:
    """The member ``key`` of an open .npz, or DataError naming it where it is stored as pickled objects.

    numpy said "Object arrays cannot be loaded when allow_pickle=False", as if the fix were to allow
    pickles (never loaded here: a pickle runs code); the cause is usually channels of unequal lengths.
    """
    try:
        return data[key]
    except ValueError as exc:
        if "allow_pickle" not in str(exc):
            raise
        raise DataError(f"{shown_path(path)}: not a readable .npz file ({key} is stored as Python objects: an object "
                        f"array, as np.savez makes of a list of channels of unequal lengths or of a dict; pickled "
                        f"objects are never loaded): store {key} as one numeric array "
                        f"{_MEMBER_FORMS.get(key, '')}".rstrip()) from None


def _load_npz(path: Path) -> Record:
    try:
        if problem := _not_an_archive(path):
            raise DataError(f"{shown_path(path)}: not a readable .npz file ({problem})")
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):  # a bare .npy renamed .npz
            raise DataError(f"{shown_path(path)}: a single array, not an .npz archive with y and sample_time_s")
        with data:
            missing = [k for k in ("y", "sample_time_s") if k not in data.files]
            member = functools.partial(_member, data, path=path)
            y = member("y") if "y" in data.files else None
            n_samples = np.shape(y)[0] if np.ndim(y) else 0  # the records' checks judge a y of no rows themselves
            if missing:
                hint = missing_key_hint(data.files, member, missing, n_samples)
                raise DataError(f"{shown_path(path)}: missing key(s) {', '.join(missing)} "
                                f"(has {', '.join(data.files) or 'none'}){': ' + hint if hint else ''}")
            u = member("u") if "u" in data.files else np.zeros((n_samples, 0))
            sample_time_s = member("sample_time_s")
            if "stamp_s" in data.files and (jump := stamp_jump_problem(member("stamp_s"), sample_time_s,
                                                                       n_samples=n_samples)):
                raise DataError(f"{shown_path(path)}: {jump}")
            arr = np.asarray(sample_time_s)
            if arr.size == 1 and arr.dtype.kind in "iuf" and sample_time_problem(float(arr.reshape(()))) is None:
                # (a sample time that is no such number is refused as it is, by Record.validate)
                check_npz_keys(path, data.files, member, n_samples=n_samples, sample_time_s=float(arr.reshape(())))
            return Record(u, y, sample_time_s)
    except DataError:
        raise
    except Exception as exc:  # noqa: BLE001 - a damaged archive raises zipfile, zlib, EOF, OS, value errors
        raise DataError(f"{shown_path(path)}: not a readable .npz file "
                        f"({type(exc).__name__}: {one_line(exc)})") from None


def load_record(path: str | Path, *, allow_nonfinite: bool = False) -> Record:
    """Read and validate a record from .npz or .csv (see module docstring).

    ``allow_nonfinite``: samples with NaN/Inf are kept (see :meth:`Record.validate`).

    Raises
    ------
    DataError
        one line naming the file and what is wrong with it.
    """
    path = Path(path)
    if not path.exists():
        raise DataError(f"{shown_path(path)}: no such file")
    if path.is_dir():
        raise DataError(f"{shown_path(path)}: a folder, not a record file")
    if kind := special_file_kind(path):  # a FIFO would be waited on for ever
        raise DataError(f"{shown_path(path)}: not a regular file ({kind}); a record is an .npz or .csv file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        record = _load_npz(path)
    elif suffix == ".csv":
        record = Record(*read_csv_record(path))
    else:
        raise DataError(f"{shown_path(path)}: unknown format {suffix!r}; expected .npz or .csv")
    try:
        return record.validate(allow_nonfinite=allow_nonfinite)
    except DataError as exc:
        raise DataError(f"{shown_path(path)}: {exc}") from None


def save_record(path: str | Path, u: np.ndarray, y: np.ndarray, sample_time_s: float, **extra) -> None:
    """Write a record as .npz (``extra`` arrays are stored beside ``u``, ``y``, ``sample_time_s``).

    Written to a temporary file beside ``path`` and renamed: a failed write leaves nothing.
    """
    write_atomically(path, lambda stream: np.savez(stream, u=np.asarray(u, float), y=np.asarray(y, float),
                                                   sample_time_s=float(sample_time_s), **extra))
