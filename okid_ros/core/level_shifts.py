"""Level shifts: one output's level stepping at one sample and staying (a sensor re-zeroed).

A sensor re-zeroed, an amplifier's range switched, a connector reseated: the channel's level steps
by some amount at one sample and stays there. Least squares takes the step for a response with
a pole at z = 1; the trend step (:mod:`.sensor_faults`) took it for a drift and removed a line,
which left most of the step in: on the paper's structure (3750 samples, 20 seeds) a step of 10
output spreads in one output lost 5 of the 60 modes that the clean records find, and the two
edge samples of one of 30 spreads were left out as spikes.

The rule: at each sample ``k`` of an output, ``d_k`` is the mean of the :data:`SHIFT_WINDOW`
samples from ``k`` on less the mean of those before it. A stationary channel's ``d`` is a
stationary signal whatever its dynamics (slow modes and lightly damped ringing make it larger,
everywhere); a step of size ``s`` makes ``|d|`` peak at ``s`` at the step's sample. ``k`` is a
shift when ``|d_k - median d|`` exceeds :data:`SHIFT_RATIO` robust standard deviations (1.4826
times the median absolute deviation) of the channel's ``d``; a drift only moves ``d``'s median.
Three events are no fault of one sensor and are not named: a shift of every output at once (p >= 2:
the structure itself moved, an unmeasured load), one where an input shifts or jumps too within
the window (the response to a measured step or impact), and a level that does not stay (the
median of the samples beyond the window after less that before the step holds less than
:data:`PERSISTENCE` of it: an impact's ringing in a quiet record lies far beyond the record's
usual mean differences, but dies out to the level before; and the level must hold to the next
step: each step's size fitted over the channel, :func:`_held`, is at least that share too, since
the spans next to a blow in another's ringing hold that ringing, not a level). A channel with more than
:data:`MAX_SHIFTS` shifts is named as unusable and kept (a loose contact, a noisy channel: no
level to keep). A step within 150 samples of either end of the record is not looked for: the rule
needs a window on its side and half a window of the level beyond the next, which tells a re-zero
from an impact's ringing (docs/robustness.md, "A level shift at a record's ends").

Each shift's sample is the one where the step best explains the channel's prediction errors
around the peak (the channel's own AR fit, a matched filter of the step through it, the level
fitted with it over a window on each side of the peak: ``d`` alone puts it within a few samples);
its size is the least-squares fit of the levels between the shifts and a line over the channel
(the drift the trend step removes after). The step is subtracted from the shift's sample on: the
level before is kept.

scipy offers no change-point detector (``ruptures`` and the like are not dependencies); the rule
is a running mean, a median and ``scipy.signal.find_peaks`` for the separate peaks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import find_peaks

from okid_ros.core.channels import column_peaks
from okid_ros.core.output_spikes import MAD_TO_STD, widened

__all__ = ["MAX_SHIFTS", "PERSISTENCE", "SHIFT_RATIO", "SHIFT_WINDOW", "LevelShifts", "level_shifts", "without_shifts"]

#: Samples on each side of a sample whose means are compared.
SHIFT_WINDOW = 100
#: Robust standard deviations of a channel's mean differences beyond which a sample is a shift
#: (records without impacts or steps: at most 6.5, the steel subframe, which names two at 6; a step
#: of 3 spreads on the paper's structure: 30 and more, of 1 spread beyond 8, 44 of 64 beyond 10; of
#: 3 spreads on the koma frame's slow channels beyond 10 on 15 of 40, 8 on 32). Not 8: a dropout's
#: edge is then named a step (docs/robustness.md, "Small level shifts and the threshold").
SHIFT_RATIO = 10.0
#: The level after a shift (beyond its window) differs from that before by at least this share of
#: the shift's mean difference, with its sign: the level stays.
PERSISTENCE = 0.5
#: Windows over which the level after a shift must stay (beyond the window next to the step).
_HOLD = 4
#: More shifts than this in one channel: the channel is named unusable, none removed.
MAX_SHIFTS = 3
#: Order of the channel's AR fit that places a shift at its sample.
_AR_ORDER = 20


@dataclass(frozen=True)
class LevelShifts:
    """The level shifts of a record's outputs.

    Attributes
    ----------
    by_output : {output: (samples (K,) int, sizes (K,) float)}, the shifts of each output with at
        most :data:`MAX_SHIFTS`, in the output's units (level after less level before).
    unusable : {output: (K,) int samples}, the outputs with more shifts than that.
    spread : (p,) each output's standard deviation over the samples present, its shifts removed.
    """

    by_output: dict[int, tuple[np.ndarray, np.ndarray]]
    unusable: dict[int, np.ndarray]
    spread: np.ndarray


def level_shifts(u: np.ndarray, y: np.ndarray, *, valid: np.ndarray | None = None) -> LevelShifts:
    """The level shifts of ``y`` (module docstring).

    Parameters
    ----------
    u : (N, m) inputs (m may be 0); y : (N, p) outputs; valid : (N,) bool, False at missing
        samples (any value there), None: none missing.
    """
    n, p = y.shape
    present = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
    none = LevelShifts({}, {}, np.zeros(p))
    if n < 4 * SHIFT_WINDOW or p == 0:
        return none
    ratio_y = _shift_ratio(y, present)
    flagged = ratio_y > SHIFT_RATIO
    if not flagged.any():
        return none
    near = widened(flagged, SHIFT_WINDOW)
    every_output = near.sum(axis=1) >= p if p >= 2 else np.zeros(n, bool)
    excluded = every_output
    if u.shape[1]:
        inputs = _shift_ratio(u, present, local=False) > SHIFT_RATIO
        excluded = excluded | widened(inputs, SHIFT_WINDOW).any(axis=1)  # inputs flagged a window around theirs
    by_output, unusable = {}, {}
    for i in np.flatnonzero(flagged.any(axis=0)):
        peaks, _ = find_peaks(np.where(excluded, 0.0, ratio_y[:, i]), height=SHIFT_RATIO, distance=SHIFT_WINDOW)
        if not peaks.size:
            continue
        at = {_step_sample(y[:, i], present, k): k for k in peaks}  # the step's sample: its peak
        samples, peaks = np.array(sorted(at)), np.array([at[k] for k in sorted(at)])
        local = _mean_differences(y[:, [i]], present)[0][peaks, 0]
        stays = _stays(y[:, i], present, samples, local)
        samples, sizes = _held(y[:, i], present, samples[stays], local[stays])
        if samples.size > MAX_SHIFTS:
            unusable[int(i)] = samples
        elif samples.size:
            by_output[int(i)] = (samples, sizes)
    if not by_output and not unusable:
        return none
    kept = without_shifts(y, by_output, valid=valid)[present]
    peak = _peak(kept, np.ones(kept.shape[0], bool))
    spread = np.std(kept / peak, axis=0) * peak
    return LevelShifts(by_output, unusable, spread)


def without_shifts(y: np.ndarray, by_output: dict[int, tuple[np.ndarray, np.ndarray]], *,
                   valid: np.ndarray | None = None) -> np.ndarray:
    """``y`` (N, p) with each shift subtracted from its sample on (a new array; missing samples keep their values)."""
    out = np.array(y, dtype=float, copy=True)
    for i, (samples, sizes) in by_output.items():
        steps = np.zeros(y.shape[0])
        for k, size in zip(samples, sizes):
            steps[k:] += size
        out[:, i] -= steps if valid is None else np.where(valid, steps, 0.0)
    return out


def _mean_differences(x: np.ndarray, present: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``d`` (N, k): the mean of the window's samples present from ``k`` on less the mean of those before it.

    And (N,) bool, the samples where it is judged: present, a whole window on each side within
    the record, at least half of each window present (0 elsewhere).
    """
    n, w = x.shape[0], SHIFT_WINDOW
    peak = _peak(x, present)  # unit peaks: no running sum overflows near the float limits
    total = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(np.where(present[:, None], x / peak, 0.0), axis=0)])
    count = np.r_[0.0, np.cumsum(present)]
    sums, counts = total[w:] - total[:-w], (count[w:] - count[:-w])[:, None]  # window j: samples j .. j + w - 1
    with np.errstate(divide="ignore", invalid="ignore"):
        means = sums / counts
    d = np.zeros(x.shape)
    d[w : n - w + 1] = (means[w:] - means[:-w]) * peak
    usable = np.zeros(n, bool)
    usable[w : n - w + 1] = (counts[w:, 0] >= w / 2) & (counts[:-w, 0] >= w / 2) & present[w : n - w + 1]
    d[~usable] = 0.0
    return d, usable


