"""A record (``u``, ``y``, sample time) assembled from a bag exactly as the nodes assemble samples.

The input sources and the sample grid are those of the estimator node's parameters
(``inputs.sources``, ``sample_time_s``, ``n_inputs``, ``n_outputs``; :func:`okid_ros.tools.process.
load_node_parameters`, with ``--params``, ``--param`` and ``--source`` as for `process`), so
`identify`, `track` and `export` see the same samples as the live nodes and `process`.

The batch methods need contiguous samples: the record is the longest run of samples without a
dropped slot or a time jump; the samples left out are counted (:class:`BagRecord`). For the
commands that fill short gaps (`identify`, `track`) the dropped slots of short gaps are NaN rows
instead, in the longest stretch :func:`okid_ros.records.bridged_run` takes.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from okid_ros.core.gap_fill import MAX_GAP_SAMPLES
from okid_ros.core.window_minimum import OUTPUT_ONLY_MIN_SAMPLES
from okid_ros.errors import DataError, OkidWarning, shown_path
from okid_ros.records import Record, bridged_bounds, load_record

__all__ = ["BagRecord", "RECORD_SUFFIXES", "fewest_usable_samples", "record_from_bag", "load_any_record"]

RECORD_SUFFIXES = (".npz", ".csv")


@dataclass
class BagRecord:
    """The longest contiguous run of samples of a bag.

    Attributes
    ----------
    record : u (N, m), y (N, p), sample_time_s (NaN rows at dropped slots with ``missing_as_nan``).
    stamp_s : (N,) the samples' stamps [s] (of the slots, for the dropped ones).
    samples_total : samples assembled from the whole bag.
    runs : contiguous runs found (1 without gaps; with ``missing_as_nan`` the stretches between time
        jumps and gaps longer than ``MAX_GAP_SAMPLES``).
    messages : messages read on the source topics.
    rejected : messages the sample grid refused, by reason (only reasons that occurred).
    missing : sample times the grid dropped incomplete (a message missing on some source topic).
    """

    record: Record
    stamp_s: np.ndarray
    samples_total: int
    runs: int
    messages: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    missing: int = 0
    no_data_note: str = ""  # per topic, its messages whose covariance declared no data (REP 145)

    @property
    def samples_left_out(self) -> int:
        return self.samples_total - self.samples_used

    @property
    def samples_used(self) -> int:
        """Samples of the bag in the record (its NaN rows are dropped slots, not samples)."""
        return int(np.count_nonzero(np.isfinite(self.record.y).all(axis=1)))

    def summary(self) -> str:
        n, rows = self.samples_used, self.record.u.shape[0]
        text = f"{n} samples of {self.record.sample_time_s:g} s"
        if rows > n:
            text += f" and {rows - n} dropped slots between them"
        if self.runs > 1:
            kind = "stretches" if rows > n else "contiguous runs"
            text += f" (longest of {self.runs} {kind}; {self.samples_left_out} samples left out)"
        return text

    def rejection_note(self) -> str:
        """One sentence on the messages the grid refused ("" if none), with the likely cause.

        Also said when most samples stand alone between empty sample times: a sample time finer
        than the stamps' spacing refuses nothing but leaves every other slot empty.
        """
        from okid_ros.tools.grid_hints import loss_worth_saying, stand_alone_hint

        dt = self.record.sample_time_s
        notes = []
        if loss_worth_saying(self.missing, self.samples_total + self.missing):
            notes.append(f"{self.missing} sample times dropped incomplete (a message missing on some source topic: "
                         "one that stopped or dropped messages?)")
        if sum(self.rejected.values()):
            notes.append(_rejected_messages(self.rejected, self.messages, dt, {"no_data": self.no_data_note}))
        present = np.isfinite(self.record.y).all(axis=1)  # the dropped slots of a stretch are NaN rows
        alone = present & ~np.r_[False, present[:-1]] & ~np.r_[present[1:], False]
        notes.append(stand_alone_hint(samples=self.samples_total, runs=self.runs, alone=int(alone.sum()),
                                      present=int(present.sum()), rejected=self.rejected, sample_time_s=dt))
        return "; ".join(note for note in notes if note)


def _rejected_messages(rejected: dict[str, int], messages: int, sample_time_s: float,
                       notes: dict[str, str] | None = None) -> str:
    """"N of the M messages were rejected (n reason, ...)", with the notes of the reasons and the likely cause.

    The cause: :func:`~okid_ros.tools.grid_hints.rejection_hint` (a sample time that is not the
    stamps' spacing); ``notes`` by reason: the sizes after a wrong size, the covariances after no data.
    """
    from okid_ros.tools.grid_hints import rejection_hint

    notes = notes or {}
    reasons = ", ".join(f"{n} {reason.replace('_', ' ')}" + (f" ({notes[reason]})" if notes.get(reason) else "")
                        for reason, n in rejected.items() if n)
    hint = rejection_hint(rejected, sample_time_s, messages=messages)
    text = f"{sum(rejected.values())} of the {messages} messages were rejected ({reasons})"
    return f"{text}; {hint}" if hint else text


def fewest_usable_samples(n_outputs: int, n_inputs: int) -> int:
    """The fewest contiguous samples any command identifies from, with these channels.

    identify's rule with inputs (:func:`~okid_ros.core.arx_order.fewest_samples_to_identify`: ARX
    order 2 and its realization), or output-only identification's
    :data:`~okid_ros.core.window_minimum.OUTPUT_ONLY_MIN_SAMPLES`.
    """
    from okid_ros.core.arx_order import fewest_samples_to_identify

    return (min(fewest_samples_to_identify(n_outputs, n_inputs), OUTPUT_ONLY_MIN_SAMPLES) if n_inputs
            else OUTPUT_ONLY_MIN_SAMPLES)


def record_from_bag(bag_path: str | Path, est_values: dict, *, missing_as_nan: bool = False) -> BagRecord:
    """Assemble the samples of ``bag_path`` with the estimator node's sources and grid.

    ``missing_as_nan``: the record is the stretch :func:`okid_ros.records.bridged_run` takes
    between time jumps and gaps of more than ``MAX_GAP_SAMPLES`` dropped slots, with a NaN row
    at each dropped slot; else the longest contiguous run.

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
        for topic, log_ns, msg in bag.stored_messages([s.topic for s in inputs.specs]):
            samples += inputs.add(topic, msg, log_ns * 1e-9)
        samples += inputs.grid.flush()
    if len(samples) < 2:  # one sample is no record either: `process` refuses it, `export` wrote it
        counters = inputs.grid.counters
        rejected = counters.rejections()
        dt = float(est_values["sample_time_s"])
        notes = {"wrong_size": inputs.wrong_size_note, "no_data": inputs.no_data_note()}
        why = (f": {_rejected_messages(rejected, int(counters.messages), dt, notes)}"
               if any(rejected.values()) else "")
        made = "no complete sample" if not samples else "one complete sample only"
        raise DataError(f"{shown_path(bag_path)}: {made} on the topics "
                        f"{', '.join(s.topic for s in inputs.specs)}" + why)
    dt, grid = float(est_values["sample_time_s"]), inputs.grid.counters
    if missing_as_nan:
        record, stamps, runs = _longest_stretch(samples, dt)
        return BagRecord(record, stamps, len(samples), runs, int(grid.messages), grid.rejections(), int(grid.missing),
                         inputs.no_data_note())
    starts = [0] + [k for k in range(1, len(samples)) if samples[k].gap_before] + [len(samples)]
    runs = list(zip(starts[:-1], starts[1:]))
    lo, hi = max(runs, key=lambda r: r[1] - r[0])
    chosen = samples[lo:hi]
    record = Record(np.array([s.u for s in chosen]), np.array([s.y for s in chosen]), dt).validate()
    found = BagRecord(record, np.array([s.stamp_s for s in chosen]), len(samples), len(runs), int(grid.messages),
                      grid.rejections(), int(grid.missing), inputs.no_data_note())
    if hi - lo < 2:  # each sample alone between sample times without one: `export` wrote one sample, exit 0
        note = found.rejection_note()
        raise DataError(f"{shown_path(bag_path)}: no two complete samples in a row on the topics "
                        f"{', '.join(s.topic for s in inputs.specs)} ({len(samples)} samples, each alone)"
                        + (f": {note}" if note else ""))
    return found


