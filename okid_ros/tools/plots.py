"""PNG figures of an identification run, like the paper's Figs 2-5, plus the modes over time.

Input: a bag with the nodes' output topics, i.e. the output of ``okid-ros process`` or a live
recording of ``/okid/arx_model``, ``/okid/state_space_model`` and ``/okid/modal_states``. The
truth (from ``okid-ros simulate``) is drawn when the bag's metadata carries it under
``okid_ros.truth`` (``process`` copies it from its input), or when ``truth`` is given.

=============================  ==================================================================
file                           content
=============================  ==================================================================
fig2_system_markov.png         system Markov parameters Y_k (1,1), k = 0, 1, ... of the last valid
                               ArxModel (Y_0 = D, Y_k = C A^(k-1) B; paper Fig. 2)
fig3_stochastic_markov.png     stochastic Markov parameters C A^i K (1,1), i = 1 .. n_terms, of the
                               last StateSpaceModel (paper Fig. 3)
fig4_modal_states.png          first coordinate of each mode's normalized modal state over the
                               last ``window_s`` seconds (paper Fig. 4)
fig5_output_estimate.png       output 1 measured and its one-step prediction ``y - innovation``
                               (the model's prediction before it sees the sample), and as a
                               second, labelled curve the filtered estimate ``y_estimated``
                               (after the measurement update), over the last ``window_s`` seconds
                               (paper Fig. 5); the fit of both in the legend
modes_over_time.png            frequency and damping ratio of every mode id at each model update,
                               with error bars of +-2 standard deviations where known
=============================  ==================================================================

The measured output of Fig. 5 comes from the input bag (``input_bag``; for ``process`` output
the source recorded in its metadata is used by default), assembled into samples with the
estimator node's ``inputs.sources`` exactly as the node does and matched by stamp. Without an
input bag the one-step prediction is rebuilt from the message alone, ``y_estimated - C K
innovation`` (``x_post = x_prior + K e``, with C and K of the StateSpaceModel that produced the
sample), and the measurement as that plus the innovation.

Time axes are seconds from the start of the experiment (the first input sample: recorded by
``process``, or read from the input bag), counted along the bag's log time (the sample stamps
for ``process`` output, the receive time for live recordings, so a replay loop does not fold
the axis). Without either, they start at the bag's first message.
matplotlib runs with the Agg backend (no display needed).
"""

from __future__ import annotations

import math
from collections import defaultdict, deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from okid_ros.core.markov import markov_from_state_space, stochastic_markov_from_state_space
from okid_ros.errors import OutputError, shown_path, write_atomically
from okid_ros.tools.bagio import PROCESS_KEY, STABILIZATION_KEY, TRUTH_KEY, open_bag
from okid_ros.tools.errors import BagReadError, OutputExistsError, ToolParameterError
from okid_ros.tools.plot_messages import LeftOut, arx_markov, state_space_model
from okid_ros.tools.plot_metadata import check_plot_metadata

__all__ = [
    "FIGURES",
    "MAX_TERMS",
    "PlotData",
    "add_measured_outputs",
    "fit_percent",
    "make_figure_dir",
    "output_estimates",
    "read_plot_data",
    "write_figures",
]

FIGURES = (
    "fig2_system_markov.png",
    "fig3_stochastic_markov.png",
    "fig4_modal_states.png",
    "fig5_output_estimate.png",
    "modes_over_time.png",
)

#: Most stochastic Markov parameters drawn (``--terms``): Fig. 3 is about 800 pixels wide, and
#: these terms decay like the predictor, so more are neither visible nor informative.
MAX_TERMS = 10_000

ARX_TOPIC = "/okid/arx_model"
STATE_SPACE_TOPIC = "/okid/state_space_model"
MODAL_STATES_TOPIC = "/okid/modal_states"


