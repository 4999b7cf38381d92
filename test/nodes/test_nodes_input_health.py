"""The inputs' health as a node reports it (nodes/input_frontend.py), without DDS.

An :class:`InputFrontend` on a stand-in node (its clock set by the test, its subscriptions never
served): the test hands it messages as the input thread would and reads its warnings and status.
"""

from __future__ import annotations

import re
from types import SimpleNamespace as NS

import pytest
from diagnostic_msgs.msg import DiagnosticStatus

from okid_ros.nodes.input_frontend import InputFrontend
from okid_ros.service.params import ARX_NODE, resolve_parameters

DT = 0.008
SOURCES = ["io_sample /okid/io_sample u[0]=u0 u[1]=u1", "imu /imu1 linear_acceleration.x=y0 linear_acceleration.z=y1"]


class StandInNode:
    """What InputFrontend asks of its node; the clock is ``now_ns``, set by the test."""

    def __init__(self) -> None:
        self.now_ns = 0
        self.warnings: list[str] = []

    def get_namespace(self) -> str:
        return "/"

    def get_clock(self):
        return NS(now=lambda: NS(nanoseconds=self.now_ns))

    def get_logger(self):
        return NS(warning=self.warnings.append, info=lambda text: None)

    def create_subscription(self, *args, **kwargs):
        return NS(handle=None, msg_type=args[0])

    def count_publishers(self, topic: str) -> int:
        return 1

    def get_publishers_info_by_topic(self, topic: str) -> list:
        return []


def feed(frontend: InputFrontend, node: StandInNode, seconds: float, imu_lag_s: float, k0: int) -> int:
    """Both sources at 125 Hz for ``seconds``, the Imu stamped ``imu_lag_s`` behind; the diagnostics at 4 Hz."""
    k = k0
    for _ in range(int(round(seconds / DT))):
        node.now_ns = int(round(k * DT * 1e9))
        frontend._accept(0, 1000.0 + k * DT, [0.1, 0.2], node.now_ns)
        frontend._accept(1, 1000.0 + k * DT - imu_lag_s, [0.3, 0.4], node.now_ns)
        k += 1
        if k % 31 == 0:
            for text, is_warning in frontend.update_health():
                if is_warning:
                    node.warnings.append(text)
    return k


@pytest.mark.parametrize("lag_s", [0.2, 1.5])
def test_messages_that_make_no_sample_are_told_not_receiving(lag_s):
    # An Imu stamped 200 ms (or 1.5 s) behind the IoSample (the grid's latency is 5 sample times, 40 ms):
    # every sample time went missing, node 2 published nothing, and the inputs said "2 input(s)
    # receiving", status OK, with no warning (measured live: 0 ModalStates in 4 s).
    node = StandInNode()
    values = resolve_parameters(ARX_NODE, {"inputs.sources": SOURCES})
    emitted = []
    frontend = InputFrontend(node, values, emitted.append)
    k = feed(frontend, node, 2.0, 0.0, 0)
    assert len(emitted) > 200 and not node.warnings
    assert frontend.status("n").level == DiagnosticStatus.OK
    before = len(emitted)
    k = feed(frontend, node, 3.0, lag_s, k)
    assert len(emitted) - before < 10  # the few slots before the lag began
    status = frontend.status("n")
    assert status.level == DiagnosticStatus.WARN
    assert status.message == "no sample assembled for more than 1 s though messages arrive"
    [warning] = node.warnings
    assert warning.startswith("inputs: messages arrive but no sample was assembled for more than 1 s: ")
    # Beyond inputs.time_jump_s (1 s) the grid follows the Imu's timeline and the IoSample is late.
    assert re.search(r"\d+ sample times missing; messages refused meanwhile: /(imu1|okid/io_sample) late \d+", warning)
    feed(frontend, node, 2.0, 0.0, k)
    assert frontend.status("n").level == DiagnosticStatus.OK and len(node.warnings) == 1
