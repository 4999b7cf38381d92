"""The two nodes' logic run offline over a bag, faster than real time.

Per node, exactly what the live node does with its topics, minus the middleware:

- identification (``okid_arx_identifier``): input messages -> its own
  :class:`~okid_ros.service.sample_grid.SampleGrid` -> :class:`ArxIdentificationService`;
  instead of the node's wall-clock timer, a snapshot is taken every ``1 / publish_rate_hz``
  seconds of *sample* time (:meth:`ArxIdentificationService.due`) and written as ``ArxModel``;
- estimation (``okid_modal_estimator``): input messages -> its own sample grid ->
  :class:`ModalEstimationService` ``step`` per sample -> ``ModalStates`` (and
  ``StateSpaceModel`` on each accepted model); every valid ``ArxModel`` goes back in through
  the same message conversion the node uses (``arx_fit_from_msg``) and is realized at once
  (``process_pending``), so it takes over at the next sample. A structural change declared by
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
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from okid_ros.errors import ParameterError
from okid_ros.jsonio import dumps
from okid_ros.tools.bagio import PROCESS_KEY, STABILIZATION_KEY, TRUTH_KEY, BagWriter, open_bag, prepare_output
from okid_ros.tools.errors import BagReadError, BagWriteError

__all__ = [
    "NodeInputs",
    "OfflineNodes",
    "ProcessSummary",
    "load_node_parameters",
    "mode_summary",
    "process_bag",
]


def load_node_parameters(param_files: Sequence[str | Path] = (), overrides: Sequence[str] = (),
                         sources: Sequence[str] = (), *, namespace: str | None = None,
                         strict: bool = False, report: Callable[[str], None] | None = None) -> tuple[dict, dict]:
    """Resolved parameters of both nodes, as the nodes would read them.

    Parameters
    ----------
    param_files : ROS parameter YAML files, later ones override earlier ones (as several
        ``--params-file`` do); none: the defaults (equal to config/okid.yaml).
    overrides : ``NAME=VALUE`` (dotted name, YAML value), applied to each node that has
        the parameter, after the files.
    sources : if given, replaces ``inputs.sources`` of both nodes.
    namespace : the nodes' namespace (None: the root namespace); decides which sections of
        the files apply, as for the live nodes.
    strict : unknown parameter names (or sections naming a node that do not apply) in the
        files are an error instead of a report.
    report : called with each such problem when not ``strict`` (default: print to stderr).

    Returns
    -------
        (identification node values, estimation node values), dotted names.

    Raises
    ------
    ParameterError
        unreadable file, bad value, an override no node knows, or (``strict``) an unknown
        name in a file.
    """
    import yaml

    from okid_ros.service.param_files import file_report, node_fqn, node_values_from_tree
    from okid_ros.service.params import (
        ARX_NODE,
        ESTIMATOR_NODE,
        node_params,
        read_parameter_file,
        resolve_parameters,
    )

    names = {node: {s.name for s in node_params(node)} for node in (ARX_NODE, ESTIMATOR_NODE)}
    layered: list[tuple[str, Any]] = []
    for item in overrides:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ParameterError(f"--param {item!r} must be NAME=VALUE, e.g. publish_rate_hz=0.5")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError:
            raise ParameterError(f"--param {item!r}: the value is not valid YAML") from None
        if not any(name in known for known in names.values()):
            raise ParameterError(f"--param {name}: no such parameter of {ARX_NODE} or {ESTIMATOR_NODE}")
        layered.append((name, value))
    if sources:
        layered.append(("inputs.sources", list(sources)))
    trees = [(str(path), read_parameter_file(path)) for path in param_files]
    problems = [p for label, tree in trees for p in file_report(tree, label, names, namespace)]
    if problems and strict:
        raise ParameterError("; ".join(problems))
    for problem in problems:
        (report or (lambda text: print(f"warning: {text}", file=sys.stderr, flush=True)))(problem)
    values = []
    for node in (ARX_NODE, ESTIMATOR_NODE):
        merged: dict[str, Any] = {}
        origin: dict[str, str] = {}
        for label, tree in trees:
            found = node_values_from_tree(tree, node_fqn(node, namespace))
            merged.update(found)
            origin.update({name: label for name in found})
        merged.update((name, value) for name, value in layered if name in names[node])
        merged = {k: v for k, v in merged.items() if k in names[node]}
        try:
            values.append(resolve_parameters(node, merged))
        except ParameterError as exc:
            label = next((origin[n] for n in origin if f"parameter {n} " in str(exc)), None)
            raise ParameterError(f"{label}: {exc}" if label else str(exc)) from None
    return values[0], values[1]


def mode_summary(mode: Any) -> dict:
    """JSON-ready dict of a core Mode (NaN indicators as null)."""
    def num(x: float) -> float | None:
        x = float(x)
        return x if math.isfinite(x) else None

    return {
        "id": int(mode.id),
        "frequency_rad_s": float(mode.frequency_rad_s),
        "frequency_hz": float(mode.frequency_hz),
        "damping_ratio": float(mode.damping_ratio),
        "emac": num(mode.emac),
        "mpc": num(mode.mpc),
        "msv": num(mode.msv),
        "mac_previous": num(mode.mac_previous),
        "stable": bool(mode.stable),
        "frequency_hz_std": num(getattr(mode, "frequency_hz_std", math.nan)),
        "damping_ratio_std": num(getattr(mode, "damping_ratio_std", math.nan)),
    }


@dataclass
class ProcessSummary:
    """What :func:`process_bag` did."""

    input_messages: int = 0
    samples: int = 0
    arx_models: int = 0
    valid_arx_models: int = 0
    models: int = 0
    modal_states: int = 0
    first_stamp_s: float = math.nan
    last_stamp_s: float = math.nan
    elapsed_s: float = 0.0
    updates: list = field(default_factory=list)  # the JSON lines
    changes: list = field(default_factory=list)  # StructuralChange summaries, in order
    arx_diagnostics: dict = field(default_factory=dict)
    estimator_diagnostics: dict = field(default_factory=dict)
    grid_counters: dict = field(default_factory=dict)

    @property
    def data_duration_s(self) -> float:
        return 0.0 if math.isnan(self.first_stamp_s) else self.last_stamp_s - self.first_stamp_s

    @property
    def final_modes(self) -> list[dict]:
        return self.updates[-1]["modes"] if self.updates else []


class NodeInputs:
    """One node's input sources and sample grid (what InputFrontend does, minus subscriptions)."""

    def __init__(self, values: dict, namespace: str | None = None) -> None:
        from okid_ros.service.inputs import sources_and_grid

        self.m, self.p = int(values["n_inputs"]), int(values["n_outputs"])
        self.specs, self.grid = sources_and_grid(values, namespace)
        self.by_topic: dict[str, list[int]] = {}
        for i, spec in enumerate(self.specs):
            self.by_topic.setdefault(spec.topic, []).append(i)

    def add(self, topic: str, msg: Any, arrival_s: float) -> list:
        from okid_ros.nodes.conversions import source_values

        samples = []
        for i in self.by_topic.get(topic, ()):
            stamp, values = source_values(msg, self.specs[i], self.m, self.p)
            samples += self.grid.add(i, arrival_s if stamp is None else stamp, values)
        return samples


