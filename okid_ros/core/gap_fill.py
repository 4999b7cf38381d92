"""Short gaps of a window filled by its ARX model's prediction, for the realization.

A sensor stream over a best-effort transport loses a sample now and then: with 2 % of the
samples lost at random, a window of 1000 holds no contiguous run of more than a couple of
hundred samples, and a realization that needs contiguous samples gets none. The ARX fit of the
window (node 1 leaves out the regressor rows that span a gap) is valid; only the realization's
passes over the samples (state completion, refinement, warm start) need them in sequence.

:func:`fill_short_gaps` puts each missing slot back: the input interpolated linearly between
its neighbours (the inputs are measured signals, smooth at the sample rate of a structure's
test), the output predicted one step ahead by the window's own ARX model from the (filled) past
(the least-squares estimate of the output given the past; it lacks that sample's innovation).
The filled slots are marked not valid: the realization's Gram of past data (the ERA weighting
and the state regressions) leaves out every row that reaches them. At most
:data:`MAX_FILLED_FRACTION` of a window is filled; a window with more missing is refused.

No rclpy; numpy only. (No library fills gaps with the prediction of an ARX model given as
``theta``; ``np.interp`` does the inputs.)
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.arx import ArxFit, fit_from_normal_equations
from okid_ros.core.arx_gram import arx_normal_equations
from okid_ros.core.options import MAX_GAP_SAMPLES
from okid_ros.core.regressors import real_array, regressor_at

__all__ = ["MAX_FILLED_FRACTION", "MAX_GAP_SAMPLES", "fill_missing", "fill_short_gaps", "fit_and_fill",
           "fill_missing_outputs", "mark_missing", "missing_mask", "missing_problem", "OUTPUT_ONLY_VAR_ORDER"]

#: Largest fraction of a window's samples that may be filled: beyond it the realization would
#: fit the ARX model's predictions more than the data.
MAX_FILLED_FRACTION = 0.1
#: Order of the vector autoregression that frames an output-only window (``track --order auto``
#: without an input) and fills an output-only record's gaps: its model comes from the output
#: correlations, the VAR only predicts a sample or a few, so it stays small.
OUTPUT_ONLY_VAR_ORDER = 10


def fill_short_gaps(u: np.ndarray, y: np.ndarray, skipped: np.ndarray,
                    fit: ArxFit) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The window with its missing samples filled, and which samples are measured.

    Parameters
    ----------
    u : (N, m) received inputs; y : (N, p) received outputs, in time order.
    skipped : (N,) missing slots just before each received sample (>= 0; the first entry is
        ignored: the window starts at a received sample).
    fit : the window's ARX fit (order q, ``theta`` (m + q (p + m), p), in the samples' units).

    Returns
    -------
    u_full : (N + S, m); y_full : (N + S, p) with the S missing slots filled.
    valid : (N + S,) bool, False at the filled slots.

    Raises
    ------
    ValueError if a gap is negative or more than :data:`MAX_FILLED_FRACTION` of the window
    would be filled.
    """
    u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
    gaps = np.asarray(skipped, dtype=np.int64).copy()
    gaps[:1] = 0
    if np.any(gaps < 0):
        raise ValueError("a gap in the window is a time restart, not missing samples")
    n_missing = int(gaps.sum())
    total = u.shape[0] + n_missing
    if n_missing > MAX_FILLED_FRACTION * total:
        raise ValueError(f"{n_missing} of the window's {total} samples are missing; at most "
                         f"{MAX_FILLED_FRACTION:.0%} are filled by prediction")
    position = np.arange(u.shape[0]) + np.cumsum(gaps)  # each received sample's slot
    valid = np.zeros(total, dtype=bool)
    valid[position] = True
    m, p, q = u.shape[1], y.shape[1], fit.order
    u_full = np.empty((total, m))
    for channel in range(m):
        u_full[:, channel] = np.interp(np.arange(total), position, u[:, channel])
    # The prediction on the window's centred signals: the fit may or may not carry an intercept.
    u_mean, y_mean = u.mean(axis=0), y.mean(axis=0)
    y_full = np.empty((total, p))
    y_full[position] = y - y_mean
    uc = u_full - u_mean
    theta = fit.theta
    for k in np.flatnonzero(~valid):
        if k < q:
            y_full[k] = y_full[k - 1]  # too early for a regressor: the last output held
            continue
        y_full[k] = regressor_at(uc, y_full, k, q) @ theta
    y_full += y_mean
    y_full[position] = y  # the measured samples exactly as measured
    return u_full, y_full, valid


def missing_mask(valid, n_samples: int) -> np.ndarray | None:
    """``valid`` as a bool mask of ``n_samples`` samples, None when none is missing.

    Raises
    ------
    ValueError if ``valid`` is not one flag per sample, or ``u`` or ``y`` not real numbers.
    """
    valid = np.asarray(valid, dtype=bool)
    if valid.shape != (n_samples,):
        raise ValueError(f"valid must hold one flag per sample: shape {valid.shape} for {n_samples} samples")
    return None if valid.all() else valid


