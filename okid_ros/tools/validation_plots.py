"""The modal analyst's views of one identified model: FRF, MAC and stabilization diagram.

=================  ==============================================================================
file               content
=================  ==============================================================================
frf.png            measured FRF (H1 from the record's spectra) against the model's
                   ``C (zI - A)^-1 B + D``, magnitude and phase, per chosen output/input pair;
                   the identified modes' frequencies marked
mac.png            auto-MAC of the identified modes' shapes; MAC against a reference set of modes
                   (another model, or the truth of a simulation) when one is given
stabilization.png  poles of every model order tried, marked by the criteria they meet (frequency;
                   + damping; + shape), over the singular values of the output spectrum (CMIF),
                   the chosen modes highlighted; only when the model carries ``stabilization``
=================  ==============================================================================

Each figure has a ``*_data`` function returning the numbers drawn (tests check those) and a
``plot_*`` function drawing them on given axes. :func:`write_validation_figures` writes the
files (never replacing one without ``force``). ``okid-ros identify --plot-dir`` and ``okid-ros
plot`` use it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from okid_ros.core.options import HIGHEST_FREQUENCY_HZ, SAMPLE_TIME_RANGE_S
from okid_ros.core.validation import h1_frf, mac_matrix, model_frf, output_singular_values
from okid_ros.jsonio import finite_number

__all__ = [
    "VALIDATION_FIGURES",
    "ModelView",
    "FrfData",
    "frf_data",
    "plot_frf",
    "mac_data",
    "reference_modes",
    "plot_mac",
    "plot_stabilization",
    "stabilization_points",
    "parse_pairs",
    "write_validation_figures",
]

VALIDATION_FIGURES = ("frf.png", "mac.png", "stabilization.png")
#: Pairs drawn when none are chosen: all of them up to this many, else the first ones.
MAX_DEFAULT_PAIRS = 16
#: Pairs one figure takes when they are listed (each panel costs about 0.7 s to draw; 28 outputs
#: by 2 inputs are 56).
MAX_LISTED_PAIRS = 64


def _mode_record(mode: Any) -> dict:
    """frequency_hz, damping_ratio and complex shape of a core Mode or a mode dict."""
    if isinstance(mode, dict):
        shape = mode.get("shape")
        if shape is None and "shape_real" in mode:
            shape = np.asarray(mode["shape_real"], float) + 1j * np.asarray(mode.get("shape_imag", 0.0), float)
        return {"frequency_hz": float(mode["frequency_hz"]), "damping_ratio": float(mode.get("damping_ratio", np.nan)),
                "shape": None if shape is None else np.asarray(shape, complex), "id": mode.get("id")}
    return {"frequency_hz": float(mode.frequency_hz), "damping_ratio": float(mode.damping_ratio),
            "shape": np.asarray(mode.shape, complex), "id": getattr(mode, "id", None)}


def _stabilization_dicts(stabilization: Sequence[Any] | None) -> list[dict] | None:
    """The stabilization data as JSON-like dicts (a model carries ``StabilizationOrder`` objects)."""
    if stabilization is None:
        return None
    return [entry.as_dict() if hasattr(entry, "as_dict") else entry for entry in stabilization]


@dataclass
class ModelView:
    """What the views need of a model: matrices (innovation form), sample time, modes.

    ``modes`` are dicts with ``frequency_hz``, ``damping_ratio``, ``shape`` (p,) complex, ``id``.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    sample_time_s: float
    modes: list = field(default_factory=list)
    stabilization: list | None = None

    @classmethod
    def of(cls, model: Any) -> "ModelView":
        """From an IdentifiedModel (or any object / dict with A, B, C, D, sample_time_s, modes)."""
        if isinstance(model, dict):
            get = model.get
        else:
            def get(k, d=None):
                return getattr(model, k, d)
        return cls(np.asarray(get("A"), float), np.asarray(get("B"), float), np.asarray(get("C"), float),
                   np.asarray(get("D"), float), float(get("sample_time_s")),
                   [_mode_record(m) for m in get("modes", [])], _stabilization_dicts(get("stabilization")))


