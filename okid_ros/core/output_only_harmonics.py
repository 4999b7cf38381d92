"""Harmonic disturbances in a record: found, told apart from modes, removed.

A harmonic force (a machine's rotation, the mains) makes the outputs hold a sinusoid of
constant amplitude. Stochastic subspace identification sees it as an undamped, perfectly
order-stable pole; it is no mode, and next to a mode it also disturbs that mode's pole. Two
facts of the record tell the two apart (Brincker, Andersen & Moller 2000, "An indicator for
separation of structural and harmonic modes in output-only modal testing"):

- a **spectral line**: the record's periodogram (Hann window, the full record) holds the
  harmonic's power in its window's main lobe, ``HARMONIC_LINE_RATIO`` times or more above the
  median of the bins around it; a structural mode spreads its power over its half-power
  bandwidth ``2 zeta f``;
- a **constant envelope**: the record band-passed around the line (``HARMONIC_BAND_BINS``
  bins each side) and projected on the line's spatial direction is a sinusoid, whose
  probability density has kurtosis 1.5; a randomly excited mode's response is Gaussian
  (kurtosis 3). A line is a harmonic when its kurtosis is at most ``HARMONIC_MAX_KURTOSIS``.

Measured: harmonics 1.50-1.51 (line ratios above 4000, the simulated harmonic case); structural
modes 1.78-4.1 (line ratios up to 130 on the 8-s subframe record, below 20 on 600-s records);
a lightly damped mode's Gaussian response, simulated 300 times for every record holding 4 to 32
of its decay times: 1st percentile 1.71-2.15, lowest 1.68. A harmonic is flagged when its
in-band power is about 20 times the noise's or more (kurtosis ``(1.5 r^2 + 6 r + 3) / (r + 1)^2``
at power ratio r).

The envelope tells the two apart only over several decay times ``1 / (zeta omega)`` of the mode:
over a shorter record a lightly damped mode's amplitude hardly changes and its kurtosis nears a
sinusoid's (simulated, 20 records each: a 3 Hz mode at 0.2 % damping is taken for a harmonic in
14 records holding 0.2 of its decay times, 4 holding 0.8, none from 1.5 on; at 0.5 % in 3
holding 0.5). A line is therefore tested only when the record holds ``LINE_DECAY_TIMES`` decay
times of a mode at ``REFERENCE_DAMPING`` at its frequency, that is ``LINE_DECAY_TIMES / (2 pi
REFERENCE_DAMPING)`` (about 160) of its cycles; a harmonic with fewer cycles in the record stays
in it (an undamped pole the mode selection rejects by its damping, or a warning sign in the
diagram).

Each harmonic found is removed by least squares (its frequency refined to a fraction of a
bin, then one cosine and one sine per harmonic and channel) before the correlations are
taken. A harmonic whose amplitude or frequency drifts is removed only in part.

With measured inputs (``identify``'s input-output route) the outputs' lines are found the same
way; one the inputs hold too is the response to a measured harmonic force, which the model
explains, and stays. An unmeasured one left in made the chain list it as a mode at 0.0 %
damping and, at half the outputs' spread, drop the paper structure's 48.5 Hz mode.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize, stats

from okid_ros.core.channels import channel_mean, power_of_two_scales

__all__ = ["Harmonic", "find_harmonics", "remove_harmonics", "without_harmonics"]

#: A line's peak bin stands this many times above the median of its neighbourhood.
HARMONIC_LINE_RATIO = 100.0
#: Kurtosis of the band-passed, projected record at most this: a sinusoid (1.5), not a mode (3).
HARMONIC_MAX_KURTOSIS = 1.65
#: A line is tested when the record holds this many decay times of a mode at the reference
#: damping at its frequency (module docstring): bins (cycles in the record) of at least
#: ``LINE_DECAY_TIMES / (2 pi REFERENCE_DAMPING)``.
LINE_DECAY_TIMES = 2.0
REFERENCE_DAMPING = 0.002
#: Half-width of the band (bins of the full record) of the kurtosis test.
HARMONIC_BAND_BINS = 10
#: The neighbourhood of a line: bins 4 .. 24 away on either side (the Hann main lobe is +-2).
_RING_INNER, _RING_OUTER = 4, 24
#: A line of the outputs is in the inputs too when their power in its main lobe stands this many
#: times above their background (a random input's bins: a few times; a harmonic force: thousands).
INPUT_LINE_RATIO = 10.0
#: Most lines tested (the strongest first) and most harmonics removed.
MAX_LINES = 32
#: Share of the band-passed signal cut at each end (the circular FFT's wrap-around).
_EDGE = 0.1


@dataclass
class Harmonic:
    """One harmonic line: its frequency (Hz, refined), line ratio and kurtosis."""

    frequency_hz: float
    line_ratio: float
    kurtosis: float


def find_harmonics(y: np.ndarray, sample_time_s: float) -> list[Harmonic]:
    """The harmonic lines of a record (module docstring), strongest first.

    Parameters
    ----------
    y : (N, p) outputs, means removed.
    sample_time_s : sample time (s).

    Returns
    -------
    list of :class:`Harmonic` (empty when the record holds none).
    """
    n = y.shape[0]
    if n < 8 * _RING_OUTER:
        return []
    windowed, power, ratio = _line_ratios(y)
    local_max = np.r_[False, (power[1:-1] >= power[:-2]) & (power[1:-1] >= power[2:]), False]
    bins = np.flatnonzero(local_max & (ratio >= HARMONIC_LINE_RATIO))
    min_cycles = LINE_DECAY_TIMES / (2 * np.pi * REFERENCE_DAMPING)
    bins = bins[(bins >= max(3, min_cycles)) & (bins <= power.size - 4)]
    bins = bins[np.argsort(ratio[bins])[::-1]][:MAX_LINES]
    if bins.size == 0:
        return []
    raw = np.fft.rfft(y, axis=0)
    found = []
    for k in bins:
        kurtosis = _band_kurtosis(raw, windowed[k], int(k), n)
        if kurtosis <= HARMONIC_MAX_KURTOSIS:
            found.append(Harmonic(_refine(y, k / (n * sample_time_s), n * sample_time_s, sample_time_s),
                                  float(ratio[k]), kurtosis))
    return found


def _line_ratios(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The spectral lines' evidence of ``x`` (N, k): ``(windowed, power, ratio)``.

    The Hann-windowed spectrum (F, k), its power summed over the channels (F,) and each bin's
    power over the median of its neighbourhood (F,).
    """
    windowed = np.fft.rfft(x * np.hanning(x.shape[0])[:, None], axis=0)
    power = np.sum(np.abs(windowed) ** 2, axis=1)
    footprint = np.ones(2 * _RING_OUTER + 1, bool)
    footprint[_RING_OUTER - _RING_INNER + 1 : _RING_OUTER + _RING_INNER] = False
    background = ndimage.median_filter(power, footprint=footprint, mode="reflect")
    return windowed, power, power / np.maximum(background, np.finfo(float).tiny)


