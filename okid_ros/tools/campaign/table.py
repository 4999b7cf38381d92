"""The campaign's tables: campaign mode ids, ``modes.parquet`` (``modes.csv``) and ``summary.csv``.

Mode ids across the campaign are given in one pass after every bag is gathered, so that the
engine and the order in which bags finish change nothing: bags in the order of their first
stamp (then path), model updates in stamp order within a bag, each update's modes matched by
:class:`okid_ros.service.mode_registry.ModeRegistry` with the estimation node's ``tracking.*``
parameters (relative frequency change, MAC of the shapes, memory in model updates), as the node
does between its own updates. The node's id within its bag is kept as ``bag_mode_id``.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from okid_ros.tools.campaign.manifest import atomic_write_bytes

__all__ = ["MODE_COLUMNS", "SUMMARY_COLUMNS", "campaign_order", "mode_rows", "write_modes", "write_summary"]

#: Columns of modes.parquet, in order (add, never rename).
MODE_COLUMNS = ("bag", "bag_index", "stamp_s", "model_id", "arx_model_id", "n_states", "mode_id", "bag_mode_id",
                "frequency_hz", "frequency_rad_s", "damping_ratio", "frequency_hz_std", "damping_ratio_std",
                "mpc", "emac", "msv", "mac_previous", "stable")
#: Columns of summary.csv, in order (add, never rename).
SUMMARY_COLUMNS = ("bag", "status", "reason", "models", "duration_s", "seconds", "samples", "start_s", "reused",
                   "outputs", "given")
_INT_COLUMNS = {"bag_index", "model_id", "arx_model_id", "n_states", "mode_id", "bag_mode_id"}


def campaign_order(results: list[dict]) -> list[dict]:
    """Results in campaign order: first stamp (unknown last), then the bag's name."""
    def key(result: dict) -> tuple:
        start = result.get("start_s", math.nan)
        start = math.inf if start is None or not math.isfinite(start) else start
        return (start, str(result["bag"]))

    return sorted(results, key=key)


def _float(value: object) -> float:
    return math.nan if value is None else float(value)


def _mode(entry: dict):
    from okid_ros.core.modal import Mode

    shape = np.asarray(entry.get("shape_real") or [], float) + 1j * np.asarray(entry.get("shape_imag") or [], float)
    return Mode(frequency_rad_s=float(entry["frequency_rad_s"]), frequency_hz=float(entry["frequency_hz"]),
                damping_ratio=float(entry["damping_ratio"]), eigenvalue=0j, shape=shape,
                mpc=_float(entry.get("mpc")), msv=_float(entry.get("msv")), emac=_float(entry.get("emac")),
                stable=bool(entry.get("stable", True)), physical=True, id=int(entry["id"]))


def mode_rows(results: list[dict], tracking: dict) -> list[dict]:
    """One row per mode per model update of the ok bags, with campaign mode ids.

    Parameters
    ----------
    results : bag results (any order; see :func:`campaign_order`).
    tracking : the estimation node's parameters (``tracking.max_frequency_change``,
        ``tracking.min_mac``, ``tracking.mode_memory``).
    """
    from okid_ros.service.mode_registry import ModeRegistry

    registry = ModeRegistry(max_frequency_change=tracking["tracking.max_frequency_change"],
                            min_mac=tracking["tracking.min_mac"], mode_memory=tracking["tracking.mode_memory"])
    rows: list[dict] = []
    ok = [r for r in campaign_order(results) if r["status"] == "ok"]
    for bag_index, result in enumerate(ok):
        for update in result["updates"]:
            entries = update["modes"]
            modes = [_mode(e) for e in entries]
            modes = registry.assign(modes, registry.match(modes))
            for entry, mode in zip(entries, modes):
                rows.append({
                    "bag": str(result["bag"]), "bag_index": bag_index, "stamp_s": float(update["stamp_s"]),
                    "model_id": int(update["model_id"]), "arx_model_id": int(update.get("arx_model_id", -1)),
                    "n_states": int(update.get("n_states", -1)), "mode_id": int(mode.id),
                    "bag_mode_id": int(entry["id"]), "frequency_hz": float(entry["frequency_hz"]),
                    "frequency_rad_s": float(entry["frequency_rad_s"]), "damping_ratio": float(entry["damping_ratio"]),
                    "frequency_hz_std": _float(entry.get("frequency_hz_std")),
                    "damping_ratio_std": _float(entry.get("damping_ratio_std")),
                    "mpc": _float(entry.get("mpc")), "emac": _float(entry.get("emac")), "msv": _float(entry.get("msv")),
                    "mac_previous": float(mode.mac_previous), "stable": bool(entry.get("stable", True)),
                })
    return rows


def _arrow_table(rows: list[dict]):
    import pyarrow as pa

    fields = []
    for name in MODE_COLUMNS:
        kind = pa.string() if name == "bag" else pa.bool_() if name == "stable" else (
            pa.int64() if name in _INT_COLUMNS else pa.float64())
        fields.append(pa.field(name, kind))
    schema = pa.schema(fields)
    return pa.table({name: [row[name] for row in rows] for name in MODE_COLUMNS}, schema=schema)


def write_modes(rows: list[dict], out_dir: Path, *, csv_too: bool = False) -> list[Path]:
    """Write ``modes.parquet`` (and ``modes.csv``) atomically; returns the paths written."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    table = _arrow_table(rows)
    buffer = io.BytesIO()
    pq.write_table(table, buffer)
    written = [out_dir / "modes.parquet"]
    atomic_write_bytes(written[0], buffer.getvalue())
    if csv_too:
        buffer = io.BytesIO()
        pacsv.write_csv(table, buffer)
        written.append(out_dir / "modes.csv")
        atomic_write_bytes(written[1], buffer.getvalue())
    return written


def read_modes(out_dir: Path, columns: tuple[str, ...] = MODE_COLUMNS):
    """The ``modes.parquet`` of a campaign directory as a pyarrow Table.

    Raises
    ------
    DataError
        the file is missing, unreadable (cut, not Parquet) or lacks one of ``columns``.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    from okid_ros.errors import DataError, shown_path

    path = Path(out_dir) / "modes.parquet"
    again = "a rerun of `okid-ros batch` with the same bags and --out writes it again"
    try:
        table = pq.read_table(path)
    except (OSError, ValueError, pa.ArrowException) as exc:
        reason = " ".join(str(exc).replace(f"Could not open Parquet input source '{path}': ", "").split())
        reason = reason or type(exc).__name__
        raise DataError(f"{shown_path(path)}: not a readable modes table of okid-ros batch ({reason}); "
                        f"{again}") from None
    missing = [name for name in columns if name not in table.column_names]
    if missing:
        raise DataError(f"{shown_path(path)}: not a modes table of okid-ros batch (no column {', '.join(missing)}); "
                        f"{again}")
    return table


def write_summary(entries: list[dict], out_dir: Path) -> Path:
    """Write ``summary.csv`` (one row per bag, ``entries`` in SUMMARY_COLUMNS keys) atomically."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=SUMMARY_COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for entry in entries:
        row = dict(entry)
        for name in ("duration_s", "seconds", "start_s"):
            value = row.get(name)
            row[name] = "" if value is None or not math.isfinite(float(value)) else f"{float(value):.3f}"
        writer.writerow(row)
    path = out_dir / "summary.csv"
    atomic_write_bytes(path, buffer.getvalue().encode())
    return path
