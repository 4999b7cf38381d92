"""A looped bag through both nodes over DDS.

With reset_on_time_jump (the default) both nodes
restart at each loop, the first model after a loop comes as soon as after the first start, and
nothing is logged once per second meanwhile.

The bag is 10 s of the simulated experiment (IoSample at 125 Hz), replayed at twice its speed
(5 s per pass) with `okid-ros replay --loop`; the nodes get a small ARX problem (order 20,
window 800 rows, a model once 200 rows are in) so that a model comes within each pass on a
loaded machine (in CI the first model of a pass came 1.9-2.9 s of bag time into it). Without
the reset, node 1's window still holds the previous pass after a loop and node 2 needs 410
contiguous samples of it: the first model after a loop comes about 2 s of bag time later than
after the start, beyond the 1 s a publish period of node 1 may add (and node 2 logs "... samples
of the ARX window ... follow its last gap" meanwhile).
"""

from __future__ import annotations

import re
import sys
import time

import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import REPO_ROOT, ProbeNode, RosProcess, subprocess_env

from okid_msgs.msg import ArxModel, IoSample, StateSpaceModel

pytestmark = pytest.mark.dds  # over DDS: `make test` runs it after the rest, in one process

SMALL = """
/**/okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: 2.0
    arx: {order: 20, window_length: 800, min_window_fill: 0.25}
/**/okid_modal_estimator:
  ros__parameters:
    realization: {n_states: 6, refine: false}
"""
BAG_S = 10.0
RATE = 2.0


def stamp_s(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class LoopProbe(ProbeNode):
    """Notes the wall time of each pass's first sample and of every StateSpaceModel."""

    def __init__(self) -> None:
        super().__init__("okid_loop_probe")
        self.pass_starts: list[tuple[float, float]] = []  # (wall time, stamp) of each pass's first sample
        self.models: list[tuple[float, float, int]] = []  # (wall time, stamp, model id)
        self.arx: list[tuple[float, int, int]] = []  # (stamp, samples used, model id)
        self._last_stamp = float("inf")
        self.node.create_subscription(IoSample, "/okid/io_sample", self._on_sample,
                                      QoSProfile(depth=500, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.node.create_subscription(StateSpaceModel, "/okid/state_space_model", self._on_model,
                                      QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
        self.node.create_subscription(ArxModel, "/okid/arx_model", self._on_arx,
                                      QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
        self.start()

    def _on_sample(self, msg: IoSample) -> None:
        stamp = stamp_s(msg)
        with self.lock:
            if stamp < self._last_stamp - 1.0:
                self.pass_starts.append((time.monotonic(), stamp))
            self._last_stamp = stamp

    def _on_model(self, msg: StateSpaceModel) -> None:
        with self.lock:
            self.models.append((time.monotonic(), stamp_s(msg), int(msg.model_id)))

    def _on_arx(self, msg: ArxModel) -> None:
        with self.lock:
            self.arx.append((stamp_s(msg), int(msg.samples_used), int(msg.model_id)))



def test_a_looped_bag_restarts_both_nodes_cleanly(ros_domain_id, tmp_path):
    env = subprocess_env(ros_domain_id)
    params = tmp_path / "small.yaml"
    params.write_text(SMALL)
    up = RosProcess([sys.executable, "-m", "okid_ros.cli", "up", "--params", str(REPO_ROOT / "config" / "okid.yaml"),
                     "--params", str(params)], env)
    probe = LoopProbe()
    replay = None
    try:
        # The bag is simulated while the nodes start (no sample reaches them before the replay).
        bag = tmp_path / "experiment"
        sim = RosProcess([sys.executable, "-m", "okid_ros.cli", "simulate", "--out", str(bag),
                          "--duration", f"{BAG_S:g}", "--seed", "3"], env)
        assert sim.proc.wait(timeout=120) == 0, sim.output()
        up.wait_for_output(r"\[okid_arx_identifier\]: ready", 60)
        up.wait_for_output(r"\[okid_modal_estimator\]: ready", 60)
        passes = 3
        replay = RosProcess([sys.executable, "-m", "okid_ros.cli", "replay", str(bag), "--topics", "/okid/io_sample",
                             "--loop", "--rate", f"{RATE:g}", "--subscribers", "3",
                             "--duration", f"{passes * BAG_S / RATE - 1.0:g}"], env)
        assert replay.proc.wait(timeout=120) == 0, replay.output()
        deadline = time.monotonic() + 1.0  # the last pass's first model, if still on its way (was: 1 s always)
        while time.monotonic() < deadline:
            with probe.lock:
                if len(probe.pass_starts) == passes and any(w >= probe.pass_starts[-1][0] for w, _, _ in probe.models):
                    break
            time.sleep(0.05)
        with probe.lock:
            starts, models, arx = list(probe.pass_starts), list(probe.models), list(probe.arx)
        assert len(starts) == passes, (starts, replay.output())
        delays = []  # bag time from the start of each pass to its first model
        # Every pass starts at the bag's first stamp; the probe (best effort) may miss a few.
        start_stamp = min(stamp for _, stamp in starts)
        for i, (start_wall, _) in enumerate(starts):
            # The probe may see the first pass's samples late (its best-effort subscription
            # matched after the replay began); it was up before the replay, so every model
            # before the second pass belongs to the first.
            start_wall = start_wall if i else float("-inf")
            end = starts[i + 1][0] if i + 1 < len(starts) else float("inf")
            first = [(stamp, model_id) for wall, stamp, model_id in models
                     if start_wall <= wall < end and start_stamp <= stamp < start_stamp + BAG_S]
            assert first, f"no model in pass {i + 1}; log:\n{up.output()}"
            delays.append(first[0][0] - start_stamp)
            # Node 2 restarted: model ids start again at 1 in every pass.
            assert first[0][1] == 1, (i, first[:3])
        # Node 1 restarted: its first ArxModel after each loop counts only the new pass's samples.
        for start_wall, _ in starts[1:]:
            after = [(stamp, used) for stamp, used, _ in arx if start_stamp <= stamp < start_stamp + BAG_S - 2.0]
            assert after, arx
            stamp, used = after[0]
            assert used <= (stamp - start_stamp) / 0.008 + 50, (stamp - start_stamp, used)
        # The first model after each loop comes as soon as after the first start (the window
        # restarted with the loop instead of holding the previous pass): within one publish
        # period of bag time (node 1's timer runs on wall time, so its phase at each pass start is
        # any; CI saw 1.87 s then 2.88 s) and 0.5 s for a realization on a loaded machine.
        period_bag_s = RATE / 2.0  # publish_rate_hz 2.0 of SMALL, in bag seconds
        for delay in delays[1:]:
            assert delay <= delays[0] + period_bag_s + 0.5, delays
        log = up.output()
        assert len(re.findall(r"okid_arx_identifier\]: time jump back to .* restarted", log)) == passes - 1, log
        assert len(re.findall(r"okid_modal_estimator\]: time jump back to .* restarted", log)) == passes - 1, log
        # Nothing once per second: at most one line about a refused model per pass. (The replay
        # waits for node 1, node 2 and the probe: with one subscription matched it once started
        # before node 2 had, which then refused a window for the samples it missed.)
        refused = re.findall(r"model not used", log)
        assert len(refused) <= passes, log
    finally:
        if replay is not None:
            replay.stop()
        probe.close()
        up.stop()
