"""Messages <-> numpy: the one place where ROS message layouts meet the service layer.

Reading uses attribute access only, so it works on rclpy messages and on messages deserialized
by ``rosbags`` alike. Writing builds messages from a :class:`MessageTypes` namespace with every
field given as a keyword, which both rclpy classes and rosbags dataclasses accept:

    types = ros_message_types()                 # rclpy classes (okid_msgs, std_msgs, ...)
    types = MessageTypes.from_typestore(store)  # rosbags classes, for writing bags

Float arrays are passed as float64 numpy arrays. This module imports no ROS package at import
time.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass
from typing import Any

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.markov import markov_from_arx, markov_problem
from okid_ros.core.modal import Mode
from okid_ros.core.regressors import regressor_length
from okid_ros.service.arx_solve import ArxSnapshot
from okid_ros.service.grid_samples import NO_DATA
from okid_ros.service.inputs import SourceSpec, declares_no_data
from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams
from okid_ros.service.params import ARX_PARAMS
from okid_ros.service.records import MESSAGE_MODE_FIELDS, mode_record, mode_shape
from okid_ros.service.results import ModalStatesResult, ModelUpdate, StructuralChangeEvent

__all__ = [
    "MessageTypes", "ros_message_types", "stamp_to_seconds", "stamp_parts", "seconds_to_stamp", "source_values",
    "io_sample_msg", "arx_model_msg", "arx_fit_from_msg", "estimator_arx_fit", "mode_msg", "mode_from_msg",
    "modal_states_msg", "fill_modal_states", "modal_states_from_msg", "state_space_model_msg",
    "state_space_from_msg", "message_array", "structural_change_msg", "structural_change_from_msg",
]

_EMPTY = np.zeros(0)


@dataclass(frozen=True)
class MessageTypes:
    """Message classes to build outgoing messages with (rclpy's or rosbags')."""

    Time: Any
    Header: Any
    IoSample: Any
    Mode: Any
    ModalStates: Any
    ArxModel: Any
    StateSpaceModel: Any
    StructuralChange: Any = None

    @classmethod
    def from_typestore(cls, store: Any) -> "MessageTypes":
        """From a rosbags typestore that has the okid_msgs types registered."""
        t = store.types
        return cls(
            t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"], t["okid_msgs/msg/IoSample"],
            t["okid_msgs/msg/Mode"], t["okid_msgs/msg/ModalStates"], t["okid_msgs/msg/ArxModel"],
            t["okid_msgs/msg/StateSpaceModel"], t["okid_msgs/msg/StructuralChange"],
        )


def ros_message_types() -> MessageTypes:
    """The rclpy message classes (needs the ROS Python packages and okid_msgs)."""
    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header

    from okid_msgs.msg import ArxModel, IoSample, ModalStates, StateSpaceModel, StructuralChange
    from okid_msgs.msg import Mode as ModeMsg

    return MessageTypes(Time, Header, IoSample, ModeMsg, ModalStates, ArxModel, StateSpaceModel, StructuralChange)


# ---------------------------------------------------------------------------------- time
def stamp_to_seconds(stamp: Any) -> float:
    """``builtin_interfaces/Time`` (``sec``, ``nanosec``) -> seconds."""
    return stamp_seconds(stamp.sec, stamp.nanosec)


def stamp_seconds(sec: int, nanosec: int) -> float:
    """A stamp's ``sec`` and ``nanosec`` -> seconds (the one rule; also for stamps read from bytes)."""
    return sec + nanosec * 1e-9


def stamp_parts(t: float) -> tuple[int, int]:
    """Seconds -> ``(sec, nanosec)`` of a ``builtin_interfaces/Time`` (rounded; negative or NaN -> 0)."""
    if not math.isfinite(t) or t < 0:
        return 0, 0
    return divmod(int(round(t * 1e9)), 1_000_000_000)


def seconds_to_stamp(t: float, types: MessageTypes) -> Any:
    """Seconds -> ``builtin_interfaces/Time`` (:func:`stamp_parts`)."""
    sec, nanosec = stamp_parts(t)
    return types.Time(sec=sec, nanosec=nanosec)


def _header(t: float, frame_id: str, types: MessageTypes) -> Any:
    return types.Header(stamp=seconds_to_stamp(t, types), frame_id=frame_id)