def mark_missing(u: np.ndarray, y: np.ndarray, valid) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A record whose missing samples (``valid`` False) hold 0 instead of whatever they held (NaN).

    Parameters
    ----------
    u : (N, m) or (N,); y : (N, p) or (N,) the record; valid : (N,) bool, False at missing samples.

    Returns
    -------
    u, y as float arrays with 0 at the missing samples; valid as a bool array, None when no
    sample is missing.

    Raises
    ------
    ValueError if ``valid`` is not one flag per sample, or ``u`` or ``y`` not real numbers.
    """
    u, y = real_array("u", u), real_array("y", y)
    lengths = {np.shape(a)[0] if np.ndim(a) else -1 for a in (u, y)}
    if len(lengths) != 1:
        raise ValueError(f"valid must hold one flag per sample: u{u.shape} and y{y.shape} differ in length")
    valid = missing_mask(valid, lengths.pop())
    if valid is None:
        return u, y, None
    return (np.where(valid.reshape((-1,) + (1,) * (u.ndim - 1)), u, 0.0),
            np.where(valid.reshape((-1,) + (1,) * (y.ndim - 1)), y, 0.0), valid)


def missing_problem(valid: np.ndarray, *, max_gap: int = MAX_GAP_SAMPLES) -> str:
    """Why the missing samples of a record (``valid`` (N,) False) cannot be filled ("" if they can).

    Filled: runs of at most ``max_gap`` missing samples, at most :data:`MAX_FILLED_FRACTION` of
    the record, its first and last sample measured.
    """
    present = np.flatnonzero(valid)
    if present.size < 2 or present[0] != 0 or present[-1] != valid.size - 1:
        return "a record with missing samples must start and end with a measured one"
    skipped = np.diff(present, prepend=0) - 1
    if skipped.max() > max_gap:
        return (f"{int(skipped.max())} samples are missing in a row before sample {int(present[np.argmax(skipped)])}; "
                f"at most {max_gap} are filled by prediction: identify the part before or after that gap")
    if valid.size - present.size > MAX_FILLED_FRACTION * valid.size:
        return (f"{valid.size - present.size} of the {valid.size} samples are missing; at most "
                f"{MAX_FILLED_FRACTION:.0%} are filled by prediction")
    return ""


def fill_missing(u: np.ndarray, y: np.ndarray, valid: np.ndarray, fit: ArxFit, *,
                 max_gap: int = MAX_GAP_SAMPLES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`fill_short_gaps` for a whole record whose missing samples ``valid`` marks.

    Parameters
    ----------
    u : (N, m); y : (N, p) the record (any values at the missing samples); valid : (N,) bool;
    fit : its ARX fit (rows reaching a missing sample left out); max_gap : as :func:`missing_problem`.

    Returns
    -------
    u, y : (N, m), (N, p) with the missing samples filled; valid : (N,) as given.

    Raises
    ------
    ValueError with :func:`missing_problem`'s reason.
    """
    if problem := missing_problem(valid, max_gap=max_gap):
        raise ValueError(problem)
    present = np.flatnonzero(valid)
    u_full, y_full, _ = fill_short_gaps(u[present], y[present], np.diff(present, prepend=0) - 1, fit)
    return u_full, y_full, valid


def fill_missing_outputs(y: np.ndarray, valid: np.ndarray, *, order: int = OUTPUT_ONLY_VAR_ORDER) -> np.ndarray:
    """An output-only record with its missing samples filled, as node 2 fills its window.

    The prediction of a vector autoregression of ``order`` (ridge, with an intercept) fitted on
    the record's rows that reach no missing sample (:func:`fill_missing`).

    Parameters
    ----------
    y : (N, p) outputs (any values at the missing samples); valid : (N,) bool, False at them.

    Returns
    -------
    (N, p) outputs with the missing samples filled.

    Raises
    ------
    ValueError as :func:`missing_problem`, or when too few rows remain for the VAR.
    """
    u, y, valid = mark_missing(np.zeros((np.shape(y)[0], 0)), y, valid)
    if valid is None:
        return y
    if problem := missing_problem(valid):
        raise ValueError(problem)
    p = y.shape[1]
    fit = fit_from_normal_equations(arx_normal_equations(u, y, order, valid), order, p, 0, center=True)
    return fill_missing(u, y, valid, fit)[1]


def fit_and_fill(u: np.ndarray, y: np.ndarray, valid: np.ndarray | None, order: int, normal, *, regularization: str,
                 center: bool) -> tuple[ArxFit, np.ndarray, np.ndarray, np.ndarray | None]:
    """The ARX fit of ``order`` and the record with its missing samples filled by it (:func:`fill_missing`).

    ``normal``: the order's normal equations when already formed (None: formed here); ``valid``
    None: no sample missing (the record is returned as it is). Raises ValueError when the fit fails.
    """
    if normal is None:
        normal = arx_normal_equations(u, y, order, valid)
    arx = fit_from_normal_equations(normal, order, y.shape[1], u.shape[1], regularization, center=center)
    return (arx, *fill_missing(u, y, valid, arx)) if valid is not None else (arx, u, y, None)
