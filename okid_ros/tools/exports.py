"""Exports of an identified model for other tools: a CSV modal table and Universal File Format.

- :func:`write_modal_csv`: one row per mode, ``id, frequency_hz, frequency_hz_std,
  frequency_rad_s, damping_ratio, damping_ratio_std, mpc, msv, emac, stable`` and the shape at
  each output (``shape_real_1.., shape_imag_1..``); values that could not be computed are
  empty cells. Damping ratios are fractions, as everywhere in okid_ros.
- :func:`write_uff`: mode shapes as UFF dataset 55 (one per mode, complex eigenvalue analysis
  type, the outputs as nodes 1..p in direction +X) and FRFs as dataset 58 (one per
  output/input pair, function type 4 = frequency response function, complex), written with
  ``pyuff``. Read them back with ``pyuff.UFF(path).read_sets()``.

Callers check ``--force`` before writing (these functions overwrite).
"""

from __future__ import annotations

import csv
import math
import tempfile
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from okid_ros.errors import OkidWarning, write_atomically
from okid_ros.service.records import mode_record, mode_shape

__all__ = ["MODAL_CSV_COLUMNS", "write_modal_csv", "write_uff"]

MODAL_CSV_COLUMNS = ("id", "frequency_hz", "frequency_hz_std", "frequency_rad_s", "damping_ratio",
                     "damping_ratio_std", "mpc", "msv", "emac", "stable")


def _cell(value: Any) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    value = float(value)
    return repr(value) if math.isfinite(value) else ""


def write_modal_csv(path: str | Path, modes: Sequence[Any]) -> None:
    """Write the modal table of ``modes`` (core Mode objects) to ``path``."""
    n_out = max((np.asarray(m.shape).size for m in modes), default=0)
    header = list(MODAL_CSV_COLUMNS) + [f"shape_real_{k + 1}" for k in range(n_out)] + [
        f"shape_imag_{k + 1}" for k in range(n_out)]
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for mode in modes:
            record = mode_record(mode)  # the one serialized shape of a mode
            shape_real, shape_imag = mode_shape(mode)
            row = [_cell(math.nan if record[name] is None else record[name]) for name in MODAL_CSV_COLUMNS]
            row += [_cell(v) for v in shape_real] + [_cell(v) for v in shape_imag]
            writer.writerow(row)


def write_uff(path: str | Path, modes: Sequence[Any], *, frequency_hz: np.ndarray | None = None,
              frfs: dict[str, np.ndarray] | None = None, description: str = "okid_ros") -> int:
    """Mode shapes (dataset 55) and FRFs (dataset 58) into one UFF file (replaced if it exists).

    Parameters
    ----------
    modes : core Mode objects (``frequency_hz``, ``damping_ratio``, ``shape`` (p,), ``id``); the
        pole is written as ``-zeta w + i w sqrt(1 - zeta^2)`` [rad/s], the shape at nodes 1..p, +X.
    frequency_hz : (F,) uniform frequency grid of the FRFs.
    frfs : label -> (F, p, m) complex FRF [output unit / input unit], e.g. ``{"model": H,
        "measured H1": H1}``; one dataset per label and output/input pair (response node =
        output, reference node = input, label in ID line 2). NaN marks a frequency the FRF
        does not determine (a measured FRF where the inputs' cross-spectrum is singular): the
        dataset leaves it out (uneven abscissa), a pair undetermined everywhere is not written,
        and an :class:`~okid_ros.errors.OkidWarning` says so.

    Returns
    -------
    Number of datasets written.
    """
    import pyuff

    sets = []
    for k, mode in enumerate(modes, start=1):
        shape = np.asarray(mode.shape, complex)
        p = shape.size
        omega = 2.0 * np.pi * float(mode.frequency_hz)
        zeta = float(mode.damping_ratio)
        pole = complex(-zeta * omega, omega * math.sqrt(max(1.0 - zeta * zeta, 0.0)))
        sets.append(pyuff.prepare_55(
            model_type=1, id1=f"{description} mode {getattr(mode, 'id', k)}", id2=f"{mode.frequency_hz:.6g} Hz",
            id3=f"damping ratio {zeta:.6g}", id4="shape at the outputs (nodes 1..p, +X)", id5="NONE",
            analysis_type=3, data_ch=2, spec_data_type=12, load_case=1, mode_n=k,
            eig=pole, modal_a=0j, modal_b=0j,
            node_nums=np.arange(1, p + 1), r1=shape, r2=np.zeros(p, complex), r3=np.zeros(p, complex),
        ))
    if frfs and frequency_hz is not None:
        freq = np.asarray(frequency_hz, float)
        for label, frf in frfs.items():
            frf = np.asarray(frf, complex)
            _warn_undetermined(label, np.isfinite(frf))
            for i in range(frf.shape[1]):
                for j in range(frf.shape[2]):
                    known = np.isfinite(frf[:, i, j])
                    if known.any():
                        sets.append(_frf_dataset(pyuff, f"{description} FRF output {i + 1} / input {j + 1}", label,
                                                 (i + 1, j + 1), freq[known], frf[known, i, j], even=known.all()))
    # pyuff writes (appends) to a file name: a fresh file in a temporary folder, then its bytes
    # through write_atomically, so a device is written into and a failure leaves the old file.
    with tempfile.TemporaryDirectory() as folder:
        staged = Path(folder) / "modes.uff"
        pyuff.UFF(str(staged)).write_sets(sets, mode="add")
        write_atomically(path, lambda stream: stream.write(staged.read_bytes()))
    return len(sets)


def _frf_dataset(pyuff, name: str, label: str, nodes: tuple[int, int], freq: np.ndarray, values: np.ndarray, *,
                 even: bool) -> dict:
    """Dataset 58 of one output/input pair: its abscissa even (start and step) or listed point by point."""
    step = float(np.mean(np.diff(freq))) if even and freq.size > 1 else 0.0
    return pyuff.prepare_58(
        binary=0, id1=name, id2=label, id3="NONE", id4="NONE", id5="NONE", func_type=4, ver_num=0,
        load_case_id=0, rsp_ent_name="okid", rsp_node=nodes[0], rsp_dir=1, ref_ent_name="okid", ref_node=nodes[1],
        ref_dir=1, ord_data_type=6, num_pts=freq.size, abscissa_spacing=1 if even else 0,
        abscissa_min=float(freq[0]), abscissa_inc=step, data=values, x=freq, abscissa_spec_data_type=18,
        ordinate_spec_data_type=0, orddenom_spec_data_type=0, z_axis_spec_data_type=0, abscissa_axis_units_lab="Hz",
    )


def _warn_undetermined(label: str, known: np.ndarray) -> None:
    """One warning for an FRF (F, p, m) with undetermined frequencies (``known`` False there)."""
    if known.all():
        return
    missing = int(np.sum(~known.all(axis=(1, 2))))
    if not known.any():
        text = f"UFF: the {label} FRF is undetermined at every frequency: not written"
    else:
        text = (f"UFF: the {label} FRF is undetermined at {missing} of {known.shape[0]} frequencies: "
                f"left out of its datasets (uneven abscissa)")
    warnings.warn(text, OkidWarning, stacklevel=3)