def _f64(values: Any) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(values, dtype=np.float64).reshape(-1))


# ---------------------------------------------------------------------------------- inputs
def source_values(msg: Any, spec: SourceSpec, n_inputs: int, n_outputs: int) -> tuple[float | None, np.ndarray]:
    """The stamp [s] and channel values of one input message, in the order of ``spec.channels``.

    The stamp is None when the message has none (Float64MultiArray without a stamp element):
    the caller stamps it with the arrival time. Values of the wrong size come back as an
    empty array, which :class:`okid_ros.service.sample_grid.SampleGrid` counts as wrong_size, those of
    a message that declares no data (REP 145, :func:`~okid_ros.service.inputs.declares_no_data`) as
    :data:`~okid_ros.service.grid_samples.NO_DATA`, counted no_data.
    """
    kind = spec.kind
    if kind == "io_sample":
        u, y = msg.u, msg.y
        stamp = stamp_to_seconds(msg.header.stamp)
        if spec.whole_sample:
            if len(u) != n_inputs or len(y) != n_outputs:
                return stamp, _EMPTY
            return stamp, np.concatenate([np.asarray(u, dtype=float), np.asarray(y, dtype=float)])
        try:
            return stamp, np.array([(u if name == "u" else y)[i] for name, i in spec.fields], dtype=float)
        except IndexError:
            return stamp, _EMPTY
    if kind == "array":
        data = msg.data
        try:
            values = np.array([data[i] for _, i in spec.fields], dtype=float)
            stamp = float(data[spec.stamp_index]) if spec.stamp_index is not None else None
        except IndexError:
            return None, _EMPTY
        return stamp, values
    stamp = stamp_to_seconds(msg.header.stamp)
    if spec.no_data_checks and declares_no_data([getattr(msg, name)[i] for name, i in spec.no_data_checks]):
        return stamp, NO_DATA
    values = np.empty(len(spec.fields))
    for i, path in enumerate(spec.fields):
        obj = msg
        for name in path:
            obj = getattr(obj, name)
        values[i] = obj
    return stamp, values


def io_sample_msg(t: float, u: Any, y: Any, types: MessageTypes, frame_id: str = "") -> Any:
    """An ``okid_msgs/IoSample``."""
    return types.IoSample(header=_header(t, frame_id, types), u=_f64(u), y=_f64(y))


# ---------------------------------------------------------------------------------- ArxModel
def arx_model_msg(snapshot: ArxSnapshot, types: MessageTypes, frame_id: str = "", markov: bool = True) -> Any:
    """``okid_msgs/ArxModel`` of a snapshot (coefficients empty if there never was a good fit).

    ``condition_number`` is the 2-norm condition number of the column-scaled regressor matrix,
    the square root of that of the normal equations the service reports.
    """
    fit = snapshot.fit
    p, m = snapshot.n_outputs, snapshot.n_inputs
    if fit is not None:
        theta = _f64(fit.theta)
        rows, cols = fit.theta.shape
        res_cov = _published_covariance(np.asarray(fit.residual_covariance, dtype=float))
        markov_params = markov_from_arx(fit) if markov else np.zeros((0, p, m))
    else:
        theta, rows, cols, res_cov, markov_params = _EMPTY, 0, 0, _EMPTY, np.zeros((0, p, m))
    cond = snapshot.condition_number
    return types.ArxModel(
        header=_header(snapshot.stamp_s, frame_id, types),
        model_id=int(snapshot.model_id),
        valid=bool(snapshot.valid),
        sample_time_s=float(snapshot.sample_time_s),
        order=int(snapshot.order),
        n_inputs=int(m),
        n_outputs=int(p),
        window_length=int(snapshot.window_length),
        window_fill=int(snapshot.window_rows),  # the message's window_fill is a row count
        forgetting_factor=float(snapshot.forgetting_factor),
        regularization=float(snapshot.penalty) if math.isfinite(snapshot.penalty) else 0.0,  # the penalty
        coefficients_rows=int(rows),
        coefficients_cols=int(cols),
        coefficients=theta,
        markov_parameters_count=int(markov_params.shape[0]),
        markov_parameters=_f64(markov_params),
        residual_covariance=res_cov,
        condition_number=math.sqrt(cond) if cond >= 0 else math.nan,
        samples_used=int(snapshot.samples_used),
        samples_rejected=int(snapshot.samples_rejected),
    )


