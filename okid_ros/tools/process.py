"""The two nodes' logic run offline over a bag, faster than real time.

Per node, exactly what the live node does with its topics, minus the middleware:

- identification (``okid_arx_identifier``): input messages -> its own
  :class:`~okid_ros.service.sample_grid.SampleGrid` -> :class:`ArxIdentificationService`;
  instead of the node's wall-clock timer, a snapshot is taken every ``1 / publish_rate_hz``
  seconds of *sample* time (:meth:`ArxIdentificationService.due`) and written as ``ArxModel``;
- estimation (``okid_modal_estimator``): input messages -> its own sample grid ->
  :class:`ModalEstimationService` ``step`` per sample -> ``ModalStates`` (and
  ``StateSpaceModel`` on each accepted model); every valid ``ArxModel`` goes back in through
  the same call the node makes (``estimator_arx_fit``) and is realized at once
  (``WindowedPipeline.realize_now``), so it takes over at the next sample; at the end of the
  record, one realized at (or near) the last sample takes over after it
  (``WindowedPipeline.finish``, as the live node's idle timer once a replay has ended): its
  ``StateSpaceModel`` and JSON line are written, with no ``ModalStates``. A structural change declared by
  the estimation service is written as ``StructuralChange`` and restarts the identification's
  window at the change point, as node 1 does when it receives the message. Live, the realization runs on a
  worker thread while samples go on, and a model that arrives while one is being realized
  replaces the waiting one; offline every valid ArxModel is realized.

The parameters come from the same YAML file as the nodes' (sections ``/**`` and per node,
:func:`okid_ros.service.params.load_parameters`), so they mean the same thing live and offline.

Messages are built by :mod:`okid_ros.nodes.conversions` with the rosbags typestore's classes
and written with the rosbags writer (see :mod:`okid_ros.tools.bagio` for why not rclpy's
serializer); the output bag therefore needs no ROS installation to be written or read.
The log time of every output message is the stamp of the sample being processed when it was
produced. The truth of a simulated input (``okid_ros.truth``) is copied into the output's
metadata, and ``okid_ros.process`` records the source and the resolved parameters.
"""

from __future__ import annotations

import math
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from okid_ros.errors import OkidWarning, ParameterError, shown_path
from okid_ros.jsonio import JsonLines, dumps
from okid_ros.tools.bagio import (
    PROCESS_KEY,
    STABILIZATION_KEY,
    TRUTH_KEY,
    BagWriter,
    open_bag,
)
from okid_ros.tools.errors import BagReadError
from okid_ros.tools.node_parameters import load_node_parameters
from okid_ros.tools.offline import TOPIC_PARAMETERS, NodeInputs, OfflineNodes, ProcessSummary
from okid_ros.tools.output_paths import StagedOutput, check_file_name, check_output_paths, check_replaceable
from okid_ros.tools.source_check import bag_fingerprint

__all__ = [
    "NodeInputs",
    "OfflineNodes",
    "ProcessSummary",
    "load_node_parameters",
    "mode_summary",
    "process_bag",
]


def mode_summary(mode: Any) -> dict:
    """JSON-ready dict of a core Mode (:func:`okid_ros.service.records.mode_record`)."""
    from okid_ros.service.records import mode_record

    return mode_record(mode)


