"""The monitor.

The table's contents from ModalStates (trend, amplitude, indicators, a time jump), its drawing
on a terminal and on a pipe, and `okid-ros monitor` over DDS.
"""

from __future__ import annotations

import io
import math
import sys
import time
from types import SimpleNamespace

import pytest
import rclpy
from rclpy.qos import QoSProfile
from ros_helpers import REPO_ROOT, RosProcess, subprocess_env

from okid_msgs.msg import ModalStates, Mode
from okid_ros.tools.monitor import ANSI_HOME_CLEAR, ModalStatesView, TerminalMonitor

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process

ARROWS = ("UP", "DOWN", "FLAT")


def own_lines(output: str) -> list[str]:
    """The process's own lines, without Fast DDS's log lines.

    Fast DDS's lines are colored (they start with ESC); it prints them when, e.g., another
    process holds a shared-memory port lock.
    """
    return [line for line in output.splitlines() if line.strip() and not line.startswith("\x1b")]


def mode(mode_id: int, f_hz: float, zeta: float = 0.01, mac: float = math.nan):
    return SimpleNamespace(id=mode_id, frequency_hz=f_hz, frequency_rad_s=2 * math.pi * f_hz, damping_ratio=zeta,
                           emac=0.9, mpc=0.99, msv=0.5, mac_previous=mac, stable=True)


def states(t: float, modes, coords, model_id: int = 1, innovation=(0.1, -0.1)):
    sec = int(math.floor(t))
    return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=int(round((t - sec) * 1e9)))),
                           model_id=model_id, modes=modes, modal_coordinates=list(coords), y_estimated=[0.0, 0.0],
                           innovation=list(innovation))


