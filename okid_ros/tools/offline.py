"""Both nodes without ROS, fed input messages one by one (``okid-ros process``).

Per node, exactly what the live node does with its topics, minus the middleware: each node's
own sample grid (:class:`NodeInputs`, what the nodes' input frontend does), then the one
windowed pipeline of the service layer (:class:`okid_ros.service.windowed.WindowedPipeline`:
node 1's window and its snapshots by sample time, node 2's estimator and realizations, the
window restart at a structural change, the model still pending at the end of the record,
:meth:`OfflineNodes.finish`). Here only the messages are built and read: every
output with :mod:`okid_ros.nodes.conversions`, and every valid ``ArxModel`` goes back into
node 2 through the node's own call (``estimator_arx_fit``: the conversion at node 2's sample time).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from okid_ros.errors import ParameterError
from okid_ros.service.grid_samples import NO_DATA, REJECTION_REASONS

__all__ = ["TOPIC_PARAMETERS", "NodeInputs", "OfflineNodes", "ProcessSummary"]

_ARX, _MODEL, _CHANGE = "okid_msgs/msg/ArxModel", "okid_msgs/msg/StateSpaceModel", "okid_msgs/msg/StructuralChange"
#: node -> topic parameter -> message type on that topic (published or subscribed).
TOPIC_PARAMETERS: dict[str, dict[str, str]] = {
    "okid_arx_identifier": {"arx_model_topic": _ARX, "structural_change_topic": _CHANGE},
    "okid_modal_estimator": {"arx_model_topic": _ARX, "structural_change_topic": _CHANGE,
                             "state_space_model_topic": _MODEL, "modal_states_topic": "okid_msgs/msg/ModalStates"},
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
    input_note: str = ""  # how the input bag was read when not as a whole (a cut-off recording)
    wrong_size_note: str = ""  # the sizes expected and those of the first message of a wrong size
    unjudged_alarm: str = ""  # the change test's alarm the record ended before its modes' verdict (one sentence)
    no_data_note: str = ""  # per topic, its messages whose covariance declared no data (REP 145) and why
    arx_malformed: int = 0  # valid ArxModels node 2 did not take (``estimator_arx_fit``), as the node counts them
    arx_malformed_why: str = ""  # the first one's line, as node 2 logs it
    sample_time_s: float = math.nan  # node 1's grid
    stretches: int = 0  # runs of samples between the stamps' jumps back in time (1 without)
    stamp_span_s: float = 0.0  # the stamps the samples span, each stretch on its own, gaps included
    gap_s: float = 0.0  # of it, the time between samples with no sample (beyond one sample time)
    gaps: int = 0  # samples that follow missing ones
    runs: int = 0  # contiguous runs of samples (a new one after a gap or a jump back)
    alone: int = 0  # samples of a closed run of one (:attr:`alone_samples` counts the open one too)
    _run_length: int = 0
    longest_gap: tuple = ()  # (stamp before it [s], its length [s], samples missing in it)
    _stretch_start_s: float = math.nan

    @property
    def data_duration_s(self) -> float:
        """Seconds of data: the stamps the samples span, each stretch alone, without the gaps between them."""
        return self.sample_span_s - self.gap_s

    @property
    def sample_span_s(self) -> float:
        """Seconds of sample time the samples span (gaps included), each stretch alone."""
        open_stretch = 0.0 if math.isnan(self._stretch_start_s) else self.last_stamp_s - self._stretch_start_s
        return self.stamp_span_s + open_stretch

    def add_sample(self, sample: Any) -> None:
        """Count one sample of node 1's grid (a ``GridSample``): the stretches and gaps of its stamps."""
        stamp = sample.stamp_s
        self.samples += 1
        if math.isnan(self.first_stamp_s):
            self.first_stamp_s = stamp
        if sample.restart or math.isnan(self._stretch_start_s):  # the start, or the stamps went back
            if not math.isnan(self._stretch_start_s):
                self.stamp_span_s += self.last_stamp_s - self._stretch_start_s
            self._stretch_start_s = stamp
            self.stretches += 1
        elif sample.skipped > 0:
            length = stamp - self.last_stamp_s
            self.gap_s += max(0.0, length - self.sample_time_s)
            self.gaps += 1
            if not self.longest_gap or length > self.longest_gap[1]:
                self.longest_gap = (self.last_stamp_s, length, int(sample.skipped))
        if sample.gap_before:
            self.runs += 1
            self.alone += self._run_length == 1
            self._run_length = 0
        self._run_length += 1
        self.last_stamp_s = stamp

    @property
    def alone_samples(self) -> int:
        """Samples with a gap (or the start or end) on both sides."""
        return self.alone + (self._run_length == 1)

    def data_text(self) -> str:
        """``"20.0 s of data"``, with the stretches after the stamps went back and the gaps when there are any."""
        text = f"{self.data_duration_s:.1f} s of data"
        if self.stretches > 1:  # the grid started again: after a jump back in time, or re-anchored
            again = self.stretches - 1
            times = "once" if again == 1 else f"{again} times"
            why = ("the stamps went back in time" if self.grid_counters.get("time_jumps") == again
                   else "the grid started again (jumps back in time, re-anchorings)")
            text += f" in {self.stretches} stretches: {why} {times}"
        if self.gap_s >= 0.05:
            text += f", and {self.gap_s:.1f} s of gaps without samples"
        return text

    @property
    def final_modes(self) -> list[dict]:
        return self.updates[-1]["modes"] if self.updates else []

    def arx_refused_note(self) -> str:
        """What node 2 refused of node 1's ArxModels, in one sentence ("" when nothing beyond a change's).

        Refusals of windows that start before a declared structural change are the change's
        expected wait (said with it); any other (a time jump of hours: windows across the gap)
        is said with its count and reasons, which the live node gives in its diagnostics.
        """
        d = self.estimator_diagnostics
        ignored = (f"node 2 ignored {self.arx_malformed} of the {self.valid_arx_models} valid ArxModels of node 1, "
                   f"the first: {self.arx_malformed_why}") if self.arx_malformed else ""
        refused = d.get("arx_models_refused", 0)
        if refused <= d.get("windows_refused_for_change", 0):
            return ignored
        refused_note = (f"node 2 refused {refused} of the {d.get('arx_models_received', 0)} ArxModels of node 1: "
                        f"{d.get('arx_models_refused_why', '')}")
        return "; ".join(note for note in (ignored, refused_note) if note)

    def rejection_note(self) -> str:
        """What node 1's sample grid and window refused, in one sentence ("" when nothing).

        Said when no sample or no model came out, so that a wrong ``n_outputs`` does not pass
        as a record too short.
        """
        counts = self.grid_counters
        rejected, messages = counts.get("rejected_messages", 0), counts.get("messages", 0)
        # Samples the identification window refused in turn (values it cannot square in float64).
        values = {"NaN/Inf": self.arx_diagnostics.get("rejected_nonfinite", 0),
                  "beyond 1e150": self.arx_diagnostics.get("rejected_magnitude", 0)}
        refused = ", ".join(f"{n} {why}" for why, n in values.items() if n)
        refused = f"node 1 refused {sum(values.values())} of the samples ({refused})" if refused else ""
        if not rejected and not counts.get("missing"):
            return refused
        notes = {"wrong_size": self.wrong_size_note, "no_data": self.no_data_note}
        reasons = [f"{counts[key]} {key}" + (f" ({notes[key]})" if notes.get(key) else "")
                   for key in REJECTION_REASONS if counts.get(key)]
        missing = self._missing_text(counts.get("missing", 0), rejected)
        head = (f"all {messages} input messages were rejected" if rejected >= messages
                else f"{rejected} of the {messages} input messages were rejected")
        # samples missing only: a gap in the recording, not a refusal ("0 of the ... rejected")
        notes = [f"{head}: {', '.join(reasons + ([missing] if missing else []))}" if rejected else missing,
                 *self.grid_hints(), refused]
        return "; ".join(note for note in notes if note)

    def losses_worth_saying(self) -> bool:
        """Whether the samples dropped incomplete or the messages refused are worth the note though models came."""
        from okid_ros.tools.grid_hints import loss_worth_saying

        counts = self.grid_counters
        missing = counts.get("missing", 0)
        return (loss_worth_saying(missing, self.samples + missing)
                or loss_worth_saying(counts.get("rejected_messages", 0), counts.get("messages", 0)))

    def grid_hints(self) -> list[str]:
        """The likely cause when the messages do not fit node 1's grid (:mod:`okid_ros.tools.grid_hints`)."""
        from okid_ros.tools.grid_hints import rejection_hint, stand_alone_hint

        by_reason = {key: self.grid_counters[key] for key in REJECTION_REASONS if self.grid_counters.get(key)}
        hints = [rejection_hint(by_reason, self.sample_time_s, messages=self.grid_counters.get("messages", 0)),
                 stand_alone_hint(samples=self.samples, runs=self.runs, alone=self.alone_samples,
                                  present=self.samples, rejected=by_reason, sample_time_s=self.sample_time_s)]
        return [hint for hint in hints if hint]

    def _missing_text(self, missing: int, rejected: int) -> str:
        """"N samples missing", with the gaps that hold them ("" when none)."""
        if not missing:
            return ""
        if not self.longest_gap:
            return f"{missing} samples dropped incomplete (missing)"
        before_s, length_s, skipped = self.longest_gap
        kind = "without a sample" if rejected else "with no messages"  # rejected messages leave gaps too
        after = f"after the stamp {before_s:.3f} s"
        if 2 * skipped >= missing:
            most = "" if skipped >= missing else f"{skipped} in "
            return f"{missing} samples missing: {most}a gap of {length_s:.6g} s {kind} {after}"
        return f"{missing} samples missing in {self.gaps} gaps {kind}, the longest {length_s:.6g} s {after}"


