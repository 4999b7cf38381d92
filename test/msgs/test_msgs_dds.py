"""Every okid_msgs type travels between two processes over DDS and arrives unchanged.

The test process publishes each message, with every field set to a non-default value, to an
echo node in another process (dds_echo.py), which publishes it back; the copy that returns
must equal the original field by field. Runs over rclpy and Fast DDS in this session's
private ROS domain (conftest.py).
"""

from __future__ import annotations

import array
import importlib
import itertools
import re
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import RosProcess, subprocess_env

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process

MESSAGE_TYPES = ("IoSample", "Mode", "ModalStates", "ArxModel", "StateSpaceModel", "StructuralChange")
QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
TIMEOUT_S = 30.0

# Fields other programs rely on (issue 2); renaming or retyping one breaks them.
REQUIRED_FIELDS: dict[str, dict[str, str]] = {
    "IoSample": {"header": "std_msgs/Header", "u": "sequence<double>", "y": "sequence<double>"},
    "Mode": {
        "id": "uint32", "frequency_hz": "double", "frequency_rad_s": "double",
        "damping_ratio": "double", "emac": "double", "mpc": "double", "msv": "double",
        "mac_previous": "double", "stable": "boolean",
        "shape_real": "sequence<double>", "shape_imag": "sequence<double>",
    },
    "ModalStates": {
        "header": "std_msgs/Header", "modes": "sequence<okid_msgs/Mode>",
        "modal_coordinates": "sequence<double>", "y_estimated": "sequence<double>",
        "innovation": "sequence<double>",
    },
    "ArxModel": {
        "header": "std_msgs/Header", "sample_time_s": "double", "order": "uint32",
        "n_inputs": "uint32", "n_outputs": "uint32", "window_length": "uint32",
        "window_fill": "uint32", "coefficients_rows": "uint32", "coefficients_cols": "uint32",
        "coefficients": "sequence<double>", "markov_parameters": "sequence<double>",
        "residual_covariance": "sequence<double>", "condition_number": "double",
    },
    "StateSpaceModel": {
        "header": "std_msgs/Header", "sample_time_s": "double", "n_states": "uint32",
        "n_inputs": "uint32", "n_outputs": "uint32", "a": "sequence<double>",
        "b": "sequence<double>", "c": "sequence<double>", "d": "sequence<double>",
        "k": "sequence<double>", "innovation_covariance": "sequence<double>",
        "hankel_singular_values": "sequence<double>", "modes": "sequence<okid_msgs/Mode>",
    },
    "StructuralChange": {
        "header": "std_msgs/Header", "change_id": "uint32", "change_stamp": "builtin_interfaces/Time",
        "detection_stamp": "builtin_interfaces/Time", "detection_delay_samples": "uint32",
        "statistic": "double", "threshold": "double", "variance_ratio": "double", "identified": "boolean",
        "modes_before": "sequence<okid_msgs/Mode>", "modes_after": "sequence<okid_msgs/Mode>",
        "retired_ids": "sequence<uint32>",
    },
}


def import_type(name: str) -> type:
    """'okid_msgs/Mode' or 'okid_msgs/msg/Mode' -> the message class."""
    package, *_, type_name = name.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), type_name)


# --- non-default values for every field, by introspection -----------------------------------

_INT_RANGES = {
    "int8": (-(2**7), 2**7 - 1), "uint8": (0, 2**8 - 1), "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1), "int32": (-(2**31), 2**31 - 1), "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1), "uint64": (0, 2**64 - 1),
}


