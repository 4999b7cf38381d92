"""What a record's sensors did besides measuring the structure: drift, level shifts, spikes, clipping, dropouts.

Faults of real records that the identification cannot tell from dynamics (an output that drops
out alone, holding one value while the others respond, is named by :func:`held_channel_warnings`):

- **Drift**, a slow trend of a channel (a sensor warming up, a charge amplifier's leak, an
  integrated signal). A straight line is a double pole at z = 1: the realization puts poles on
  or beyond the unit circle at every order, and a trend holding 8-20 % of an output's variance
  left the published model of the paper's structure without a single mode (3750 samples, two
  seeds of three). The least-squares line of a channel is removed when it holds at least
  :data:`TREND_SHARE` of the channel's variance, with a warning; the channel's mean is kept, so
  the offsets the model keeps are the record's means as before. Stationary records stay well
  below the share (measured at most 0.05 % on the steel subframe, the koma frame and the
  simulated benchmark records); a pure sine over ``k`` periods reaches 2 % only for ``k < 5``
  (its line then holds up to 0.024 at ``k = 5``, 0.006 at ``k = 10``), a record too short for
  its slowest mode anyway.
- **Level shifts**, one output's level stepping at one sample and staying (a sensor re-zeroed, an
  amplifier's range switched): :mod:`.level_shifts` finds them on the raw values, before the
  spikes (a large step's two edge samples look like spikes) and the trend (a step is no line);
  ``record_faults`` subtracts each from its sample on (the level before kept) when it removes
  the trends (``detrend``), and names it in any case.
- **Spikes**, single samples of an output far beyond their neighbours (interference, a bit error):
  :mod:`.output_spikes` finds them; ``record_faults(leave_out_spikes=True)`` (``identify``) marks
  those of :data:`SPIKE_LEAVE_OUT_SPREADS` or more missing, filled by prediction as a record's
  gaps are, where the gaps allow; the others are named and kept.
- **Clipping**, a channel held at the end of its range (a sensor or recorder saturating): the
  flat tops are a nonlinearity whose harmonics the linear model lists as modes (an output of
  the paper's structure clipped at 80 % of its peak, 3 % of its samples: two spurious modes
  at 18.1 and 29.7 Hz). It is named in a warning. Leaving the clipped samples out as missing
  (filled by prediction as a record's gaps are) was measured and not adopted: it took the
  spurious modes out of the paper's structure, and every mode out of the steel subframe with
  7 of its 28 outputs clipped at 70 % (5 % of the samples missing, most ARX rows lost;
  docs/robustness.md).

:func:`record_faults` names the faults and takes out what it can; :func:`record_fault_warnings`
names them by the same rules and changes nothing (``okid-ros track``, whose windows are the
record as node 1 sees it live).

``scipy.signal.detrend`` removes a line too, but neither keeps the mean nor fits only the
samples present; the least-squares line is two sums per channel.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.excitation import frozen_output_warnings, longest_held_run
from okid_ros.core.gap_fill import mark_missing, missing_problem
from okid_ros.core.level_shifts import MAX_SHIFTS, level_shifts, without_shifts
from okid_ros.core.output_only_harmonics import without_harmonics
from okid_ros.core.output_spikes import most_spikes, output_spikes, spike_spreads

__all__ = ["TREND_SHARE", "clipped_samples", "held_channel_warnings", "record_fault_warnings", "record_faults",
           "remove_trends", "spikes_left_out"]

#: A channel's least-squares line is removed (and named) when it holds this share of its variance.
TREND_SHARE = 0.02
#: A channel is clipped when one of its extreme values holds at least this share of the samples
#: (and :data:`CLIP_MIN_SAMPLES`) ...
CLIP_SHARE = 0.001
CLIP_MIN_SAMPLES = 5
#: ... in at least this many separate runs (a slow signal's quantized peak dwells in one run) ...
CLIP_MIN_RUNS = 3
#: ... this many times as often as the next value inward (a quantized smooth tail thins out), in a
#: channel of at least this many distinct values (a two-level test signal sits at its extremes).
CLIP_PILE_UP = 5.0
CLIP_MIN_LEVELS = 16


def record_faults(u: np.ndarray, y: np.ndarray, *, valid: np.ndarray | None = None, detrend: bool = True,
                  sample_time_s: float | None = None, leave_out_spikes: bool = False
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[str]]:
    """A record's faults named and, where the chain can, taken out: ``(u, y, valid, warnings)``.

    In this order (each judged on what the one before leaves): stalled samples named, on the raw
    values; output level shifts (:mod:`.level_shifts`) removed (``detrend``) or only named (the
    faults after them judged without them, but clipping); output spikes (:mod:`.output_spikes`)
    named, and with ``leave_out_spikes`` marked missing (``valid`` False, 0 in ``u`` and ``y``)
    when the record's gaps can take them (:func:`.gap_fill.missing_problem`); clipped channels
    named, on the raw values (a removed step, trend or sinusoid would move or tilt the flat tops);
    trends removed (``detrend``) or only named, fitted without the clipped samples; with
    ``sample_time_s``, the outputs' harmonic lines that the inputs do not hold removed, fitted to
    the samples present
    (:func:`.output_only_harmonics.without_harmonics`).

    Parameters
    ----------
    u : (N, m); y : (N, p) the record, 0 at missing samples; valid : (N,) bool or None (none missing).
    """
    return _faults(u, y, valid=valid, detrend=detrend, sample_time_s=sample_time_s, kept=False,
                   leave_out_spikes=leave_out_spikes)


def record_fault_warnings(u: np.ndarray, y: np.ndarray, *, valid: np.ndarray | None = None,
                          sample_time_s: float | None = None) -> list[str]:
    """The faults :func:`record_faults` names, named only: for a record fitted as recorded (``okid-ros track``).

    The same rules, judged on the same values in the same order; the warnings say that the
    record keeps what ``identify`` takes out (its trends, its harmonic lines). ``u`` and ``y``
    are not changed.

    Parameters
    ----------
    u : (N, m); y : (N, p) the record, any value (NaN) at missing samples.
    valid : (N,) bool, False at missing samples; None: none missing.
    sample_time_s : sample time (s), for the harmonic lines; None: they are not looked for.
    """
    if valid is not None:  # record_faults takes 0 at the missing samples (new arrays: the record stays)
        u, y = np.where(valid[:, None], u, 0.0), np.where(valid[:, None], y, 0.0)
        valid = None if valid.all() else valid
    return _faults(u, y, valid=valid, detrend=True, sample_time_s=sample_time_s, kept=True,
                   leave_out_spikes=False)[3]


#: What a fault :func:`record_fault_warnings` names does to a record fitted as recorded.
_KEPT_TREND = ("NOT removed: track fits its windows as recorded, as node 1 sees them live (`okid-ros identify` "
               "removes it); it may hide the windows' modes")
_KEPT_HARMONICS = ("kept: track fits its windows as recorded, as node 1 sees them live (`okid-ros identify` "
                   "removes it); the windows' models may list it as a mode")


def _faults(u: np.ndarray, y: np.ndarray, *, valid: np.ndarray | None, detrend: bool, sample_time_s: float | None,
            kept: bool, leave_out_spikes: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[str]]:
    """:func:`record_faults`; ``kept``: only named, in the words of :func:`record_fault_warnings`."""
    # A gap is no held value: NaN never repeats (the record's 0 there would read as one).
    held = y if valid is None else np.where(valid[:, None], y, np.nan)
    warnings = frozen_output_warnings(held) + held_channel_warnings(held)
    # Before the spikes: a large step's two edge samples look like spikes, its size like a drift. The
    # faults after are judged without the steps; the raw signals (not detrend) get them back at the end.
    raw = y
    y, shift_warnings = _shifts(u, y, valid, remove=detrend, kept=kept, sample_time_s=sample_time_s)
    steps = raw - y if not (detrend or kept or y is raw) else None
    warnings += shift_warnings
    spiked, spike_warnings = _spikes(u, y, valid, leave_out=leave_out_spikes, kept=kept)
    if spiked is not valid:
        u, y, valid = mark_missing(u, y, spiked)
    warnings += spike_warnings
    u_clipped, u_named = clipped_samples(u, "input", valid=valid)
    y_clipped, y_named = clipped_samples(raw, "output", valid=valid)  # the samples marked missing are left out
    clipped = u_clipped | y_clipped
    present = valid if not clipped.any() else (np.ones(y.shape[0], dtype=bool) if valid is None else valid) & ~clipped
    # Kept trends are still taken out of the copies the harmonic lines are looked for in, as identify does.
    action = _KEPT_TREND if kept else None
    u, u_trends = remove_trends(u, "input", valid=present, remove=detrend, action=action)
    y, y_trends = remove_trends(y, "output", valid=present, remove=detrend, action=action)
    harmonics = []
    if sample_time_s is not None:
        y, harmonics = without_harmonics(y, sample_time_s, u=u, remove=not kept, valid=valid)
        harmonics = [f"{text}; {_KEPT_HARMONICS}" for text in harmonics] if kept else harmonics
    if steps is not None:  # not at the samples missing (0 there), the spikes left out among them
        y = y + (steps if valid is None else np.where(valid[:, None], steps, 0.0))
    model = "the windows' models" if kept else "the model"
    named = [f"{text}; {model} may list spurious modes from it" for text in u_named + y_named]
    return u, y, valid, warnings + named + u_trends + y_trends + harmonics


def _shifts(u: np.ndarray, y: np.ndarray, valid: np.ndarray | None, *, remove: bool, kept: bool,
            sample_time_s: float | None) -> tuple[np.ndarray, list[str]]:
    """``y`` with its outputs' level shifts (:mod:`.level_shifts`) removed, and a warning per output.

    ``remove`` and ``kept`` choose only what the warnings say is done (the caller keeps the raw values).
    """
    shifts = level_shifts(u, y, valid=valid)
    if kept:
        action = ("NOT removed: track fits its windows as recorded, as node 1 sees them live (`okid-ros identify` "
                  "removes it), until its change test finds the step and takes it off from there, as node 2 does; "
                  "the windows holding it may hide the modes")
    elif remove:
        action = "removed from that sample on before identification, the level before kept"
    else:
        action = "NOT removed (offsets='none'): it may hide the modes"
    warnings = []
    for i, (samples, sizes) in shifts.by_output.items():
        steps = ", ".join(f"at sample {k}" + (f" ({k * sample_time_s:.6g} s)" if sample_time_s else "")
                          + f" by {size / shifts.spread[i]:+.1f} standard deviations ({size:+.4g})"
                          for k, size in zip(samples, sizes))
        warnings.append(f"output {i} changes level {steps}: a sensor re-zeroed or its range switched? (no input and "
                        f"not every output steps with it); {action}")
    for i, samples in shifts.unusable.items():
        listed = _listed(samples)
        warnings.append(f"output {i} changes level at {samples.size} samples ({listed}): more than {MAX_SHIFTS} level "
                        f"shifts, a loose contact or an unusable channel? kept as recorded; leave it out")
    return (without_shifts(y, shifts.by_output, valid=valid) if shifts.by_output else y), warnings


_KEPT_SPIKES = ("judged as the nodes judge them live: a glitch in some outputs goes into track's windows as the last "
                "fit's prediction (node 1's gate), the realization leaves large spikes out (node 2's rule), others are "
                "kept (`okid-ros identify` leaves them out); the windows holding those may list spurious modes")


#: A spike is left out (``leave_out_spikes``) when it lies this many of its channel's standard
#: deviations from its neighbours or more: a smaller one weighs less in the least squares than the
#: ARX rows leaving it out costs (each missing sample takes the q + 1 rows that reach it). On
#: DaISy's winding record one glitch of 4 spreads left out made the held-out one-step prediction
#: 1-2 % worse; the glitches of bench/record_faults.py (30 spreads) cost modes when kept.
SPIKE_LEAVE_OUT_SPREADS = 8.0


def spikes_left_out(u: np.ndarray, y: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray | None:
    """``valid`` (N,) with the output spikes ``identify`` leaves out marked missing; ``valid`` itself if none.

    The rule of ``record_faults(leave_out_spikes=True)``: spikes of :data:`SPIKE_LEAVE_OUT_SPREADS`
    or more, unless the record is heavy-tailed or the gaps cannot take them. Node 2 and ``track``
    apply it to each realization's window (:func:`okid_ros.core.realization_window.realization_window`).
    """
    return _spikes(u, y, valid, leave_out=True, kept=False)[0]


def _spikes(u: np.ndarray, y: np.ndarray, valid: np.ndarray | None, *, leave_out: bool, kept: bool
            ) -> tuple[np.ndarray | None, list[str]]:
    """The record's output spikes named; ``leave_out``: ``valid`` with the large ones missing where the gaps allow."""
    spikes, by_output = output_spikes(u, y, valid=valid)
    if not by_output:
        return valid, []
    n = y.shape[0]
    large = {i: samples[spike_spreads(y[:, i], samples, valid=valid) >= SPIKE_LEAVE_OUT_SPREADS]
             for i, samples in by_output.items()}
    left_out = np.ones(n, bool) if valid is None else valid.copy()
    for samples in large.values():
        left_out[samples] = False
    count = int(spikes.sum())
    small = (f"kept: within {SPIKE_LEAVE_OUT_SPREADS:g} standard deviations of the channel, such a sample weighs "
             f"less than the ARX rows leaving it out costs")
    if count > most_spikes(n):
        action, leave = (f"kept: {count} such samples ({100 * count / n:.1f} % of the record) are a heavy-tailed "
                         f"signal rather than glitches"), False
    elif not leave_out:
        action, leave = (_KEPT_SPIKES if kept else "kept; the model may list spurious modes from them"), False
    elif not any(samples.size for samples in large.values()):
        action, leave = small, False
    elif problem := missing_problem(left_out):
        action, leave = f"kept, as they cannot be filled: {problem}", False
    else:
        action, leave = "left out as missing samples, filled by the model's prediction as a record's gaps are", True
    warnings = []
    for i, samples in by_output.items():
        parts = [(large[i], action), (np.setdiff1d(samples, large[i]), small)] if leave else [(samples, action)]
        for chosen, said in parts:
            if chosen.size:
                listed = _listed(chosen)
                warnings.append(f"output {i} jumps far beyond its neighbours at {chosen.size} sample(s) ({listed}): a "
                                f"spike or glitch, not the structure's response; {said}")
    return (left_out if leave else valid), warnings