@dataclass
class PlotData:
    """What the figures need, read from a bag."""

    start_ns: int = 0
    arx_markov: np.ndarray | None = None  # (count, p, m) of the last valid ArxModel
    arx_model_id: int | None = None
    state_space: dict | None = None  # last StateSpaceModel (conversions.state_space_from_msg: A, C, K, model_id, ...)
    # id -> [(t_s, f_hz, zeta, f_hz_std, zeta_std)], std NaN where unknown
    mode_history: dict = field(default_factory=lambda: defaultdict(list))
    modal_t: list = field(default_factory=list)  # log time [s] of the recent ModalStates
    modal_stamp_ns: list = field(default_factory=list)  # their header stamps [ns]
    modal_first: list = field(default_factory=list)  # {mode id: first coordinate}
    modal_model_id: list = field(default_factory=list)  # StateSpaceModel id of each recent sample
    output_gain: dict = field(default_factory=dict)  # model id -> C K (p, p): y_est = y_pred + C K e
    y_estimated: list = field(default_factory=list)  # (p,) per recent sample
    innovation: list = field(default_factory=list)
    measured: list | None = None  # (p,) measured outputs per recent sample (nan if not found)
    measured_source: str = ""
    measured_span_ns: tuple = ()  # earliest and latest stamp of the input bag's samples
    process_info: dict | None = None
    truth: dict | None = None
    counts: dict = field(default_factory=dict)
    experiment_start_ns: int | None = None  # stamp of the first input sample, if known
    stabilization: list | None = None  # of the last model, if `process` recorded it (STABILIZATION_KEY)
    first_stamp_log_ns: tuple | None = None  # (header stamp, log time) of the first ModalStates

    def time_shift_s(self) -> float:
        """Add to the log-time axes (seconds from ``start_ns``) to count from the experiment start."""
        if self.experiment_start_ns is None or self.first_stamp_log_ns is None:
            return 0.0
        stamp_ns, log_ns = self.first_stamp_log_ns
        origin_log_ns = log_ns - (stamp_ns - self.experiment_start_ns)
        return (self.start_ns - origin_log_ns) * 1e-9


def _take_model(data: PlotData, msg, t_s: float, *, arx: bool) -> None:
    """The ArxModel (``arx``) or StateSpaceModel ``msg`` as the last one drawn; ValueError when it cannot be drawn."""
    if arx:
        if msg.valid and msg.markov_parameters_count:
            data.arx_markov, data.arx_model_id = arx_markov(msg), int(msg.model_id)
        return
    data.state_space = state_space_model(msg)
    data.output_gain[int(msg.model_id)] = data.state_space["C"] @ data.state_space["K"]
    for mode in msg.modes:
        data.mode_history[int(mode.id)].append((
            t_s, float(mode.frequency_hz), float(mode.damping_ratio),
            float(getattr(mode, "frequency_hz_std", math.nan)),
            float(getattr(mode, "damping_ratio_std", math.nan)),
        ))


