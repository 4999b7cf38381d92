"""Per-channel scales of a record: the spread of each channel, without overflow or underflow.

The batch identification (:mod:`okid_ros.core.scaling`) and the ARX fit of a record
(:func:`okid_ros.core.arx.fit_arx`) work on channels divided by their spread, so that values
near the float64 limits neither overflow nor underflow the squares of the normal equations.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

__all__ = ["ChannelScales", "channel_mean", "channel_scales", "channel_spread", "channel_std", "column_peaks",
           "group_scales", "power_of_two_scales", "record_units"]


def column_peaks(x: np.ndarray) -> np.ndarray:
    """Largest magnitude of each column of ``x`` (N, c): (c,), 0 without rows, NaN where a column holds NaN.

    ``np.max(np.abs(x), axis=0)``, the same values: numpy reduces axis 0 of a row-major (N, c)
    array c values at a time, one row after another (60000 x 4: 1.6 ms); the rows of the
    transposed copy take 0.15 ms, and a maximum does not depend on the order it is taken in.
    """
    x = np.asarray(x)
    if x.shape[0] == 0:
        return np.zeros(x.shape[1])
    return np.abs(np.ascontiguousarray(x.T)).max(axis=1)


def power_of_two_scales(x: np.ndarray) -> np.ndarray:
    """Per-column power of two nearest the column's largest magnitude of ``x`` (N, c): (c,).

    1 for a column of zeros or one holding Inf/NaN. Dividing by it is exact: sums and medians of
    the quotients are those of the values, scaled, without overflow near the float64 limits.
    """
    peak = column_peaks(x)
    usable = (peak > 0) & (peak < np.inf)
    return np.where(usable, _power_of_two(np.log2(np.where(usable, peak, 1.0))), 1.0)


def _power_of_two(exponent: np.ndarray | float) -> np.ndarray:
    """``2 ** round(exponent)``, at most 2**1023: a peak above 2**1023.5 (1.27e308) rounded to 2**1024, Inf."""
    return 2.0 ** np.minimum(np.round(exponent), 1023)


def channel_mean(x: np.ndarray) -> np.ndarray:
    """Per-column mean of ``x`` (N, c) without overflow: (c,), 0 without rows.

    The same as ``x.mean(axis=0)`` wherever that does not overflow (the columns are divided by a
    power of two); ``np.mean`` of a column of values near 1e307 overflows its sum.
    """
    x = np.asarray(x, dtype=float)
    if x.shape[0] == 0:
        return np.zeros(x.shape[1])
    scale = power_of_two_scales(x)
    return (x / scale).mean(axis=0) * scale


def channel_std(x: np.ndarray) -> np.ndarray:
    """Per-column standard deviation of ``x`` (N, c) without overflow or underflow: (c,).

    Computed on each column divided by its largest magnitude, so values near the float64
    limits (1e+-300) neither overflow nor lose precision (``np.std`` squares them).
    """
    x = np.asarray(x, dtype=float)
    if x.shape[0] == 0:
        return np.zeros(x.shape[1])
    peak = column_peaks(x)
    safe_peak = np.where(peak > 0, peak, 1.0)
    return (x / safe_peak).std(axis=0) * safe_peak


def channel_spread(x: np.ndarray) -> np.ndarray:
    """Per-column spread of ``x`` (N, c): (c,) positive, the scale a channel is divided by.

    The standard deviation (:func:`channel_std`); for a constant column its absolute value; for
    an all-zero column (or no samples) 1.
    """
    x = np.asarray(x, dtype=float)
    spread = channel_std(x)
    constant = ~(spread > 0)
    if x.shape[0]:
        spread[constant] = column_peaks(x)[constant]
    spread[~(spread > 0)] = 1.0
    return spread


@dataclass(frozen=True)
class ChannelScales:
    """Per-channel scales: ``input`` (m,) and ``output`` (p,) positive, in the channels' units."""

    input: np.ndarray
    output: np.ndarray

    def scale(self, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``u`` (N, m) and ``y`` (N, p) divided channel by channel by the scales."""
        return u / self.input, y / self.output

    def where_needed(self, u: np.ndarray, y: np.ndarray, *, limit: float = 2.0**64, sizes=None) -> ChannelScales:
        """These scales for a group (inputs, outputs) with a channel beyond ``[1 / limit, limit]``, else ones.

        Dividing by a power of two guards sums of squares near the float64 limits (values of
        1e+-150); a group of ordinary size needs no division and keeps its units, so that what is
        said of its windows (``constant 5`` for a stuck channel) is said in them. ``u`` (N, m),
        ``y`` (N, p): the record the scales are of (NaN/Inf and dead channels do not count); ``sizes``:
        the sizes of the inputs' and of the outputs' channels not all zeros, ((k_u,), (k_y,)); None: their peaks.
        """
        def extreme(peaks: np.ndarray) -> bool:
            return bool(np.any((peaks < 1.0 / limit) | (peaks > limit)))

        input_sizes, output_sizes = (_channel_peaks(u), _channel_peaks(y)) if sizes is None else sizes
        return ChannelScales(self.input if extreme(input_sizes) else np.ones_like(self.input),
                             self.output if extreme(output_sizes) else np.ones_like(self.output))

    def inverse(self) -> ChannelScales:
        """The reciprocal scales: ``inverse().restore_arx`` takes a fit to the scaled units."""
        return ChannelScales(1.0 / self.input, 1.0 / self.output)

    def restore_arx(self, arx: Any) -> Any:
        """An :class:`~okid_ros.core.arx.ArxFit` of scaled data, in physical units (coefficients, covariance)."""
        su, sy = self.input, self.output
        # Regressor rows: u_k (m), then per lag [y (p), u (m)] (see ArxFit.observer_markov).
        regressor = np.concatenate([su, np.tile(np.concatenate([sy, su]), arx.order)])
        theta = arx.theta * sy[None, :] / regressor[:, None]
        return replace(arx, theta=theta, residual_covariance=arx.residual_covariance * np.outer(sy, sy))


def channel_scales(u: np.ndarray, y: np.ndarray) -> ChannelScales:
    """The spread of each input (N, m) and output (N, p) channel (see :func:`channel_spread`)."""
    return ChannelScales(channel_spread(u), channel_spread(y))


def group_scales(u: np.ndarray, y: np.ndarray) -> ChannelScales:
    """One power of two for all inputs (N, m) and one for all outputs (N, p).

    Each is the geometric mean of the group's channel peaks, rounded to a power of two: channels
    of 1e150 and 1e-150 in one group both keep squares within float64. Dividing by a power of
    two is exact, and the ridge/TC prior (per channel) and the GCV score (summed over outputs)
    are unchanged by one common factor per group: the ARX fit of the scaled record is the fit of
    the record itself, restored, yet values near 1e+-150 neither overflow nor underflow.
    """
    def power(x: np.ndarray) -> float:
        peaks = _channel_peaks(x)
        return float(_power_of_two(np.mean(np.log2(peaks)))) if peaks.size else 1.0

    return ChannelScales(np.full(u.shape[1], power(u)), np.full(y.shape[1], power(y)))


def record_units(u: np.ndarray, y: np.ndarray) -> ChannelScales:
    """One power of two for all inputs (N, m) and one for all outputs (N, p) of a record in far units, else ones.

    As :func:`group_scales` with :meth:`ChannelScales.where_needed`, but each channel's size is its
    typical magnitude (:func:`_typical_magnitudes`), not its peak: a record whose channels lie near
    1e+-150 is divided into ordinary units, while one sample far beyond its channel (1e200 in a
    record of unit spread, a glitch the nodes refuse for its size) neither divides the whole record
    (its ordinary samples towards the float64 floor) nor comes within the windows' bound.
    """
    def power(sizes: np.ndarray) -> float:
        return float(_power_of_two(np.mean(np.log2(sizes)))) if sizes.size else 1.0

    sizes = _typical_magnitudes(u), _typical_magnitudes(y)  # each channel's median once: its power and its bound
    scales = ChannelScales(np.full(u.shape[1], power(sizes[0])), np.full(y.shape[1], power(sizes[1])))
    return scales.where_needed(u, y, sizes=sizes)


def _typical_magnitudes(x: np.ndarray) -> np.ndarray:
    """The median magnitude of the finite non-zero samples of each channel of ``x`` (N, k) that has some."""
    sizes = []
    for column in np.abs(np.asarray(x, dtype=float)).T:
        column = column[np.isfinite(column) & (column > 0)]
        if column.size:
            sizes.append(np.median(column))
    return np.array(sizes)


def _channel_peaks(x: np.ndarray) -> np.ndarray:
    """The largest magnitude of each channel of ``x`` (N, k) that is not all zeros (NaN/Inf do not count).

    NaN/Inf samples are missing samples in ``track``; a dead channel has no size to scale by.
    """
    x = np.where(np.isfinite(x), x, 0.0)
    peaks = column_peaks(x)
    return peaks[peaks > 0]
