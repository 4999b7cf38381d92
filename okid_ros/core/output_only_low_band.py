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

The longer lags also resolve what the full rate's cannot: a tuned mass damper splits a mode into two
of nearly one measured shape, 1-1.4 half-power bandwidths apart, which the full-rate window (two
periods) reads as one real-shaped pole between them, stable at every order. A slow full-rate mode
that the decimated identification finds again at no frequency within :data:`MATCH_TOLERANCE`, but
as two modes, one on each side of it, each nearer to it than to any other listed mode and within
:data:`MERGED_PAIR_BANDWIDTHS` of its half-power bandwidths (``2 zeta f``), stands for that pair
and is not listed (a warning names the pair; docs/benchmarks-output-only.md, forty-ninth session).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from okid_ros.core.identified_model import IdentificationError, IdentifiedModel
from okid_ros.core.modal import Mode

__all__ = ["MergedPair", "refine_low_modes"]

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
#: Farthest a resolved pair member lies from the full-rate pole standing for both, in its half-power bandwidths.
MERGED_PAIR_BANDWIDTHS = 1.0


@dataclass(frozen=True)
class MergedPair:
    """A full-rate mode the decimated identification resolves into two modes on either side of it."""

    mode: Mode
    below_hz: float
    above_hz: float

    def warning(self) -> str:
        """The note of the mode left unlisted."""
        return (f"the pole at {self.mode.frequency_hz:.4g} Hz stands for two modes the longer lags of the decimated "
                f"record resolve at {self.below_hz:.4g} and {self.above_hz:.4g} Hz: not listed (an unresolved pair)")


def _merged_pair(mode: Mode, found: np.ndarray, listed: np.ndarray) -> MergedPair | None:
    """``mode`` as a pair of the decimated modes ``found`` (module docstring), None when it is not one."""
    f = mode.frequency_hz
    below, above = found[found < f], found[found > f]
    if below.size == 0 or above.size == 0:
        return None
    pair = np.array([below.max(), above.min()])
    nearest_listed = listed[np.argmin(np.abs(pair[:, None] - listed[None, :]), axis=1)]
    if np.any(nearest_listed != f) or np.any(np.abs(pair - f) > MERGED_PAIR_BANDWIDTHS * 2 * mode.damping_ratio * f):
        return None
    return MergedPair(mode, float(pair[0]), float(pair[1]))


def _decimate(y: np.ndarray, factor: int) -> tuple[np.ndarray, int]:
    """``y`` decimated by stages of at most :data:`MAX_STAGE` (zero-phase FIR), the factor used."""
    used = 1
    while factor // used > 1:
        stage = min(factor // used, MAX_STAGE)
        y = signal.decimate(y, stage, ftype="fir", axis=0, zero_phase=True)
        used *= stage
    return y, used


def refine_low_modes(model: IdentifiedModel, y: np.ndarray, sample_time_s: float, select) -> list[MergedPair]:
    """Re-estimate ``model``'s slow modes in place (module docstring), the modes that stand for a pair returned.

    Parameters
    ----------
    model : the full-rate identification of ``y``.
    y : (N, p) the record it was identified from (means and harmonics removed).
    select : ``select(y, sample_time_s, block_rows)`` -> the selected modes of a record, dicts
        with ``frequency_hz``, ``damping_ratio`` and their ``_std`` (the full-rate selection).

    Returns
    -------
    The slow modes the decimated record resolves into two (left in ``model.modes``; empty when none).
    """
    if not model.modes:
        return []
    slowest_hz = min(mode.frequency_hz for mode in model.modes)
    factor = int(1.0 / (sample_time_s * SAMPLES_PER_PERIOD * slowest_hz))
    if factor < MIN_DECIMATION or y.shape[0] // factor < MIN_DECIMATED_SAMPLES:
        return []
    try:
        low, factor = _decimate(y, factor)
    except ValueError:  # a stage's record shorter than its filter's padding
        return []
    low_dt = sample_time_s * factor
    block_rows = int(np.ceil(PERIODS_PER_BLOCK_ROWS / (low_dt * slowest_hz)))
    try:
        decimated = select(low, low_dt, block_rows)
    except IdentificationError:
        return []  # the record is too short for the longer lags: the full-rate values stand
    band_hz = min(BAND_FRACTION * 0.5 / low_dt, SLOWEST_FACTOR * slowest_hz)
    found = np.array([m["frequency_hz"] for m in decimated])
    listed = np.array([mode.frequency_hz for mode in model.modes])
    merged = []
    for mode in model.modes:
        if mode.frequency_hz > band_hz or found.size == 0:
            continue
        j = int(np.argmin(np.abs(found - mode.frequency_hz)))
        if abs(found[j] / mode.frequency_hz - 1) > MATCH_TOLERANCE:
            merged += [pair for pair in [_merged_pair(mode, found, listed)] if pair is not None]
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
    return merged