class OfflineNodes:
    """Both nodes without ROS: feed input messages, get output messages.

    Parameters
    ----------
    arx_values, est_values : resolved parameters (:func:`load_node_parameters`).
    types : message classes for the outputs (default: the rosbags typestore's).
    namespace : the rig namespace relative topic names resolve in (None: ``/okid``, as the
        nodes in the root namespace; :mod:`okid_ros.service.topics`).
    """

    def __init__(self, arx_values: dict, est_values: dict, types: Any = None, namespace: str | None = None) -> None:
        from okid_ros.nodes.conversions import MessageTypes
        from okid_ros.service.estimation import ModalEstimationParams, ModalEstimationService
        from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
        from okid_ros.tools.bagio import okid_typestore

        self.types = types or MessageTypes.from_typestore(okid_typestore())
        from okid_ros.service.topics import resolve_topic

        self.arx_inputs = NodeInputs(arx_values, namespace)
        self.est_inputs = NodeInputs(est_values, namespace)
        try:
            self.arx = ArxIdentificationService(ArxIdentificationParams.from_parameters(arx_values))
            self.est = ModalEstimationService(ModalEstimationParams.from_parameters(est_values))
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self.arx_topic = resolve_topic(arx_values["arx_model_topic"], namespace)
        self.arx_input_topic = resolve_topic(est_values["arx_model_topic"], namespace)
        self.state_space_topic = resolve_topic(est_values["state_space_model_topic"], namespace)
        self.modal_states_topic = resolve_topic(est_values["modal_states_topic"], namespace)
        self.structural_change_topic = resolve_topic(est_values["structural_change_topic"], namespace)
        self.change_input_topic = resolve_topic(arx_values["structural_change_topic"], namespace)
        self._change_since_update: dict | None = None
        self.summary = ProcessSummary()
        self._mode_msgs: list = []
        self._fits: dict[int, dict] = {}  # id(model) -> prediction_fits on its window
        self._reset_on_jump = (bool(arx_values["reset_on_time_jump"]), bool(est_values["reset_on_time_jump"]))
        self.frame_ids = (str(arx_values["frame_id"]), str(est_values["frame_id"]))

    @property
    def input_topics(self) -> dict[str, str]:
        """Topic -> message type of every input source of either node."""
        out = {}
        for inputs in (self.arx_inputs, self.est_inputs):
            for spec in inputs.specs:
                out[spec.topic] = spec.msg_type
        return out

    @property
    def output_topics(self) -> dict[str, str]:
        return {
            self.arx_topic: "okid_msgs/msg/ArxModel",
            self.state_space_topic: "okid_msgs/msg/StateSpaceModel",
            self.modal_states_topic: "okid_msgs/msg/ModalStates",
            self.structural_change_topic: "okid_msgs/msg/StructuralChange",
        }

    def feed(self, topic: str, msg: Any, log_time_s: float) -> list[tuple[str, Any]]:
        """One input message (rosbags or rclpy); returns the ``(topic, message)`` outputs in order."""
        self.summary.input_messages += 1
        # node 2 first: a model realized from the previous ArxModel takes over at this sample
        out = self._estimate(self.est_inputs.add(topic, msg, log_time_s))
        out += self._identify(self.arx_inputs.add(topic, msg, log_time_s))
        return out

    def finish(self) -> list[tuple[str, Any]]:
        """End of the record: complete samples still pending in the grids are processed too."""
        out = self._estimate(self.est_inputs.grid.flush())
        out += self._identify(self.arx_inputs.grid.flush())
        s = self.summary
        s.arx_diagnostics = self.arx.diagnostics()
        s.estimator_diagnostics = self.est.diagnostics()
        s.grid_counters = self.arx_inputs.grid.counters.as_dict()
        return out

    def _estimate(self, samples: list) -> list[tuple[str, Any]]:
        """What the estimation node does with its samples (modal_estimator_node._on_sample)."""
        from okid_ros.nodes.conversions import modal_states_msg, mode_msg, state_space_model_msg, structural_change_msg
        from okid_ros.service.sample_grid import RESTART_SKIP

        s = self.summary
        out: list[tuple[str, Any]] = []
        for sample in samples:
            if sample.time_jump and self._reset_on_jump[1]:
                self.est.reset()  # as the node does (reset_on_time_jump)
                self._mode_msgs = []
            skipped = RESTART_SKIP if sample.restart else sample.skipped
            result = self.est.step(sample.stamp_s, sample.u, sample.y, skipped)
            if result is None:
                continue
            if result.change is not None:
                change = result.change
                out.append((self.structural_change_topic, structural_change_msg(change, sample.stamp_s, self.types,
                                                                                  frame_id=self.frame_ids[1])))
                if self.change_input_topic == self.structural_change_topic:
                    self.arx.restart_at(change.change_stamp_s)  # what node 1 does with the message
                line = _change_summary(change)
                s.changes.append(line)
                if not change.modes_after:
                    self._change_since_update = line
            if result.update is not None:
                update = result.update
                self._mode_msgs = [mode_msg(m, self.types) for m in update.modes]
                out.append((self.state_space_topic,
                            state_space_model_msg(update, self.types, frame_id=self.frame_ids[1])))
                s.models += 1
                s.updates.append({
                    "stamp_s": float(update.stamp_s),
                    "applied_at_stamp_s": float(sample.stamp_s),
                    "model_id": int(update.model_id),
                    "arx_model_id": int(update.arx_model_id),
                    "n_states": int(update.model.n_states),
                    "window_samples": int(update.window_samples),
                    "realization_time_s": float(update.realization_time_s),
                    "modes": [mode_summary(m) for m in update.modes],
                    **self._change_fields(),
                })
                fits = self._fits.pop(id(update.model), None)
                if fits is not None:  # on the model's own window, after the ARX order's samples
                    s.updates[-1].update(fit_one_step_pct=fits["one_step_pct"],
                                         fit_simulation_pct=fits["simulation_pct"])
            out.append((self.modal_states_topic, modal_states_msg(result, self.types, frame_id=self.frame_ids[1],
                                                                  mode_msgs=self._mode_msgs)))
            s.modal_states += 1
        return out

    def _realize_pending(self) -> None:
        """``ModalEstimationService.process_pending``, keeping the fits of the new model on its window."""
        from okid_ros.core.validation import prediction_fits

        job = self.est.take_job()
        if job is None:
            return
        outcome = self.est.run_job(job, follow=False)
        if outcome.model is not None:
            self._fits[id(outcome.model)] = prediction_fits(outcome.model, job.u, job.y)
        self.est.deliver(outcome)

    def _change_fields(self) -> dict:
        """``change_detected`` (a change was declared since the previous update) and its details."""
        change, self._change_since_update = self._change_since_update, None
        if change is None:
            return {"change_detected": False}
        return {"change_detected": True, "change_stamp_s": change["change_stamp_s"],
                "change_detection_stamp_s": change["detection_stamp_s"], "change_statistic": change["statistic"]}

    def _identify(self, samples: list) -> list[tuple[str, Any]]:
        """What the identification node does, and the estimation node's handling of its models.

        The identification node pushes and publishes at its rate; each ArxModel is handled as
        the estimation node does (modal_estimator_node._on_arx_model), realized at once.
        """
        from okid_ros.nodes.conversions import arx_fit_from_msg, arx_model_msg

        s = self.summary
        out: list[tuple[str, Any]] = []
        for sample in samples:
            s.samples += 1
            if math.isnan(s.first_stamp_s):
                s.first_stamp_s = sample.stamp_s
            s.last_stamp_s = sample.stamp_s
            if sample.time_jump and self._reset_on_jump[0]:
                self.arx.reset()  # as the node does (reset_on_time_jump)
            self.arx.push(sample.stamp_s, sample.u, sample.y, gap_before=sample.gap_before)
            if not self.arx.due(sample.stamp_s):
                continue
            arx_msg = arx_model_msg(self.arx.snapshot(), self.types, frame_id=self.frame_ids[0])
            out.append((self.arx_topic, arx_msg))
            s.arx_models += 1
            if self.arx_input_topic != self.arx_topic or not arx_msg.valid:
                continue  # the estimator listens elsewhere, or ignores invalid models (as live)
            s.valid_arx_models += 1
            try:
                fit, stamp_s, rows = arx_fit_from_msg(arx_msg)
            except ValueError:
                continue
            self.est.submit_arx(fit, stamp_s, int(arx_msg.model_id), rows)
            self._realize_pending()
        return out