def parse_pairs(text: str | None, n_outputs: int, n_inputs: int) -> list[tuple[int, int]]:
    """``"1:1,2:1"`` (output:input, 1-based) -> 0-based pairs, each once; None: all (at most 16).

    Raises
    ------
    ValueError naming the bad pair.
    """
    if not text:
        pairs = [(i, j) for i in range(n_outputs) for j in range(n_inputs)]
        return pairs[:MAX_DEFAULT_PAIRS]
    pairs = []
    for item in text.replace(" ", "").split(","):
        out, sep, inp = item.partition(":")
        try:
            i, j = int(out) - 1, int(inp) - 1
        except ValueError:
            raise ValueError(f"FRF pair {item!r} must be OUTPUT:INPUT, e.g. 1:2") from None
        if not (sep and 0 <= i < n_outputs and 0 <= j < n_inputs):
            raise ValueError(f"FRF pair {item!r} out of range: outputs 1..{n_outputs}, inputs 1..{n_inputs}")
        if (i, j) not in pairs:  # a pair listed twice is drawn once
            pairs.append((i, j))
    if len(pairs) > MAX_LISTED_PAIRS:
        raise ValueError(f"{len(pairs)} FRF pairs: at most {MAX_LISTED_PAIRS} in one figure")
    return pairs


@dataclass
class FrfData:
    """The curves of frf.png.

    frequency_hz : (F,) Welch grid; measured : (F, p, m) H1; model : (F, p, m) on the same grid;
    dense_frequency_hz, dense_model : a finer grid for the model's peaks; mode_frequency_hz :
    the identified modes; model_at_modes : (n_modes, p, m) the model's FRF there.
    """

    frequency_hz: np.ndarray
    measured: np.ndarray
    model: np.ndarray
    dense_frequency_hz: np.ndarray
    dense_model: np.ndarray
    mode_frequency_hz: np.ndarray
    model_at_modes: np.ndarray
    pairs: list


def frf_data(view: ModelView, u: np.ndarray, y: np.ndarray, *, pairs: Sequence[tuple[int, int]] | None = None,
             segment_samples: int | None = None) -> FrfData:
    """H1 of the record ``u`` (N, m), ``y`` (N, p) and the model's FRF on the same grid."""
    dt = view.sample_time_s
    freq, H1 = h1_frf(u, y, dt, segment_samples=segment_samples)
    Hm = model_frf(view.A, view.B, view.C, view.D, freq, dt)
    dense = np.linspace(0.0, 0.5 / dt, 4000)
    mode_f = np.array([m["frequency_hz"] for m in view.modes], float)
    at_modes = model_frf(view.A, view.B, view.C, view.D, mode_f, dt) if mode_f.size else np.zeros((0,) + Hm.shape[1:])
    pairs = list(pairs) if pairs is not None else parse_pairs(None, view.C.shape[0], view.B.shape[1])
    return FrfData(freq, H1, Hm, dense, model_frf(view.A, view.B, view.C, view.D, dense, dt), mode_f, at_modes, pairs)


def _decade_shift(*magnitudes: np.ndarray) -> int:
    """A power of ten that brings magnitudes near the float64 limits to where log axes work.

    matplotlib's log-axis ticks overflow beyond about 1e+-290; 0 for ordinary magnitudes.
    """
    values = np.concatenate([m[np.isfinite(m) & (m > 0)] for m in magnitudes])
    if not values.size or (values.max() < 1e200 and values.min() > 1e-200):
        return 0
    return int(np.round(np.log10(values.max()) / 2 + np.log10(values.min()) / 2))


def _shift_label(shift: int) -> str:
    """`` x 1e+300`` for an axis whose values were divided by 10**shift (nothing for 0)."""
    return f" x 1e{shift:+d}" if shift else ""


def _log_limits(ax, *magnitudes: np.ndarray) -> None:
    """Log-axis limits set from the data: matplotlib's own margins overflow beyond 1e+-300."""
    values = np.concatenate([m[np.isfinite(m) & (m > 0)] for m in magnitudes])
    if values.size:
        low, high = values.min(), values.max()
        # The pending autoscale runs once more inside set_ylim (its overflow is then discarded).
        with np.errstate(over="ignore", under="ignore"):
            ax.set_ylim(max(low / 2, np.finfo(float).tiny), min(high * 2, np.finfo(float).max / 10))