def read_plot_data(path: str | Path, window_s: float = 5.0, truth: dict | None = None,
                   namespace: str | None = None) -> PlotData:
    """Read the last models, the mode history and the last ``window_s`` of modal states.

    ``namespace``: the rig namespace of the output topics (None: ``/okid``; a bag recorded with
    ``okid-ros record --namespace /rig1`` has ``/rig1/arx_model``, ...).

    Raises
    ------
        BagReadError: the bag lacks all three output topics, or a topic has another type.
    """
    from okid_ros.service.topics import ARX_MODEL, MODAL_STATES, STATE_SPACE_MODEL, resolve_topic

    ARX_TOPIC, STATE_SPACE_TOPIC, MODAL_STATES_TOPIC = (  # noqa: N806 (the module constants' names)
        resolve_topic(name, namespace) for name in (ARX_MODEL, STATE_SPACE_MODEL, MODAL_STATES))
    data = PlotData(truth=truth)
    recent: deque = deque()
    left_out = LeftOut()
    with open_bag(path) as bag:
        present = {t: bag.topics[t] for t in (ARX_TOPIC, STATE_SPACE_TOPIC, MODAL_STATES_TOPIC) if t in bag.topics}
        if not present:
            raise BagReadError(f"{shown_path(path)}: none of {ARX_TOPIC}, {STATE_SPACE_TOPIC}, {MODAL_STATES_TOPIC}; "
                               f"is it the output of `okid-ros process`? It has: {', '.join(sorted(bag.topics))}")
        expected = {ARX_TOPIC: "okid_msgs/msg/ArxModel", STATE_SPACE_TOPIC: "okid_msgs/msg/StateSpaceModel",
                    MODAL_STATES_TOPIC: "okid_msgs/msg/ModalStates"}
        for topic in present:
            bag.require_topic(topic, [expected[topic]])
        if data.truth is None:
            data.truth = bag.custom_json(TRUTH_KEY)
        data.process_info = bag.custom_json(PROCESS_KEY)
        data.stabilization = bag.custom_json(STABILIZATION_KEY)
        check_plot_metadata(path, data)
        data.start_ns = bag.start_ns
        first_stamp_s = (data.process_info or {}).get("first_stamp_s")
        if isinstance(first_stamp_s, (int, float)):
            data.experiment_start_ns = int(round(first_stamp_s * 1e9))
        data.counts = {t: bag.message_count([t]) for t in present}
        for topic, log_ns, msg in bag.messages(list(present)):
            t_s = (log_ns - data.start_ns) * 1e-9
            if topic in (ARX_TOPIC, STATE_SPACE_TOPIC):
                try:
                    _take_model(data, msg, t_s, arx=topic == ARX_TOPIC)
                except ValueError as exc:
                    left_out.add(topic, msg, exc)
            else:
                first = {int(mode.id): float(msg.modal_coordinates[2 * i])
                         for i, mode in enumerate(msg.modes) if 2 * i < len(msg.modal_coordinates)}
                stamp_ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                if data.first_stamp_log_ns is None:
                    data.first_stamp_log_ns = (stamp_ns, int(log_ns))
                recent.append((t_s, stamp_ns, first, np.asarray(msg.y_estimated, float),
                               np.asarray(msg.innovation, float), int(msg.model_id)))
                while recent and recent[0][0] <= t_s - window_s:
                    recent.popleft()
    left_out.warn(shown_path(path), data.counts)
    for t_s, stamp_ns, first, y_est, innov, model_id in recent:
        data.modal_t.append(t_s)
        data.modal_model_id.append(model_id)
        data.modal_stamp_ns.append(stamp_ns)
        data.modal_first.append(first)
        data.y_estimated.append(y_est)
        data.innovation.append(innov)
    return data


def add_measured_outputs(
    data: PlotData, input_bag: str | Path, est_values: dict, namespace: str | None = None
) -> int:
    """Fill ``data.measured`` from the input bag; return how many samples matched.

    Samples assembled with the estimator node's
    sources (as the node does), matched to the ModalStates by stamp; return how many matched.

    Raises
    ------
        BagReadError: unreadable input bag, or a source topic missing / of another type.
    """
    import bisect

    from okid_ros.tools.process import NodeInputs

    if not data.modal_stamp_ns:
        return 0
    inputs = NodeInputs(est_values, namespace)
    # Sample stamps pass through float seconds (about 0.2 us resolution at today's epoch):
    # match them to the ModalStates stamps to the nearest within 2 us, not exactly.
    wanted = sorted(set(data.modal_stamp_ns))
    tolerance_ns = 2_000
    found: dict[int, np.ndarray] = {}
    first_ns, span_ns = None, [math.inf, -math.inf]  # the first sample's stamp; the earliest and the latest
    with open_bag(input_bag) as bag:
        for spec in inputs.specs:
            bag.require_topic(spec.topic, [spec.msg_type])
        for sample in _bag_samples(bag, inputs):
            stamp_ns = sample.stamp_s * 1e9
            first_ns = stamp_ns if first_ns is None else first_ns
            span_ns = [min(span_ns[0], stamp_ns), max(span_ns[1], stamp_ns)]
            i = bisect.bisect_left(wanted, stamp_ns - tolerance_ns)
            if i < len(wanted) and abs(wanted[i] - stamp_ns) <= tolerance_ns:
                found[wanted[i]] = sample.y
    p = len(data.y_estimated[0]) if data.y_estimated else 1
    missing = np.full(p, np.nan)
    data.measured = [found.get(stamp, missing) for stamp in data.modal_stamp_ns]
    data.measured_source = str(input_bag)
    if first_ns is not None:
        data.measured_span_ns = (int(round(span_ns[0])), int(round(span_ns[1])))
        if data.experiment_start_ns is None:
            data.experiment_start_ns = int(round(first_ns))
    return len(found)


