"""Input messages read from their serialized bytes (the nodes' input thread).

Taking an input message as a message object makes rclpy build its Python object: an ``Imu`` is
a header and 37 doubles in nested objects, about 20 us of CPU per message, so with 28
accelerometer topics at 1024 Hz about half a core of each node's input thread. The channels
are a few of those doubles. So the input thread takes each message as its serialized bytes
(``take_message(raw=True)``) and reads the stamp and the channels from them: plain
little-endian CDR, the rmw's own encoding, in which each field is aligned to its size counted
from the start of the data (after the 4-byte encapsulation header) and an empty sequence has
no padding.

A source's reader is made only if it reads messages rclpy serialized (marker values in the
source's fields, covariances that declare no data (REP 145) or hold a variance, every padding a
frame_id can leave, empty and filled sequences) exactly as
:func:`~okid_ros.nodes.conversions.source_values` reads the objects rclpy deserializes from
the same bytes; otherwise the source's messages are taken as objects, as before. A message in
another encoding (big-endian, another vendor's XCDR2) or whose bytes do not hold what its
layout says is deserialized by rclpy and read as an object; one that rclpy cannot read either
comes back without values, which the sample grid counts as ``wrong_size``.
"""

from __future__ import annotations

import importlib
import struct
from typing import Any

import numpy as np

from okid_ros.nodes.conversions import source_values, stamp_seconds
from okid_ros.service.grid_samples import NO_DATA
from okid_ros.service.inputs import NO_DATA_COVARIANCE, SourceSpec, declares_no_data

__all__ = ["PLAIN_CDR_LE", "RawSourceReader", "message_class", "raw_reader"]

_EMPTY = np.zeros(0)
PLAIN_CDR_LE = b"\x00\x01"  # the encapsulation header's first two bytes: plain little-endian CDR
_DATA = 4  # bytes of the encapsulation header; CDR aligns from the end of it
_HEADER = struct.Struct("<iII")  # std_msgs/Header: stamp sec, nanosec, frame_id length (with its NUL)
_LENGTH = struct.Struct("<I")
_FLOAT = np.dtype("<f8")
# Frame ids of every length modulo 8 (each leaves another padding before the doubles).
_TEST_FRAME_IDS = tuple("abcdefgh"[:k] for k in range(9))


def _aligned(pos: int, size: int) -> int:
    return pos + (-(pos - _DATA)) % size


def _float_sequence(data: bytes, pos: int) -> tuple[np.ndarray, int]:
    """``float64[]`` at ``pos``: its values (a read-only view) and the position after it."""
    pos = _aligned(pos, 4)
    (count,) = _LENGTH.unpack_from(data, pos)
    pos += 4
    if count == 0:
        return _EMPTY, pos
    pos = _aligned(pos, 8)
    end = pos + 8 * count
    if end > len(data):
        raise ValueError("sequence runs past the message")
    return np.frombuffer(data, _FLOAT, count, pos), end


def _after_header(data: bytes) -> tuple[float, int]:
    """The header's stamp [s] and the position after its frame_id."""
    sec, nanosec, length = _HEADER.unpack_from(data, _DATA)
    return stamp_seconds(sec, nanosec), _DATA + _HEADER.size + length