def without_harmonics(y: np.ndarray, sample_time_s: float, *, u: np.ndarray | None = None, remove: bool = True,
                      valid: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """``y`` less its harmonic lines (a disturbance, not a mode), and a warning naming them.

    Parameters
    ----------
    y : (N, p) outputs (their means are kept); sample_time_s : sample time (s).
    u : (N, m) the measured inputs, if any: a line the inputs hold too (within the Hann main
        lobe, :data:`INPUT_LINE_RATIO` above their background) is the response to a measured
        harmonic force, part of what the model must explain, and stays.
    remove : False: the lines are only named (``y`` returned as it is, the warning without an action
        for the caller to complete).
    valid : (N,) bool, False at missing samples (any value there): the spectra take them as 0
        after the means of the others are removed, the sinusoids are fitted to the others, and
        the missing samples keep their values. A few dropped samples spread a line's power by
        their share only; a long gap breaks the line's constant envelope, so the line is kept
        rather than taken for a mode's (the kurtosis test). None: every sample present.
    """
    present = np.ones(y.shape[0], bool) if valid is None else np.asarray(valid, bool)
    mean = channel_mean(y[present])
    centred = np.where(present[:, None], y - mean, 0.0)
    scale = _power_of_two(centred)  # exact: the spectra's squares neither overflow nor underflow
    found = find_harmonics(centred / scale, sample_time_s)
    measured = u is not None and u.shape[1] > 0
    if found and measured and u.shape[0] >= 8 * _RING_OUTER:
        inputs = np.where(present[:, None], u - channel_mean(u[present]), 0.0)
        ratio = _line_ratios(inputs / _power_of_two(inputs))[2]
        duration_s = y.shape[0] * sample_time_s
        lobe = [np.arange(round(h.frequency_hz * duration_s) - 2, round(h.frequency_hz * duration_s) + 3)
                for h in found]
        found = [h for h, bins in zip(found, lobe)
                 if not np.max(ratio[np.clip(bins, 0, ratio.size - 1)]) >= INPUT_LINE_RATIO]
    if not found:
        return y, []
    listed = ", ".join(f"{h.frequency_hz:.5g} Hz" for h in found)
    where = " (not a mode; the inputs hold no such line)" if measured else " (not a mode)"
    if not remove:
        return y, [f"harmonic disturbance in the outputs{where}: {listed}"]
    cleaned = mean + scale * remove_harmonics(centred / scale, sample_time_s, found, valid=valid)
    return np.where(present[:, None], cleaned, y), [
        f"harmonic disturbance removed before identification{where}: {listed}"]


def _power_of_two(x: np.ndarray) -> float:
    """The power of two nearest the largest magnitude of ``x``, one for all channels (1 for an all-zero ``x``)."""
    return float(power_of_two_scales(np.reshape(x, (-1, 1)))[0])


def _band_kurtosis(raw: np.ndarray, direction: np.ndarray, k: int, n: int) -> float:
    """Kurtosis of the record band-passed around bin ``k`` and projected on ``direction`` (p,)."""
    unit = np.conj(direction) / max(float(np.linalg.norm(direction)), np.finfo(float).tiny)
    lo, hi = max(k - HARMONIC_BAND_BINS, 1), min(k + HARMONIC_BAND_BINS + 1, raw.shape[0])
    band = np.zeros(n, complex)
    band[lo:hi] = raw[lo:hi] @ unit  # one-sided: the analytic signal of the projection
    signal = np.fft.ifft(band).real
    cut = int(_EDGE * n)
    return float(stats.kurtosis(signal[cut : n - cut], fisher=False))


def _refine(y: np.ndarray, frequency_hz: float, duration_s: float, sample_time_s: float) -> float:
    """The frequency within one bin of ``frequency_hz`` that maximizes the record's summed power."""
    t = np.arange(y.shape[0]) * sample_time_s

    def negative_power(f: float) -> float:
        return -float(np.sum(np.abs(np.exp(-2j * np.pi * f * t) @ y) ** 2))

    bin_hz = 1.0 / duration_s
    result = optimize.minimize_scalar(negative_power, bounds=(frequency_hz - bin_hz, frequency_hz + bin_hz),
                                      method="bounded", options={"xatol": 1e-4 * bin_hz})
    return float(result.x)


def remove_harmonics(y: np.ndarray, sample_time_s: float, harmonics: list[Harmonic], *,
                     valid: np.ndarray | None = None) -> np.ndarray:
    """``y`` (N, p) less the least-squares sinusoids at the harmonics' frequencies (all at once).

    ``valid`` (N,) bool: the sinusoids are fitted to these samples only (None: all).
    """
    if not harmonics:
        return y
    t = np.arange(y.shape[0]) * sample_time_s
    phase = 2 * np.pi * np.outer(t, [h.frequency_hz for h in harmonics])
    basis = np.hstack([np.cos(phase), np.sin(phase)])  # (N, 2 H)
    fitted = (basis, y) if valid is None else (basis[valid], y[valid])
    coefficients = np.linalg.lstsq(*fitted, rcond=None)[0]
    return y - basis @ coefficients