def arx_fit_from_msg(msg: Any, sample_time_s: float | None = None) -> tuple[ArxFit, float, int]:
    """``ArxModel`` -> (ArxFit, stamp of its newest sample [s], rows in its window).

    ``sample_time_s``: the receiver's; a model of another sample time is refused (its
    coefficients mean other dynamics on this grid).

    Raises
    ------
    ValueError when the order or the window is beyond what node 1 publishes, the coefficient array
    does not match its declared shape or holds NaN or Inf, its Markov parameters are beyond the bound of a
    sample (:func:`~okid_ros.core.markov.markov_problem`),
    the residual covariance is not a finite symmetric positive semidefinite p x p matrix, or the
    sample times differ.
    """
    m, p, q = int(msg.n_inputs), int(msg.n_outputs), int(msg.order)
    if sample_time_s is not None and not abs(float(msg.sample_time_s) - sample_time_s) <= 1e-9 * sample_time_s:
        # repr, not :g: times 1e-6 apart read as one (0.008 and 0.008) at six digits
        raise ValueError(f"ArxModel of sample time {float(msg.sample_time_s)!r} s; this node's sample_time_s is "
                         f"{float(sample_time_s)!r} s")
    # Limits of node 1's own parameters: a message beyond them (from anyone on the domain) would
    # size node 2's sample buffer (4e9 rows: a 33 GB allocation that ended the node).
    limits = {spec.name: spec.high for spec in ARX_PARAMS if spec.name in ("arx.order", "arx.window_length")}
    if not 1 <= q <= limits["arx.order"]:
        raise ValueError(f"ArxModel order {q} is outside arx.order's range [1, {limits['arx.order']}]")
    if int(msg.window_fill) > limits["arx.window_length"]:
        raise ValueError(f"ArxModel window of {int(msg.window_fill)} rows exceeds arx.window_length's limit "
                         f"{limits['arx.window_length']}")
    # Node 1's rules of its order at its start (the regressor's length, an order node 2 can realize): an
    # ArxModel of order 5000 kept node 2's worker busy for minutes, no other model realized meanwhile.
    if problem := ArxIdentificationParams(order=q, n_inputs=m, n_outputs=p, window_length=0).size_problem():
        raise ValueError(f"ArxModel beyond what node 1 publishes: {problem}")
    d = regressor_length(q, p, m)
    rows, cols = int(msg.coefficients_rows), int(msg.coefficients_cols)
    theta = np.asarray(msg.coefficients, dtype=float)
    if (rows, cols) != (d, p) or theta.size != d * p:
        raise ValueError(
            f"ArxModel coefficients are {rows} x {cols} ({theta.size} values); order {q} with "
            f"{m} inputs and {p} outputs needs {d} x {p}"
        )
    # Malformed like a wrong size: realized, NaN or Inf cost a realization on node 2's worker and
    # came back as 'realization failed: array must not contain infs or NaNs', counted as a
    # rejected model rather than a malformed message.
    if not np.isfinite(theta).all():
        raise ValueError(f"ArxModel coefficients are not finite ({int(np.count_nonzero(~np.isfinite(theta)))} "
                         f"of {theta.size} values NaN or Inf)")
    cov = _residual_covariance_from_msg(msg.residual_covariance, p)
    cond = float(msg.condition_number)
    fit = ArxFit(
        theta=theta.reshape(d, p), order=q, n_inputs=m, n_outputs=p, residual_covariance=cov,
        condition_number=cond * cond, regularization="ridge", penalty=float(msg.regularization),
        n_rows=int(msg.window_fill),
    )
    # Finite but absurd (coefficients of 1e150): realized, they failed as a rejected model, numpy's
    # overflow warnings printed from node 2's worker.
    if problem := markov_problem(fit):
        raise ValueError(f"ArxModel coefficients are absurd: {problem}")
    return fit, stamp_to_seconds(msg.header.stamp), int(msg.window_fill)


