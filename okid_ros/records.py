"""Input/output records on disk: the .npz and .csv formats read by `identify` and `track`.

.npz
    Arrays ``u`` (N, m), ``y`` (N, p) and a scalar ``sample_time_s``. One-dimensional ``u`` or
    ``y`` are read as a single channel.

.csv
    A header line naming the columns, then one row per sample. Columns whose names start with
    ``u`` (``u1``, ``u_2``) are inputs, those starting with ``y`` are outputs, in the order they
    appear; other columns are ignored. The sample time comes from a first comment line
    ``# sample_time_s=0.008`` or, failing that, from a ``time_s`` column with uniform steps::

        # sample_time_s=0.008
        u1,u2,y1,y2
        0.12,-0.3,0.004,0.001
        ...
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from okid_ros.errors import DataError

__all__ = ["Record", "load_record", "save_record"]


@dataclass
class Record:
    """A uniformly sampled input/output record: ``u`` (N, m), ``y`` (N, p), seconds per sample."""

    u: np.ndarray
    y: np.ndarray
    sample_time_s: float

    def validate(self) -> "Record":
        """Check shapes, lengths, finiteness and the sample time; raise DataError with the reason."""
        u = np.asarray(self.u, dtype=float)
        y = np.asarray(self.y, dtype=float)
        u = u[:, None] if u.ndim == 1 else u
        y = y[:, None] if y.ndim == 1 else y
        if u.ndim != 2 or y.ndim != 2:
            raise DataError(f"u and y must be 2-D arrays (N, channels); got u{u.shape}, y{y.shape}")
        if u.shape[0] != y.shape[0]:
            raise DataError(f"length mismatch: u has {u.shape[0]} samples, y has {y.shape[0]}")
        if u.shape[1] == 0 or y.shape[1] == 0:
            raise DataError(f"need at least one input and one output channel; got u{u.shape}, y{y.shape}")
        for name, arr in (("u", u), ("y", y)):
            bad = ~np.isfinite(arr)
            if bad.any():
                k, c = np.argwhere(bad)[0]
                raise DataError(f"{name} holds {int(bad.sum())} NaN/Inf values (first at sample {k}, channel {c})")
        dt = float(self.sample_time_s)
        if not np.isfinite(dt) or dt <= 0:
            raise DataError(f"sample_time_s must be a positive number of seconds, got {self.sample_time_s}")
        return Record(u, y, dt)


def _load_npz(path: Path) -> Record:
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in ("u", "y", "sample_time_s") if k not in data.files]
            if missing:
                raise DataError(f"{path}: missing key(s) {', '.join(missing)} (has {', '.join(data.files) or 'none'})")
            dt = np.asarray(data["sample_time_s"])
            if dt.size != 1:
                raise DataError(f"{path}: sample_time_s must be a scalar, got shape {dt.shape}")
            return Record(data["u"], data["y"], float(dt.reshape(())))
    except DataError:
        raise
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: not a readable .npz file ({exc})") from None


def _load_csv(path: Path) -> Record:
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read ({exc})") from None
    dt = None
    body = []
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("#"):
            key, _, value = stripped.lstrip("#").partition("=")
            if key.strip() == "sample_time_s":
                try:
                    dt = float(value)
                except ValueError:
                    raise DataError(f"{path}: bad sample_time_s comment {stripped!r}") from None
        elif stripped:
            body.append(line)
    if not body:
        raise DataError(f"{path}: no header line")
    header = [h.strip() for h in next(csv.reader([body[0]]))]
    try:
        values = np.array([[float(x) for x in row] for row in csv.reader(body[1:])], dtype=float)
    except ValueError as exc:
        raise DataError(f"{path}: non-numeric value ({exc})") from None
    if values.ndim != 2 or values.shape[1] != len(header):
        raise DataError(f"{path}: every row must have {len(header)} values like the header")
    u_cols = [i for i, h in enumerate(header) if h.lower().startswith("u")]
    y_cols = [i for i, h in enumerate(header) if h.lower().startswith("y")]
    if not u_cols or not y_cols:
        raise DataError(f"{path}: header needs input columns 'u...' and output columns 'y...', got {header}")
    if dt is None:
        if "time_s" not in header:
            raise DataError(f"{path}: no '# sample_time_s=...' line and no time_s column")
        t = values[:, header.index("time_s")]
        steps = np.diff(t)
        if steps.size == 0 or np.any(steps <= 0) or np.ptp(steps) > 1e-6 * np.mean(steps):
            raise DataError(f"{path}: time_s is not uniformly increasing")
        dt = float(np.mean(steps))
    return Record(values[:, u_cols], values[:, y_cols], dt)


def load_record(path: str | Path) -> Record:
    """Read and validate a record from .npz or .csv (see module docstring)."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        record = _load_npz(path)
    elif suffix == ".csv":
        record = _load_csv(path)
    else:
        raise DataError(f"{path}: unknown format {suffix!r}; expected .npz or .csv")
    return record.validate()


def save_record(path: str | Path, u: np.ndarray, y: np.ndarray, sample_time_s: float, **extra) -> None:
    """Write a record as .npz (``extra`` arrays are stored beside ``u``, ``y``, ``sample_time_s``)."""
    np.savez(path, u=np.asarray(u, float), y=np.asarray(y, float), sample_time_s=float(sample_time_s), **extra)