def test_view_shows_trend_amplitude_and_model_updates():
    view = ModalStatesView(window_samples=4, trend_window_s=2.0, arrows=ARROWS)
    for k in range(40):  # 4 s at 10 Hz; mode 0 rises 1 % per second, mode 1 stays
        t = 100.0 + 0.1 * k
        view.update(states(t, [mode(0, 5.0 * (1 + 0.01 * (t - 100))), mode(1, 7.0)], [3.0, 4.0, 0.0, 2.0],
                           model_id=1 + k // 10))
    assert view.trend(0) == "UP" and view.trend(1) == "FLAT"
    assert view.amplitude(0) == pytest.approx(5.0) and view.amplitude(1) == pytest.approx(2.0)
    assert view.model_id == 4 and view.model_changes == 3 and view.messages == 40
    table = view.render("t")
    rows = [line.split() for line in table.splitlines()[2:]]
    assert [r[0] for r in rows] == ["0", "1"]
    assert rows[0][6] == "UP" and rows[0][-1] == "5.000e+00" and rows[1][-1] == "2.000e+00"
    assert rows[0][3] == "1.000"  # damping in percent
    assert rows[0][4:6] == ["-", "-"]  # standard deviations not known
    # a falling mode, a new one, and a lost one
    for k in range(30):
        t = 104.0 + 0.1 * k
        view.update(states(t, [mode(0, 5.0 * (1 - 0.01 * (t - 104))), mode(7, 9.0)], [1.0, 0.0, 0.0, 1.0]))
    assert view.trend(0) == "DOWN" and view.trend(7) == "FLAT"
    assert view.current_ids == [0, 7] and " 7 " in view.render()


def test_view_shows_the_standard_deviations_of_frequency_and_damping():
    view = ModalStatesView(arrows=ARROWS)
    known = SimpleNamespace(**vars(mode(0, 5.0)), frequency_hz_std=0.0123, damping_ratio_std=0.00045)
    view.update(states(1.0, [known], [1.0, 0.0]))
    header, row = view.render("t").splitlines()[1:3]
    assert "+-f [Hz]" in header and "+-zeta [%]" in header
    assert row.split()[4:6] == ["1.23e-02", "4.50e-02"]
def test_rate_is_never_nan_the_stream_shows_when_it_stopped_and_columns_keep_one_format():
    view = ModalStatesView(arrows=ARROWS)
    tty = io.StringIO()
    monitor = TerminalMonitor(view, tty, interval_s=0.5, ansi=False)
    view.update(states(1.0, [mode(0, 5.0), mode(1, 7.0)], [1.0, 0.0, 1e-4, 0.0]), received_s=10.0)
    first = view.render("t", now=10.0)
    assert "nan" not in first and "starting" in first
    for k in range(1, 100):
        view.update(states(1.0 + 0.01 * k, [mode(0, 5.0), mode(1, 7.0, zeta=0.5)], [1.0, 0.0, 1e-4, 0.0]),
                    received_s=10.0 + 0.01 * k)
    assert "100.0 /s" in view.render("t", now=11.0)
    assert monitor.maybe_draw(now=11.0)
    # The replay ended: six seconds without a message.
    assert "stopped (no message for 6.0 s)" in view.render("t", now=16.99)
    assert monitor.maybe_draw(now=17.0), "a pipe must get a table when the stream stops"
    assert "stopped" in [line for line in tty.getvalue().splitlines() if "samples" in line][-1]
    assert not monitor.maybe_draw(now=20.0)  # nothing new since
    # One number format per column, whatever the magnitudes (MSV and RMS amplitude in e-notation).
    rows = [line.split() for line in view.render("t", now=11.0).splitlines()[2:]]
    assert rows[0][-1] == "1.000e+00" and rows[1][-1] == "1.000e-04"
    assert rows[0][9] == rows[1][9] == "5.00e-01"


def test_a_time_jump_restarts_the_trends():
    view = ModalStatesView(trend_window_s=1.0, arrows=ARROWS)
    for k in range(30):
        view.update(states(50.0 + 0.1 * k, [mode(0, 5.0 + 0.1 * k)], [1.0, 1.0]))
    assert view.trend(0) == "UP"
    view.update(states(10.0, [mode(0, 8.0)], [1.0, 1.0]))  # a bag loop: stamps 40 s back
    assert view.trend(0) == "new"
    for k in range(1, 15):
        view.update(states(10.0 + 0.1 * k, [mode(0, 8.0)], [1.0, 1.0]))
    assert view.trend(0) == "FLAT"


def test_terminal_redraws_in_place_and_a_pipe_gets_periodic_tables():
    view = ModalStatesView(arrows=ARROWS)
    tty = io.StringIO()
    monitor = TerminalMonitor(view, tty, interval_s=0.25, ansi=True)
    assert monitor.maybe_draw(now=0.0)  # "waiting" screen
    view.update(states(1.0, [mode(0, 5.0)], [1.0, 0.0]))
    assert not monitor.maybe_draw(now=0.1) and monitor.maybe_draw(now=0.3)
    assert tty.getvalue().count(ANSI_HOME_CLEAR) == 2 and "waiting" in tty.getvalue()

    pipe = io.StringIO()
    monitor = TerminalMonitor(view, pipe, interval_s=2.0, ansi=False)
    assert monitor.maybe_draw(now=10.0)
    assert not monitor.maybe_draw(now=13.0)  # nothing new arrived: no repeated table
    view.update(states(1.1, [mode(0, 5.0)], [1.0, 0.0]))
    assert not monitor.maybe_draw(now=11.0) and monitor.maybe_draw(now=13.0)
    assert "\x1b" not in pipe.getvalue() and pipe.getvalue().count("okid-ros monitor") == 2


def test_monitor_once_prints_the_modes_arriving_over_dds(ros_domain_id):
    env = subprocess_env(ros_domain_id)
    proc = RosProcess([sys.executable, "-m", "okid_ros.cli", "monitor", "--once", "--duration", "60",
                       "--topic", "/test/modal_states"], env, REPO_ROOT)
    context = rclpy.Context()
    rclpy.init(context=context, args=[])
    try:
        node = rclpy.create_node("okid_test_states", context=context)
        pub = node.create_publisher(ModalStates, "/test/modal_states", QoSProfile(depth=10))
        msg = ModalStates()
        msg.model_id = 3
        msg.modes = [Mode(id=4, frequency_hz=5.9042, frequency_rad_s=37.0973, damping_ratio=0.0028, emac=0.9,
                          mpc=0.99, msv=1.0, mac_previous=float("nan"), stable=True)]
        msg.modal_coordinates = [3.0, 4.0]
        msg.innovation = [0.5, 0.5]
        deadline = time.monotonic() + 60
        while proc.proc.poll() is None:
            assert time.monotonic() < deadline, proc.output()
            pub.publish(msg)
            time.sleep(0.05)
    finally:
        context.try_shutdown()
        proc.stop()
    assert proc.proc.returncode == 0, proc.output()
    lines = own_lines(proc.output())
    row = next(line for line in lines if line.split()[:1] == ["4"])
    assert row.split()[1:4] == ["5.9042", "37.0973", "0.280"]
    assert row.split()[-1] == "5.000e+00" and "model 3" in lines[0] and not any("\x1b" in line for line in lines)


@pytest.mark.dds_startup
def test_monitor_once_without_messages_is_a_one_line_error(ros_domain_id):
    proc = RosProcess([sys.executable, "-m", "okid_ros.cli", "monitor", "--once", "--duration", "1",
                       "--topic", "/test/silent"], subprocess_env(ros_domain_id), REPO_ROOT)
    assert proc.proc.wait(timeout=60) == 2
    expected = ["okid-ros monitor: error: no okid_msgs/ModalStates on /test/silent within 1 s"]
    assert own_lines(proc.output()) == expected, \
        proc.output()