def _longest_stretch(samples: list, dt: float) -> tuple[Record, np.ndarray, int]:
    """The stretch of ``samples`` that :func:`okid_ros.records.bridged_bounds` takes, NaN at dropped slots.

    Stretches end at a time jump (or restart) and at more than ``MAX_GAP_SAMPLES`` dropped slots.
    Returns the record, the slots' stamps and the number of stretches.
    """
    breaks = [0] + [k for k in range(1, len(samples))
                    if samples[k].restart or samples[k].skipped > MAX_GAP_SAMPLES] + [len(samples)]
    best: tuple = (0,)  # (its length, its samples, their rows, its bounds in those rows)
    for lo, hi in zip(breaks[:-1], breaks[1:]):
        rows = np.arange(hi - lo) + np.cumsum([0] + [s.skipped for s in samples[lo + 1 : hi]])
        present = np.zeros(rows[-1] + 1, dtype=bool)
        present[rows] = True
        first, last = bridged_bounds(present)
        if last - first > best[0]:
            best = (last - first, samples[lo:hi], rows, first, last)
    _, chosen, rows, first, last = best
    u = np.full((rows[-1] + 1, chosen[0].u.size), np.nan)
    y = np.full((rows[-1] + 1, chosen[0].y.size), np.nan)
    u[rows], y[rows] = [s.u for s in chosen], [s.y for s in chosen]
    stamps = chosen[0].stamp_s + dt * np.arange(rows[-1] + 1)  # the dropped slots' stamps on the grid
    stamps[rows] = [s.stamp_s for s in chosen]
    record = Record(u[first:last], y[first:last], dt).validate(allow_nonfinite=True)
    return record, stamps[first:last], len(breaks) - 1