def process_bag(
    bag_path: str | Path,
    out_path: str | Path,
    arx_values: dict,
    est_values: dict,
    *,
    jsonl_path: str | Path | None = None,
    force: bool = False,
    storage: str = "mcap",
    progress: bool | None = None,
    progress_stream: TextIO | None = None,
    provenance: dict | None = None,
    on_update: Callable[[dict], None] | None = None,
    namespace: str | None = None,
) -> ProcessSummary:
    """Run both nodes' logic over ``bag_path``; write ``out_path`` (and ``jsonl_path``).

    Parameters
    ----------
    bag_path : input bag (any rosbag2 / ROS 1 bag that AnyReader opens).
    out_path : output bag to create (refused if it exists, unless ``force``).
    arx_values, est_values : resolved node parameters.
    jsonl_path : one JSON object per model update.
    force : replace existing outputs.
    storage : storage plugin of the output bag.
    progress : progress bar on ``progress_stream`` (default stderr); None: only on a terminal.
    provenance : extra JSON recorded under ``okid_ros.process`` in the output metadata.
    on_update : called with each JSON line as it is produced.
    namespace : rig namespace of the topics (None: ``/okid``), as ``okid-ros up --namespace``.

    Raises
    ------
    BagReadError
        missing/corrupt input, a source topic missing or of another type, no sample accepted.
    OutputExistsError
        an output exists and ``force`` is false.
    OutputError
        an output is, holds or lies in the input (even with ``force``), or overlaps the other one.
    ParameterError
        a topic parameter is not a valid ROS 2 name, or two give one topic two message types.
    """
    bag_path, out_path = Path(bag_path), Path(out_path)
    nodes = OfflineNodes(arx_values, est_values, namespace=namespace)
    jsonl_path = _check_outputs(bag_path, out_path, jsonl_path, nodes, force)
    started = time.perf_counter()
    staged: list[StagedOutput] = []
    try:
        with open_bag(bag_path) as bag:
            total, truth = _check_input(bag, bag_path, nodes, arx_values)
            writer, jsonl = _new_outputs(staged, out_path, jsonl_path, force=force, storage=storage)
            bar = _Progress(total, progress, progress_stream)
            with writer:
                emit = _Emitter(writer, nodes, jsonl, on_update, truth)
                record = {"source": str(bag_path), "source_files": bag_fingerprint(bag_path),  # checked by plot
                          "parameters": {"okid_arx_identifier": arx_values, "okid_modal_estimator": est_values},
                          **(provenance or {})}
                try:
                    emit.run(bag, bar, record)
                finally:
                    bar.close()
                    if jsonl is not None:
                        jsonl.close()
                summary = _with_samples(nodes.summary, bag_path)
                summary.input_note = bag.read_note
                summary.elapsed_s = time.perf_counter() - started
                _write_metadata(writer, nodes, record)
    except KeyboardInterrupt:
        for output in staged:  # what was written stays, closed, readable and marked cut short
            output.commit()
        raise
    except BaseException:
        for output in staged:  # no half-written outputs after an error; the previous ones stay
            output.discard()
        raise
    for output in staged:
        output.commit()
    return summary


def _new_outputs(staged: list[StagedOutput], out_path: Path, jsonl_path: Path | None, *, force: bool,
                 storage: str) -> tuple[BagWriter, JsonLines | None]:
    """The output bag's writer and the JSON lines file, each added to ``staged`` as it is made.

    Made only once the input is known to be usable; an existing output is replaced (``force``) only
    by a complete new one (:class:`StagedOutput`).
    """
    staged.append(StagedOutput(out_path, force=force))
    writer = BagWriter(staged[-1].staged, storage=storage)
    if jsonl_path is None:
        return writer, None
    staged.append(StagedOutput(jsonl_path, force=force, kind="JSON lines file"))
    return writer, JsonLines(staged[-1].staged)


def publish_rate_warning(arx_values: dict, samples: int) -> str:
    """What a ``publish_rate_hz`` at or above the sampling rate costs, when the default rate is below it ("" else).

    Offline an ArxModel is due every ``1 / publish_rate_hz`` s of sample time, and each valid one
    is realized: at or above the sampling rate, at every sample, which makes `process` many times
    slower than the default rate. On a slow grid (a sample time of ``1 / default`` or more) the
    default is a model at every sample already, and any rate costs the same: nothing said.

    Parameters
    ----------
    arx_values : node 1's resolved parameters.
    samples : about how many samples the bag makes (its messages on the busiest input topic).
    """
    from okid_ros.service.params import ARX_NODE, default_value

    rate, dt = float(arx_values["publish_rate_hz"]), float(arx_values["sample_time_s"])
    default = float(default_value(ARX_NODE, "publish_rate_hz"))
    if default * dt >= 1.0 or rate * dt < 1.0 - 1e-9:
        return ""
    where = "at" if math.isclose(rate * dt, 1.0) else "above"
    return (f"publish_rate_hz {rate:g} is {where} the sampling rate {1.0 / dt:g} Hz: a model at every sample, about "
            f"{samples} ArxModel solved and each valid one realized, against about {samples * dt * default:.0f} at the "
            f"default {default:g} Hz: process may take up to {1.0 / (dt * default):.3g} times as long")


