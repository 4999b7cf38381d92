"""ModalStates written into a serialized template read back as the message object rclpy would send.

Real rclpy message classes and rclpy's own (de)serialization; no node.
"""

from __future__ import annotations

import math
from array import array

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from okid_msgs.msg import ModalStates, Mode
from okid_ros.nodes.conversions import fill_modal_states, modal_states_from_msg
from okid_ros.nodes.serialized_states import ModalStatesBytes
from okid_ros.service.results import ModalStatesResult
from okid_ros.tools.bagio import okid_typestore

STORE = okid_typestore()  # rosbags' strict CDR reader: a size mismatch is an error


def mode_msgs(n_modes: int, n_outputs: int, seed: int) -> list:
    rng = np.random.default_rng(seed)
    return [
        Mode(id=int(rng.integers(0, 2**32)), frequency_hz=float(rng.uniform(1, 500)), damping_ratio=0.01 * (i + 1),
             emac=0.9, mpc=float(rng.uniform()), msv=float(rng.uniform()), stable=bool(i % 2),
             mac_previous=math.nan if i == 0 else 0.99, frequency_hz_std=math.nan, damping_ratio_std=1e-3,
             shape_real=array("d", rng.standard_normal(n_outputs)),
             shape_imag=array("d", rng.standard_normal(n_outputs)))
        for i in range(n_modes)
    ]


def sample(n_modes: int, n_outputs: int, rng, stamp_s: float, model_id: int) -> ModalStatesResult:
    return ModalStatesResult(stamp_s=stamp_s, model_id=model_id, modes=[],
                             coordinates=rng.standard_normal((n_modes, 2)),
                             y_estimated=rng.standard_normal(n_outputs), innovation=rng.standard_normal(n_outputs))


def contents(msg) -> dict:
    """Every field of a ModalStates, NaN compared as equal (via the module the nodes' readers use)."""
    read = modal_states_from_msg(msg)
    read["frame_id"] = msg.header.frame_id
    read["stamp"] = (msg.header.stamp.sec, msg.header.stamp.nanosec)
    read["modes"] = [{k: np.asarray(v) for k, v in mode.items()} for mode in read["modes"]]
    return read


def assert_same(got, want) -> None:
    a, b = contents(got), contents(want)
    assert a.keys() == b.keys() and len(a["modes"]) == len(b["modes"])
    for key in a:
        if key == "modes":
            for ma, mb in zip(a["modes"], b["modes"]):
                assert all(np.array_equal(ma[k], mb[k], equal_nan=True) for k in ma), (ma, mb)
        else:
            assert np.array_equal(np.asarray(a[key]), np.asarray(b[key])), key


@pytest.mark.parametrize("overrun", [b"", b"\xab" * 6])
@pytest.mark.parametrize(("n_modes", "n_outputs"), [(1, 1), (3, 2), (15, 28)])
def test_the_bytes_read_back_as_the_message_object_of_each_sample(n_modes, n_outputs, overrun):
    writer, modes = ModalStatesBytes(ModalStates), mode_msgs(n_modes, n_outputs, seed=n_modes)
    # rmw_fastrtps may hand back a buffer longer than the CDR (tools/bagio.py): as if it did.
    writer._serialize = lambda msg: serialize_message(msg) + overrun
    rng = np.random.default_rng(0)
    stamps = [0.0, 12.000000001, 1.7e9 + 0.123456789, -3.0, math.nan]  # the last two are written as 0
    for k, stamp_s in enumerate(stamps):
        result = sample(n_modes, n_outputs, rng, stamp_s, model_id=[0, 1, 2**32 - 1, 5, 6][k])
        data = writer.message(result, modes, "okid_frame")
        assert isinstance(data, bytes)
        reference = ModalStates()
        reference.header.frame_id = "okid_frame"
        expected = deserialize_message(serialize_message(fill_modal_states(reference, result, modes)), ModalStates)
        assert_same(deserialize_message(data, ModalStates), expected)
        # Exactly the CDR, nothing after it: bags recorded from the wire are read strictly.
        strict = STORE.deserialize_cdr(data, "okid_msgs/msg/ModalStates")
        assert np.array_equal(strict.innovation, result.innovation)


def test_a_new_mode_list_a_new_frame_id_or_new_lengths_make_a_new_template():
    writer, rng = ModalStatesBytes(ModalStates), np.random.default_rng(1)
    writer.message(sample(2, 3, rng, 1.0, 1), mode_msgs(2, 3, seed=1), "a")
    # A list of the same length with other modes (as the node makes one per model, the last one
    # dropped, so the new one may take its place in memory): its modes go out.
    second = mode_msgs(2, 3, seed=2)
    for modes, frame_id, n_outputs in ((second, "a", 3), (second, "b", 3), (second, "b", 4)):
        result = sample(2, n_outputs, rng, 2.0, 2)
        got = deserialize_message(writer.message(result, modes, frame_id), ModalStates)
        assert got.header.frame_id == frame_id and got.modes[0].id == modes[0].id
        assert np.array_equal(np.asarray(got.innovation), result.innovation)


def test_without_a_template_the_message_object_is_published(monkeypatch):
    monkeypatch.setattr(ModalStatesBytes, "_matches", lambda self, *args: False)
    writer, rng, modes = ModalStatesBytes(ModalStates), np.random.default_rng(2), mode_msgs(2, 3, seed=3)
    result = sample(2, 3, rng, 5.5, 9)
    got = writer.message(result, modes, "f")
    assert isinstance(got, ModalStates) and got.header.frame_id == "f" and got.model_id == 9
    assert np.array_equal(np.asarray(got.modal_coordinates), result.coordinates.ravel())