class NodeInputs:
    """One node's input sources and sample grid (what InputFrontend does, minus subscriptions)."""

    def __init__(self, values: dict, namespace: str | None = None) -> None:
        from okid_ros.service.inputs import sources_and_grid

        self.m, self.p = int(values["n_inputs"]), int(values["n_outputs"])
        self.specs, self.grid = sources_and_grid(values, namespace)
        self.by_topic: dict[str, list[int]] = {}
        for i, spec in enumerate(self.specs):
            self.by_topic.setdefault(spec.topic, []).append(i)
        self.wrong_size_note = ""  # set at the first message of a wrong size
        self._readers: list | None = None  # per source, its bytes' reader (made at the first stored message)

    def add(self, topic: str, msg: Any, arrival_s: float) -> list:
        """One input message: a message object or a bag's ``StoredMessage`` (read from its bytes)."""
        from okid_ros.nodes.conversions import source_values
        from okid_ros.tools.bagio import StoredMessage

        stored = isinstance(msg, StoredMessage)
        samples = []
        for i in self.by_topic.get(topic, ()):
            reader = self._reader(i) if stored else None
            parsed = reader.parse(msg.raw) if reader is not None else None
            if parsed is None:
                parsed = source_values(msg.message if stored else msg, self.specs[i], self.m, self.p)
            stamp, values = parsed
            # empty, not NO_DATA: the message has the wrong size
            if values is not NO_DATA and not len(values) and not self.wrong_size_note:
                self._note_wrong_size(topic, msg.message if stored else msg, self.specs[i])
            samples += self.grid.add(i, arrival_s if stamp is None else stamp, values)
        return samples

    def no_data_note(self) -> str:
        """Per topic whose messages declared no data (REP 145): how many of its messages and why ("" if none)."""
        from okid_ros.service.inputs import no_data_reason

        notes = {}
        for i, spec in enumerate(self.specs):
            counters = self.grid.source_counters(i)
            if counters.no_data and spec.topic not in notes:
                notes[spec.topic] = (f"{spec.topic}: {counters.no_data} of its {counters.messages} messages rejected, "
                                     f"never used as data: {no_data_reason(spec)}")
        return "; ".join(notes.values())

    def _note_wrong_size(self, topic: str, msg: Any, spec: Any) -> None:
        have = ", ".join(f"{name} of {len(getattr(msg, name))}" for name in ("u", "y", "data") if hasattr(msg, name))
        # A source mapping fields reads them, whatever n_inputs and n_outputs are ("u of 2" for u[5]).
        wanted = f"n_inputs {self.m}, n_outputs {self.p}" if spec.whole_sample else f"the fields of {spec.text!r}"
        self.wrong_size_note = f"{wanted} expected; the first on {topic} has {have or 'other'} values"

    def _reader(self, index: int) -> Any:
        """The reader of source ``index``'s bytes (:func:`okid_ros.nodes.raw_inputs.raw_reader`), or None.

        Checked against rclpy's serialization of the source's type: rosbags' objects, which the
        bytes are read instead of, hold the same values (``test_nodes_raw_inputs.py`` reads bytes
        rosbags wrote). None without rclpy: the messages are decoded by rosbags as before.
        """
        if self._readers is None:
            from okid_ros.nodes.raw_inputs import raw_reader

            self._readers = [raw_reader(spec, self.m, self.p) for spec in self.specs]
        return self._readers[index]


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
        from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams
        from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE
        from okid_ros.service.topics import resolve_topic
        from okid_ros.service.windowed import PipelineSettings, WindowedPipeline
        from okid_ros.tools.bagio import okid_typestore

        self.types = types or MessageTypes.from_typestore(okid_typestore())
        self.arx_inputs = NodeInputs(arx_values, namespace)
        self.est_inputs = NodeInputs(est_values, namespace)
        # node -> parameter -> full topic name; resolve_topic refuses a bad name, naming the parameter
        self.topic_parameters: dict[str, dict[str, str]] = {
            node: {name: resolve_topic(values[name], namespace, parameter=f"{name} of {node}")
                   for name in TOPIC_PARAMETERS[node]}
            for node, values in ((ARX_NODE, arx_values), (ESTIMATOR_NODE, est_values))
        }
        arx_topics, est_topics = self.topic_parameters[ARX_NODE], self.topic_parameters[ESTIMATOR_NODE]
        self.arx_topic, self.change_input_topic = arx_topics["arx_model_topic"], arx_topics["structural_change_topic"]
        self.arx_input_topic = est_topics["arx_model_topic"]
        self.state_space_topic = est_topics["state_space_model_topic"]
        self.modal_states_topic = est_topics["modal_states_topic"]
        self.structural_change_topic = est_topics["structural_change_topic"]
        settings = PipelineSettings(
            reset_arx_on_time_jump=bool(arx_values["reset_on_time_jump"]),
            reset_estimator_on_time_jump=bool(est_values["reset_on_time_jump"]),
            restart_on_change=self.change_input_topic == self.structural_change_topic,
        )
        try:
            self.pipeline = WindowedPipeline(ArxIdentificationParams.from_parameters(arx_values),
                                             ModalEstimationParams.from_parameters(est_values), settings)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self.arx, self.est = self.pipeline.arx, self.pipeline.est
        # The JSON lines and change records are the pipeline's (one serializer).
        self.summary = ProcessSummary(updates=self.pipeline.updates, changes=self.pipeline.changes,
                                      sample_time_s=self.arx_inputs.grid.sample_time_s)
        self._mode_msgs: list = []
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
        """End of the record: complete samples still pending in the grids are processed too.

        Then node 2 applies the model it still holds (:meth:`WindowedPipeline.finish
        <okid_ros.service.windowed.WindowedPipeline.finish>`; live: its idle timer after a replay):
        its StateSpaceModel (and StructuralChange) as at a sample, with no ModalStates.
        """
        out = self._estimate(self.est_inputs.grid.flush())
        out += self._identify(self.arx_inputs.grid.flush())
        for switch in self.pipeline.finish():
            out += self._model_messages(switch.update, switch.change, switch.stamp_s)
        s = self.summary
        s.arx_diagnostics = self.arx.diagnostics()
        s.estimator_diagnostics = self.est.diagnostics()
        s.grid_counters = self.arx_inputs.grid.counters.as_dict()
        s.wrong_size_note = self.arx_inputs.wrong_size_note
        s.no_data_note = self.arx_inputs.no_data_note()
        s.unjudged_alarm = self.pipeline.unjudged_alarm
        return out

    def _estimate(self, samples: list) -> list[tuple[str, Any]]:
        """Node 2's samples through the pipeline; its messages."""
        from okid_ros.nodes.conversions import modal_states_msg

        s = self.summary
        out: list[tuple[str, Any]] = []
        for sample in samples:
            if sample.time_jump and self.pipeline.settings.reset_estimator_on_time_jump:
                self._mode_msgs = []  # as the node does (reset_on_time_jump)
            result = self.pipeline.estimate(sample)
            if result is None:
                continue
            out += self._model_messages(result.update, result.change, sample.stamp_s)
            out.append((self.modal_states_topic, modal_states_msg(result, self.types, frame_id=self.frame_ids[1],
                                                                  mode_msgs=self._mode_msgs)))
            s.modal_states += 1
        return out

    def _model_messages(self, update: Any, change: Any, stamp_s: float) -> list[tuple[str, Any]]:
        """Node 2's StructuralChange and StateSpaceModel of a switch (at a sample or after the last one)."""
        from okid_ros.nodes.conversions import mode_msg, state_space_model_msg, structural_change_msg

        frame_id = self.frame_ids[1]
        out: list[tuple[str, Any]] = []
        if change is not None:
            out.append((self.structural_change_topic,
                        structural_change_msg(change, stamp_s, self.types, frame_id=frame_id)))
        if update is not None:
            self._mode_msgs = [mode_msg(m, self.types) for m in update.modes]
            out.append((self.state_space_topic, state_space_model_msg(update, self.types, frame_id=frame_id)))
            self.summary.models += 1
        return out

    def _identify(self, samples: list) -> list[tuple[str, Any]]:
        """Node 1's samples through the pipeline; its ArxModel, each handed to node 2 as the node does.

        Node 2 takes a valid ArxModel through the message conversion the node uses
        (modal_estimator_node._on_arx_model) and realizes it at once.
        """
        from okid_ros.nodes.conversions import arx_model_msg

        s = self.summary
        out: list[tuple[str, Any]] = []
        for sample in samples:
            s.add_sample(sample)
            snapshot = self.pipeline.identify(sample)
            if snapshot is None:
                continue
            arx_msg = arx_model_msg(snapshot, self.types, frame_id=self.frame_ids[0])
            out.append((self.arx_topic, arx_msg))
            s.arx_models += 1
            if self.arx_input_topic != self.arx_topic or not arx_msg.valid:
                continue  # the estimator listens elsewhere, or ignores invalid models (as live)
            s.valid_arx_models += 1
            self.take_arx_model(arx_msg)
        return out

    def take_arx_model(self, arx_msg: Any) -> str:
        """Node 2 takes a valid ArxModel as the node does (``estimator_arx_fit``): realized now, or why it is not.

        A refusal is counted as the node counts it (``arx_models_malformed``) and its first line kept
        (:meth:`ProcessSummary.arx_refused_note`).
        """
        from okid_ros.nodes.conversions import estimator_arx_fit

        try:
            fit, stamp_s, rows = estimator_arx_fit(arx_msg, self.est.params)
        except ValueError as exc:
            self.summary.arx_malformed += 1
            self.summary.arx_malformed_why = self.summary.arx_malformed_why or str(exc)
            return str(exc)
        self.pipeline.realize_now(fit, stamp_s, int(arx_msg.model_id), rows)
        return ""