def _shift_ratio(x: np.ndarray, present: np.ndarray, *, local: bool = True) -> np.ndarray:
    """``|d_k - median d|`` (:func:`_mean_differences`) over the robust spread of ``d`` (N, k), 0 where not judged.

    A channel whose ``d`` is mostly constant (a command held between steps: no spread) is 0
    everywhere as an output (``local``: nothing to judge by) and Inf at each change as an input
    (each is a step its response may follow).
    """
    d, usable = _mean_differences(x, present)
    if not usable.any():
        return np.zeros(x.shape)
    size = np.abs(d - np.median(d[usable], axis=0))
    scale = MAD_TO_STD * np.median(size[usable], axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        unscaled = 0.0 if local else np.where(size > 0, np.inf, 0.0)
        ratio = np.where(scale > 0, size / np.where(scale > 0, scale, 1.0), unscaled)
    ratio[~usable] = 0.0
    return ratio


def _peak(x: np.ndarray, present: np.ndarray) -> np.ndarray:
    """Each channel's largest magnitude over the samples present (1 for a channel of zeros): (k,)."""
    peak = column_peaks(np.where(present[:, None], x, 0.0)) if x.shape[0] else np.ones(x.shape[1])
    return np.where(np.isfinite(peak) & (peak > 0), peak, 1.0)


def _step_sample(x: np.ndarray, present: np.ndarray, peak: int) -> int:
    """The sample within half a window of ``peak`` where a step best explains ``x``'s AR prediction errors.

    A step ``s`` at ``k`` adds ``s g_(t-k)`` to the errors ``e = A(z) x`` of the channel's AR
    fit, ``g`` the AR filter's step response, and the channel's level adds a constant; over the
    rows within a window of the peak, the sample whose ``g`` (the constant projected out of both)
    explains most of ``e`` (``(g . e)^2 / g . g``) is the step's (the generalized likelihood ratio
    of a step in an AR signal of unknown level). The fit leaves out the rows that
    reach the peak's window, which the step would bias. A sample measured (``present``) is returned.
    """
    n, w, q = x.shape[0], SHIFT_WINDOW, _AR_ORDER
    index = np.flatnonzero(present)
    x = np.interp(np.arange(n), index, x[index] / _peak(x[index, None], present[index])[0])  # missing ones bridged
    rows = np.arange(q, n)
    lags = np.lib.stride_tricks.sliding_window_view(x, q + 1)[:, ::-1]  # row t - q: x_t, x_(t-1), ..., x_(t-q)
    usable = np.lib.stride_tricks.sliding_window_view(present, q + 1).all(axis=1)
    fit = usable & (np.abs(rows - peak) > 2 * w)
    if np.count_nonzero(fit) < 4 * q:
        return peak
    regressors = np.column_stack([lags[fit, 1:], np.ones(np.count_nonzero(fit))])
    coef = np.linalg.lstsq(regressors, lags[fit, 0], rcond=None)[0]
    # The level is fitted within the window, not taken from the fit's rows: near an end those all
    # lie on one side of the step, and a level from one side pulls the match to the search's edge.
    window = rows[np.abs(rows - peak) <= w]
    errors = lags[window - q, 0] - lags[window - q, 1:] @ coef[:-1]
    g = 1.0 - np.r_[0.0, np.cumsum(coef[:-1])]
    candidates = np.arange(max(peak - w // 2, q), min(peak + w // 2, n - 1) + 1)
    lag = window[None, :] - candidates[:, None]
    steps = np.where(lag >= 0, g[np.clip(lag, 0, q)], 0.0)  # (candidate, row): the step's errors
    steps -= steps.mean(axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        match = (steps @ (errors - errors.mean())) ** 2 / np.einsum("ij,ij->i", steps, steps)
    best = int(candidates[np.argmax(np.where(np.isfinite(match), match, -1.0))])
    # A step within missing samples is the same step at the first sample measured after them (the
    # record's values are changed there only), and is judged there: placed at the gap's start, near
    # an end its level before lacked the samples _stays needs and the step was missed.
    measured = index[index >= best]
    return int(measured[0]) if measured.size else best


def _stays(x: np.ndarray, present: np.ndarray, samples: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Whether the level of ``x`` (N,) after each of ``samples`` (K,, sorted) stays: (K,) bool.

    The median of the samples present from a window after the step to :data:`_HOLD` windows after
    it (or to a window before the next candidate) less that of the same span before it differs by
    at least :data:`PERSISTENCE` of the step's mean difference ``local`` (K,), with its sign: an
    impact's ringing, or a burst of any kind, returns to the level before (a pair of opposite steps).
    """
    w, n = SHIFT_WINDOW, x.shape[0]
    bounds = np.r_[-w, samples, n + w]  # a window from every candidate: its own transient
    stays = np.zeros(samples.size, bool)
    for j, k in enumerate(samples):
        before = np.arange(max(k - w - _HOLD * w, bounds[j] + w), k - w)
        after = np.arange(k + w, min(k + w + _HOLD * w, bounds[j + 2] - w))
        before, after = before[present[before]], after[present[after]]
        if min(before.size, after.size) >= w // 2:
            held = np.median(x[after]) - np.median(x[before])
            stays[j] = local[j] != 0 and held / local[j] >= PERSISTENCE
    return stays


def _held(x: np.ndarray, present: np.ndarray, samples: np.ndarray,
          local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``samples`` (K,, sorted) of ``x`` (N,) whose level holds to the next step, and their sizes.

    A step's level holds until the next step or the record's end: its size fitted over the whole
    channel (:func:`_step_sizes`) is at least :data:`PERSISTENCE` of its mean difference ``local``
    (K,), with its sign. A transient's ringing averages out over those spans whatever its phase next
    to the step (the spans :func:`_stays` judges are cut short by a neighbouring blow's own transient
    and may hold only its ringing). The sample that holds least is dropped and the rest fitted again.
    """
    while samples.size:
        sizes = _step_sizes(x, present, samples)
        held = np.where(local != 0, sizes / np.where(local != 0, local, 1.0), -np.inf)
        if held.min() >= PERSISTENCE:
            return samples, sizes
        keep = np.arange(samples.size) != np.argmin(held)
        samples, local = samples[keep], local[keep]
    return samples, np.zeros(0)


def _step_sizes(x: np.ndarray, present: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """The steps at ``samples`` of ``x`` (N,): a level, a line and the steps fitted to the samples present."""
    n, peak = x.shape[0], _peak(x[:, None], present)[0]
    t = np.arange(n, dtype=float)
    columns = [np.ones(n), (t - t.mean()) / n] + [(t >= k).astype(float) for k in samples]
    design = np.column_stack(columns)[present]
    return np.linalg.lstsq(design, x[present] / peak, rcond=None)[0][2:] * peak