def _bag_samples(bag, inputs):
    """Every sample the input sources make of the bag, those still pending at its end too."""
    for topic, log_ns, msg in bag.stored_messages([s.topic for s in inputs.specs]):
        yield from inputs.add(topic, msg, log_ns * 1e-9)
    yield from inputs.grid.flush()


def _truth_matrices(truth: dict | None) -> dict | None:
    if not truth or not all(k in truth for k in ("A", "B", "C", "D", "K")):
        return None
    return {k: np.asarray(truth[k], dtype=float) for k in ("A", "B", "C", "D", "K")}


def fit_percent(measured: np.ndarray, estimate: np.ndarray) -> float:
    """``100 (1 - ||y - yhat|| / ||y - mean(y)||)`` over the finite samples (NaN if none)."""
    y, y_hat = np.asarray(measured, float), np.asarray(estimate, float)
    ok = np.isfinite(y) & np.isfinite(y_hat)
    if ok.sum() < 2:
        return math.nan
    spread = np.linalg.norm(y[ok] - y[ok].mean())
    return 100.0 * (1.0 - np.linalg.norm(y[ok] - y_hat[ok]) / spread) if spread > 0 else math.nan


def output_estimates(data: PlotData, output: int = 0) -> dict[str, np.ndarray]:
    """Fig. 5's curves for one output.

    ``measured``, ``one_step`` (prediction before the sample's
    update) and ``filtered`` (``y_estimated``), each (N,), plus ``measured_label``.
    """
    y_est = np.array([y[output] if y.size > output else np.nan for y in data.y_estimated])
    innov = np.array([e[output] if e.size > output else np.nan for e in data.innovation])
    if data.measured is not None:
        measured = np.array([y[output] for y in data.measured])
        return {"measured": measured, "one_step": measured - innov, "filtered": y_est, "measured_label": "measured"}
    # x_post = x_prior + K e, so y_est = y_pred + C K e (C K of the model that made the sample).
    correction = []
    for model_id, e in zip(data.modal_model_id, data.innovation):
        gain = data.output_gain.get(model_id)
        correction.append(np.nan if gain is None or e.size <= output else float(gain[output] @ e))
    one_step = y_est - np.asarray(correction)
    return {"measured": one_step + innov, "one_step": one_step, "filtered": y_est,
            "measured_label": "measured (one-step prediction + innovation)"}


def _figure_system_markov(plt, data: PlotData, truth: dict | None, n_stochastic: int):
    """Paper Fig. 2: system Markov parameters (1,1) of the last valid ArxModel (none without input)."""
    if data.arx_markov is None or data.arx_markov.shape[2] == 0:
        return None
    fig, ax = plt.subplots(figsize=(7, 3.5))
    Y = data.arx_markov
    k = np.arange(Y.shape[0])
    ax.plot(k, Y[:, 0, 0], ".-", ms=3, lw=0.8, label=f"identified (ArxModel {data.arx_model_id})")
    if truth is not None:
        Yt = markov_from_state_space(truth["A"], truth["B"], truth["C"], truth["D"], Y.shape[0])
        ax.plot(k, Yt[:, 0, 0], "--", lw=0.8, color="k", label="truth")
    ax.set_xlabel("k [time steps]")
    ax.set_ylabel("Y_k (1,1) [output 1 unit / input 1 unit]")
    ax.set_title("System Markov parameters, element (1,1)")
    ax.legend()
    return fig


