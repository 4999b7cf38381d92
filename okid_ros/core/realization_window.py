"""The samples of an ARX window that a realization runs on: node 2's rule, and ``okid-ros track``'s.

The newest run of the window without a long gap or a time restart; its short gaps filled by the
window's ARX prediction (:func:`.gap_fill.fill_short_gaps`); and, in an input-output window, the
output spikes ``identify`` leaves out of a record (:func:`.sensor_faults.spikes_left_out`) left
out of its samples and of its ARX fit, refitted without the rows that reach them, and filled by
that fit's prediction. A glitch (interference, a bit error) in the samples the realization's
passes read (state completion, refit, refinement) cost the paper structure's windows modes; the
fit must be of the samples they read: node 1's fit without the glitch (:mod:`.arx_glitches`)
realized over samples still holding it lost more than the glitch itself (docs/robustness.md).

No rclpy; numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.gap_fill import fill_short_gaps, fit_and_fill
from okid_ros.core.sensor_faults import spikes_left_out
from okid_ros.core.window_minimum import realization_minimum

__all__ = ["RealizationWindow", "newest_run_start", "realization_window", "run_breaks"]


@dataclass(frozen=True)
class RealizationWindow:
    """The samples of an ARX window that a realization runs on (:func:`realization_window`).

    Attributes
    ----------
    u : (N, m); y : (N, p) contiguous samples, short gaps filled.
    valid : (N,) bool, False at filled slots (gaps, spikes); None when nothing was filled.
    filled : slots filled by prediction.
    fit : the ARX fit to realize: the window's, or its refit without the spikes' rows.
    """

    u: np.ndarray
    y: np.ndarray
    valid: np.ndarray | None
    filled: int
    fit: ArxFit


def realization_window(u: np.ndarray, y: np.ndarray, skipped: np.ndarray, fit: ArxFit, *, max_gap: int,
                       need: int, center: bool = True, refit: bool = False,
                       next_sample: tuple[np.ndarray, np.ndarray] | None = None) -> RealizationWindow:
    """The newest run of an ARX window without a long gap or a time restart, short gaps and spikes filled.

    The one rule of node 2 and ``okid-ros track`` for a window with missing samples: a gap of
    more than ``max_gap`` slots (or a restart) ends what the realization can use, shorter ones are
    filled by :func:`.gap_fill.fill_short_gaps`; then an input-output window's large output spikes
    are filled too (the module docstring).

    Parameters
    ----------
    u : (N, m) received inputs; y : (N, p) received outputs, in time order.
    skipped : (N,) missing slots just before each sample (< 0: a time restart).
    fit : the window's ARX fit; max_gap : longest gap filled, in samples.
    need : the window's samples (rows plus the ARX order): at least ``max(4 q, need // 2)`` of
        them must remain.
    center : the refit without the spikes' rows has an intercept (node 2's ``offsets``: "remove").
    refit : the samples are not those ``fit`` was made of (node 2 took a sensor's re-zero off
        them, :mod:`okid_ros.service.watch`): refit the ARX model to them.
    next_sample : ``(u (m,), y (p,))`` of the sample after the window, when there is one
        (``track``): the spike rule judges the window's last sample by it, as any other.
        Without it a glitch there stays (node 2's windows end before node 1's held candidate).

    Raises
    ------
    ValueError with the reason when too much is missing.
    """
    skipped = np.asarray(skipped, dtype=np.int64)
    first = newest_run_start(skipped, max_gap=max_gap, order=fit.order, need=need)
    u, y, skipped = u[first:], y[first:], skipped[first:]
    valid = None
    filled = 0
    if np.any(skipped[1:]):
        try:
            u, y, valid = fill_short_gaps(u, y, skipped, fit)
        except ValueError as exc:
            raise ValueError(f"ARX window: {exc}") from None
        filled = int(np.count_nonzero(~valid))
    if u.shape[1]:  # output-only windows: named there, not left out (identify's rule)
        spiked = _spikes_left_out(u, y, valid, next_sample)
        if spiked is not valid and not spiked[-1]:  # a spike at the last sample: the window ends before it
            last = int(np.flatnonzero(spiked)[-1]) + 1
            u, y, spiked, refit = u[:last], y[:last], (None if spiked[:last].all() else spiked[:last]), True
        if spiked is not valid or refit:
            # The fit to realize leaves their rows out too: the realization's passes over the samples
            # must see the data the ARX model was fitted to (a fit holding a glitch realized over a
            # window without it lost more modes than the glitch itself).
            fit, u, y, valid = fit_and_fill(u, y, spiked, fit.order, None, regularization=fit.regularization,
                                            center=center)
            filled = 0 if valid is None else int(np.count_nonzero(~valid))
    _check_run(u.shape[0], max_gap=max_gap, order=fit.order, need=need)
    return RealizationWindow(u, y, valid, filled, fit)


def newest_run_start(skipped: np.ndarray, *, max_gap: int, order: int, need: int) -> int:
    """Index of the first sample of a window's newest run without a long gap or a time restart.

    What :func:`realization_window` keeps, found cheaply: node 2 refuses a window on its
    sample path by this and leaves the filling to the realization's worker.

    Parameters
    ----------
    skipped : (N,) missing slots just before each sample (< 0: a time restart).
    max_gap : longest gap filled, in samples; order : the ARX order; need : the window's samples.

    Raises
    ------
    ValueError when fewer than :func:`realization_minimum` samples follow the run's start.
    """
    skipped = np.asarray(skipped, dtype=np.int64)
    breaks = run_breaks(skipped, max_gap)
    first = int(breaks[-1]) if breaks.size else 0
    _check_run(skipped.size - first, max_gap=max_gap, order=order, need=need)
    return first


def run_breaks(skipped: np.ndarray, max_gap: int) -> np.ndarray:
    """Indices of the samples after a gap longer than ``max_gap`` or a restart in ``skipped`` (N,), the first not."""
    skipped = np.asarray(skipped, dtype=np.int64)
    return np.flatnonzero((skipped[1:] < 0) | (skipped[1:] > max_gap)) + 1


def _check_run(samples: int, *, max_gap: int, order: int, need: int) -> None:
    """ValueError if ``samples`` are fewer than a realization needs of the window (:func:`realization_minimum`)."""
    minimum = realization_minimum(order, need)
    if samples < minimum:
        raise ValueError(f"{samples} samples of the ARX window of {need} follow its last gap longer than "
                         f"{max_gap} samples; the realization needs at least {minimum}")


def _spikes_left_out(u: np.ndarray, y: np.ndarray, valid: np.ndarray | None,
                     next_sample: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray | None:
    """:func:`.sensor_faults.spikes_left_out` of the window, its last sample judged by ``next_sample`` if given."""
    if next_sample is None:
        return spikes_left_out(u, y, valid)
    n = u.shape[0]
    judged = None if valid is None else np.r_[valid, True]
    spiked = spikes_left_out(np.vstack([u, next_sample[0]]), np.vstack([y, next_sample[1]]), judged)
    if spiked is judged or spiked[:n].all():
        return valid
    return spiked[:n]
