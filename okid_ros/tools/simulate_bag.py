"""A simulated experiment like the paper's, recorded as a rosbag2 with the truth in its metadata.

The structure is the model published by Chen, Huang & Juang (1991) (:func:`okid_ros.sim.paper_model`:
three modes, 37.10 rad/s 0.28 %, 46.13 rad/s 2.87 %, 304.49 rad/s 0.40 %), driven by two
thrusters with random forces low-passed at 15 Hz (:func:`okid_ros.sim.lowpass_input`, unit
variance) and measured by two accelerometers at the tip, sampled at 125 Hz, with the
innovation noise of the model (``Re = I``; :func:`okid_ros.sim.simulate_innovation`).

Topics (all stamps on the 8 ms grid; the log time of each message equals its header stamp):

==========================  ==========================  =============================================
topic                       type                        content
==========================  ==========================  =============================================
``/thruster1/wrench``      geometry_msgs/WrenchStamped ``wrench.force.x``: thruster 1 force u[0] [N]
``/thruster2/wrench``      geometry_msgs/WrenchStamped ``wrench.force.x``: thruster 2 force u[1] [N]
``/accel/tip1/imu``         sensor_msgs/Imu             ``linear_acceleration.x``: output y[0] [m/s^2]
``/accel/tip2/imu``         sensor_msgs/Imu             ``linear_acceleration.x``: output y[1] [m/s^2]
``/okid/io_sample``         okid_msgs/IoSample          ``u`` = [u0, u1], ``y`` = [y0, y1], same stamp
==========================  ==========================  =============================================

The Imu messages follow REP 145 for what an accelerometer does not measure: orientation and
angular velocity covariances start with -1 ("not provided"); the acceleration covariance is
all zero ("unknown"). Force components other than ``force.x`` and torques are zero.

The truth goes into the bag metadata, ``metadata.yaml`` -> ``custom_data`` ->
``okid_ros.truth``, as one JSON document (read it with
``BagReader.custom_json(TRUTH_KEY)``): the modes (``frequency_rad_s``, ``frequency_hz``,
``damping_ratio``), the matrices A, B, C, D, K of the innovation form and the innovation
covariance, the input, the seed and the topic/channel map.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from okid_ros.core.window_samples import MAX_SAMPLE_MAGNITUDE
from okid_ros.jsonio import dumps
from okid_ros.service.sample_buffer import memory_shortfall
from okid_ros.service.sample_grid import MAX_STAMP_S
from okid_ros.tools.bagio import TRUTH_KEY, BagWriter
from okid_ros.tools.errors import ToolParameterError

__all__ = [
    "IMU_TOPICS",
    "IO_SAMPLE_TOPIC",
    "THRUSTER_TOPICS",
    "Experiment",
    "experiment_samples",
    "simulate_experiment",
    "write_experiment_bag",
    "write_staged_bag",
]

IO_SAMPLE_TOPIC = "/okid/io_sample"
THRUSTER_TOPICS = ("/thruster1/wrench", "/thruster2/wrench")
IMU_TOPICS = ("/accel/tip1/imu", "/accel/tip2/imu")
THRUSTER_FRAMES = ("thruster1", "thruster2")
IMU_FRAMES = ("accel_tip1", "accel_tip2")
RIG_FRAME = "truss_tip"
DEFAULT_CUTOFF_HZ = 15.0
#: The largest innovation variance: its standard deviation 1e140 leaves ten decades below the samples'
#: bound (MAX_SAMPLE_MAGNITUDE, 1e150, which node 1 and `process` refuse beyond) for the model's gain
#: and the noise's tails; --noise 1e300 wrote a bag whose every output was refused.
MAX_INNOVATION_VARIANCE = 1e280
#: The lowest input cut-off: the filter's start-up of 20 / cutoff seconds is simulated and thrown away
#: (5.5 h at 1e-3 Hz; 1e-12 Hz ran out of memory, 1e-300 Hz failed in numpy).
MIN_CUTOFF_HZ = 1e-3
#: Peak memory of a simulation per sample of the record [bytes] (about 330 measured: input, its
#: filter, states, outputs, messages), to refuse a --duration this machine cannot hold before the work.
SIMULATION_BYTES_PER_SAMPLE = 400


@dataclass
class Experiment:
    """A simulated record on the sample grid.

    Attributes
    ----------
        sample_time_s: sample period (0.008 s).
        start_ns: stamp of sample 0 [ns since the epoch].
        u: (N, 2) thruster forces [N].
        y: (N, 2) tip accelerations [m/s^2].
        truth: the JSON-ready truth document stored in the bag (see the module docstring).
    """

    sample_time_s: float
    start_ns: int
    u: np.ndarray
    y: np.ndarray
    truth: dict = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        return int(self.u.shape[0])

    @property
    def stamps_ns(self) -> np.ndarray:
        """(N,) int64 header stamps on the grid."""
        step_ns = int(round(self.sample_time_s * 1e9))
        return self.start_ns + step_ns * np.arange(self.n_samples, dtype=np.int64)


def simulate_experiment(
    duration_s: float = 60.0,
    seed: int = 1,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    innovation_variance: float = 1.0,
    start_ns: int | None = None,
) -> Experiment:
    """Simulate the paper-like experiment.

    Parameters
    ----------
    duration_s : record length [s] (> 0); N = round(duration_s / 0.008) samples.
    seed : seed of the input and noise generators (an integer >= 0).
    cutoff_hz : -3 dB cut-off of the thruster signals' low-pass [Hz], in (0, 62.5).
    innovation_variance : ``r`` in ``Re = r I``.
    start_ns : stamp of the first sample [ns]; default: now, on a whole second. Every stamp of the
        record must lie between 0 and ``MAX_STAMP_S`` seconds (a ROS 2 stamp's ``sec`` is an int32).

    Returns
    -------
        The experiment with its truth document.

    Raises
    ------
    ToolParameterError
        an argument out of range.
    """
    from okid_ros.sim import lowpass_input, paper_model, paper_modes, simulate_innovation
    from okid_ros.sim.paper_model import PAPER_PUBLISHED_MODES

    # Checked before the model is built: an infinite variance made it NaN (scipy's "infs or NaNs").
    if not 0 < innovation_variance < np.inf:
        raise ToolParameterError(f"innovation variance must be a positive finite number, got {innovation_variance}")
    if innovation_variance > MAX_INNOVATION_VARIANCE:
        raise ToolParameterError(
            f"--noise {innovation_variance:g} is more than {MAX_INNOVATION_VARIANCE:g}: its outputs would pass "
            f"{MAX_SAMPLE_MAGNITUDE:g}, beyond which the nodes and `process` refuse samples")
    model = paper_model(innovation_variance=innovation_variance)
    dt = model.sample_time_s
    n_samples = _check_options(duration_s, seed, cutoff_hz, dt)
    if start_ns is None:
        start_ns = int(time.time()) * 1_000_000_000
    _check_start(start_ns, n_samples, dt)
    u = lowpass_input(n_samples, model.n_inputs, cutoff_hz, dt, seed=seed)
    y, _ = simulate_innovation(model, u, seed=seed + 1_000_003)
    modes = [
        {
            "frequency_rad_s": float(m["frequency_rad_s"]),
            "frequency_hz": float(m["frequency_hz"]),
            "damping_ratio": float(m["damping_ratio"]),
            # the 48.5 Hz pair of the published A is not in the paper's table of modes
            "in_paper_table": any(abs(m["frequency_rad_s"] - f) < 0.1 for f, _ in PAPER_PUBLISHED_MODES),
        }
        for m in paper_modes()
    ]
    truth = {
        "system": "published model of Chen, Huang & Juang (1991), okid_ros.sim.paper_model",
        "form": "x[k+1] = A x[k] + B u[k] + A K e[k]; y[k] = C x[k] + D u[k] + e[k]",
        "sample_time_s": dt,
        "n_samples": n_samples,
        "duration_s": n_samples * dt,
        "start_ns": int(start_ns),
        "seed": int(seed),
        "modes": modes,
        "A": model.A.tolist(),
        "B": model.B.tolist(),
        "C": model.C.tolist(),
        "D": model.D.tolist(),
        "K": model.K.tolist(),
        "innovation_covariance": model.innovation_covariance.tolist(),
        "input": {"kind": "butterworth low-pass white noise", "order": 4, "cutoff_hz": float(cutoff_hz),
                  "variance": 1.0},
        "topics": {
            "io_sample": IO_SAMPLE_TOPIC,
            "inputs": [f"{t} wrench.force.x [N]" for t in THRUSTER_TOPICS],
            "outputs": [f"{t} linear_acceleration.x [m/s^2]" for t in IMU_TOPICS],
        },
    }
    return Experiment(sample_time_s=dt, start_ns=int(start_ns), u=u, y=y, truth=truth)


def _check_options(duration_s: float, seed: int, cutoff_hz: float, dt: float) -> int:
    """The number of samples of ``duration_s``; raises ToolParameterError for an option out of range."""
    if not MIN_CUTOFF_HZ <= cutoff_hz < 0.5 / dt:
        raise ToolParameterError(f"--cutoff {cutoff_hz:g} Hz: the input cut-off must be from {MIN_CUTOFF_HZ:g} to "
                                 f"below {0.5 / dt:g} Hz (below {MIN_CUTOFF_HZ:g} Hz the filter's start-up of "
                                 f"20 / cutoff s is too long to simulate)")
    return experiment_samples(duration_s, seed, dt)


def experiment_samples(duration_s: float, seed: int, dt: float) -> int:
    """The number of samples of a simulated experiment of ``duration_s`` at ``dt``, its options checked.

    One rule for the input-output and the ambient experiment (`simulate`, `demo`).

    Raises
    ------
    ToolParameterError
        a duration that is not positive, beyond a ROS 2 stamp, shorter than two samples or more
        than the memory holds; a seed that is not an integer >= 0.
    """
    if not np.isfinite(duration_s) or duration_s <= 0:
        raise ToolParameterError(f"--duration must be a positive number of seconds, got {duration_s}")
    if duration_s > MAX_STAMP_S:
        raise ToolParameterError(f"--duration {duration_s:g} s is more than the {MAX_STAMP_S} s a ROS 2 stamp can "
                                 f"hold (its sec is an int32)")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ToolParameterError(f"--seed must be an integer >= 0, got {seed!r}")  # numpy's default_rng needs it
    n_samples = int(round(duration_s / dt))
    if n_samples < 2:
        raise ToolParameterError(f"--duration {duration_s} s is shorter than two samples of {dt} s")
    shortfall = memory_shortfall(n_samples * SIMULATION_BYTES_PER_SAMPLE)
    if shortfall:
        raise ToolParameterError(f"--duration {duration_s:g} s: simulating its {n_samples} samples {shortfall} "
                                 f"(estimated at {SIMULATION_BYTES_PER_SAMPLE} bytes a sample)")
    return n_samples


def _check_start(start_ns: int, n_samples: int, dt: float) -> None:
    """Every stamp of the record must fit a ROS 2 stamp (``sec`` an int32) and a bag's unsigned log time."""
    last_s = (int(start_ns) + int(round(dt * 1e9)) * (n_samples - 1)) // 1_000_000_000
    if start_ns < 0 or last_s > MAX_STAMP_S:
        raise ToolParameterError(
            f"--start-time {start_ns * 1e-9:.10g} s: the record's stamps must lie between 0 and {MAX_STAMP_S} s "
            f"since the epoch (a ROS 2 stamp's sec is an int32; a bag's log time is unsigned); "
            f"this record of {n_samples * dt:g} s would end at {last_s} s")


def accelerometer_message(bag: BagWriter):
    """``make(stamp, frame_id, (ax, ay, az))`` -> the bag's ``sensor_msgs/Imu`` of an accelerometer.

    REP 145 for what it does not measure: orientation and angular velocity covariances start
    with -1 ("not provided"), the acceleration covariance is all zero ("unknown").
    """
    Header = bag.msg_class("std_msgs/msg/Header")
    Vector3 = bag.msg_class("geometry_msgs/msg/Vector3")
    Quaternion = bag.msg_class("geometry_msgs/msg/Quaternion")
    Imu = bag.msg_class("sensor_msgs/msg/Imu")
    not_provided = np.zeros(9)
    not_provided[0] = -1.0
    unknown = np.zeros(9)
    zero = Vector3(x=0.0, y=0.0, z=0.0)
    identity = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)

    def make(stamp, frame_id: str, acceleration) -> object:
        ax, ay, az = acceleration
        return Imu(header=Header(stamp=stamp, frame_id=frame_id), orientation=identity,
                   orientation_covariance=not_provided, angular_velocity=zero,
                   angular_velocity_covariance=not_provided, linear_acceleration=Vector3(x=ax, y=ay, z=az),
                   linear_acceleration_covariance=unknown)

    return make