def estimator_arx_fit(msg: Any, params: ModalEstimationParams) -> tuple[ArxFit, float, int]:
    """An ``ArxModel`` as node 2 takes it: :func:`arx_fit_from_msg` at node 2's ``sample_time_s``.

    The one reading of node 2 (``modal_estimator_node``) and ``okid-ros process`` (``tools/offline.py``).

    Raises
    ------
    ValueError ``"ArxModel <id> ignored: <why>"``, the line node 2 logs.
    """
    try:
        return arx_fit_from_msg(msg, params.sample_time_s)
    except ValueError as exc:
        raise ValueError(f"ArxModel {msg.model_id} ignored: {exc}") from None


def _residual_covariance_from_msg(values: Any, p: int) -> np.ndarray:
    """The (p, p) residual covariance of an ArxModel; ValueError unless a covariance.

    Unused by the realization today, but a message carrying NaN, a non-symmetric or an
    indefinite matrix there is malformed like one with wrong coefficients (it used to be taken,
    and a wrong size silently became the identity). Round-off is allowed: asymmetry and negative
    eigenvalues up to 1e-9 of the largest magnitude (:func:`arx_model_msg` publishes none below 0).
    """
    cov = np.asarray(values, dtype=float)
    if cov.size != p * p:
        raise ValueError(f"ArxModel residual_covariance has {cov.size} values; {p} outputs need {p} x {p}")
    cov = cov.reshape(p, p)
    if cov.size == 0:
        return cov  # no outputs: refused by the receiver for its sizes
    if not np.isfinite(cov).all():
        raise ValueError("ArxModel residual_covariance is not finite")
    tol = 1e-9 * float(np.abs(cov).max())
    if float(np.abs(cov - cov.T).max()) > tol:
        raise ValueError("ArxModel residual_covariance is not symmetric")
    lowest = float(np.linalg.eigvalsh(cov)[0])
    if lowest < -tol:
        raise ValueError(f"ArxModel residual_covariance is not positive semidefinite (eigenvalue {lowest:.3g})")
    return cov


def _published_covariance(cov: np.ndarray) -> np.ndarray:
    """``cov`` with negative eigenvalues (round-off of a near-exact fit) raised to 0, flattened.

    So that node 1 never publishes what :func:`arx_fit_from_msg` refuses.
    """
    if cov.size == 0 or not np.isfinite(cov).all():
        return _f64(cov)
    w, v = np.linalg.eigh(cov)
    if w[0] < 0:
        cov = (v * np.maximum(w, 0.0)) @ v.T
        cov = 0.5 * (cov + cov.T)
    return _f64(cov)


# ---------------------------------------------------------------------------------- modes
def mode_msg(mode: Mode, types: MessageTypes) -> Any:
    """``okid_msgs/Mode`` of a core Mode (:func:`~okid_ros.service.records.mode_record`; NaN where unknown)."""
    record = mode_record(mode)
    shape_real, shape_imag = mode_shape(mode)
    fields = {name: math.nan if record[name] is None else record[name] for name in MESSAGE_MODE_FIELDS}
    return types.Mode(**fields, shape_real=_f64(shape_real), shape_imag=_f64(shape_imag))


def mode_from_msg(msg: Any, *, n_outputs: int | None = None) -> dict[str, Any]:
    """``Mode`` -> dict with the message's field names (shape as a complex array; no imaginary part: real).

    ``n_outputs``: the model's; then ValueError unless the frequency and damping are finite and the shape has
    ``n_outputs`` real values and as many imaginary ones or none.
    """
    frequency_hz, damping_ratio = float(msg.frequency_hz), float(msg.damping_ratio)
    real, imag = np.asarray(msg.shape_real, dtype=float), np.asarray(msg.shape_imag, dtype=float)
    if n_outputs is not None and not (math.isfinite(frequency_hz) and math.isfinite(damping_ratio)):
        raise ValueError(f"mode {int(msg.id)}: frequency_hz {frequency_hz!r}, damping_ratio {damping_ratio!r}")
    if n_outputs is not None and (real.size != n_outputs or imag.size not in (0, n_outputs)):
        raise ValueError(f"mode {int(msg.id)}: its shape has {real.size} real and {imag.size} imaginary values, "
                         f"the model {n_outputs} outputs")
    return {
        "id": int(msg.id),
        "frequency_hz": frequency_hz,
        "frequency_rad_s": float(msg.frequency_rad_s),
        "damping_ratio": damping_ratio,
        "emac": float(msg.emac),
        "mpc": float(msg.mpc),
        "msv": float(msg.msv),
        "mac_previous": float(msg.mac_previous),
        "stable": bool(msg.stable),
        "frequency_hz_std": float(getattr(msg, "frequency_hz_std", math.nan)),
        "damping_ratio_std": float(getattr(msg, "damping_ratio_std", math.nan)),
        "shape": real + 1j * (imag if imag.size else 0.0),
    }