class RawSourceReader:
    """The stamp and channel values of one source's messages, from their serialized bytes.

    Make one with :func:`raw_reader`, which checks it against rclpy.

    Parameters
    ----------
    spec : the source.
    n_inputs, n_outputs : the node's m and p.
    message_type : the rclpy class of the source's messages.
    """

    def __init__(self, spec: SourceSpec, n_inputs: int, n_outputs: int, message_type: Any) -> None:
        from rclpy.serialization import deserialize_message, serialize_message  # the nodes' layer

        self.spec, self.n_inputs, self.n_outputs = spec, n_inputs, n_outputs
        self.message_type = message_type
        self._serialize, self._deserialize = serialize_message, deserialize_message
        parse = {"io_sample": self._io_sample, "array": self._array}.get(spec.kind)
        if parse is None:  # a header and a fixed block of doubles (imu, accel, wrench)
            places = self._double_places()
            # Only the span of doubles that holds the source's fields (and their covariances' element 0) is read.
            self._first = int(places.min())
            self._span = struct.Struct(f"<{int(places.max()) - self._first + 1}d")
            n_fields = len(spec.fields)
            self._picks = (places[:n_fields] - self._first).tolist()
            self._checks = (places[n_fields:] - self._first).tolist()
            parse = self._fixed
        self._parse = parse

    def parse(self, data: bytes) -> tuple[float | None, np.ndarray] | None:
        """:meth:`read` from the bytes alone; None if they are not plain little-endian CDR of the layout."""
        if data[:2] != PLAIN_CDR_LE:
            return None
        try:
            return self._parse(data)
        except (struct.error, ValueError):
            return None

    def read(self, data: bytes) -> tuple[float | None, np.ndarray]:
        """``(stamp_s or None, values (len(spec.channels),))`` as ``source_values`` gives them."""
        parsed = self.parse(data)
        if parsed is not None:
            return parsed
        try:  # another encoding, or not the layout it should be: rclpy decides
            msg = self._deserialize(data, self.message_type)
        except Exception:  # noqa: BLE001 - bytes rclpy cannot read are a message without values
            return None, _EMPTY
        return source_values(msg, self.spec, self.n_inputs, self.n_outputs)

    # ------------------------------------------------------------------------------ layouts
    def _fixed(self, data: bytes) -> tuple[float, np.ndarray]:
        stamp, pos = _after_header(data)
        span = self._span.unpack_from(data, _aligned(pos, 8) + 8 * self._first)
        if self._checks and declares_no_data([span[i] for i in self._checks]):
            return stamp, NO_DATA
        return stamp, np.array([span[i] for i in self._picks])

    def _io_sample(self, data: bytes) -> tuple[float, np.ndarray]:
        stamp, pos = _after_header(data)
        u, pos = _float_sequence(data, pos)
        y, _ = _float_sequence(data, pos)
        if self.spec.whole_sample:
            if len(u) != self.n_inputs or len(y) != self.n_outputs:
                return stamp, _EMPTY
            return stamp, np.concatenate([u, y])
        try:
            return stamp, np.array([(u if name == "u" else y)[i] for name, i in self.spec.fields], dtype=float)
        except IndexError:
            return stamp, _EMPTY

    def _array(self, data: bytes) -> tuple[float | None, np.ndarray]:
        # std_msgs/MultiArrayLayout: MultiArrayDimension[] dim (string label, uint32 size,
        # uint32 stride), uint32 data_offset; then float64[] data.
        (n_dims,) = _LENGTH.unpack_from(data, _DATA)
        pos = _DATA + 4
        for _ in range(n_dims):
            (length,) = _LENGTH.unpack_from(data, pos)
            pos = _aligned(pos + 4 + length, 4) + 8
        values, _ = _float_sequence(data, pos + 4)
        try:
            picked = np.array([values[i] for _, i in self.spec.fields], dtype=float)
            stamp = float(values[self.spec.stamp_index]) if self.spec.stamp_index is not None else None
        except IndexError:
            return None, _EMPTY
        return stamp, picked

    def _double_places(self) -> np.ndarray:
        """Where the source's fields, then the covariance elements it checks, sit among the doubles (marker values)."""
        msg = self.message_type()
        paths = self.spec.fields + self.spec.no_data_checks
        markers = self._marked(msg, np.arange(len(paths)), paths)
        data = self._serialize(msg)
        start = _aligned(_after_header(data)[1], 8)
        places = []
        for marker in markers:
            at = data.find(struct.pack("<d", marker), start)
            if at < 0 or (at - start) % 8:
                raise ValueError(f"field of {self.spec.text!r} not found in its serialized message")
            places.append((at - start) // 8)
        return np.asarray(places)

    # ------------------------------------------------------------------------------ the check
    def _marked(self, msg: Any, seeds: np.ndarray, paths: tuple) -> list[float]:
        """Write marker values (distinct, no other field's) at ``paths`` of ``msg`` (a final int: an element)."""
        markers = [float(v) for v in 1e-300 * (1.25 + seeds / 7.0 + 0.123456789)]
        for path, value in zip(paths, markers):
            obj = msg
            for name in path[:-1]:
                obj = getattr(obj, name)
            if isinstance(path[-1], int):
                obj[path[-1]] = value
            else:
                setattr(obj, path[-1], value)
        return markers

    def test_messages(self) -> list[Any]:
        """Messages of the source's type with values in its fields, in every layout the check covers."""
        rng = np.random.default_rng(20261130)
        out = []
        for frame_id in _TEST_FRAME_IDS:
            msg = self.message_type()
            if self.spec.kind == "io_sample":
                u_len, y_len = self._sequence_lengths()
                msg.u, msg.y = rng.standard_normal(u_len).tolist(), rng.standard_normal(y_len).tolist()
            elif self.spec.kind == "array":
                msg = self._array_message(len(frame_id), rng)
            else:
                self._marked(msg, rng.integers(0, 1000, len(self.spec.fields)), self.spec.fields)
                self._declare_variances(msg, len(frame_id))
            if self.spec.has_header:
                msg.header.frame_id = frame_id
                msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_000 + len(frame_id), 123_456_789
            out.append(msg)
        return out

    def _declare_variances(self, msg: Any, k: int) -> None:
        """Covariances of the checked fields: in turn one that declares no data (REP 145), else a variance."""
        checks = self.spec.no_data_checks
        for j, (name, index) in enumerate(checks):
            getattr(msg, name)[index] = NO_DATA_COVARIANCE if k % 2 and j == k // 2 % len(checks) else 0.25 * k

    def _sequence_lengths(self) -> tuple[int, int]:
        if self.spec.whole_sample:
            return self.n_inputs, self.n_outputs
        need = {"u": 0, "y": 0}
        for name, i in self.spec.fields:
            need[name] = max(need[name], i + 1)
        return need["u"], need["y"]

    def _array_message(self, n_dims: int, rng: np.random.Generator) -> Any:
        from std_msgs.msg import MultiArrayDimension  # the nodes' layer

        msg = self.message_type()
        msg.layout.dim = [MultiArrayDimension(label="xyz"[: k % 4], size=k + 1, stride=2 * k + 1)
                          for k in range(n_dims % 4)]
        msg.layout.data_offset = n_dims
        size = max([i for _, i in self.spec.fields] + [self.spec.stamp_index or 0]) + 1 + n_dims
        msg.data = rng.standard_normal(size).tolist()
        return msg

    def agrees_with_rclpy(self) -> bool:
        """Whether every test message's bytes read as rclpy's object of them reads."""
        for msg in self.test_messages():
            data = self._serialize(msg)
            if data[:2] != PLAIN_CDR_LE:
                return False
            try:
                stamp, values = self._parse(data)
            except (struct.error, ValueError):
                return False
            want_stamp, want = source_values(self._deserialize(data, self.message_type), self.spec,
                                             self.n_inputs, self.n_outputs)
            if stamp != want_stamp or (values is NO_DATA) != (want is NO_DATA):
                return False
            if values is not NO_DATA and (not np.array_equal(values, want) or values.size == 0):
                return False
        return True


def message_class(name: str) -> type:
    """'sensor_msgs/msg/Imu' -> the rclpy message class."""
    package, kind, type_name = name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), type_name)


def raw_reader(spec: SourceSpec, n_inputs: int, n_outputs: int, message_type: Any = None) -> RawSourceReader | None:
    """A checked :class:`RawSourceReader` for the source, or None (take its messages as objects).

    ``message_type``: the rclpy class (default: the source's, imported; none without rclpy).
    """
    try:
        message_type = message_type or message_class(spec.msg_type)
        reader = RawSourceReader(spec, n_inputs, n_outputs, message_type)
        return reader if reader.agrees_with_rclpy() else None
    except Exception:  # noqa: BLE001 - any surprise in the layout: the messages are taken as objects
        return None
