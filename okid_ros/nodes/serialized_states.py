"""``ModalStates`` as serialized bytes: the per-sample fields written into a template (node 2).

Publishing a message object makes rclpy convert it to C and serialize it for every sample, the
``Mode`` list too (at 28 outputs and 15 modes 9 kB of the message, about 90 us of CPU per sample
of the 125 us its publish cost). The modes change only with the model. So the message is
serialized once per model by rclpy itself (:func:`rclpy.serialization.serialize_message`), and a
sample writes its stamp, model id and three float arrays at their places in those bytes, which
``Publisher.publish`` sends as they are (rclpy publishes ``bytes`` raw).

The places are found in the template by values written there for the purpose, and the template
is accepted only if rclpy reads a test sample written into it back as that sample (CDR's
alignment and byte order stay rclpy's business). Without a template (one that failed that
check) a sample is published as the message object
(:func:`~okid_ros.nodes.conversions.fill_modal_states`); a sample whose arrays have other
lengths than the template's gets a template of its own.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np

from okid_ros.nodes.conversions import fill_modal_states, stamp_parts
from okid_ros.nodes.raw_inputs import PLAIN_CDR_LE
from okid_ros.service.results import ModalStatesResult

__all__ = ["ModalStatesBytes"]

# The fields a sample writes, as little-endian CDR holds them.
_FLOAT = np.dtype("<f8")
_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time: int32 sec, uint32 nanosec
_MODEL_ID = struct.Struct("<I")


class ModalStatesBytes:
    """Serialized ``ModalStates`` of each sample, from a template made once per model.

    Parameters
    ----------
    message_type : the rclpy ``okid_msgs/ModalStates`` class.
    """

    def __init__(self, message_type: Any) -> None:
        from rclpy.serialization import deserialize_message, serialize_message  # the nodes' layer

        self._serialize, self._deserialize = serialize_message, deserialize_message
        self._message_type = message_type
        self._fallback = message_type()
        self._modes: list | None = None
        self._key: tuple | None = None
        self._parts: list[bytes] | None = None  # the template cut at the fields a sample writes

    def message(self, result: ModalStatesResult, mode_msgs: list, frame_id: str) -> bytes | Any:
        """The sample's ``ModalStates``: serialized bytes, or the message object if no template fits."""
        sizes = (result.coordinates.size, result.y_estimated.size, result.innovation.size)
        # The list itself is held (not its id, which a new list may reuse): the node makes a new
        # one per model and never changes one it has made.
        if mode_msgs is not self._modes or (frame_id, sizes) != self._key:
            self._modes, self._key = mode_msgs, (frame_id, sizes)
            self._parts = self._template(mode_msgs, frame_id, sizes)
        if self._parts is None:
            self._fallback.header.frame_id = frame_id
            return fill_modal_states(self._fallback, result, mode_msgs)
        return self._write(result)

    def _write(self, result: ModalStatesResult) -> bytes:
        sec, nanosec = stamp_parts(result.stamp_s)
        p = self._parts
        return b"".join((
            p[0], _STAMP.pack(sec, nanosec), p[1], _MODEL_ID.pack(int(result.model_id)), p[2],
            np.asarray(result.coordinates, dtype=_FLOAT).tobytes(), p[3],
            np.asarray(result.y_estimated, dtype=_FLOAT).tobytes(), p[4],
            np.asarray(result.innovation, dtype=_FLOAT).tobytes(), p[5],
        ))

    def _template(self, mode_msgs: list, frame_id: str, sizes: tuple[int, int, int]) -> list[bytes] | None:
        """The serialized message cut where a sample's fields go; None if it cannot be done exactly."""
        rng = np.random.default_rng(20261129)
        # Marker values no Mode field holds: random mantissas, so each one's bytes occur once.
        arrays = [rng.uniform(1.0, 2.0, size) * 1e-300 for size in sizes]
        stamp, model_id = (0x1A3C96E1, 0x3C5A1E97), 0x6E1F5A3C
        msg = self._filled(mode_msgs, frame_id, stamp, model_id, arrays)
        data = self._serialize(msg)
        if len(data) < 4 or data[:2] != PLAIN_CDR_LE:  # the fields below are written as plain little-endian CDR
            return None
        fields = [(_STAMP.pack(*stamp), 8), (_MODEL_ID.pack(model_id), 4)]
        fields += [(a.astype(_FLOAT).tobytes(), 8 * a.size) for a in arrays]
        parts, start = [], 0
        for marker, length in fields:
            at = data.find(marker, start) if marker else start
            if at < 0 or (marker and data.find(marker, at + 1) >= 0):
                return None
            parts.append(data[start:at])
            start = at + length
        # The innovation is the message's last field: the CDR ends with its values. rclpy's buffer
        # may run on past that (rmw_fastrtps sizes it by an upper bound, see tools/bagio.py), and
        # those bytes would reach the wire and bags recorded from it, so they are cut off.
        if sizes[-1] == 0:
            return None
        parts.append(b"")
        self._parts = parts
        if not self._matches(mode_msgs, frame_id, sizes):
            return None
        return parts

    def _matches(self, mode_msgs: list, frame_id: str, sizes: tuple[int, int, int]) -> bool:
        """Whether rclpy reads a test sample written into the template back as that sample.

        Read back, not compared with rclpy's own bytes: CDR's padding bytes are not defined.
        """
        values = [np.linspace(-1.0, 1.0, size) * (k + 1) for k, size in enumerate(sizes)]
        sample = ModalStatesResult(stamp_s=1234.5678, model_id=7, modes=[], coordinates=values[0],
                                   y_estimated=values[1], innovation=values[2])
        try:
            back = self._deserialize(self._write(sample), self._message_type)
        except Exception:  # noqa: BLE001 - any failure to read it back refuses the template
            return False
        stamp = back.header.stamp
        return (
            (stamp.sec, stamp.nanosec) == stamp_parts(sample.stamp_s) and back.header.frame_id == frame_id
            and back.model_id == 7 and len(back.modes) == len(mode_msgs)
            and all(np.array_equal(np.asarray(got, dtype=float), want) for got, want in zip(
                (back.modal_coordinates, back.y_estimated, back.innovation), values))
        )

    def _filled(self, mode_msgs: list, frame_id: str, stamp: tuple[int, int], model_id: int,
                arrays: list[np.ndarray]) -> Any:
        msg = self._message_type()
        msg.header.frame_id = frame_id
        msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
        msg.model_id = model_id
        msg.modes = mode_msgs
        msg.modal_coordinates, msg.y_estimated, msg.innovation = (a.astype(float).tolist() for a in arrays)
        return msg
