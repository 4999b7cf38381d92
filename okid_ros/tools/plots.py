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
fig5_output_estimate.png       output 1 measured and estimated (``y_estimated``) over the last
                               ``window_s`` seconds (paper Fig. 5)
modes_over_time.png            frequency and damping ratio of every mode id at each model update
=============================  ==================================================================

The measured output of Fig. 5 comes from the input bag (``input_bag``; for ``process`` output
the source recorded in its metadata is used by default), assembled into samples with the
estimator node's ``inputs.sources`` exactly as the node does and matched by stamp. Without an
input bag it falls back to ``y_estimated + innovation``, which is the measurement only if
``y_estimated`` is the one-step prediction (see ``msg_defs/msg/ModalStates.msg``).

Time axes are the bag's log time from its first message (the sample stamps for ``process``
output, the receive time for live recordings), so a replay loop does not fold the axis.
matplotlib runs with the Agg backend (no display needed).
"""

from __future__ import annotations

from collections import defaultdict, deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from okid_ros.core.markov import markov_from_state_space, stochastic_markov_from_state_space
from okid_ros.tools.bagio import PROCESS_KEY, TRUTH_KEY, open_bag
from okid_ros.tools.errors import BagReadError, OutputExistsError, ToolParameterError

__all__ = [
    "FIGURES",
    "PlotData",
    "add_measured_outputs",
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

ARX_TOPIC = "/okid/arx_model"
STATE_SPACE_TOPIC = "/okid/state_space_model"
MODAL_STATES_TOPIC = "/okid/modal_states"


@dataclass
class PlotData:
    """What the figures need, read from a bag."""

    start_ns: int = 0
    arx_markov: np.ndarray | None = None  # (count, p, m) of the last valid ArxModel
    arx_model_id: int | None = None
    state_space: dict | None = None  # last StateSpaceModel: A, C, K, n, model_id, sample_time_s
    mode_history: dict = field(default_factory=lambda: defaultdict(list))  # id -> [(t_s, f_hz, zeta)]
    modal_t: list = field(default_factory=list)  # log time [s] of the recent ModalStates
    modal_stamp_ns: list = field(default_factory=list)  # their header stamps [ns]
    modal_first: list = field(default_factory=list)  # {mode id: first coordinate}
    y_estimated: list = field(default_factory=list)  # (p,) per recent sample
    innovation: list = field(default_factory=list)
    measured: list | None = None  # (p,) measured outputs per recent sample (nan if not found)
    measured_source: str = ""
    process_info: dict | None = None
    truth: dict | None = None
    counts: dict = field(default_factory=dict)


def _matrix(values, rows: int, cols: int) -> np.ndarray:
    return np.asarray(values, dtype=float).reshape(rows, cols)


def read_plot_data(path: str | Path, window_s: float = 5.0, truth: dict | None = None) -> PlotData:
    """Read the last models, the mode history and the last ``window_s`` of modal states.

    Raises:
        BagReadError: the bag lacks all three output topics, or a topic has another type.
    """
    data = PlotData(truth=truth)
    recent: deque = deque()
    with open_bag(path) as bag:
        present = {t: bag.topics[t] for t in (ARX_TOPIC, STATE_SPACE_TOPIC, MODAL_STATES_TOPIC) if t in bag.topics}
        if not present:
            raise BagReadError(f"{path}: none of {ARX_TOPIC}, {STATE_SPACE_TOPIC}, {MODAL_STATES_TOPIC}; "
                               f"is it the output of `okid-ros process`? It has: {', '.join(sorted(bag.topics))}")
        expected = {ARX_TOPIC: "okid_msgs/msg/ArxModel", STATE_SPACE_TOPIC: "okid_msgs/msg/StateSpaceModel",
                    MODAL_STATES_TOPIC: "okid_msgs/msg/ModalStates"}
        for topic in present:
            bag.require_topic(topic, [expected[topic]])
        if data.truth is None:
            data.truth = bag.custom_json(TRUTH_KEY)
        data.process_info = bag.custom_json(PROCESS_KEY)
        data.start_ns = bag.start_ns
        data.counts = {t: bag.message_count([t]) for t in present}
        for topic, log_ns, msg in bag.messages(list(present)):
            t_s = (log_ns - data.start_ns) * 1e-9
            if topic == ARX_TOPIC:
                if msg.valid and msg.markov_parameters_count:
                    data.arx_markov = _matrix(msg.markov_parameters, msg.markov_parameters_count,
                                              msg.n_outputs * msg.n_inputs).reshape(
                        msg.markov_parameters_count, msg.n_outputs, msg.n_inputs)
                    data.arx_model_id = int(msg.model_id)
            elif topic == STATE_SPACE_TOPIC:
                n, p = int(msg.n_states), int(msg.n_outputs)
                data.state_space = {
                    "A": _matrix(msg.a, n, n), "C": _matrix(msg.c, p, n), "K": _matrix(msg.k, n, p),
                    "n": n, "model_id": int(msg.model_id), "sample_time_s": float(msg.sample_time_s),
                }
                for mode in msg.modes:
                    data.mode_history[int(mode.id)].append((t_s, float(mode.frequency_hz), float(mode.damping_ratio)))
            else:
                first = {int(mode.id): float(msg.modal_coordinates[2 * i])
                         for i, mode in enumerate(msg.modes) if 2 * i < len(msg.modal_coordinates)}
                stamp_ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                recent.append((t_s, stamp_ns, first, np.asarray(msg.y_estimated, float),
                               np.asarray(msg.innovation, float)))
                while recent and recent[0][0] <= t_s - window_s:
                    recent.popleft()
    for t_s, stamp_ns, first, y_est, innov in recent:
        data.modal_t.append(t_s)
        data.modal_stamp_ns.append(stamp_ns)
        data.modal_first.append(first)
        data.y_estimated.append(y_est)
        data.innovation.append(innov)
    return data


def add_measured_outputs(data: PlotData, input_bag: str | Path, est_values: dict) -> int:
    """Fill ``data.measured`` from the input bag: samples assembled with the estimator node's
    sources (as the node does), matched to the ModalStates by stamp; return how many matched.

    Raises:
        BagReadError: unreadable input bag, or a source topic missing / of another type.
    """
    import bisect

    from okid_ros.tools.process import NodeInputs

    if not data.modal_stamp_ns:
        return 0
    inputs = NodeInputs(est_values)
    # Sample stamps pass through float seconds (about 0.2 us resolution at today's epoch):
    # match them to the ModalStates stamps to the nearest within 2 us, not exactly.
    wanted = sorted(set(data.modal_stamp_ns))
    tolerance_ns = 2_000
    found: dict[int, np.ndarray] = {}
    with open_bag(input_bag) as bag:
        for spec in inputs.specs:
            bag.require_topic(spec.topic, [spec.msg_type])
        for topic, log_ns, msg in bag.messages([s.topic for s in inputs.specs]):
            for sample in inputs.add(topic, msg, log_ns * 1e-9):
                stamp_ns = sample.stamp_s * 1e9
                i = bisect.bisect_left(wanted, stamp_ns - tolerance_ns)
                if i < len(wanted) and abs(wanted[i] - stamp_ns) <= tolerance_ns:
                    found[wanted[i]] = sample.y
        for sample in inputs.grid.flush():
            stamp_ns = sample.stamp_s * 1e9
            i = bisect.bisect_left(wanted, stamp_ns - tolerance_ns)
            if i < len(wanted) and abs(wanted[i] - stamp_ns) <= tolerance_ns:
                found[wanted[i]] = sample.y
    p = len(data.y_estimated[0]) if data.y_estimated else 1
    missing = np.full(p, np.nan)
    data.measured = [found.get(stamp, missing) for stamp in data.modal_stamp_ns]
    data.measured_source = str(input_bag)
    return len(found)


def _truth_matrices(truth: dict | None) -> dict | None:
    if not truth or not all(k in truth for k in ("A", "B", "C", "D", "K")):
        return None
    return {k: np.asarray(truth[k], dtype=float) for k in ("A", "B", "C", "D", "K")}


def write_figures(data: PlotData, out_dir: str | Path, force: bool = False, n_stochastic: int = 100,
                  dpi: int = 110) -> list[Path]:
    """Write the PNG files of :data:`FIGURES` that the data allow; return their paths.

    Raises:
        OutputExistsError: a figure file exists and ``force`` is false.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if n_stochastic < 1:
        raise ToolParameterError(f"--terms must be at least 1, got {n_stochastic}")
    out_dir = Path(out_dir)
    existing = [name for name in FIGURES if (out_dir / name).exists()]
    if existing and not force:
        raise OutputExistsError(f"{out_dir}: {', '.join(existing)} exist already, not overwriting (use --force)")
    out_dir.mkdir(parents=True, exist_ok=True)
    truth = _truth_matrices(data.truth)
    written: list[Path] = []

    def save(fig, name: str) -> None:
        fig.tight_layout()
        path = out_dir / name
        fig.savefig(path, dpi=dpi)
        plt.close(fig)
        written.append(path)

    if data.arx_markov is not None:
        fig, ax = plt.subplots(figsize=(7, 3.5))
        Y = data.arx_markov
        k = np.arange(Y.shape[0])
        ax.plot(k, Y[:, 0, 0], ".-", ms=3, lw=0.8, label=f"identified (ArxModel {data.arx_model_id})")
        if truth is not None:
            Yt = markov_from_state_space(truth["A"], truth["B"], truth["C"], truth["D"], Y.shape[0])
            ax.plot(k, Yt[:, 0, 0], "--", lw=0.8, color="k", label="truth")
        ax.set_xlabel("k (time step)")
        ax.set_ylabel("Y_k (1,1)")
        ax.set_title("System Markov parameters, element (1,1)")
        ax.legend()
        save(fig, FIGURES[0])

    if data.state_space is not None:
        ss = data.state_space
        fig, ax = plt.subplots(figsize=(7, 3.5))
        i = np.arange(1, n_stochastic + 1)
        M = stochastic_markov_from_state_space(ss["A"], ss["C"], ss["K"], n_stochastic)
        ax.plot(i, M[:, 0, 0], ".-", ms=3, lw=0.8, label=f"identified (model {ss['model_id']}, n = {ss['n']})")
        if truth is not None:
            Mt = stochastic_markov_from_state_space(truth["A"], truth["C"], truth["K"], n_stochastic)
            ax.plot(i, Mt[:, 0, 0], "--", lw=0.8, color="k", label="truth")
        ax.set_xlabel("i (time step)")
        ax.set_ylabel("C A^i K (1,1)")
        ax.set_title("Stochastic Markov parameters, element (1,1)")
        ax.legend()
        save(fig, FIGURES[1])

    if data.modal_t:
        t = np.asarray(data.modal_t)
        ids = sorted({i for first in data.modal_first for i in first})
        fig, axes = plt.subplots(len(ids) or 1, 1, figsize=(7, 1.8 * max(len(ids), 1) + 0.6), sharex=True,
                                 squeeze=False)
        for ax, mode_id in zip(axes[:, 0], ids):
            values = np.array([first.get(mode_id, np.nan) for first in data.modal_first])
            freq = data.mode_history.get(mode_id)
            label = f"mode {mode_id}" + (f" ({freq[-1][1]:.3f} Hz)" if freq else "")
            ax.plot(t, values, lw=0.7)
            ax.set_ylabel(label, fontsize=8)
        axes[-1, 0].set_xlabel("time [s]")
        axes[0, 0].set_title("Modal states: first coordinate of each mode")
        save(fig, FIGURES[2])

        y_est = np.array([y[0] if y.size else np.nan for y in data.y_estimated])
        if data.measured is not None:
            measured, label = np.array([y[0] for y in data.measured]), "measured"
        else:
            innov = np.array([e[0] if e.size else np.nan for e in data.innovation])
            measured, label = y_est + innov, "y_estimated + innovation"
        fig, ax = plt.subplots(figsize=(7, 3.5))
        ax.plot(t, measured, lw=0.8, label=label)
        ax.plot(t, y_est, "--", lw=0.8, label="estimated")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("output 1")
        ax.set_title("Output 1: measured and estimated")
        ax.legend()
        save(fig, FIGURES[3])

    if data.mode_history:
        fig, (ax_f, ax_z) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
        for mode_id, rows in sorted(data.mode_history.items()):
            arr = np.asarray(rows)
            ax_f.plot(arr[:, 0], arr[:, 1], ".-", ms=3, lw=0.7, label=f"id {mode_id}")
            ax_z.plot(arr[:, 0], 100 * arr[:, 2], ".-", ms=3, lw=0.7)
        if data.truth and data.truth.get("modes"):
            for mode in data.truth["modes"]:
                ax_f.axhline(mode["frequency_hz"], color="k", ls="--", lw=0.6)
                ax_z.axhline(100 * mode["damping_ratio"], color="k", ls="--", lw=0.6)
        ax_f.set_ylabel("frequency [Hz]")
        ax_z.set_ylabel("damping ratio [%]")
        ax_z.set_xlabel("time [s]")
        ax_f.set_title("Identified modes at each model update (dashed: truth)")
        if len(data.mode_history) <= 12:
            ax_f.legend(fontsize=7, ncol=4)
        save(fig, FIGURES[4])
    return written