def _change_summary(change: Any) -> dict:
    """JSON-ready dict of a StructuralChangeEvent."""
    return {
        "change_id": int(change.change_id),
        "change_stamp_s": float(change.change_stamp_s),
        "detection_stamp_s": float(change.stamp_s),
        "detection_delay_samples": int(change.detection_delay_samples),
        "statistic": float(change.statistic),
        "threshold": float(change.threshold),
        "variance_ratio": float(change.variance_ratio),
        "modes_before": [mode_summary(m) for m in change.modes_before],
        "modes_after": [mode_summary(m) for m in change.modes_after],
        "retired_ids": [int(i) for i in change.retired_ids],
    }


def process_bag(
    bag_path: str | Path,
    out_path: str | Path,
    arx_values: dict,
    est_values: dict,
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
        missing/corrupt input, a source topic missing or of another type.
    OutputExistsError
        an output exists and ``force`` is false.
    """
    bag_path, out_path = Path(bag_path), Path(out_path)
    if out_path.resolve() == bag_path.resolve():
        raise BagWriteError(f"{out_path}: the output bag cannot be the input bag")
    nodes = OfflineNodes(arx_values, est_values, namespace=namespace)
    clash = sorted(set(nodes.input_topics) & set(nodes.output_topics))
    if clash:
        raise ParameterError(f"input and output topics overlap: {', '.join(clash)}")
    if jsonl_path is not None:
        jsonl_path = Path(jsonl_path)
        if jsonl_path.exists() and not force:
            prepare_output(jsonl_path, force=False, kind="JSON lines file")
    if out_path.exists() and not force:
        prepare_output(out_path, force=False)
    started = time.perf_counter()
    created: list[Path] = []
    try:
        with open_bag(bag_path) as bag:
            for topic, msgtype in nodes.input_topics.items():
                bag.require_topic(topic, [msgtype])
            total = bag.message_count(nodes.input_topics)
            if total == 0:
                raise BagReadError(f"{bag_path}: the input topics {', '.join(nodes.input_topics)} have no messages")
            truth = bag.custom_data.get(TRUTH_KEY)
            # Outputs are created only once the input is known to be usable.
            jsonl = None
            if jsonl_path is not None:
                prepare_output(jsonl_path, force=force, kind="JSON lines file")
                jsonl = open(jsonl_path, "w")
                created.append(jsonl_path)
            writer = BagWriter(out_path, storage=storage, force=force)
            created.append(out_path)
            bar = _Progress(total, progress, progress_stream)
            with writer:
                if truth is not None:
                    writer.set_custom_data(TRUTH_KEY, truth)
                for topic, msgtype in nodes.output_topics.items():
                    writer.add_topic(topic, msgtype)
                written_updates = 0

                def emit(outputs: list, log_ns: int) -> None:
                    nonlocal written_updates
                    for out_topic, out_msg in outputs:
                        writer.write(out_topic, _log_time_ns(nodes.summary.last_stamp_s, log_ns), out_msg)
                    while written_updates < len(nodes.summary.updates):
                        line = nodes.summary.updates[written_updates]
                        written_updates += 1
                        if jsonl is not None:
                            jsonl.write(dumps(line) + "\n")
                            jsonl.flush()
                        if on_update is not None:
                            on_update(line)

                try:
                    log_ns = 0
                    for topic, log_ns, msg in bag.messages(nodes.input_topics):
                        emit(nodes.feed(topic, msg, log_ns * 1e-9), log_ns)
                        bar.update()
                    emit(nodes.finish(), log_ns)
                finally:
                    bar.close()
                    if jsonl is not None:
                        jsonl.close()
                summary = nodes.summary
                summary.elapsed_s = time.perf_counter() - started
                stabilization = getattr(nodes.est.current_model, "stabilization", None)
                if stabilization:  # for `okid-ros plot`'s stabilization diagram of the last model
                    writer.set_custom_data(STABILIZATION_KEY, dumps([entry.as_dict() for entry in stabilization]))
                writer.set_custom_data(PROCESS_KEY, dumps({
                    "source": str(bag_path),
                    "input_topics": nodes.input_topics,
                    "samples": summary.samples,
                    "first_stamp_s": summary.first_stamp_s,
                    "arx_models": summary.arx_models,
                    "models": summary.models,
                    "elapsed_s": summary.elapsed_s,
                    "parameters": {"okid_arx_identifier": arx_values, "okid_modal_estimator": est_values},
                    **(provenance or {}),
                }, default=str))
    except KeyboardInterrupt:
        raise  # what was written stays, closed and readable
    except BaseException:
        for path in created:  # no half-written outputs after an error
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            elif path.exists():
                path.unlink()
        raise
    return summary


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