def modal_states_msg(result: ModalStatesResult, types: MessageTypes, frame_id: str = "",
                     mode_msgs: list | None = None) -> Any:
    """``okid_msgs/ModalStates`` of one sample's estimate.

    ``mode_msgs``: the model's Mode messages, if the caller keeps them per model (they change
    only with the model; building them per sample costs more than the rest of the message).
    """
    if mode_msgs is None:
        mode_msgs = [mode_msg(m, types) for m in result.modes]
    return types.ModalStates(
        header=_header(result.stamp_s, frame_id, types),
        model_id=int(result.model_id),
        modes=mode_msgs,
        modal_coordinates=_f64(result.coordinates),
        y_estimated=_f64(result.y_estimated),
        innovation=_f64(result.innovation),
    )


def fill_modal_states(msg: Any, result: ModalStatesResult, mode_msgs: list) -> Any:
    """Refill an existing ``ModalStates`` message in place (the node's per-sample path).

    Cheaper than building one per sample: rclpy serializes on publish, so one message object
    can be reused. Float arrays go in as ``array.array('d')``, the form rclpy stores.
    """
    stamp = msg.header.stamp
    stamp.sec, stamp.nanosec = stamp_parts(result.stamp_s)
    msg.model_id = int(result.model_id)
    if msg.modes is not mode_msgs:
        msg.modes = mode_msgs
    msg.modal_coordinates = array("d", result.coordinates.ravel().tolist())
    msg.y_estimated = array("d", result.y_estimated.tolist())
    msg.innovation = array("d", result.innovation.tolist())
    return msg


def modal_states_from_msg(msg: Any) -> dict[str, Any]:
    """``ModalStates`` -> dict: stamp_s, model_id, modes (dicts), coordinates (n, 2), y_estimated, innovation."""
    coords = np.asarray(msg.modal_coordinates, dtype=float)
    return {
        "stamp_s": stamp_to_seconds(msg.header.stamp),
        "model_id": int(msg.model_id),
        "modes": [mode_from_msg(m) for m in msg.modes],
        "coordinates": coords.reshape(-1, 2),
        "y_estimated": np.asarray(msg.y_estimated, dtype=float),
        "innovation": np.asarray(msg.innovation, dtype=float),
    }


# ---------------------------------------------------------------------------------- StateSpaceModel
def state_space_model_msg(update: ModelUpdate, types: MessageTypes, frame_id: str = "") -> Any:
    """``okid_msgs/StateSpaceModel`` of an accepted model (states in normalized modal form)."""
    model = update.model
    n, m = model.B.shape
    p = model.C.shape[0]
    return types.StateSpaceModel(
        header=_header(update.stamp_s, frame_id, types),
        model_id=int(update.model_id),
        arx_model_id=int(update.arx_model_id),
        sample_time_s=float(model.sample_time_s),
        n_states=int(n),
        n_inputs=int(m),
        n_outputs=int(p),
        a=_f64(model.A),
        b=_f64(model.B),
        c=_f64(model.C),
        d=_f64(model.D),
        k=_f64(model.K),
        innovation_covariance=_f64(model.innovation_covariance),
        hankel_singular_values=_f64(model.hankel_singular_values),
        input_offset=_f64(np.zeros(m) if model.input_offset is None else model.input_offset),
        output_offset=_f64(np.zeros(p) if model.output_offset is None else model.output_offset),
        spectral_radius=float(model.spectral_radius()),
        predictor_spectral_radius=float(model.predictor_spectral_radius()),
        modes=[mode_msg(mo, types) for mo in update.modes],
    )


