"""`okid-ros plot DIR` of a campaign: frequency and damping of every mode id over the campaign.

One PNG, ``campaign_modes.png``: frequency [Hz] (top) and damping ratio [%] (bottom) of each
model update against its stamp, one colour and one series per campaign mode id, error bars of
one standard deviation (``frequency_hz_std``, ``damping_ratio_std``; none where it is unknown),
bag boundaries as thin vertical lines. The time axis is the time since the campaign's first
model, in seconds, hours or days by the campaign's span.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

__all__ = ["CAMPAIGN_FIGURES", "campaign_series", "write_campaign_figures"]

CAMPAIGN_FIGURES = ("campaign_modes.png",)


def campaign_series(out_dir: Path) -> dict[int, dict[str, np.ndarray]]:
    """The rows of each campaign mode id, as (N,) arrays.

    Keys: ``stamp_s``, ``frequency_hz``, ``frequency_hz_std``, ``damping_ratio``, ``damping_ratio_std``,
    ``bag_index``.
    """
    from okid_ros.errors import DataError, OkidWarning, shown_path
    from okid_ros.tools.campaign.table import read_modes

    names = ("stamp_s", "frequency_hz", "frequency_hz_std", "damping_ratio", "damping_ratio_std", "bag_index")
    table = read_modes(out_dir, ("mode_id", *names)).to_pydict()
    series: dict[int, dict[str, list]] = {}
    left_out: list[int] = []
    try:
        for i, mode_id in enumerate(table["mode_id"]):
            if not _drawable(table, i):
                left_out.append(i)
                continue
            entry = series.setdefault(int(mode_id), {name: [] for name in names})
            for name in names:
                entry[name].append(table[name][i])
        arrays = {mid: {k: np.asarray(v, float) for k, v in entry.items()} for mid, entry in sorted(series.items())}
    except (TypeError, ValueError) as exc:  # a null mode id, text where numbers belong
        raise DataError(f"{Path(out_dir) / 'modes.parquet'}: not a modes table of okid-ros batch "
                        f"({' '.join(str(exc).split())})") from None
    if left_out:
        why = (f"a stamp_s beyond any ROS 2 time, or a frequency_hz or damping_ratio not finite (okid-ros batch "
               f"writes none; the first: row {left_out[0]})")
        if not arrays:
            raise DataError(f"{shown_path(Path(out_dir) / 'modes.parquet')}: none of its {len(left_out)} rows can "
                            f"be drawn: {why}")
        warnings.warn(f"{shown_path(Path(out_dir) / 'modes.parquet')}: {len(left_out)} of the "
                      f"{len(table['mode_id'])} rows left out, not drawn: {why}", OkidWarning, stacklevel=2)
    return arrays


def _drawable(table: dict, row: int) -> bool:
    """Whether a row of the table has a stamp, frequency and damping to draw (a frequency > 0: the axis is log)."""
    from okid_ros.service.stamp_steps import MAX_STAMP_S

    values = [table[name][row] for name in ("stamp_s", "frequency_hz", "damping_ratio")]
    if any(value is None for value in values):  # a null: NaN as the Parquet table holds it
        return False
    stamp, frequency, damping = map(float, values)
    return abs(stamp) <= MAX_STAMP_S and 0 < frequency < math.inf and math.isfinite(damping)


def _time_axis(span_s: float) -> tuple[float, str]:
    if span_s > 3 * 86400:
        return 86400.0, "d"
    if span_s > 3 * 3600:
        return 3600.0, "h"
    return 1.0, "s"


def write_campaign_figures(out_dir: Path, figure_dir: Path, *, force: bool = False) -> list[Path]:
    """Draw ``campaign_modes.png`` into ``figure_dir``; returns the paths written.

    Raises
    ------
    OutputExistsError
        the figure exists and ``force`` is false.
    ToolParameterError
        the campaign has no mode rows.
    """
    from okid_ros.errors import shown_path
    from okid_ros.tools.errors import ToolParameterError
    from okid_ros.tools.plots import make_figure_dir, pyplot, refuse_existing, save_figure

    series = campaign_series(out_dir)
    if not series:
        raise ToolParameterError(f"{shown_path(out_dir)}: modes.parquet has no modes to draw (no bag gave a model)")
    refuse_existing(figure_dir, CAMPAIGN_FIGURES, force)
    make_figure_dir(figure_dir)
    t0 = min(float(s["stamp_s"].min()) for s in series.values())
    t1 = max(float(s["stamp_s"].max()) for s in series.values())
    scale, unit = _time_axis(t1 - t0)
    plt = pyplot()
    fig, (ax_f, ax_d) = plt.subplots(2, 1, sharex=True, figsize=(10, 7))
    colours = plt.get_cmap("tab10")
    for k, (mode_id, s) in enumerate(series.items()):
        t = (s["stamp_s"] - t0) / scale
        style = dict(fmt="o", markersize=3, capsize=2, elinewidth=0.8, color=colours(k % 10))
        ax_f.errorbar(t, s["frequency_hz"], yerr=np.nan_to_num(s["frequency_hz_std"]), label=f"mode {mode_id}", **style)
        ax_d.errorbar(t, 100 * s["damping_ratio"], yerr=100 * np.nan_to_num(s["damping_ratio_std"]), **style)
    starts = _bag_starts(series)
    for start in starts[1:]:
        for ax in (ax_f, ax_d):
            ax.axvline((start - t0) / scale, color="0.85", linewidth=0.6, zorder=0)
    ax_f.set_yscale("log")  # modes decades apart stay readable
    ax_f.set_ylabel("frequency [Hz]")
    ax_d.set_ylabel("damping ratio [%]")
    ax_d.set_xlabel(f"time since the first model [{unit}]")
    ax_f.set_title(f"{len(series)} mode ids over {len(starts)} bag(s) of {out_dir} (error bars: 1 std)")
    ax_f.legend(fontsize="small", ncol=max(1, math.ceil(len(series) / 12)), loc="best")
    for ax in (ax_f, ax_d):
        ax.grid(True, alpha=0.3)
    return [save_figure(plt, fig, figure_dir / CAMPAIGN_FIGURES[0])]


def _bag_starts(series: dict[int, dict[str, np.ndarray]]) -> list[float]:
    """First model stamp of each bag, in campaign order."""
    first: dict[int, float] = {}
    for s in series.values():
        for index, stamp in zip(s["bag_index"].astype(int), s["stamp_s"]):
            first[index] = min(first.get(index, math.inf), float(stamp))
    return [first[i] for i in sorted(first)]
