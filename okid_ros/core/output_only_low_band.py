"""Modes far below the sampling rate re-estimated from a decimated record with longer lags.

The lag window of :mod:`.output_covariance` spans one period of the slowest mode per block row
(lags up to two periods): enough to find every mode, short for the slowest ones when they sit
below a few percent of the sampling rate, whose decay takes many periods. Their damping then
scatters by +-50 % (0.8 Hz at 2 % damping, 100 Hz: 0.75-3.1 % over 20 seeds). Longer lags at
the full rate cost a Hankel of thousands of rows; the same lags on the record decimated to
:data:`SAMPLES_PER_PERIOD` samples per period of the slowest mode cost a small one. There the
Hankel spans :data:`PERIODS_PER_BLOCK_ROWS` periods per block row (measured on the low-mode
simulation, 20 seeds: damping 1.45-2.44 % against 2 %, frequency RMS error 0.35 % against 0.49 %
with the full-rate window; damping within 30 % on 20 of 20 seeds against 13).

The lags are sized for the slowest mode: modes up to :data:`SLOWEST_FACTOR` times its
frequency (a mode at twice the slowest one's frequency lost accuracy there: damping within 30 %
on 18 of 20 seeds against 20 at the full rate) and below :data:`BAND_FRACTION` of the decimated
Nyquist frequency (the anti-aliasing filter's flat band) that the decimated identification finds
again within :data:`MATCH_TOLERANCE` take its damping and that one's standard deviation, and its
frequency (and standard deviation) only where the jackknife holds the decimated frequency the
more tightly: a slow mode's frequency is often as well resolved at the full rate, and three
random records lost a mode found there within 0.5 % to a decimated frequency 0.6 % off with the
larger standard deviation (docs/benchmarks-output-only.md, forty-third session). Their shapes and
the model stay those of the full-rate identification (``extras["full_rate_frequency_hz"]`` and
``extras["full_rate_damping_ratio"]`` keep its values).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from okid_ros.core.identified_model import IdentificationError, IdentifiedModel

__all__ = ["refine_low_modes"]

#: Samples per period of the slowest mode after decimation (decimation only when it saves 4x).
SAMPLES_PER_PERIOD = 10
MIN_DECIMATION = 4
#: Fewest samples of the decimated record worth identifying from.
MIN_DECIMATED_SAMPLES = 1000
#: Largest factor of one decimation stage (scipy's FIR decimation, stages for larger factors).
MAX_STAGE = 10
#: Block rows per period of the slowest mode in the decimated Hankel.
PERIODS_PER_BLOCK_ROWS = 4.0
#: Modes re-estimated: below this fraction of the decimated Nyquist frequency and this factor
#: times the slowest mode's frequency.
BAND_FRACTION = 0.4
SLOWEST_FACTOR = 1.5
#: A decimated mode replaces a full-rate one within this relative frequency.
MATCH_TOLERANCE = 0.01


def _decimate(y: np.ndarray, factor: int) -> tuple[np.ndarray, int]:
    """``y`` decimated by stages of at most :data:`MAX_STAGE` (zero-phase FIR), the factor used."""
    used = 1
    while factor // used > 1:
        stage = min(factor // used, MAX_STAGE)
        y = signal.decimate(y, stage, ftype="fir", axis=0, zero_phase=True)
        used *= stage
    return y, used


def refine_low_modes(model: IdentifiedModel, y: np.ndarray, sample_time_s: float, select) -> None:
    """Re-estimate ``model``'s slow modes in place (module docstring); nothing when none is slow.

    Parameters
    ----------
    model : the full-rate identification of ``y``.
    y : (N, p) the record it was identified from (means and harmonics removed).
    select : ``select(y, sample_time_s, block_rows)`` -> the selected modes of a record, dicts
        with ``frequency_hz``, ``damping_ratio`` and their ``_std`` (the full-rate selection).
    """
    if not model.modes:
        return
    slowest_hz = min(mode.frequency_hz for mode in model.modes)
    factor = int(1.0 / (sample_time_s * SAMPLES_PER_PERIOD * slowest_hz))
    if factor < MIN_DECIMATION or y.shape[0] // factor < MIN_DECIMATED_SAMPLES:
        return
    try:
        low, factor = _decimate(y, factor)
    except ValueError:  # a stage's record shorter than its filter's padding
        return
    low_dt = sample_time_s * factor
    block_rows = int(np.ceil(PERIODS_PER_BLOCK_ROWS / (low_dt * slowest_hz)))
    try:
        decimated = select(low, low_dt, block_rows)
    except IdentificationError:
        return  # the record is too short for the longer lags: the full-rate values stand
    band_hz = min(BAND_FRACTION * 0.5 / low_dt, SLOWEST_FACTOR * slowest_hz)
    found = np.array([m["frequency_hz"] for m in decimated])
    for mode in model.modes:
        if mode.frequency_hz > band_hz or found.size == 0:
            continue
        j = int(np.argmin(np.abs(found - mode.frequency_hz)))
        if abs(found[j] / mode.frequency_hz - 1) > MATCH_TOLERANCE:
            continue
        better = decimated[j]
        mode.extras.update(full_rate_frequency_hz=mode.frequency_hz, full_rate_damping_ratio=mode.damping_ratio,
                           decimation=factor, block_rows=block_rows)
        # The longer lags are for the decay; a frequency the full rate already holds more tightly stands.
        # Judged by the screening jackknife's deviations; listed with ``finer_std`` where given (the deviations').
        f_std, z_std = better.get("finer_std", (better["frequency_hz_std"], better["damping_ratio_std"]))
        if not better["frequency_hz_std"] >= mode.frequency_hz_std:
            mode.frequency_hz, mode.frequency_rad_s = better["frequency_hz"], 2 * np.pi * better["frequency_hz"]
            mode.frequency_hz_std = f_std
        mode.damping_ratio, mode.damping_ratio_std = better["damping_ratio"], z_std