def _figure_stochastic_markov(plt, data: PlotData, truth: dict | None, n_stochastic: int):
    """Paper Fig. 3: ``C A^i K`` (1,1) of the last StateSpaceModel."""
    if data.state_space is None:
        return None
    ss = data.state_space
    fig, ax = plt.subplots(figsize=(7, 3.5))
    i = np.arange(1, n_stochastic + 1)
    # Only element (1,1) is drawn: C[:1] A^i K[:, :1], not all p x p of every term.
    M = stochastic_markov_from_state_space(ss["A"], ss["C"][:1], ss["K"][:, :1], n_stochastic)
    ax.plot(i, M[:, 0, 0], ".-", ms=3, lw=0.8, label=f"identified (model {ss['model_id']}, n = {ss['A'].shape[0]})")
    if truth is not None:
        Mt = stochastic_markov_from_state_space(truth["A"], truth["C"][:1], truth["K"][:, :1], n_stochastic)
        ax.plot(i, Mt[:, 0, 0], "--", lw=0.8, color="k", label="truth")
    ax.set_xlabel("i [time steps]")
    ax.set_ylabel("C A^i K (1,1) [-]")
    ax.set_title("Stochastic Markov parameters, element (1,1)")
    ax.legend()
    return fig


def _figure_modal_states(plt, data: PlotData, truth: dict | None, n_stochastic: int):
    """Paper Fig. 4: first coordinate of each mode's modal state over the recent window."""
    if not data.modal_t:
        return None
    t = np.asarray(data.modal_t) + data.time_shift_s()
    ids = sorted({i for first in data.modal_first for i in first})
    fig, axes = plt.subplots(len(ids) or 1, 1, figsize=(7, 1.8 * max(len(ids), 1) + 0.6), sharex=True,
                             squeeze=False)
    for ax, mode_id in zip(axes[:, 0], ids):
        values = np.array([first.get(mode_id, np.nan) for first in data.modal_first])
        freq = data.mode_history.get(mode_id)
        label = f"mode {mode_id}" + (f" ({freq[-1][1]:.3f} Hz)" if freq else "")
        ax.plot(t, values, lw=0.7)
        ax.set_ylabel(label + "\n[output unit]", fontsize=8)
    axes[-1, 0].set_xlabel("time from the start of the experiment [s]")
    axes[0, 0].set_title("Modal states: first coordinate of each mode")
    return fig


def _figure_output_estimate(plt, data: PlotData, truth: dict | None, n_stochastic: int):
    """Paper Fig. 5: output 1 measured against the one-step prediction (and the filtered estimate)."""
    if not data.modal_t:
        return None
    t = np.asarray(data.modal_t) + data.time_shift_s()
    curves = output_estimates(data, 0)
    fit_pred = fit_percent(curves["measured"], curves["one_step"])
    fit_filt = fit_percent(curves["measured"], curves["filtered"])
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(t, curves["measured"], lw=0.8, label=curves["measured_label"])
    ax.plot(t, curves["one_step"], "--", lw=0.8, label=f"one-step prediction (fit {fit_pred:.1f} %)")
    ax.plot(t, curves["filtered"], ":", lw=0.8, color="0.4",
            label=f"filtered estimate, after the update (fit {fit_filt:.1f} %)")
    ax.set_xlabel("time from the start of the experiment [s]")
    ax.set_ylabel("output 1 [output unit]")
    ax.set_title("Output 1: measured and one-step prediction")
    ax.legend(fontsize=7)
    return fig


def _figure_modes_over_time(plt, data: PlotData, truth: dict | None, n_stochastic: int):
    """Frequency and damping of every mode id at each model update, +-2 std error bars."""
    if not data.mode_history:
        return None
    shift = data.time_shift_s()
    fig, (ax_f, ax_z) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    for mode_id, rows in sorted(data.mode_history.items()):
        arr = np.asarray(rows, dtype=float)
        t = arr[:, 0] + shift
        f_err = 2.0 * np.nan_to_num(arr[:, 3]) if arr.shape[1] > 3 else None
        z_err = 200.0 * np.nan_to_num(arr[:, 4]) if arr.shape[1] > 4 else None
        line = ax_f.errorbar(t, arr[:, 1], yerr=f_err, fmt=".-", ms=3, lw=0.7, elinewidth=0.6, capsize=1.5,
                             label=f"id {mode_id}")
        ax_z.errorbar(t, 100 * arr[:, 2], yerr=z_err, fmt=".-", ms=3, lw=0.7, elinewidth=0.6, capsize=1.5,
                      color=line[0].get_color())
    if data.truth and data.truth.get("modes"):
        for mode in data.truth["modes"]:
            ax_f.axhline(mode["frequency_hz"], color="k", ls="--", lw=0.6)
            ax_z.axhline(100 * mode["damping_ratio"], color="k", ls="--", lw=0.6)
    ax_f.set_ylabel("frequency [Hz]")
    ax_z.set_ylabel("damping ratio [%]")
    ax_z.set_xlabel("time from the start of the experiment [s]")
    ax_f.set_title("Identified modes at each model update (bars: +-2 std; dashed: truth)")
    if len(data.mode_history) <= 12:
        ax_f.legend(fontsize=7, ncol=4)
    return fig


