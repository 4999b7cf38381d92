"""Input sources: which topics fill which channels of the sample ``[u; y]``.

Both nodes read the same sources, given by the string array parameter ``inputs.sources``,
one string per topic::

    KIND TOPIC [FIELD=CHANNEL ...]

``CHANNEL`` is ``u<i>`` (input i, 0-based, i < n_inputs) or ``y<j>`` (output j < n_outputs).
Over all sources, each channel is filled once and each field of a topic fills one channel.
Kinds, their message types and their fields:

============  ==================================  ===========================================
KIND          message type                        FIELDs
============  ==================================  ===========================================
io_sample     okid_msgs/msg/IoSample              ``u[i]``, ``y[j]``; no mapping: all channels,
                                                  ``u[i]=ui`` and ``y[j]=yj``
imu           sensor_msgs/msg/Imu                 ``linear_acceleration.x|y|z``,
                                                  ``angular_velocity.x|y|z``
accel         geometry_msgs/msg/AccelStamped      ``accel.linear.x|y|z``, ``accel.angular.x|y|z``
wrench        geometry_msgs/msg/WrenchStamped     ``wrench.force.x|y|z``, ``wrench.torque.x|y|z``
                                                  (``force.x`` and ``torque.x`` are short forms)
array         std_msgs/msg/Float64MultiArray      ``data[i]``; ``data[i]=stamp`` takes the stamp
                                                  in seconds from element i
============  ==================================  ===========================================

Examples::

    io_sample /okid/io_sample
    imu /truss/tip_accel_1 linear_acceleration.x=y0
    wrench /truss/thruster_1 force.x=u0
    array /daq/frame data[0]=stamp data[1]=u0 data[2]=u1 data[3]=y0 data[4]=y1

No data: REP 145 has a sensor that does not measure a field of ``sensor_msgs/Imu`` set element 0 of
the field's covariance to -1. An imu message whose covariance declares so for a field the source
reads is rejected whole, counted ``no_data`` (:func:`declares_no_data`); a covariance of zeros
("unknown") is no such declaration. The orientation is never read, so its covariance is not looked at.

Stamps: ``header.stamp`` of the message; a Float64MultiArray has no header, so without a
``stamp`` element it is stamped with its arrival time on the node clock, which is only as good
as the transport jitter (use it with one source for all channels, or give a stamp element).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from okid_ros.service.channels import channel_index, channel_name

__all__ = ["NO_DATA_COVARIANCE", "SOURCE_KINDS", "SourceSpec", "declares_no_data", "no_data_reason", "parse_source",
           "parse_sources", "sources_and_grid", "time_jump_note"]

#: kind -> (message type, field aliases -> canonical field path)
SOURCE_KINDS: dict[str, str] = {
    "io_sample": "okid_msgs/msg/IoSample",
    "imu": "sensor_msgs/msg/Imu",
    "accel": "geometry_msgs/msg/AccelStamped",
    "wrench": "geometry_msgs/msg/WrenchStamped",
    "array": "std_msgs/msg/Float64MultiArray",
}

_AXES = ("x", "y", "z")
_FIELDS: dict[str, dict[str, tuple]] = {
    "imu": {
        f"{group}.{a}": (group, a) for group in ("linear_acceleration", "angular_velocity") for a in _AXES
    },
    "accel": {
        **{f"accel.{g}.{a}": ("accel", g, a) for g in ("linear", "angular") for a in _AXES},
        **{f"{g}.{a}": ("accel", g, a) for g in ("linear", "angular") for a in _AXES},
    },
    "wrench": {
        **{f"wrench.{g}.{a}": ("wrench", g, a) for g in ("force", "torque") for a in _AXES},
        **{f"{g}.{a}": ("wrench", g, a) for g in ("force", "torque") for a in _AXES},
    },
}
#: imu field group -> its covariance, whose element 0 at :data:`NO_DATA_COVARIANCE` declares no data (REP 145).
_COVARIANCES = {"linear_acceleration": "linear_acceleration_covariance",
                "angular_velocity": "angular_velocity_covariance"}
#: REP 145 (sensor_msgs/Imu): element 0 of a field's covariance at -1 declares that the field carries no data.
NO_DATA_COVARIANCE = -1.0
_INDEXED = re.compile(r"^(u|y|data)\[(\d+)\]$")


@dataclass(frozen=True)
class SourceSpec:
    """One parsed input source.

    Attributes
    ----------
    kind : io_sample, imu, accel, wrench or array.
    topic : the topic name.
    msg_type : ROS type name, e.g. ``sensor_msgs/msg/Imu``.
    fields : per value, the attribute path in the message; a final int indexes a sequence
        (``("linear_acceleration", "x")``, ``("u", 1)``, ``("data", 3)``).
    channels : per value, the channel index in ``[u_0 .. u_{m-1}, y_0 .. y_{p-1}]``.
    stamp_index : element of ``data`` holding the stamp in seconds (array sources), else None.
    text : the specification as given.
    whole_sample : an io_sample source without mappings (``u`` and ``y`` must have m and p values).
    no_data_checks : per covariance of the fields read (imu), the path of its element 0
        (``("linear_acceleration_covariance", 0)``): :func:`declares_no_data` reads them.
    """

    kind: str
    topic: str
    msg_type: str
    fields: tuple[tuple, ...]
    channels: tuple[int, ...]
    stamp_index: int | None
    text: str
    whole_sample: bool = False  # io_sample without mappings: u and y as they are
    no_data_checks: tuple[tuple, ...] = ()

    @property
    def has_header(self) -> bool:
        return self.kind != "array"


def parse_source(text: str, n_inputs: int, n_outputs: int) -> SourceSpec:
    """Parse one ``KIND TOPIC [FIELD=CHANNEL ...]`` string; ValueError says what is wrong."""
    parts = text.split()
    if len(parts) < 2:
        raise ValueError(f"input source {text!r}: expected 'KIND TOPIC [FIELD=CHANNEL ...]'")
    kind, topic, mappings = parts[0], parts[1], parts[2:]
    if kind not in SOURCE_KINDS:
        raise ValueError(f"input source {text!r}: unknown kind {kind!r}; kinds are {', '.join(SOURCE_KINDS)}")
    if not topic.startswith("/") and not re.match(r"^[A-Za-z~]", topic):
        raise ValueError(f"input source {text!r}: {topic!r} is not a topic name")
    fields: list[tuple] = []
    channels: list[int] = []
    stamp_index = None
    if kind == "io_sample" and not mappings:
        fields = [("u", i) for i in range(n_inputs)] + [("y", j) for j in range(n_outputs)]
        channels = list(range(n_inputs + n_outputs))
    for mapping in mappings:
        if mapping.count("=") != 1:
            raise ValueError(f"input source {text!r}: mapping {mapping!r} must be FIELD=CHANNEL")
        field_text, channel_text = mapping.split("=")
        if kind in ("io_sample", "array"):
            match = _INDEXED.match(field_text)
            wanted = ("u", "y") if kind == "io_sample" else ("data",)
            if not match or match.group(1) not in wanted:
                form = "u[i] or y[j]" if kind == "io_sample" else "data[i]"
                raise ValueError(f"input source {text!r}: field {field_text!r} must be {form}")
            path: tuple = (match.group(1), int(match.group(2)))
        else:
            if field_text not in _FIELDS[kind]:
                valid = sorted(f for f in _FIELDS[kind] if f.count(".") == (2 if kind != "imu" else 1))
                raise ValueError(
                    f"input source {text!r}: {kind} has no field {field_text!r}; fields are {', '.join(valid)}"
                )
            path = _FIELDS[kind][field_text]
        if channel_text == "stamp":
            if kind != "array":
                raise ValueError(f"input source {text!r}: only array sources take the stamp from a field")
            if stamp_index is not None:
                raise ValueError(f"input source {text!r}: two stamp fields")
            stamp_index = path[1]
            continue
        try:
            channel = channel_index(channel_text, n_inputs, n_outputs)
        except ValueError as exc:
            raise ValueError(f"input source {text!r}: {exc}") from None
        if channel in channels:
            raise ValueError(f"input source {text!r}: channel {channel_text} mapped twice")
        fields.append(path)
        channels.append(channel)
    if not channels:
        raise ValueError(f"input source {text!r}: maps no channel (add FIELD=CHANNEL)")
    checks = tuple((_COVARIANCES[group], 0) for group in dict.fromkeys(path[0] for path in fields)
                   if kind == "imu" and group in _COVARIANCES)
    return SourceSpec(
        kind, topic, SOURCE_KINDS[kind], tuple(fields), tuple(channels), stamp_index, text,
        whole_sample=kind == "io_sample" and not mappings, no_data_checks=checks,
    )


def declares_no_data(first_elements: list[float]) -> bool:
    """Whether a message's covariances (the values at ``spec.no_data_checks``) declare a field without data.

    The one rule of the nodes and the offline tools, on message objects and on serialized bytes alike.
    """
    return NO_DATA_COVARIANCE in first_elements


def no_data_reason(spec: SourceSpec) -> str:
    """Why a message of ``spec`` that :func:`declares_no_data` is refused, naming the covariances looked at."""
    names = " or ".join(f"{name}[{index}]" for name, index in spec.no_data_checks)
    return f"{names} is -1, which REP 145 reserves for a field the sensor does not measure (no data)"


def _field_name(path: tuple) -> str:
    """A field path as written in a source: ``linear_acceleration.x``, ``data[3]``."""
    return f"{path[0]}[{path[1]}]" if isinstance(path[-1], int) else ".".join(path)


def parse_sources(texts, n_inputs: int, n_outputs: int) -> list[SourceSpec]:
    """Parse every source; the channels must be covered exactly once, each field of a topic read once."""
    specs = [parse_source(t, n_inputs, n_outputs) for t in texts if t.strip()]
    if not specs:
        raise ValueError("inputs.sources is empty: give at least one input source")
    owner: dict[int, str] = {}
    reads: dict[tuple, str] = {}  # (topic, field) -> what it fills: a channel, or the stamp
    for spec in specs:
        mapped = [(field, channel_name(c, n_inputs)) for field, c in zip(spec.fields, spec.channels)]
        mapped += [(("data", spec.stamp_index), "the stamp")] if spec.stamp_index is not None else []
        for c in spec.channels:
            if c in owner:
                raise ValueError(f"channel {channel_name(c, n_inputs)} is mapped by two sources: {owner[c]!r} and "
                                 f"{spec.text!r}")
            owner[c] = spec.text
        for field, name in mapped:
            if (spec.topic, field) in reads:  # one value in two channels: a record that repeats itself
                raise ValueError(f"field {_field_name(field)} of {spec.topic} is mapped twice (to "
                                 f"{reads[spec.topic, field]} and {name}): map each field to one channel")
            reads[spec.topic, field] = name
    missing = [channel_name(c, n_inputs) for c in range(n_inputs + n_outputs) if c not in owner]
    if missing:
        raise ValueError(f"no input source provides channel(s) {', '.join(missing)}")
    return specs


def sources_and_grid(values: dict, namespace: str | None = None):
    """Input sources and the sample grid described by node parameters (``inputs.*`` and dims).

    Shared by the nodes and ``okid-ros process`` so both assemble samples the same way.
    Relative topic names are resolved in the rig namespace of ``namespace`` (the node's
    namespace; None or ``/``: ``/okid``), see :mod:`okid_ros.service.topics`.

    Returns
    -------
    (specs, grid): list of SourceSpec and a :class:`okid_ros.service.sample_grid.SampleGrid`.

    Raises
    ------
    okid_ros.errors.ParameterError naming ``inputs.sources`` when a source is invalid.
    """
    from dataclasses import replace

    from okid_ros.errors import ParameterError
    from okid_ros.service.sample_grid import SampleGrid
    from okid_ros.service.topics import resolve_topic

    m, p = int(values["n_inputs"]), int(values["n_outputs"])
    try:
        specs = parse_sources(values["inputs.sources"], m, p)
    except ValueError as exc:
        raise ParameterError(f"parameter inputs.sources: {exc}") from None
    specs = [replace(spec, topic=resolve_topic(spec.topic, namespace, parameter="inputs.sources")) for spec in specs]
    grid = SampleGrid(
        float(values["sample_time_s"]), m, p, [s.channels for s in specs],
        tolerance=float(values["inputs.stamp_tolerance"]),
        latency_samples=int(values["inputs.latency_samples"]),
        time_jump_s=float(values["inputs.time_jump_s"]),
    )
    return specs, grid


def time_jump_note(values: dict) -> str:
    """Why the grid takes a longer time-jump threshold than ``inputs.time_jump_s`` set to ``values`` ('' if not).

    The grid's threshold is never below :func:`~okid_ros.service.stamp_steps.least_time_jump_s`
    (``inputs.latency_samples + 2`` sample times). The default raised on a slow grid (1 s below
    7 sample times of 1 s) is the rule working, not worth a word; a value set lower is told.
    Shared by the nodes (a warning in their log) and the offline tools (a warning line).
    """
    from okid_ros.service.params import ARX_NODE, default_value
    from okid_ros.service.stamp_steps import JUMP_MARGIN_SAMPLES, least_time_jump_s

    given = float(values["inputs.time_jump_s"])
    dt, latency = float(values["sample_time_s"]), int(values["inputs.latency_samples"])
    least = least_time_jump_s(dt, latency)
    default = default_value(ARX_NODE, "inputs.time_jump_s")  # shared by both nodes
    if given >= least or given == default:
        return ""
    return (f"parameter inputs.time_jump_s {given:g} s raised to {least:g} s: a time jump must be longer than "
            f"inputs.latency_samples {latency} + {JUMP_MARGIN_SAMPLES} sample times of {dt:g} s (a source lagging "
            f"within the latency, or the next sample, is no jump)")