def load_any_record(path: str | Path, params: Sequence[str] = (), overrides: Sequence[str] = (),
                    sources: Sequence[str] = (), *, allow_nonfinite: bool = False) -> tuple[Record, str]:
    """A record from .npz/.csv or from a bag, and where it came from.

    .npz/.csv through :func:`okid_ros.records.load_record`; the second value is a
    one-line description of where it came from. ``allow_nonfinite``: NaN/Inf samples of an
    .npz/.csv are kept (a bag's are rejected as the nodes do).
    """
    path = Path(path)
    if path.suffix.lower() in RECORD_SUFFIXES:
        if params or overrides or sources:
            warnings.warn(f"{shown_path(path)}: --params, --param and --source say how to read a bag's topics; "
                          "a record file holds its channels and sample time itself: ignored", OkidWarning,
                          stacklevel=2)
        return load_record(path, allow_nonfinite=allow_nonfinite), f"{path}"
    if not path.exists():
        raise DataError(f"{shown_path(path)}: no such file or bag")
    from okid_ros.tools.process import load_node_parameters

    est_values = load_node_parameters(params, overrides, sources)[1]
    from_bag = record_from_bag(path, est_values, missing_as_nan=allow_nonfinite)
    note = from_bag.rejection_note()
    if note:  # said before anything can fail on what it explains (a sample time half the stamps' spacing)
        warnings.warn(f"{shown_path(path)}: {note}", OkidWarning, stacklevel=2)
    return from_bag.record, f"{path} (bag: {from_bag.summary()}{'; ' + note if note else ''})"