def _with_samples(summary: ProcessSummary, bag_path: Path) -> ProcessSummary:
    """``summary``; BagReadError when no input message made a sample, as `identify` refuses such a bag.

    An empty output bag with exit status 0 would read as a run that found nothing to identify.
    """
    if summary.samples < 2:  # one sample is no record either (stamps all equal, every other message NaN)
        note = summary.rejection_note()
        made = "no input message made a complete sample" if not summary.samples else "one complete sample only"
        raise BagReadError(f"{shown_path(bag_path)}: {made}" + (f"; {note}" if note else ""))
    return summary


def _check_outputs(bag_path: Path, out_path: Path, jsonl_path: str | Path | None, nodes: OfflineNodes,
                   force: bool) -> Path | None:
    """Refuse outputs that exist (unless ``force``), outputs over the input or each other, clashing topics."""
    clash = sorted(set(nodes.input_topics) & set(nodes.output_topics))
    if clash:
        raise ParameterError(f"input and output topics overlap: {', '.join(clash)}")
    _check_topic_types(nodes)
    if jsonl_path is not None:
        check_file_name(jsonl_path, "JSON lines file")  # as given: 'out/' wrote a file named out
    jsonl_path = None if jsonl_path is None else Path(jsonl_path)
    outputs = [(out_path, "output bag")] + ([(jsonl_path, "JSON lines file")] if jsonl_path is not None else [])
    check_output_paths(bag_path, "input bag", outputs)
    if jsonl_path is not None:  # every output checked before any is replaced
        check_replaceable(jsonl_path, force=force, kind="JSON lines file")
    check_replaceable(out_path, force=force)
    return jsonl_path


def _check_topic_types(nodes: OfflineNodes) -> None:
    """Refuse one topic for two message types (``arx_model_topic`` equal to ``modal_states_topic``)."""
    uses: dict[str, list[tuple[str, str]]] = {}
    for topic, msgtype in nodes.input_topics.items():
        uses.setdefault(topic, []).append(("inputs.sources", msgtype))
    for node, topics in nodes.topic_parameters.items():
        for name, topic in topics.items():
            uses.setdefault(topic, []).append((f"{name} of {node}", TOPIC_PARAMETERS[node][name]))
    for topic, users in sorted(uses.items()):
        if len({msgtype for _, msgtype in users}) > 1:
            listed = ", ".join(f"{label} ({msgtype.rsplit('/', 1)[-1]})" for label, msgtype in users)
            raise ParameterError(f"parameters {listed} all resolve to the topic {topic}: one topic cannot carry "
                                 "two message types; give them different topic names")


def _check_input(bag: Any, bag_path: Path, nodes: OfflineNodes, arx_values: dict) -> tuple[int, Any]:
    """The number of input messages and the simulation truth of the bag; BagReadError if unusable.

    Warns up front when ``publish_rate_hz`` makes the run slow (:func:`publish_rate_warning`).
    """
    for topic, msgtype in nodes.input_topics.items():
        bag.require_topic(topic, [msgtype])
    total = bag.message_count(nodes.input_topics)
    if total == 0:
        raise BagReadError(f"{shown_path(bag_path)}: the input topics {', '.join(nodes.input_topics)} have no messages")
    samples = max(bag.message_count([topic]) for topic in nodes.input_topics)  # one message per sample
    if warning := publish_rate_warning(arx_values, samples):
        warnings.warn(warning, OkidWarning, stacklevel=3)
    return total, bag.custom_data.get(TRUTH_KEY)


