"""A record (``u``, ``y``, sample time) assembled from a bag exactly as the nodes assemble samples.

The input sources and the sample grid are those of the estimator node's parameters
(``inputs.sources``, ``sample_time_s``, ``n_inputs``, ``n_outputs``; :func:`okid_ros.tools.process.
load_node_parameters`, with ``--params``, ``--param`` and ``--source`` as for `process`), so
`identify`, `track` and `export` see the same samples as the live nodes and `process`.

The batch methods need contiguous samples: the record is the longest run of samples without a
dropped slot or a time jump; the samples left out are counted (:class:`BagRecord`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from okid_ros.errors import DataError
from okid_ros.records import Record, load_record

__all__ = ["BagRecord", "RECORD_SUFFIXES", "record_from_bag", "load_any_record"]

RECORD_SUFFIXES = (".npz", ".csv")


@dataclass
class BagRecord:
    """The longest contiguous run of samples of a bag.

    Attributes
    ----------
    record : u (N, m), y (N, p), sample_time_s.
    stamp_s : (N,) the samples' stamps [s].
    samples_total : samples assembled from the whole bag.
    runs : contiguous runs found (1 without gaps).
    messages : messages read on the source topics.
    rejected : messages the sample grid refused, by reason (only reasons that occurred).
    """

    record: Record
    stamp_s: np.ndarray
    samples_total: int
    runs: int
    messages: int = 0
    rejected: dict[str, int] = field(default_factory=dict)

    @property
    def samples_left_out(self) -> int:
        return self.samples_total - self.record.u.shape[0]

    def summary(self) -> str:
        n = self.record.u.shape[0]
        text = f"{n} samples of {self.record.sample_time_s:g} s"
        if self.runs > 1:
            text += f" (longest of {self.runs} contiguous runs; {self.samples_left_out} samples left out)"
        return text

    def rejection_note(self) -> str:
        """One sentence on the messages the grid refused ("" if none), with the likely cause."""
        total = sum(self.rejected.values())
        if not total:
            return ""
        reasons = ", ".join(f"{n} {reason.replace('_', ' ')}" for reason, n in self.rejected.items())
        note = f"{total} of the {self.messages} messages were rejected ({reasons})"
        # Several messages per slot, or stamps between slots: the grid's sample time is not the
        # stamps' spacing.
        where = {"duplicate": "in a sample time already taken", "off_grid": "between sample times"}
        for reason, text in where.items():
            if self.rejected.get(reason, 0) > total // 2:
                note += f"; most fell {text}: is sample_time_s {self.record.sample_time_s:g} s right?"
        return note


def record_from_bag(bag_path: str | Path, est_values: dict) -> BagRecord:
    """Assemble the samples of ``bag_path`` with the estimator node's sources and grid.

    Raises
    ------
    BagReadError (a DataError): unreadable bag, a source topic missing or of another type;
    DataError: no complete sample.
    """
    from okid_ros.tools.bagio import open_bag
    from okid_ros.tools.process import NodeInputs

    inputs = NodeInputs(est_values)
    samples = []
    with open_bag(bag_path) as bag:
        for spec in inputs.specs:
            bag.require_topic(spec.topic, [spec.msg_type])
        for topic, log_ns, msg in bag.messages([s.topic for s in inputs.specs]):
            samples += inputs.add(topic, msg, log_ns * 1e-9)
        samples += inputs.grid.flush()
    if not samples:
        raise DataError(f"{bag_path}: no complete sample on the topics {', '.join(s.topic for s in inputs.specs)}")
    starts = [0] + [k for k in range(1, len(samples)) if samples[k].gap_before] + [len(samples)]
    runs = list(zip(starts[:-1], starts[1:]))
    lo, hi = max(runs, key=lambda r: r[1] - r[0])
    chosen = samples[lo:hi]
    record = Record(np.array([s.u for s in chosen]), np.array([s.y for s in chosen]),
                    float(est_values["sample_time_s"])).validate()
    grid = inputs.grid.counters
    return BagRecord(record, np.array([s.stamp_s for s in chosen]), len(samples), len(runs), int(grid.messages),
                     grid.rejections())


def load_any_record(path: str | Path, params: Sequence[str] = (), overrides: Sequence[str] = (),
                    sources: Sequence[str] = (), *, allow_nonfinite: bool = False) -> tuple[Record, str]:
    """A record from .npz/.csv or from a bag, and where it came from.

    .npz/.csv through :func:`okid_ros.records.load_record`; the second value is a
    one-line description of where it came from. ``allow_nonfinite``: NaN/Inf samples of an
    .npz/.csv are kept (a bag's are rejected as the nodes do).
    """
    path = Path(path)
    if path.suffix.lower() in RECORD_SUFFIXES:
        return load_record(path, allow_nonfinite=allow_nonfinite), f"{path}"
    if not path.exists():
        raise DataError(f"{path}: no such file or bag")
    from okid_ros.tools.process import load_node_parameters

    est_values = load_node_parameters(params, overrides, sources)[1]
    from_bag = record_from_bag(path, est_values)
    note = from_bag.rejection_note()
    return from_bag.record, f"{path} (bag: {from_bag.summary()}{'; ' + note if note else ''})"