def plot_frf(data: FrfData, *, fig=None):
    """Magnitude (log) and phase of each pair: measured H1 against the model."""
    from okid_ros.tools.plots import pyplot

    plt = pyplot()

    n = len(data.pairs)
    cols = min(n, 4)
    rows = 2 * int(np.ceil(n / cols))
    if fig is None:
        fig = plt.figure(figsize=(3.2 * cols + 0.8, 2.0 * rows + 0.6))
    axes = fig.subplots(rows, cols, squeeze=False, sharex=True)
    for k, (i, j) in enumerate(data.pairs):
        ax_m, ax_p = axes[2 * (k // cols), k % cols], axes[2 * (k // cols) + 1, k % cols]
        measured, model = np.abs(data.measured[:, i, j]), np.abs(data.dense_model[:, i, j])
        shift = _decade_shift(measured, model)
        ax_m.semilogy(data.frequency_hz, measured / 10.0**shift, lw=0.8, label="measured H1")
        ax_m.semilogy(data.dense_frequency_hz, model / 10.0**shift, "--", lw=0.8, label="model")
        _log_limits(ax_m, measured / 10.0**shift, model / 10.0**shift)
        ax_p.plot(data.frequency_hz, np.degrees(np.angle(data.measured[:, i, j])), lw=0.8)
        ax_p.plot(data.dense_frequency_hz, np.degrees(np.angle(data.dense_model[:, i, j])), "--", lw=0.8)
        for f in data.mode_frequency_hz:
            ax_m.axvline(f, color="0.6", lw=0.5, ls=":")
            ax_p.axvline(f, color="0.6", lw=0.5, ls=":")
        ax_m.set_title(f"output {i + 1} / input {j + 1}", fontsize=9)
        ax_m.set_ylabel(f"|H| [output unit / input unit]{_shift_label(shift)}", fontsize=7)
        ax_p.set_ylabel("phase [deg]", fontsize=7)
        ax_p.set_ylim(-190, 190)
        ax_p.set_xlabel("frequency [Hz]", fontsize=8)
        if k == 0:
            ax_m.legend(fontsize=7)
    for k in range(n, (rows // 2) * cols):
        axes[2 * (k // cols), k % cols].set_visible(False)
        axes[2 * (k // cols) + 1, k % cols].set_visible(False)
    fig.suptitle("FRF: measured (H1, Welch) and identified model (dotted: identified modes)", fontsize=10)
    return fig


def mac_data(view: ModelView, reference: Sequence[Any] | None = None, *, reference_label: str = "reference") -> dict:
    """MAC matrices of the identified modes.

    ``auto`` (k, k) MAC of the identified shapes; ``reference`` (k, l) against the reference
    modes (shapes of the same length) or None; plus the frequencies and ``reference_label`` for
    the labels.
    """
    shapes = [m["shape"] for m in view.modes]
    out = {"frequency_hz": [m["frequency_hz"] for m in view.modes], "auto": np.zeros((0, 0)), "reference": None,
           "reference_frequency_hz": [], "reference_label": reference_label}
    if not shapes:
        return out
    S = np.column_stack(shapes)
    out["auto"] = mac_matrix(S, S)
    if reference:
        refs = [_mode_record(m) for m in reference]
        wrong = [r for r in refs if r["shape"] is None or r["shape"].shape != (S.shape[0],)]
        if wrong:  # said, not left out of the figure without a word
            from okid_ros.errors import DataError

            raise DataError(f"{reference_label}: {len(wrong)} of {len(refs)} mode(s) have no shape of "
                            f"{S.shape[0]} entries (one per output of the model)")
        # MAC does not depend on the scale; dividing by the largest entry keeps |shape|^2 in float64.
        scaled = [r["shape"] / max(np.abs(r["shape"]).max(), np.finfo(float).tiny) for r in refs]
        out["reference"] = mac_matrix(S, np.column_stack(scaled))
        out["reference_frequency_hz"] = [r["frequency_hz"] for r in refs]
    return out


def _shape_problem(mode: dict) -> str:
    """What is wrong with the shape of a reference mode ('' when nothing)."""
    def numbers(values) -> bool:
        return isinstance(values, list) and all(map(finite_number, values))

    real, imag = mode.get("shape_real"), mode.get("shape_imag")
    if not numbers(real) or not real:
        return "shape_real is not a non-empty list of finite numbers"
    if imag is not None and not (numbers(imag) and len(imag) == len(real)):
        return f"shape_imag is not a list of {len(real)} finite numbers like shape_real"
    if not any(real) and not any(imag or []):
        return "its shape is all zero"
    return ""


def reference_modes(modes: Any, source: str, n_outputs: int | None = None) -> list[dict]:
    """Check the ``modes`` of a reference (an `okid-ros identify --json` document); returns them.

    Each mode needs a ``frequency_hz`` above 0 and at most the highest a record can hold
    (:data:`~okid_ros.core.options.HIGHEST_FREQUENCY_HZ`) and a shape: ``shape_real`` (and
    ``shape_imag``, zero when left out: a real mode shape), finite numbers, not all zero, one per
    output of the model (``n_outputs``, when given).

    Raises
    ------
    ParameterError
        one line naming ``source``, the mode and what is wrong with it.
    """
    from okid_ros.errors import ParameterError

    if not isinstance(modes, list) or not modes:
        what = "empty" if modes == [] else "not a list"
        raise ParameterError(f"{source}: 'modes' is {what}: no mode to compare with")
    for k, mode in enumerate(modes):
        if not isinstance(mode, dict):
            raise ParameterError(f"{source}: mode {k} is not an object with frequency_hz and shape_real")
        frequency = mode.get("frequency_hz")
        if not finite_number(frequency):
            raise ParameterError(f"{source}: mode {k}: frequency_hz is {frequency!r}, not a finite number")
        if not 0 < frequency <= HIGHEST_FREQUENCY_HZ:  # drawn as the MAC figure's labels (1e308: 309 digits)
            raise ParameterError(f"{source}: mode {k}: frequency_hz is {frequency!r}, not a frequency above 0 Hz and "
                                 f"at most {HIGHEST_FREQUENCY_HZ:g} Hz (the Nyquist frequency of a record sampled "
                                 f"at {SAMPLE_TIME_RANGE_S[0]:g} s, the shortest sample time read)")
        problem = _shape_problem(mode)
        if not problem and n_outputs is not None and len(mode["shape_real"]) != n_outputs:
            problem = f"its shape has {len(mode['shape_real'])} entries, the record {n_outputs} outputs"
        if problem:
            raise ParameterError(f"{source}: mode {k}: {problem}")
    return modes


def _mac_panel(ax, matrix: np.ndarray, rows_hz: list, cols_hz: list, title: str, col_label: str) -> None:
    image = ax.imshow(matrix, vmin=0.0, vmax=1.0, cmap="viridis")
    for (r, c), value in np.ndenumerate(matrix):
        ax.text(c, r, f"{value:.2f}", ha="center", va="center", fontsize=7, color="w" if value < 0.6 else "k")
    ax.set_xticks(range(len(cols_hz)), [f"{f:.2f}" for f in cols_hz], fontsize=7, rotation=45)
    ax.set_yticks(range(len(rows_hz)), [f"{f:.2f}" for f in rows_hz], fontsize=7)
    ax.set_xlabel(col_label + " [Hz]", fontsize=8)
    ax.set_ylabel("identified mode [Hz]", fontsize=8)
    ax.set_title(title, fontsize=9)
    return image


def plot_mac(data: dict, *, fig=None):
    """Auto-MAC (and MAC against the reference) as annotated matrices, MAC [-] from 0 to 1."""
    from okid_ros.tools.plots import pyplot

    plt = pyplot()

    panels = 1 + (data["reference"] is not None)
    if fig is None:
        fig = plt.figure(figsize=(4.6 * panels + 0.8, 4.4), layout="constrained")
    axes = fig.subplots(1, panels, squeeze=False)[0]
    image = _mac_panel(axes[0], data["auto"], data["frequency_hz"], data["frequency_hz"], "auto-MAC",
                       "identified mode")
    if data["reference"] is not None:
        label = data.get("reference_label", "reference")
        image = _mac_panel(axes[1], data["reference"], data["frequency_hz"], data["reference_frequency_hz"],
                           f"MAC against the {label}", f"{label} mode")
    fig.colorbar(image, ax=list(axes), shrink=0.8, label="MAC [-]")
    return fig


#: Marker per criteria met: (label, marker, colour); a pole counts for the highest level it meets.
STABILIZATION_LEVELS = (
    ("new pole", "x", "0.6"),
    ("stable frequency", "o", "tab:orange"),
    ("+ damping", "s", "tab:blue"),
    ("+ shape", "D", "tab:green"),
)


def stabilization_points(stabilization: Sequence[dict]) -> dict:
    """Poles per level of :data:`STABILIZATION_LEVELS`: ``{level: (frequency_hz[], n_states[])}``.

    Level 0 meets no criterion, 1 frequency, 2 frequency and damping, 3 also the shape.
    """
    out = {level: ([], []) for level in range(len(STABILIZATION_LEVELS))}
    for entry in stabilization:
        n = int(entry["n_states"])
        for pole in entry.get("poles", []):
            level = 0
            if pole.get("stable_frequency"):
                level = 1
                if pole.get("stable_damping"):
                    level = 2
                    if pole.get("stable_shape"):
                        level = 3
            out[level][0].append(float(pole["frequency_hz"]))
            out[level][1].append(n)
    return out


def plot_stabilization(stabilization: Sequence[dict], modes: Sequence[Any], *, u: np.ndarray | None = None,
                       y: np.ndarray | None = None, sample_time_s: float | None = None, ax=None):
    """Draw the stabilization diagram.

    Poles over model order by the criteria they meet, chosen modes
    highlighted, over the CMIF (singular values of the output spectrum) when ``y`` is given.

    Parameters
    ----------
    stabilization : ``[{"n_states": int, "poles": [{"frequency_hz", "damping_ratio",
        "stable_frequency", "stable_damping", "stable_shape"}]}]`` over the orders tried.
    modes : the chosen modes (Mode objects or dicts with ``frequency_hz``).
    u : unused (kept for a future H1-based indicator); y : (N, p) the record's outputs.
    sample_time_s : seconds per sample (needed with ``y``).
    ax : axes to draw on (default: a new figure).

    Returns
    -------
    The figure.
    """
    from okid_ros.tools.plots import pyplot

    plt = pyplot()

    if ax is None:
        fig, ax = plt.subplots(figsize=(8, 5))
    else:
        fig = ax.figure
    points = stabilization_points(stabilization)
    for level, (label, marker, colour) in enumerate(STABILIZATION_LEVELS):
        f, n = points[level]
        if f:
            ax.scatter(f, n, marker=marker, s=18 if marker != "x" else 14,
                       facecolors="none" if marker != "x" else colour,
                       edgecolors=colour if marker != "x" else None, linewidths=0.8, label=label, zorder=3)
    chosen = [_mode_record(m)["frequency_hz"] for m in modes]
    for k, f in enumerate(chosen):
        ax.axvline(f, color="tab:red", lw=1.0, alpha=0.6, label="chosen mode" if k == 0 else None, zorder=2)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("model order n [states]")
    ax.set_title("Stabilization diagram")
    if y is not None and sample_time_s is not None:
        freq, sv = output_singular_values(y, sample_time_s)
        spec = ax.twinx()
        shift = _decade_shift(sv.ravel())
        sv = sv / 10.0**shift
        for k in range(sv.shape[1]):
            spec.semilogy(freq, sv[:, k], lw=0.7, color="0.3", alpha=0.8 if k == 0 else 0.35,
                          label="CMIF: singular values of the output spectrum" if k == 0 else None)
        _log_limits(spec, sv.ravel())
        spec.set_ylabel(f"singular value of S_yy [output unit^2 / Hz]{_shift_label(shift)}", fontsize=8)
        spec.legend(loc="upper right", fontsize=7)
        ax.set_zorder(spec.get_zorder() + 1)
        ax.patch.set_visible(False)
        ax.set_xlim(0, 0.5 / sample_time_s)
    ax.legend(loc="upper left", fontsize=7)
    return fig


def write_validation_figures(view: ModelView, u: np.ndarray | None, y: np.ndarray | None, out_dir: str | Path, *,
                             force: bool = False, reference: Sequence[Any] | None = None,
                             reference_label: str = "reference", pairs: Sequence[tuple[int, int]] | None = None,
                             dpi: int = 110) -> list[Path]:
    """Write frf.png (needs the record with inputs), mac.png and stabilization.png (needs ``view.stabilization``).

    Raises
    ------
    OutputExistsError: one of the files exists and ``force`` is false.
    OutputError: ``out_dir`` is not a folder or cannot be created, a figure cannot be written.
    DataError: a reference mode has no shape of one entry per output.
    """
    from okid_ros.tools.plots import make_figure_dir, pyplot, refuse_existing, save_figure

    out_dir = Path(out_dir)
    refuse_existing(out_dir, VALIDATION_FIGURES, force)
    make_figure_dir(out_dir)
    plt = pyplot()
    written = []
    if u is not None and y is not None and u.shape[1] > 0:  # no FRF of an output-only record
        written.append(save_figure(plt, plot_frf(frf_data(view, u, y, pairs=pairs)), out_dir / "frf.png", dpi))
    if view.modes:
        data = mac_data(view, reference, reference_label=reference_label)
        written.append(save_figure(plt, plot_mac(data), out_dir / "mac.png", dpi))
    if view.stabilization:
        fig = plot_stabilization(view.stabilization, view.modes, u=u, y=y, sample_time_s=view.sample_time_s)
        written.append(save_figure(plt, fig, out_dir / "stabilization.png", dpi))
    return written