class _Emitter:
    """Writes what the offline nodes put out: messages to the bag, JSON lines, the callback."""

    def __init__(self, writer: BagWriter, nodes: OfflineNodes, jsonl: JsonLines | None,
                 on_update: Callable[[dict], None] | None, truth: Any) -> None:
        self.writer, self.nodes, self.jsonl, self.on_update = writer, nodes, jsonl, on_update
        self.written_updates = 0
        if truth is not None:  # the simulation's truth goes with the outputs
            writer.set_custom_data(TRUTH_KEY, truth)
        for topic, msgtype in nodes.output_topics.items():
            writer.add_topic(topic, msgtype)

    def run(self, bag: Any, bar: "_Progress", record: dict) -> None:
        """Every input message of the bag through the nodes, then the end of the record.

        Stopped by Ctrl-C or SIGTERM, the bag's ``record`` (its ``okid_ros.process`` metadata) is
        written, marked ``interrupted``, so that what was written stays readable and says so.
        """
        log_ns = 0
        try:
            for topic, log_ns, msg in bag.stored_messages(self.nodes.input_topics):
                self(self.nodes.feed(topic, msg, log_ns * 1e-9), log_ns)
                bar.update()
        except KeyboardInterrupt:
            _write_metadata(self.writer, self.nodes, {**record, "interrupted": True})
            raise
        self(self.nodes.finish(), log_ns)

    def __call__(self, outputs: list, log_ns: int) -> None:
        summary = self.nodes.summary
        for out_topic, out_msg in outputs:
            self.writer.write(out_topic, _log_time_ns(summary.last_stamp_s, log_ns), out_msg)
        while self.written_updates < len(summary.updates):
            line = summary.updates[self.written_updates]
            self.written_updates += 1
            if self.jsonl is not None:
                self.jsonl.write(line)
            if self.on_update is not None:
                self.on_update(line)


def _write_metadata(writer: BagWriter, nodes: OfflineNodes, extra: dict) -> None:
    """The output bag's metadata: the last model's stabilization data and what was processed how."""
    summary = nodes.summary
    stabilization = getattr(nodes.est.current_model, "stabilization", None)
    if stabilization:  # for `okid-ros plot`'s stabilization diagram of the last model
        writer.set_custom_data(STABILIZATION_KEY, dumps([entry.as_dict() for entry in stabilization]))
    writer.set_custom_data(PROCESS_KEY, dumps({
        "source": extra["source"],
        "input_topics": nodes.input_topics,
        "samples": summary.samples,
        "first_stamp_s": summary.first_stamp_s,
        "arx_models": summary.arx_models,
        "models": summary.models,
        "elapsed_s": summary.elapsed_s,
        **{key: value for key, value in extra.items() if key != "source"},
    }, default=str))


def _log_time_ns(sample_stamp_s: float, log_ns: int) -> int:
    """The stamp of the sample being processed, or the input's log time before the first one."""
    if math.isnan(sample_stamp_s):
        return int(log_ns)
    return int(round(sample_stamp_s * 1e9))


class _Progress:
    """tqdm on stderr if installed, else a plain percentage line; off when not wanted."""

    def __init__(self, total: int, enabled: bool | None, stream: TextIO | None) -> None:
        self.stream = stream or sys.stderr
        if enabled is None:
            enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.enabled = enabled
        self.total = total
        self.count = 0
        self._bar = None
        self._last_pct = -1
        if not enabled:
            return
        try:
            from tqdm import tqdm
        except ImportError:
            return
        self._bar = tqdm(total=total, file=self.stream, unit="msg", unit_scale=True, desc="process",
                         mininterval=0.5, dynamic_ncols=True)

    def update(self) -> None:
        self.count += 1
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(1)
            return
        pct = 100 * self.count // max(self.total, 1)
        if pct != self._last_pct and pct % 5 == 0:
            self._last_pct = pct
            self.stream.write(f"\rprocess: {pct:3d} % ({self.count}/{self.total} messages)")
            self.stream.flush()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        elif self.enabled:
            self.stream.write("\n")
            self.stream.flush()