#: file name -> figure step; each returns a matplotlib figure, or None when the data lack it.
FIGURE_STEPS = {
    FIGURES[0]: _figure_system_markov,
    FIGURES[1]: _figure_stochastic_markov,
    FIGURES[2]: _figure_modal_states,
    FIGURES[3]: _figure_output_estimate,
    FIGURES[4]: _figure_modes_over_time,
}


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def refuse_existing(out_dir: Path, names, force: bool) -> None:
    """Raise OutputExistsError if one of ``names`` exists in ``out_dir`` and ``force`` is false.

    Raises
    ------
    OutputError
        ``out_dir`` cannot be looked into (a name too long, no permission).
    """
    try:
        existing = [name for name in names if (Path(out_dir) / name).exists()]
    except OSError as exc:
        raise OutputError(f"{shown_path(out_dir)}: cannot be the folder of the figures "
                          f"({exc.strerror or exc})") from None
    if existing and not force:
        raise OutputExistsError(f"{shown_path(out_dir)}: {', '.join(existing)} exist already, not overwriting "
                                "(use --force)")


def make_figure_dir(out_dir: str | Path) -> Path:
    """Create the folder of the figures (and its parents) if needed; returns it.

    Raises
    ------
    OutputError
        it cannot be created (a read-only place, a name too long; a file there, which the commands
        refuse first with ``output_paths.check_folder_option``, says ``File exists``).
    """
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{shown_path(out_dir)}: cannot create the folder of the figures "
                          f"({exc.strerror or exc})") from None
    return out_dir


def save_figure(plt, fig, path: Path, dpi: int = 110) -> Path:
    """Lay out (unless the figure has its own layout engine), write and close one figure.

    The PNG is written through a temporary file and a rename: a failure leaves no half-written file.
    """
    try:
        # matplotlib's log-axis tick arithmetic overflows (harmlessly) for magnitudes near 1e+-300.
        with np.errstate(over="ignore", under="ignore"):
            if fig.get_layout_engine() is None:
                fig.tight_layout()
            write_atomically(path, lambda stream: fig.savefig(stream, format="png", dpi=dpi))
    except OSError as exc:
        raise OutputError(f"{shown_path(path)}: cannot write the figure ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)
    return path


def write_figures(data: PlotData, out_dir: str | Path, force: bool = False, n_stochastic: int = 100,
                  dpi: int = 110) -> list[Path]:
    """Write the PNG files of :data:`FIGURES` that the data allow; return their paths.

    Raises
    ------
        OutputExistsError: a figure file exists and ``force`` is false.
        OutputError: ``out_dir`` is not a folder or cannot be created, a figure cannot be written.
        ToolParameterError: ``n_stochastic`` outside 1 .. MAX_TERMS.
    """
    if not 1 <= n_stochastic <= MAX_TERMS:
        raise ToolParameterError(f"--terms must be from 1 to {MAX_TERMS}, got {n_stochastic}")
    out_dir = Path(out_dir)
    refuse_existing(out_dir, FIGURES, force)
    make_figure_dir(out_dir)
    plt = pyplot()
    truth = _truth_matrices(data.truth)
    written: list[Path] = []
    for name, step in FIGURE_STEPS.items():
        fig = step(plt, data, truth, n_stochastic)
        if fig is not None:
            written.append(save_figure(plt, fig, out_dir / name, dpi))
    return written
