"""A simulated ambient-vibration experiment (no measured input), recorded as Imu topics in a rosbag2.

The output-only counterpart of :mod:`okid_ros.tools.simulate_bag`: a structure with four modes
(:data:`AMBIENT_FREQUENCIES_HZ`, 1 % damping; :func:`okid_ros.sim.models.modal_structure`,
zero-order-hold discretized, so its discrete poles are known exactly) shaken by white forces
nobody measures and measured by two three-axis accelerometers at 200 Hz, as
``config/okid_output_only.yaml`` expects them:

==================  ==============  ===============================================
topic               type            content
==================  ==============  ===============================================
``/okid/imu_top``   sensor_msgs/Imu ``linear_acceleration.x|y|z``: outputs y0, y1, y2
``/okid/imu_base``  sensor_msgs/Imu ``linear_acceleration.x|y|z``: outputs y3, y4, y5
==================  ==============  ===============================================

The truth (the discrete poles' ``frequency_hz``, ``frequency_rad_s``, ``damping_ratio``) goes
into the bag metadata under ``okid_ros.truth``, as for the input-output experiment.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from okid_ros.jsonio import dumps
from okid_ros.tools.bagio import TRUTH_KEY, BagWriter
from okid_ros.tools.simulate_bag import Experiment, accelerometer_message, experiment_samples, write_staged_bag

__all__ = ["AMBIENT_FREQUENCIES_HZ", "AMBIENT_IMU_TOPICS", "simulate_ambient", "write_ambient_bag"]

AMBIENT_FREQUENCIES_HZ = (3.2, 7.5, 12.8, 21.0)
AMBIENT_DAMPING = 0.01
AMBIENT_SAMPLE_TIME_S = 0.005
AMBIENT_IMU_TOPICS = ("/okid/imu_top", "/okid/imu_base")
_IMU_FRAMES = ("imu_top", "imu_base")


def ambient_structure(sample_time_s: float = AMBIENT_SAMPLE_TIME_S, n_outputs: int = 6):
    """The simulated structure (:class:`okid_ros.sim.models.NoisyStateSpace`, one unused input)."""
    from okid_ros.sim.models import modal_structure

    return modal_structure(AMBIENT_FREQUENCIES_HZ, AMBIENT_DAMPING, 1, n_outputs, sample_time_s, seed=3,
                           output="acceleration", disturbance_std=1.0, measurement_noise_ratio=0.05)


def true_modes(system) -> list[dict]:
    """The discrete system's modes by frequency: ``frequency_hz``, ``frequency_rad_s``, ``damping_ratio``."""
    s = np.log(np.linalg.eigvals(system.A)) / system.sample_time_s
    s = s[s.imag > 0]
    modes = [{"frequency_rad_s": float(abs(v)), "frequency_hz": float(abs(v) / (2 * np.pi)),
              "damping_ratio": float(-v.real / abs(v))} for v in s]
    return sorted(modes, key=lambda m: m["frequency_hz"])


def simulate_ambient(duration_s: float = 90.0, seed: int = 1, start_ns: int | None = None) -> Experiment:
    """Simulate the ambient experiment: an :class:`~okid_ros.tools.simulate_bag.Experiment` with u (N, 0).

    Raises
    ------
    ToolParameterError for a duration or seed out of range (the input-output experiment's rule,
    :func:`~okid_ros.tools.simulate_bag.experiment_samples`).
    """
    from okid_ros.sim.simulators import simulate_noisy

    system = ambient_structure()
    dt = system.sample_time_s
    n_samples = experiment_samples(duration_s, seed, dt)
    if start_ns is None:
        start_ns = int(time.time()) * 1_000_000_000
    y = simulate_noisy(system, np.zeros((n_samples, 1)), seed=seed)
    truth = {
        "system": "modal structure of okid_ros.tools.simulate_ambient (white forces nobody measures)",
        "sample_time_s": dt, "n_samples": n_samples, "duration_s": n_samples * dt, "start_ns": int(start_ns),
        "seed": int(seed), "modes": true_modes(system), "n_inputs": 0,
        "topics": {"outputs": [f"{t} linear_acceleration.{a} [m/s^2]" for t in AMBIENT_IMU_TOPICS for a in "xyz"]},
    }
    return Experiment(sample_time_s=dt, start_ns=int(start_ns), u=np.zeros((n_samples, 0)), y=y, truth=truth)


def write_ambient_bag(path: str | Path, experiment: Experiment, storage: str = "mcap",
                      force: bool = False) -> dict[str, int]:
    """Write ``experiment`` (6 outputs) as two Imu topics (see the module docstring); messages per topic.

    An old bag (``force``) is replaced by a complete new one only, as `simulate` replaces one
    (:func:`~okid_ros.tools.simulate_bag.write_staged_bag`; it was removed before the writing).
    """
    return write_staged_bag(path, lambda bag: _write_imu_messages(bag, experiment), storage=storage, force=force)


def _write_imu_messages(bag: BagWriter, experiment: Experiment) -> dict[str, int]:
    """The truth, topics and messages of :func:`write_ambient_bag`; returns the messages written per topic."""
    bag.set_custom_data(TRUTH_KEY, dumps(experiment.truth))
    for topic in AMBIENT_IMU_TOPICS:
        bag.add_topic(topic, "sensor_msgs/msg/Imu")
    Time = bag.msg_class("builtin_interfaces/msg/Time")
    imu = accelerometer_message(bag)
    y = experiment.y
    for k, stamp_ns in enumerate(experiment.stamps_ns.tolist()):
        stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
        for i, topic in enumerate(AMBIENT_IMU_TOPICS):
            bag.write(topic, stamp_ns, imu(stamp, _IMU_FRAMES[i], tuple(float(v) for v in y[k, 3 * i: 3 * i + 3])))
    return dict(bag.counts)
