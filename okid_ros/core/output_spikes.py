"""Spikes: an output sample far beyond its neighbours in one or a few channels (a glitch).

Real acquisitions put single wrong samples into a channel: electromagnetic interference, a bit
error in a telemetry frame, a loose connector's contact. Least squares weighs them by their
square. On the paper's structure (3750 samples, 10 seeds) one spike of 50 output spreads in one
output cost 9 of the 30 modes, five of 30 spreads cost 4 and listed a spurious one; nothing was
said.

A sample ``k`` of output ``i`` is a spike when its second difference
``r_k = y_k - (y_(k-1) + y_(k+1)) / 2`` exceeds :data:`SPIKE_RATIO` robust standard deviations
(1.4826 times the median absolute value) of the channel's second differences, of those of the
:data:`SPIKE_NEIGHBOURHOOD` samples before it, and of those after it. A response does not jump
alone: a lightly damped mode's second differences follow its amplitude, so after an impact the
samples on one side are as large. Clean records stay below 4.5 (the 240 benchmark records of
docs/benchmarks.md at 15000 samples, the 120 random structures, the output-only cases, the steel
subframe and the koma frame); a spike of a few output spreads lies at tens to hundreds. Two
events are no glitch and stay: a jump in every output at once (an unmeasured impact; a glitch of
the whole acquisition the dependence check refuses, :func:`.excitation.output_problem`) and one
where an input jumps too (an impact hammer's response).

A spike's value must also depart from its neighbours' median by :data:`SPIKE_DEPARTURE` robust
standard deviations of their values: a lightly damped ringing's second differences stray far
from their median, its values do not (impact-hammer records). :func:`spike_spreads` says how far
each lies in its channel's standard deviations (``identify`` leaves out only the large ones,
:mod:`.sensor_faults`). scipy.signal offers
outlier-free filters (``medfilt``), not a detector with these two rules; the rules need the
per-sample scales, a few lines of numpy.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.channels import power_of_two_scales

__all__ = ["MAD_TO_STD", "MAX_SPIKES_ANY_RECORD", "MAX_SPIKE_SHARE", "SPIKE_DEPARTURE", "SPIKE_NEIGHBOURHOOD",
           "SPIKE_RATIO", "most_spikes", "output_spikes", "spike_spreads", "widened"]

#: Robust standard deviations of the second differences beyond which a sample is a spike (clean
#: records: at most 4.5, module docstring).
SPIKE_RATIO = 12.0
#: ... and whose value departs from the median of its neighbours by this many robust standard
#: deviations of the values on either side (a stationary Gaussian record: once in 5e8 samples).
SPIKE_DEPARTURE = 6.0
#: Samples on each side whose second differences give the local scale.
SPIKE_NEIGHBOURHOOD = 25
#: More spike samples than this share of the record, and than :data:`MAX_SPIKES_ANY_RECORD`, are a
#: heavy-tailed signal, not glitches (and each sample left out costs the ARX rows that reach it).
MAX_SPIKE_SHARE = 0.001
MAX_SPIKES_ANY_RECORD = 10
#: Robust standard deviation of a Gaussian per median absolute value.
MAD_TO_STD = 1.4826


def output_spikes(u: np.ndarray, y: np.ndarray, *, valid: np.ndarray | None = None
                  ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """The samples holding an output spike (module docstring).

    Parameters
    ----------
    u : (N, m) inputs (m may be 0); y : (N, p) outputs; valid : (N,) bool, False at missing
        samples (any value there: they are bridged by straight lines), None: none missing.

    Returns
    -------
    spikes : (N,) bool, True at the spikes' samples; by_output : {output: (K,) sample indices}
        of the spikes per output.
    """
    n, p = y.shape
    none = np.zeros(n, bool)
    if n < 2 * SPIKE_NEIGHBOURHOOD + 3:
        return none, {}
    present = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
    ratio_y = _jump_ratio(y, present, local=True)
    flagged = ratio_y > SPIKE_RATIO
    if not flagged.any():
        return none, {}
    at_sample = flagged.any(axis=1)
    outputs_near = widened(flagged, 1).sum(axis=1)
    every_output = (outputs_near >= p) if p >= 2 else np.zeros(n, bool)
    if u.shape[1]:
        input_jumps = widened(_jump_ratio(u, present, local=False) > SPIKE_RATIO, 1).any(axis=1)
    else:
        input_jumps = np.zeros(n, bool)
    spikes = at_sample & ~widened((every_output | input_jumps)[:, None], 1)[:, 0]
    by_output = {i: np.flatnonzero(spikes & flagged[:, i]) for i in range(p) if np.any(spikes & flagged[:, i])}
    return spikes, by_output


def spike_spreads(y: np.ndarray, samples: np.ndarray, *, valid: np.ndarray | None = None) -> np.ndarray:
    """How far each spike lies from its neighbours' median, in standard deviations of its channel.

    Parameters
    ----------
    y : (N,) one output; samples : (K,) its spikes (:func:`output_spikes`); valid : (N,) bool,
        False at missing samples (left out of the spread), None: none missing.

    Returns
    -------
    (K,) ``|y_k - median of the SPIKE_NEIGHBOURHOOD samples either side| / std``, the standard
    deviation over the channel's other samples (Inf for a channel otherwise constant).
    """
    y = _near_one(y[:, None])[:, 0]  # the spreads are ratios: the same, without overflow near 1e308
    others = np.ones(y.shape[0], bool) if valid is None else np.asarray(valid, bool).copy()
    others[samples] = False
    spread = float(np.std(y[others])) if others.any() else 0.0
    before, after = _sides(y, np.asarray(samples))
    centre = np.nanmedian(np.hstack([before, after]), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(spread > 0, np.abs(y[samples] - centre) / (spread or 1.0), np.inf)


def most_spikes(n_samples: int) -> int:
    """The most spike samples a record of ``n_samples`` may hold as glitches (more: heavy tails)."""
    return max(MAX_SPIKES_ANY_RECORD, int(MAX_SPIKE_SHARE * n_samples))


def widened(mask: np.ndarray, width: int) -> np.ndarray:
    """``mask`` (N, k) True also ``width`` samples before and after each True (a new array)."""
    n = mask.shape[0]
    counts = np.cumsum(np.vstack([np.zeros((1, mask.shape[1]), int), mask.astype(int)]), axis=0)
    samples = np.arange(n)
    return (counts[np.minimum(samples + width + 1, n)] - counts[np.maximum(samples - width, 0)]) > 0


def _jump_ratio(x: np.ndarray, present: np.ndarray, *, local: bool) -> np.ndarray:
    """``|r_k|`` over its robust scale (N, k): the channel's, and with ``local`` either side's too.

    0 at missing samples, the first and the last. In a channel whose second differences are
    mostly 0 (a quantized or flat signal, a command held between steps: no scale), 0 with
    ``local`` (an output: nothing to judge by) and Inf at every change without (an input: each
    step is a jump its response may follow).
    """
    n = x.shape[0]
    index = np.flatnonzero(present)
    if index.size < 3:
        return np.zeros(x.shape)
    x = _near_one(x)  # ratios: the same, without overflow of sums and medians near 1e308
    bridged = x if index.size == n else np.column_stack(
        [np.interp(np.arange(n), index, x[index, c]) for c in range(x.shape[1])])
    r = np.zeros(x.shape)
    r[1:-1] = bridged[1:-1] - 0.5 * (bridged[:-2] + bridged[2:])
    size = np.abs(r)
    size[~present] = 0.0
    usable = present.copy()
    usable[[0, -1]] = False
    scale = MAD_TO_STD * np.median(size[usable], axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        unscaled = 0.0 if local else np.where(size > 0, np.inf, 0.0)
        ratio = np.where(scale > 0, size / np.where(scale > 0, scale, 1.0), unscaled)
    ratio[~usable] = 0.0
    if not local:
        return ratio
    for c in np.flatnonzero(np.any(ratio > SPIKE_RATIO, axis=0)):  # the side scales only where needed
        k = np.flatnonzero(ratio[:, c] > SPIKE_RATIO)
        before_jump, after_jump = _sides(size[:, c], k)
        jump = MAD_TO_STD * np.maximum(np.nanmedian(before_jump, axis=1), np.nanmedian(after_jump, axis=1))
        # The value itself beyond the spread of the values on either side, too: a lightly damped
        # ringing (after an impact) has second differences far from their median, not values.
        before, after = _sides(bridged[:, c], k)
        spread = np.maximum(_mad(before), _mad(after))
        centre = np.nanmedian(np.hstack([before, after]), axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            departure = np.where(spread > 0, np.abs(bridged[k, c] - centre) / spread, np.inf)
        ratio[k, c] = np.where(departure >= SPIKE_DEPARTURE, size[k, c] / np.maximum(jump, scale[c]), 0.0)
    return ratio


def _near_one(x: np.ndarray) -> np.ndarray:
    """``x`` (N, k) divided channel by channel by the power of two nearest its peak: exact, and 1 for a channel of 0."""
    return x / power_of_two_scales(x)


def _sides(x: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The :data:`SPIKE_NEIGHBOURHOOD` values of ``x`` (N,) before and after each sample of ``k`` (K,).

    Two (K, W) arrays, NaN past the record's ends.
    """
    width = SPIKE_NEIGHBOURHOOD
    windows = np.lib.stride_tricks.sliding_window_view(np.r_[np.full(width, np.nan), x, np.full(width + 1, np.nan)],
                                                       width)
    return windows[k], windows[k + width + 1]


def _mad(x: np.ndarray) -> np.ndarray:
    """Robust standard deviation of each row of ``x`` (K, W): 1.4826 times its median absolute deviation."""
    return MAD_TO_STD * np.nanmedian(np.abs(x - np.nanmedian(x, axis=1, keepdims=True)), axis=1)