def held_channel_warnings(y: np.ndarray) -> list[str]:
    """A warning per output that alone holds one value over a long run (a sensor that dropped out).

    The run counts as :func:`~okid_ros.core.excitation.frozen_output_warnings` counts one of
    every output (:func:`~okid_ros.core.excitation.longest_held_run`), which names the runs all
    outputs hold; a sensor's own noise changes its reading from one sample to the next. Inputs
    are left alone: a command may hold its value (a step, a slow pseudo-random sequence).
    """
    n = y.shape[0]
    if n < 2 or y.shape[1] < 2:  # one output held is the record held: frozen_output_warnings says it
        return []
    repeats = y[1:] == y[:-1]  # (N - 1, p)
    every = np.all(repeats, axis=1)
    warnings = []
    for i in range(y.shape[1]):
        run = longest_held_run(repeats[:, i])
        if run is None or np.all(every[run[0] : run[1]]):
            continue
        first, last = run
        held = last - first + 1
        warnings.append(f"output {i} holds the value {y[first, i]:.6g} over samples {first}-{last} "
                        f"({100 * held / n:.0f} % of the record) while the others respond: a sensor that dropped "
                        f"out? Those samples are identified as measured; cut them out or leave the channel out")
    return warnings


def remove_trends(x: np.ndarray, name: str, *, valid: np.ndarray | None = None, remove: bool = True,
                  action: str | None = None) -> tuple[np.ndarray, list[str]]:
    """``x`` less the straight-line trend of each channel that holds :data:`TREND_SHARE` of it.

    Parameters
    ----------
    x : (N, k) a record's channels (finite where ``valid``).
    name : "input" or "output", for the warnings.
    valid : (N,) bool, False at missing samples: the lines are fitted to the others, and the
        missing samples keep their values.
    remove : False: the trends are only named (the raw signals were asked for).
    action : what the warnings say is done about a trend; None: what ``remove`` does.

    Returns
    -------
    The channels (a new array when a trend is removed, else ``x``), with each channel's mean
    over the samples present unchanged, and one warning per channel whose trend was found.
    """
    rows = np.arange(x.shape[0]) if valid is None else np.flatnonzero(valid)
    if rows.size < 3 or x.shape[1] == 0:
        return x, []
    t = rows - rows.mean()
    # Channels as contiguous rows (the reductions along a record's columns are strided, 3x slower).
    present = np.ascontiguousarray((x if valid is None else x[rows]).T)
    peak = np.max(np.abs(present), axis=1)
    peak = np.where(peak > 0, peak, 1.0)  # unit peaks: no sum overflows or underflows near the float limits
    centred = present / peak[:, None]
    centred -= centred.mean(axis=1, keepdims=True)
    slope = (centred @ t) / (t @ t)
    power = np.einsum("ij,ij->i", centred, centred)
    share = np.divide(slope**2 * (t @ t), power, out=np.zeros_like(power), where=power > 0)
    trending = np.flatnonzero(share >= TREND_SHARE)
    if trending.size == 0:
        return x, []
    if action is None:
        action = ("removed before identification, the model keeps the channel's mean as its offset" if remove
                  else "NOT removed (offsets='none'): it may hide the modes")
    change = slope * (rows[-1] - rows[0])  # over the record, in units of the peak
    warnings = [f"{name} {i} drifts: a straight line {'rising' if change[i] > 0 else 'falling'} by "
                f"{abs(change[i]) * peak[i]:.4g} over the record holds {100 * share[i]:.0f} % of its variance "
                f"(a drifting sensor?); {action}"
                for i in trending]
    if not remove:
        return x, warnings
    out = np.array(x, dtype=float, copy=True)
    out[np.ix_(rows, trending)] -= np.outer(t, slope[trending]) * peak[trending]
    return out, warnings