def message_array(msg: Any, name: str, shape: tuple[int, ...], *, empty_is_zero: bool = False) -> np.ndarray:
    """Field ``name`` as a float array of ``shape``; ValueError unless of its size (or empty_is_zero: 0) and finite."""
    values = np.asarray(getattr(msg, name), dtype=float)
    if empty_is_zero and values.size == 0:
        return np.zeros(shape)
    if values.size != math.prod(shape):
        raise ValueError(f"{name} has {values.size} values, its sizes give {' x '.join(map(str, shape))}")
    if not np.isfinite(values).all():
        raise ValueError(f"{name} holds values that are not finite")
    return values.reshape(shape)


def state_space_from_msg(msg: Any) -> dict[str, Any]:
    """``StateSpaceModel`` -> dict; ValueError with the reason when the message is not a model.

    Keys: stamp_s, model_id, arx_model_id, sample_time_s, A, B, C, D, K, innovation_covariance, hankel_singular_values,
    input_offset, output_offset (empty: zeros, a message from before the fields), modes (:func:`mode_from_msg`).
    Refused: an array not of the size its counts give or not finite, a sample time that is not a positive number of
    seconds, a mode :func:`mode_from_msg` refuses for the model's outputs.
    """
    n, m, p = int(msg.n_states), int(msg.n_inputs), int(msg.n_outputs)
    if not 0 < (sample_time_s := float(msg.sample_time_s)) < math.inf:
        raise ValueError(f"sample_time_s {sample_time_s!r} is not a positive number of seconds")
    shapes = {"a": (n, n), "b": (n, m), "c": (p, n), "d": (p, m), "k": (n, p), "innovation_covariance": (p, p),
              "hankel_singular_values": (len(msg.hankel_singular_values),)}
    arrays = {name.upper() if len(name) == 1 else name: message_array(msg, name, shape)
              for name, shape in shapes.items()}
    return {
        "stamp_s": stamp_to_seconds(msg.header.stamp), "model_id": int(msg.model_id),
        "arx_model_id": int(msg.arx_model_id), "sample_time_s": sample_time_s, **arrays,
        "input_offset": message_array(msg, "input_offset", (m,), empty_is_zero=True),
        "output_offset": message_array(msg, "output_offset", (p,), empty_is_zero=True),
        "modes": [mode_from_msg(mo, n_outputs=p) for mo in msg.modes],
    }


# ---------------------------------------------------------------------------------- StructuralChange
def structural_change_msg(event: StructuralChangeEvent, stamp_s: float, types: MessageTypes,
                          frame_id: str = "") -> Any:
    """``okid_msgs/StructuralChange`` of a change event, produced at the sample ``stamp_s``."""
    return types.StructuralChange(
        header=_header(stamp_s, frame_id, types),
        change_id=int(event.change_id),
        change_stamp=seconds_to_stamp(event.change_stamp_s, types),
        detection_stamp=seconds_to_stamp(event.stamp_s, types),
        detection_delay_samples=max(int(event.detection_delay_samples), 0),
        statistic=float(event.statistic),
        threshold=float(event.threshold),
        variance_ratio=float(event.variance_ratio),
        identified=bool(event.modes_after),
        modes_before=[mode_msg(m, types) for m in event.modes_before],
        modes_after=[mode_msg(m, types) for m in event.modes_after],
        retired_ids=np.asarray(event.retired_ids, dtype=np.uint32),
    )


def structural_change_from_msg(msg: Any) -> dict[str, Any]:
    """``StructuralChange`` -> dict with the message's field names (stamps in seconds)."""
    return {
        "stamp_s": stamp_to_seconds(msg.header.stamp),
        "change_id": int(msg.change_id),
        "change_stamp_s": stamp_to_seconds(msg.change_stamp),
        "detection_stamp_s": stamp_to_seconds(msg.detection_stamp),
        "detection_delay_samples": int(msg.detection_delay_samples),
        "statistic": float(msg.statistic),
        "threshold": float(msg.threshold),
        "variance_ratio": float(msg.variance_ratio),
        "identified": bool(msg.identified),
        "modes_before": [mode_from_msg(m) for m in msg.modes_before],
        "modes_after": [mode_from_msg(m) for m in msg.modes_after],
        "retired_ids": [int(i) for i in msg.retired_ids],
    }