class Filler:
    """Fills messages with distinct non-default values that exercise each type's range."""

    def __init__(self, sequence_length: int = 3) -> None:
        self.sequence_length = sequence_length
        self._counter = itertools.count(1)

    def fill(self, msg: Any) -> Any:
        """Set every field of `msg` (recursively) and return it."""
        for field, type_name in msg.get_fields_and_field_types().items():
            setattr(msg, field, self.value(type_name))
        return msg

    def value(self, type_name: str) -> Any:
        if m := re.fullmatch(r"sequence<(.+?)(?:, (\d+))?>", type_name):
            length = min(self.sequence_length, int(m[2])) if m[2] else self.sequence_length
            return [self.value(m[1]) for _ in range(length)]
        if m := re.fullmatch(r"(.+)\[(\d+)\]", type_name):
            return [self.value(m[1]) for _ in range(int(m[2]))]
        if "/" in type_name:
            return self.fill(import_type(type_name)())
        n = next(self._counter)
        if type_name in ("double", "float"):
            # 1e-10 .. 1e10 and both signs; float32 fields get values that float32 holds exactly.
            scale = 10.0 ** ((n % 21) - 10) if type_name == "double" else 2.0 ** (n % 21 - 10)
            return (-1) ** n * (n + 0.5) * scale
        if type_name in _INT_RANGES:
            low, high = _INT_RANGES[type_name]
            return high - n % 7 if n % 2 or low == 0 else low + n % 7  # near the range's ends
        if type_name == "boolean":
            return True
        if type_name in ("string", "wstring"):
            return f"okid µ-{n}"
        if type_name in ("octet", "byte"):
            return bytes([n % 255 + 1])
        if type_name == "char":
            return n % 127 + 1
        raise NotImplementedError(f"no test value for field type {type_name!r}")


def assert_msg_equal(expected: Any, actual: Any, path: str = "") -> None:
    """Compare two messages field by field, naming the first differing field."""
    assert type(actual) is type(expected), f"{path or 'message'}: type {type(actual)}"
    for field in expected.get_fields_and_field_types():
        where = f"{path}.{field}" if path else field
        want, got = getattr(expected, field), getattr(actual, field)
        if hasattr(want, "get_fields_and_field_types"):
            assert_msg_equal(want, got, where)
        elif isinstance(want, (list, tuple)) and want and hasattr(want[0], "get_fields_and_field_types"):
            assert len(got) == len(want), f"{where}: {len(got)} elements, sent {len(want)}"
            for i, (w, g) in enumerate(zip(want, got)):
                assert_msg_equal(w, g, f"{where}[{i}]")
        elif isinstance(want, (array.array, np.ndarray, list, tuple)):
            _assert_array_equal(np.asarray(want), np.asarray(got), where)
        else:
            assert got == want, f"{where}: {got!r} != {want!r}"


def _assert_array_equal(want: np.ndarray, got: np.ndarray, where: str) -> None:
    """Exact equality; the message names the first differing element, not whole arrays."""
    assert got.shape == want.shape, f"{where}: shape {got.shape}, sent {want.shape}"
    differ = np.flatnonzero(got.ravel() != want.ravel())
    assert differ.size == 0, (f"{where}[{differ[0]}]: {got.ravel()[differ[0]]!r} != "
                              f"{want.ravel()[differ[0]]!r} ({differ.size} elements differ)")


def assert_all_fields_set(msg: Any, path: str = "") -> None:
    """Every leaf field differs from a default-constructed message's, so the test covers it."""
    default = type(msg)()
    for field in msg.get_fields_and_field_types():
        where = f"{path}.{field}" if path else field
        value = getattr(msg, field)
        if hasattr(value, "get_fields_and_field_types"):
            assert_all_fields_set(value, where)
        elif isinstance(value, (array.array, np.ndarray, list, tuple)):
            assert len(value) > 0, f"{where} is empty"
            for i, element in enumerate(value):
                if hasattr(element, "get_fields_and_field_types"):
                    assert_all_fields_set(element, f"{where}[{i}]")
        else:
            assert value != getattr(default, field), f"{where} has its default value"


# --- the two processes ----------------------------------------------------------------------

def _arx_model(order: int, n_inputs: int, n_outputs: int) -> Any:
    """A fully set ArxModel with the array sizes of an ARX model of the given order."""
    msg = Filler().fill(import_type("okid_msgs/ArxModel")())
    rows = n_inputs + order * (n_outputs + n_inputs)
    rng = np.random.default_rng(order)
    msg.order, msg.n_inputs, msg.n_outputs = order, n_inputs, n_outputs
    msg.coefficients_rows, msg.coefficients_cols = rows, n_outputs
    msg.coefficients = rng.standard_normal(rows * n_outputs).tolist()
    msg.markov_parameters_count = order + 1
    msg.markov_parameters = rng.standard_normal((order + 1) * n_outputs * n_inputs).tolist()
    msg.residual_covariance = rng.standard_normal(n_outputs * n_outputs).tolist()
    return msg