def clipped_samples(x: np.ndarray, name: str, *, valid: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """The samples at which a channel of ``x`` (N, k) is held at an end of its range, and a description per channel.

    The test (module docstring): one of the channel's extreme values holds at least
    :data:`CLIP_SHARE` of the samples present and :data:`CLIP_MIN_SAMPLES`, in at least
    :data:`CLIP_MIN_RUNS` runs, :data:`CLIP_PILE_UP` times as many as the next value inward,
    in a channel of at least :data:`CLIP_MIN_LEVELS` distinct values.

    Returns
    -------
    (N,) bool, True where a clipped channel sits at its clipped value (missing samples never);
    ``"output 0 is clipped (...): 1.5 % of its samples sit at its largest value 57.6 (23 times)"``
    per clipped channel, without what is done about it.
    """
    rows = np.arange(x.shape[0]) if valid is None else np.flatnonzero(valid)
    clipped = np.zeros(x.shape[0], dtype=bool)
    n = rows.size
    if n == 0:
        return clipped, []
    least = max(CLIP_MIN_SAMPLES, CLIP_SHARE * n)
    described = []
    for i in range(x.shape[1]):
        column = x[rows, i]
        ends = [(end, column == end) for end in (column.max(), column.min())]
        if all(np.count_nonzero(at) < least for _, at in ends):  # the common case: one pass, no sort
            continue
        levels, counts = np.unique(column, return_counts=True)
        if levels.size < CLIP_MIN_LEVELS:
            continue
        held_ends = []
        for (end, at), inward, side in zip(ends, (counts[-2], counts[1]), ("largest", "smallest")):
            held = np.count_nonzero(at)
            runs = np.count_nonzero(np.diff(at.astype(np.int8), prepend=0) == 1)
            if held >= least and runs >= CLIP_MIN_RUNS and held >= CLIP_PILE_UP * inward:
                clipped[rows[at]] = True
                held_ends.append(f"{100 * held / n:.1f} % of its samples sit at its {side} value {end:.6g} "
                                 f"({runs} times)")
        if held_ends:
            described.append(f"{name} {i} is clipped (a sensor's or recorder's range exceeded?): "
                             f"{' and '.join(held_ends)}")
    return clipped, described


def _listed(samples: np.ndarray) -> str:
    """The first five of ``samples`` (K,) for a warning, "..." after them."""
    return ", ".join(str(int(k)) for k in samples[:5]) + (", ..." if samples.size > 5 else "")