def write_experiment_bag(path: str | Path, experiment: Experiment, storage: str = "mcap",
                         force: bool = False, progress=None) -> dict[str, int]:
    """Write ``experiment`` as a rosbag2 (see the module docstring for topics and fields).

    Parameters
    ----------
    path : bag directory to create (refused if it exists, unless ``force``).
    storage : "mcap" or "sqlite3".
    force : replace an existing bag.
    progress : optional callable ``progress(n_done)`` called every 1000 samples.

    Returns
    -------
        Messages written per topic.

    Raises
    ------
    OutputExistsError
        ``path`` exists and may not be replaced.
    BagWriteError
        the bag cannot be written; the partial bag this call wrote is removed, an old one it was to
        replace stays as it was.
    """
    return write_staged_bag(path, lambda bag: _write_messages(bag, experiment, progress), storage=storage,
                            force=force)


def write_staged_bag(path: str | Path, write: Callable[[BagWriter], dict[str, int]], *, storage: str,
                     force: bool) -> dict[str, int]:
    """A new bag at ``path`` whose messages ``write(bag)`` writes, returning what it returns.

    An old bag (``force``) is replaced by a complete new one only
    (:class:`~okid_ros.tools.output_paths.StagedOutput`): a failure half-way keeps it, and removes
    the partial bag.
    """
    from okid_ros.tools.output_paths import StagedOutput

    staged = StagedOutput(path, force=force)
    try:
        with BagWriter(staged.staged, storage=storage) as bag:
            counts = write(bag)
    except BaseException:
        staged.discard()
        raise
    staged.commit()
    return counts