# (topic tag, message type, factory): each case has topics of its own, so a late duplicate
# from one case can never reach another.
CASES: list[tuple[str, str, Any]] = [
    *[(name, name, lambda name=name: Filler().fill(import_type(f"okid_msgs/{name}")()))
      for name in MESSAGE_TYPES],
    # the paper's experiment: q = 100, p = m = 2 (Theta is 402 x 2)
    ("ArxModelPaper", "ArxModel", lambda: _arx_model(order=100, n_inputs=2, n_outputs=2)),
    # larger than a UDP datagram (~100 kB): Fast DDS must fragment it
    ("ArxModelLarge", "ArxModel", lambda: _arx_model(order=400, n_inputs=4, n_outputs=4)),
    # many modes per sample
    ("ModalStatesMany", "ModalStates",
     lambda: Filler(sequence_length=12).fill(import_type("okid_msgs/ModalStates")())),
]


@pytest.fixture(scope="module")
def echo(ros_domain_id: int) -> Iterator[RosProcess]:
    """The echo node in its own process, for every case."""
    args = [f"okid_msgs/msg/{type_name}:{tag}" for tag, type_name, _ in CASES]
    process = RosProcess([sys.executable, str(Path(__file__).with_name("dds_echo.py")), *args],
                         subprocess_env(ros_domain_id))
    process.wait_for_output(r"^ready", timeout_s=TIMEOUT_S)
    yield process
    code = process.stop()
    assert code == 0, f"echo node exited with {code}; output:\n{process.output()}"


@pytest.fixture(scope="module")
def client(ros_domain_id: int) -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """A node in the test process, with its own rclpy context."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("okid_test_client", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    yield node, executor
    executor.shutdown()
    node.destroy_node()
    context.try_shutdown()


def round_trip(node: Node, executor: SingleThreadedExecutor, tag: str, msg: Any) -> Any:
    """Publish `msg` to the echo node and return the copy that comes back."""
    received: list[Any] = []
    publisher = node.create_publisher(type(msg), f"/okid_test/{tag}/ping", QOS)
    subscription = node.create_subscription(
        type(msg), f"/okid_test/{tag}/pong", received.append, QOS)
    try:
        deadline = time.monotonic() + TIMEOUT_S
        # Discovery first: a message published before the endpoints match is lost.
        while publisher.get_subscription_count() < 1 or subscription.get_publisher_count() < 1:
            assert time.monotonic() < deadline, f"{tag}: echo endpoints not discovered"
            executor.spin_once(timeout_sec=0.05)
        # Matching is per side: the echo's writer may see our reader a little after we see it.
        # Resend every second until the copy arrives; duplicates are identical.
        next_send = 0.0
        while not received:
            now = time.monotonic()
            assert now < deadline, f"{tag}: no echo within {TIMEOUT_S} s"
            if now >= next_send:
                publisher.publish(msg)
                next_send = now + 1.0
            executor.spin_once(timeout_sec=0.05)
        return received[0]
    finally:
        node.destroy_subscription(subscription)
        node.destroy_publisher(publisher)


@pytest.mark.parametrize(("tag", "type_name", "make"), CASES, ids=[c[0] for c in CASES])
def test_round_trip_between_processes(echo: RosProcess, client: tuple[Node, Any],
                                      tag: str, type_name: str, make: Any) -> None:
    msg = make()
    assert type(msg).__name__ == type_name
    assert_all_fields_set(msg)
    node, executor = client
    copy = round_trip(node, executor, tag, msg)
    assert copy is not msg
    assert_msg_equal(msg, copy)
    assert copy == msg  # the generated __eq__ agrees


@pytest.mark.parametrize("type_name", MESSAGE_TYPES)
def test_required_fields(type_name: str) -> None:
    fields = import_type(f"okid_msgs/{type_name}").get_fields_and_field_types()
    for field, field_type in REQUIRED_FIELDS[type_name].items():
        assert fields.get(field) == field_type, f"{type_name}.{field}: {fields.get(field)}"


def test_filler_covers_every_field_type() -> None:
    """The generic filler sets every field of every type, so new fields are tested too."""
    for name in MESSAGE_TYPES:
        assert_all_fields_set(Filler().fill(import_type(f"okid_msgs/{name}")()))
