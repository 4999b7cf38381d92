"""Input messages read from their serialized bytes equal the message objects rclpy deserializes.

Real rclpy message classes and rclpy's own (de)serialization, and rosbags' CDR writer as a
second, independent one; no node (the nodes' DDS tests run the input thread on these readers).
"""

from __future__ import annotations

import math
from types import SimpleNamespace as NS

import numpy as np
import pytest
from _hypothesis_profiles import settings  # noqa: F401 - registers and loads the profile
from hypothesis import given
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message

from okid_ros.nodes import raw_inputs
from okid_ros.nodes.conversions import source_values
from okid_ros.nodes.raw_inputs import RawSourceReader, message_class, raw_reader
from okid_ros.service.grid_samples import NO_DATA
from okid_ros.service.inputs import parse_source, sources_and_grid
from okid_ros.tools.bagio import okid_typestore

STORE = okid_typestore()

#: (source, n_inputs, n_outputs): every kind, whole and mapped samples, output-only.
SOURCES = [
    ("imu /s linear_acceleration.x=y0 angular_velocity.z=y1 linear_acceleration.z=u0", 1, 2),
    ("accel /s accel.linear.x=y0 angular.y=u0", 1, 1),
    ("wrench /s force.x=u0 wrench.torque.z=y0 force.y=u1", 2, 1),
    ("io_sample /s", 2, 3),
    ("io_sample /s", 0, 4),
    ("io_sample /s u[1]=u0 y[0]=y0 y[2]=y1", 1, 2),
    ("array /s data[0]=stamp data[1]=u0 data[3]=y0", 1, 1),
    ("array /s data[2]=y0 data[0]=y1", 0, 2),
]

values = st.floats(allow_nan=True, allow_infinity=True, width=64)


def reader_of(text: str, m: int, p: int) -> RawSourceReader:
    spec = parse_source(text, m, p)
    reader = raw_reader(spec, m, p, message_class(spec.msg_type))
    assert reader is not None, f"no reader for {text!r}"
    return reader


def expected(reader: RawSourceReader, data: bytes) -> tuple:
    msg = deserialize_message(data, reader.message_type)
    return source_values(msg, reader.spec, reader.n_inputs, reader.n_outputs)


def assert_same(got: tuple, want: tuple) -> None:
    assert (got[0] is None) == (want[0] is None)
    assert (got[1] is NO_DATA) == (want[1] is NO_DATA)
    if got[0] is not None:
        assert got[0] == want[0] or (math.isnan(got[0]) and math.isnan(want[0]))
    np.testing.assert_array_equal(got[1], want[1])  # NaN equal to NaN


@st.composite
def messages(draw, reader: RawSourceReader):
    """A message of the reader's type: any frame_id, stamp, values and sequence lengths."""
    msg = reader.message_type()
    kind = reader.spec.kind
    if kind == "array":
        from std_msgs.msg import MultiArrayDimension

        msg.layout.dim = [MultiArrayDimension(label=draw(st.text(max_size=9)), size=draw(st.integers(0, 2**32 - 1)),
                                              stride=draw(st.integers(0, 2**32 - 1)))
                          for _ in range(draw(st.integers(0, 3)))]
        msg.layout.data_offset = draw(st.integers(0, 2**32 - 1))
        msg.data = draw(st.lists(values, max_size=8))
        return msg
    msg.header.frame_id = draw(st.text(max_size=20))
    msg.header.stamp.sec = draw(st.integers(-2**31, 2**31 - 1))
    msg.header.stamp.nanosec = draw(st.integers(0, 2**32 - 1))
    if kind == "io_sample":
        msg.u = draw(st.lists(values, max_size=5))
        msg.y = draw(st.lists(values, max_size=5))
        return msg
    for path in reader.spec.fields:
        obj = msg
        for name in path[:-1]:
            obj = getattr(obj, name)
        setattr(obj, path[-1], draw(values))
    for name, index in reader.spec.no_data_checks:  # REP 145's "no data" (-1), or any variance
        getattr(msg, name)[index] = draw(st.one_of(st.just(-1.0), values))
    return msg


@pytest.mark.parametrize(("text", "m", "p"), SOURCES)
@given(data=st.data())
def test_the_bytes_read_as_the_object_rclpy_deserializes(text, m, p, data):
    reader = reader_of(text, m, p)
    msg = data.draw(messages(reader))
    raw = serialize_message(msg)
    assert_same(reader._parse(raw), expected(reader, raw))  # the fast path itself, no fallback
    assert_same(reader.read(raw), expected(reader, raw))


@pytest.mark.parametrize(("text", "m", "p"), SOURCES)
def test_bytes_another_cdr_writer_made_read_the_same(text, m, p):
    """Bytes of another CDR writer (rosbags', as in bags other tools wrote) read as rclpy reads them."""
    reader = reader_of(text, m, p)
    for msg in reader.test_messages():
        raw = bytes(STORE.serialize_cdr(rosbags_message(serialize_message(msg), reader.spec.msg_type),
                                        reader.spec.msg_type))
        assert_same(reader._parse(raw), expected(reader, raw))