def _write_messages(bag: BagWriter, experiment: Experiment, progress) -> dict[str, int]:
    """The topics and messages of :func:`write_experiment_bag`; returns the messages written per topic."""
    bag.set_custom_data(TRUTH_KEY, dumps(experiment.truth))
    for topic in THRUSTER_TOPICS:
        bag.add_topic(topic, "geometry_msgs/msg/WrenchStamped")
    for topic in IMU_TOPICS:
        bag.add_topic(topic, "sensor_msgs/msg/Imu")
    bag.add_topic(IO_SAMPLE_TOPIC, "okid_msgs/msg/IoSample")

    Time = bag.msg_class("builtin_interfaces/msg/Time")
    Header = bag.msg_class("std_msgs/msg/Header")
    Vector3 = bag.msg_class("geometry_msgs/msg/Vector3")
    Wrench = bag.msg_class("geometry_msgs/msg/Wrench")
    WrenchStamped = bag.msg_class("geometry_msgs/msg/WrenchStamped")
    IoSample = bag.msg_class("okid_msgs/msg/IoSample")
    imu = accelerometer_message(bag)

    zero = Vector3(x=0.0, y=0.0, z=0.0)
    u, y = experiment.u, experiment.y
    for k, stamp_ns in enumerate(experiment.stamps_ns.tolist()):
        stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
        for j, topic in enumerate(THRUSTER_TOPICS):
            force = Vector3(x=float(u[k, j]), y=0.0, z=0.0)
            bag.write(topic, stamp_ns, WrenchStamped(header=Header(stamp=stamp, frame_id=THRUSTER_FRAMES[j]),
                                                     wrench=Wrench(force=force, torque=zero)))
        for i, topic in enumerate(IMU_TOPICS):
            bag.write(topic, stamp_ns, imu(stamp, IMU_FRAMES[i], (float(y[k, i]), 0.0, 0.0)))
        bag.write(IO_SAMPLE_TOPIC, stamp_ns, IoSample(header=Header(stamp=stamp, frame_id=RIG_FRAME),
                                                      u=u[k].astype(float), y=y[k].astype(float)))
        if progress is not None and (k + 1) % 1000 == 0:
            progress(k + 1)
    return dict(bag.counts)