def rosbags_message(raw: bytes, msgtype: str):
    """The rosbags object of rclpy's bytes, which may run past the CDR (tools/bagio.py): cut to size."""
    for size in range(len(raw), 3, -1):
        try:
            return STORE.deserialize_cdr(raw[:size], msgtype)
        except Exception:  # noqa: BLE001 - a size mismatch: try one byte shorter
            continue
    raise AssertionError("rosbags reads no prefix of rclpy's bytes")


def test_another_encoding_and_damaged_bytes_go_to_rclpy(monkeypatch):
    reader = reader_of(*SOURCES[0])
    raw = serialize_message(reader.test_messages()[5])
    calls = []
    real = reader._deserialize
    monkeypatch.setattr(reader, "_deserialize", lambda data, kind: calls.append(data) or real(data, kind))
    reader.read(raw)
    assert calls == []  # plain little-endian CDR: read from the bytes
    big_endian = b"\x00\x00" + raw[2:]
    reader.read(big_endian)
    assert calls == [big_endian]
    stamp, got = reader.read(raw[:30])  # cut inside the doubles: rclpy cannot read it either
    assert stamp is None and got.size == 0
    assert len(calls) == 2


def test_a_reader_that_reads_otherwise_than_rclpy_is_not_used(monkeypatch):
    text, m, p = SOURCES[0]
    spec = parse_source(text, m, p)
    msg_type = message_class(spec.msg_type)
    assert raw_reader(spec, m, p, msg_type) is not None
    # Wrong for one frame_id length (3 characters and the NUL) is enough to refuse the reader.
    real = RawSourceReader._fixed
    monkeypatch.setattr(RawSourceReader, "_fixed",
                        lambda self, data: (lambda s, v: (s, v + (data[12] == 4)))(*real(self, data)))
    assert raw_reader(spec, m, p, msg_type) is None
    monkeypatch.setattr(raw_inputs, "PLAIN_CDR_LE", b"\x00\x02")  # an rmw of another encoding
    monkeypatch.setattr(RawSourceReader, "_fixed", real)
    assert raw_reader(spec, m, p, msg_type) is None


@pytest.mark.parametrize(("text", "covariance", "no_data"), [
    ("imu /s linear_acceleration.x=y0", "linear_acceleration_covariance", True),
    ("imu /s linear_acceleration.x=y0", "angular_velocity_covariance", False),  # a field not read
    ("imu /s linear_acceleration.x=y0", "orientation_covariance", False),  # never read
    ("imu /s angular_velocity.z=y0 linear_acceleration.y=y1", "angular_velocity_covariance", True),
])
def test_a_covariance_declaring_no_data_refuses_the_message_where_its_field_is_read(text, covariance, no_data):
    """REP 145: element 0 at -1 declares the field without data; zeros ("unknown") and variances do not."""
    m, p = 0, text.count("=")
    reader = reader_of(text, m, p)
    _, grid = sources_and_grid({"n_inputs": m, "n_outputs": p, "inputs.sources": [text], "sample_time_s": 0.01,
                                "inputs.stamp_tolerance": 0.25, "inputs.latency_samples": 5,
                                "inputs.time_jump_s": 1.0})
    for k, (first, declared) in enumerate([(0.0, False), (0.04, False), (-1.0, no_data), (-0.5, False)]):
        msg = reader.test_messages()[0]
        msg.linear_acceleration.x, msg.angular_velocity.z = 3.0 + k, 4.0 + k
        getattr(msg, covariance)[0] = first
        raw = serialize_message(msg)
        for stamp, values in (reader._parse(raw), expected(reader, raw)):  # the bytes, the object
            assert (values is NO_DATA) == declared, (first, values)
            assert declared or 3.0 + k in values or 4.0 + k in values
        grid.add(0, stamp + 0.01 * k, values)
    assert grid.counters.no_data == int(no_data) and grid.counters.samples_emitted + grid.pending_slots == 4 - no_data


def test_a_node_tells_each_topic_declaring_no_data_once():
    from okid_ros.nodes.input_frontend import InputFrontend

    sources = ["imu /a linear_acceleration.x=y0", "imu /b linear_acceleration.x=y1"]
    warnings = []
    frontend = InputFrontend.__new__(InputFrontend)  # its reading of messages, without subscriptions
    frontend.node = NS(get_logger=lambda: NS(warning=warnings.append))
    frontend.specs, frontend.grid = sources_and_grid({
        "n_inputs": 0, "n_outputs": 2, "inputs.sources": sources, "sample_time_s": 0.01,
        "inputs.stamp_tolerance": 0.25, "inputs.latency_samples": 5, "inputs.time_jump_s": 1.0})
    frontend.m, frontend.p, frontend.on_sample = 0, 2, lambda sample: None
    frontend.last_arrival_ns, frontend._counts, frontend._no_data_told = [None, None], [0, 0], set()
    msg = reader_of(sources[1], 0, 2).test_messages()[0]
    msg.linear_acceleration_covariance[0] = -1.0
    for k in range(5):
        frontend._handle(0, reader_of(sources[0], 0, 2).test_messages()[0], 1 + k)
        frontend._handle(1, msg, 1 + k)
    assert frontend.grid.source_counters(1).no_data == 5 and frontend.grid.source_counters(0).no_data == 0
    assert len(warnings) == 1 and warnings[0].startswith("input /b: a message rejected, never used as data: its "
                                                         "linear_acceleration_covariance[0] is -1"), warnings
