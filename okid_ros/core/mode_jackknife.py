"""Standard deviations of the modes by a delete-one-segment jackknife of the realization.

Where the prediction-error covariance of :mod:`okid_ros.core.uncertainty` is out of reach (tens
of outputs: the predictor has thousands of parameters, and its information matrix would take
``1e11`` flops and more), the scatter of each mode is measured by the jackknife instead: the
window is cut into ``S`` segments of consecutive rows, and the realization is repeated ``S``
times, each time without one segment. No replicate passes over the data again: the ARX normal
equations and the Gram of the ERA's past data (:class:`~okid_ros.core.state_gram.StateGram`)
are sums over the rows (:mod:`okid_ros.core.arx_gram`), so each replicate's are the window's
less the segment's. A replicate is

1. the ARX coefficients of the replicate's normal equations (intercept, and the window fit's
   penalty scaled to the replicate's rows), applied as a change to the window's own ARX model
   (whatever fitted it: the order search, node 1's recursive window);
2. the weighted ERA of its observer Markov parameters at the model's order, with the weighting of
   the replicate's past data, and the state-equation regression of its Gram (the screening step
   of :mod:`okid_ros.core.order_search`);
3. for each mode of the model, the replicate's pole nearest it (log distance).

The jackknife variance is ``(S - 1) / S sum_j (theta_j - mean)^2``. The re-estimation passes
of the completion (and a refit or refinement) are not repeated, but they move the poles: the
move from the window's own state regression to the model's pole, one draw of that further
scatter, is added to each variance; so is the bias of the ARX fit's penalty, which every
replicate shares (the same regression's move when the fit is taken one more Tikhonov step on,
:func:`_penalty_bias`). Calibration on simulated truth with 16 outputs
(``bench/mode_uncertainty.py --cases many-outputs``), on the steel subframe's halves, and the
cost: docs/benchmarks-uncertainty.md.
The delete-a-group jackknife follows Efron & Tibshirani (1993), ch. 11; its use for modal
parameters of subspace identification (segments of the record) follows Reynders, Pintelon &
De Roeck (2008).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import linalg

from okid_ros.core.arx import ArxFit
from okid_ros.core.arx_gram import lagged_gram, segment_lagged_gram
from okid_ros.core.era import block_hankel, decompose_hankel
from okid_ros.core.least_squares import (
    NormalEquations,
    center_normal_equations,
    channel_mean_square,
    prior_precision,
    solve_normal_equations,
)
from okid_ros.core.regressors import valid_regressor_rows
from okid_ros.core.state_gram import StateGram
from okid_ros.core.uncertainty import UncertaintyResult

__all__ = ["attach_jackknife_std", "nearest_modes", "nearest_poles", "jackknife_std", "stands_out",
           "realization_jackknife"]

#: Fewest rows a segment must hold (fewer segments otherwise).
MIN_SEGMENT_ROWS = 100
#: Block power iterations from the window's leading subspace to a replicate's, and the spare
#: columns they carry beyond the model's order.
ITERATIONS = 2
SPARE_COLUMNS = 10


def nearest_poles(eigenvalues: np.ndarray, targets: np.ndarray, sample_time_s: float) -> np.ndarray:
    """Index of the eigenvalue nearest each target (distance of ``ln z``), of those in the upper half plane.

    Parameters
    ----------
    eigenvalues : (n,) a replicate's discrete-time poles; targets : (M,) the model's (upper half plane).

    Returns
    -------
    (M,) indices into ``eigenvalues``; -1 when there is no complex pole.
    """
    ev = np.asarray(eigenvalues, dtype=complex)
    upper = np.flatnonzero(ev.imag > 0)
    if upper.size == 0:
        return np.full(np.size(targets), -1)
    s_all = np.log(ev[upper]) / sample_time_s
    s_target = np.log(np.asarray(targets, dtype=complex)) / sample_time_s
    return upper[np.argmin(np.abs(s_all[None, :] - s_target[:, None]), axis=1)]


def nearest_modes(eigenvalues: np.ndarray, targets: np.ndarray, sample_time_s: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Frequency (Hz) and damping of the eigenvalue nearest each target (:func:`nearest_poles`).

    Parameters
    ----------
    eigenvalues : (n,) a replicate's discrete-time poles; targets : (M,) the model's (upper half plane).

    Returns
    -------
    frequency_hz, damping_ratio : (M,) each (NaN when there is no complex pole).
    """
    nearest = nearest_poles(eigenvalues, targets, sample_time_s)
    if np.any(nearest < 0):
        return np.full(targets.size, np.nan), np.full(targets.size, np.nan)
    s = np.log(np.asarray(eigenvalues, dtype=complex)[nearest]) / sample_time_s
    return np.abs(s) / (2 * np.pi), -s.real / np.abs(s)


def jackknife_std(replicates: np.ndarray) -> np.ndarray:
    """Delete-one jackknife standard deviation of each column of ``replicates`` (S, M)."""
    n_seg = replicates.shape[0]
    deviations = replicates - replicates.mean(axis=0)
    return np.sqrt((n_seg - 1) / n_seg * np.sum(deviations**2, axis=0))


def stands_out(value: complex, replicates: np.ndarray, stds: float) -> bool:
    """Whether ``|value|`` exceeds ``stds`` jackknife standard deviations of its (S,) complex ``replicates``.

    The standard deviation is the real and imaginary parts' (:func:`jackknife_std`) in quadrature; a
    NaN or infinite replicate makes it NaN, and the value does not stand out.
    """
    replicates = np.asarray(replicates, dtype=complex)
    with np.errstate(invalid="ignore"):
        spread = np.hypot(*jackknife_std(np.column_stack([replicates.real, replicates.imag])))
    return bool(abs(value) > stds * spread)


def _segment_bounds(rows: np.ndarray, n_segments: int) -> np.ndarray:
    """Sample-index bounds of ``n_segments`` runs of (about) equally many of the rows."""
    n_segments = int(max(1, min(n_segments, rows.size // MIN_SEGMENT_ROWS)))
    cuts = rows[np.linspace(0, rows.size, n_segments + 1).astype(int)[1:-1]]
    return np.concatenate([[0], cuts, [rows[-1] + 1]]).astype(int)


def _less(normal: NormalEquations, gram: np.ndarray, sums: np.ndarray, n_rows: int, p: int) -> NormalEquations:
    """The normal equations without the rows of one segment (its lagged Gram and sums)."""
    return NormalEquations(normal.R - gram[p:, p:], normal.r - gram[p:, :p], normal.yy - gram[:p, :p],
                           normal.n_rows - n_rows, normal.phi_sum - sums[p:], normal.y_sum - sums[:p])


def _arx_theta(normal: NormalEquations, precision: np.ndarray, penalty: float) -> tuple[np.ndarray, tuple | None]:
    """The ARX coefficients with an intercept at a fixed penalty, and the factor that solved them.

    The factor is the Cholesky factor of the penalized, centered ``R + lam P`` (None: no penalty,
    or singular and solved by eigh).
    """
    centered = center_normal_equations(normal)
    if penalty > 0:
        try:
            factor = linalg.cho_factor(centered.R + penalty * precision, check_finite=False)
            return linalg.cho_solve(factor, centered.r, check_finite=False), factor
        except linalg.LinAlgError:
            pass
    return solve_normal_equations(centered, precision, penalty)[0], None


def _arx_replicates(arx: ArxFit, gram: np.ndarray, sums: np.ndarray, n_rows: int,
                    parts: list[tuple[np.ndarray, np.ndarray, int]]) -> list[ArxFit] | None:
    """The window's ARX model changed as the fit without each segment changes it.

    ``gram``, ``sums`` are the lagged Gram and sums of the ARX rows (:func:`.arx_gram.lagged_gram`
    at the ARX order, or more lags: the leading block is taken), ``parts`` the segments' own.
    """
    window = _ArxWindow.of(arx, gram, sums, n_rows)
    return None if window is None else [window.without(*part) for part in parts]


@dataclass
class _ArxWindow:
    """The window's ARX fit as the replicates change it (:func:`_arx_replicates`)."""

    arx: ArxFit
    whole: NormalEquations
    precision: np.ndarray
    penalty: float
    base: np.ndarray
    #: Cholesky factor of the window's penalized, centered ``R + lam P`` (None: no penalty, or singular).
    factor: tuple | None = None

    @classmethod
    def of(cls, arx: ArxFit, gram: np.ndarray, sums: np.ndarray, n_rows: int) -> "_ArxWindow | None":
        """The window's normal equations, prior and fit (None when that fit is not finite)."""
        q, p, m = arx.order, arx.n_outputs, arx.n_inputs
        size = (q + 1) * (p + m)
        gram, sums = gram[:size, :size], sums[:size]
        whole = NormalEquations(gram[p:, p:], gram[p:, :p], gram[:p, :p], n_rows, sums[p:], sums[:p])
        kind = "tc" if arx.regularization == "tc" and arx.decay else "ridge"
        # The prior of the window's fit (fit_from_normal_equations: channel scales of the centered rows).
        scales = channel_mean_square(center_normal_equations(whole), p, m, q)
        precision = prior_precision(q, p, m, scales, kind, arx.decay or 0.95)
        penalty = float(arx.penalty) if arx.regularization != "none" else 0.0
        base, factor = _arx_theta(whole, precision, penalty)  # the factor also serves stepped()
        return cls(arx, whole, precision, penalty, base, factor) if np.all(np.isfinite(base)) else None

    def stepped(self) -> ArxFit | None:
        """The window's fit one more Tikhonov step on (:func:`_penalty_bias`; None without a factor)."""
        if self.factor is None:
            return None
        step = linalg.cho_solve(self.factor, self.penalty * (self.precision @ self.base), check_finite=False)
        return replace(self.arx, theta=self.arx.theta + step) if np.all(np.isfinite(step)) else None

    def without(self, part_gram: np.ndarray, part_sums: np.ndarray, part_rows: int) -> ArxFit:
        """The replicate without one segment (its lagged Gram, sums and row count)."""
        arx = self.arx
        size = self.whole.R.shape[0] + arx.n_outputs
        kept = self.whole.n_rows - part_rows
        less = _less(self.whole, part_gram[:size, :size], part_sums[:size], part_rows, arx.n_outputs)
        theta = _arx_theta(less, self.precision, self.penalty * kept / self.whole.n_rows)[0]
        return replace(arx, theta=arx.theta + (theta - self.base))


def _leading_subspace(h0: np.ndarray, weight: np.ndarray, start: np.ndarray, n_states: int
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Leading left singular vectors (rows, n) and values (n,) of ``h0 @ weight``.

    A replicate's Hankel matrix differs from the window's by the data of one segment, so its
    leading subspace is found from the window's (``start``, with some spare columns) by block
    power iterations, products with ``h0`` and ``weight`` apart (``h0 @ weight`` is not formed):
    ``ITERATIONS`` of them cost a few percent of a full SVD where the order is a small part of the
    Hankel matrix's rank (16 outputs, q = 100: 32 columns of 800); where it is not (the steel
    subframe: 132 of 252) the SVD is taken.
    """
    n_rows, n_cols = h0.shape
    if start.shape[1] * 2 * ITERATIONS >= min(n_rows, n_cols):  # as dear as the SVD itself
        left, values, _ = linalg.svd(h0 @ weight, full_matrices=False)
        return left[:, :n_states], values[:n_states]
    basis = start
    for _ in range(ITERATIONS):
        basis = linalg.qr(h0 @ (weight @ (weight.T @ (h0.T @ basis))), mode="economic")[0]
    small = (basis.T @ h0) @ weight
    left, values, _ = linalg.svd(small, full_matrices=False)
    return basis @ left[:, :n_states], values[:n_states]


def realization_jackknife(
    arx: ArxFit,
    u: np.ndarray,
    y: np.ndarray,
    targets: np.ndarray,
    n_states: int,
    sample_time_s: float,
    *,
    hankel_rows: int,
    hankel_cols: int,
    valid: np.ndarray | None = None,
    n_segments: int,
) -> tuple[np.ndarray, np.ndarray, str]:
    """Jackknife standard deviations of the modes of a model realized from ``arx``.

    Parameters
    ----------
    arx : the window's ARX model (the frame of ``u``, ``y``).
    u : (N, m); y : (N, p) the window's samples, offsets removed, as the realization saw them.
    targets : (M,) the modes' discrete-time eigenvalues; n_states : the model's order.
    hankel_rows, hankel_cols : the Hankel size of the realization.
    valid : (N,) bool, optional mask of the window's trustworthy samples.
    n_segments : replicates (``RealizationOptions.jackknife_segments``, 8 by default as the
        output-only route's jackknife; fewer when a segment would hold fewer than 100 rows).

    Returns
    -------
    frequency_hz_std, damping_ratio_std : (M,) each (NaN when not computed): the replicates'
        scatter and, in quadrature, each target's distance from the window's own pole (the
        state regression the replicates repeat), which the steps after it moved, and the
        penalty's bias (:func:`_penalty_bias`).
    reason : empty, or why the standard deviations could not be computed.
    """
    targets = np.asarray(targets, dtype=complex)
    nan = np.full(targets.size, np.nan)
    lags = max(arx.order, hankel_cols)
    # One pass of lagged products serves the ARX rows and the ERA's past data (its leading block).
    rows = valid_regressor_rows(u.shape[0], lags, valid)
    if rows.size < 2 * MIN_SEGMENT_ROWS:
        return nan, nan, f"not computed: {rows.size} rows are too few for the jackknife"
    bounds = _segment_bounds(rows, n_segments)
    window = _ArxWindow.of(arx, *lagged_gram(u, y, lags, valid)[:2], rows.size)
    if window is None:
        return nan, nan, "not computed: the ARX normal equations of the window are singular"
    whole = StateGram(u, y, hankel_cols, valid)
    state_size = whole.gram.shape[0]
    spare = min(n_states + SPARE_COLUMNS, hankel_rows * arx.n_outputs)
    full = decompose_hankel(arx.observer_markov, hankel_rows, hankel_cols, whole.past_weight())
    start = full.U[:, :spare].copy()
    try:
        center = _regressed_poles(whole, full.h0, full.U, full.s, n_states)
    except (ValueError, linalg.LinAlgError, np.linalg.LinAlgError) as exc:
        return nan, nan, f"not computed: the window's own realization failed ({exc})"
    del full  # its Hankel matrices are not needed in the replicates' loop
    own = nearest_modes(center, targets, sample_time_s)
    if not (np.isfinite(own[0]).all() and np.isfinite(own[1]).all()):
        return nan, nan, "not computed: the window's own realization has no complex pole near the modes"
    move = _move_from(own, targets, sample_time_s)
    bias = _penalty_bias(window, whole, own, targets, sample_time_s, hankel_rows=hankel_rows,
                         hankel_cols=hankel_cols, start=start, n_states=n_states)
    freqs = np.empty((bounds.size - 1, nan.size))
    damps = np.empty((bounds.size - 1, nan.size))
    for j in range(bounds.size - 1):
        # Each segment's Gram when its replicate needs it: one at a time in memory, not S of them.
        part_gram, part_sums, part_rows = segment_lagged_gram(u, y, lags, bounds[j : j + 2], valid)
        fit = window.without(part_gram, part_sums, part_rows)
        replicate = whole.without(part_gram[:state_size, :state_size], part_rows)
        del part_gram, part_sums
        try:
            eigenvalues = _realized_poles(fit, replicate, start, hankel_rows, hankel_cols, n_states)
        except (ValueError, linalg.LinAlgError, np.linalg.LinAlgError) as exc:
            return nan, nan, f"not computed: jackknife replicate {j} failed ({exc})"
        freqs[j], damps[j] = nearest_modes(eigenvalues, targets, sample_time_s)
        if not (np.isfinite(freqs[j]).all() and np.isfinite(damps[j]).all()):
            # No oscillating pole at all: a NaN here would make every mode's std NaN, "computed".
            return nan, nan, f"not computed: jackknife replicate {j} has no complex pole near the modes"
    f_std = np.sqrt(jackknife_std(freqs) ** 2 + move[0] ** 2 + bias[0] ** 2)
    z_std = np.sqrt(jackknife_std(damps) ** 2 + move[1] ** 2 + bias[1] ** 2)
    return f_std, z_std, ""


def _penalty_bias(window: "_ArxWindow", gram: StateGram, own: tuple[np.ndarray, np.ndarray],
                  targets: np.ndarray, sample_time_s: float, *, hankel_rows: int, hankel_cols: int,
                  start: np.ndarray, n_states: int) -> tuple[np.ndarray, np.ndarray]:
    """The regularized ARX fit's bias as the modes see it (M,) each: zero without a penalty.

    The ridge (or TC) fit ``theta = (R + lam P)^-1 r`` is biased by
    ``-lam (R + lam P)^-1 P theta_true``, to first order in the penalty; one more Tikhonov step
    from it (``theta + (R + lam P)^-1 lam P theta``) removes that term. The modes' move from the
    window's own state regression (``own``: the frequencies and dampings of its poles nearest the
    targets) to the same regression on the stepped fit estimates the bias the replicates cannot
    see (they share the penalty), and is added in quadrature as the passes' move is. Zero where
    the realization of the stepped fit fails (the replicates' errors are reported).
    """
    zero = (np.zeros(targets.size), np.zeros(targets.size))
    stepped = window.stepped()
    if stepped is None:
        return zero
    try:
        moved = _realized_poles(stepped, gram, start, hankel_rows, hankel_cols, n_states)
    except (ValueError, linalg.LinAlgError, np.linalg.LinAlgError):
        return zero
    f_moved, z_moved = nearest_modes(moved, targets, sample_time_s)
    bias = (f_moved - own[0], z_moved - own[1])
    return bias if np.isfinite(bias[0]).all() and np.isfinite(bias[1]).all() else zero


def _move_from(own: tuple[np.ndarray, np.ndarray], targets: np.ndarray, sample_time_s: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Each target's frequency and damping less ``own``'s (those of its nearest pole of the window's regression).

    The chain's model is the estimator the replicates repeat (the window's own state regression)
    moved on by steps they do not repeat (the re-estimation passes, a refit, a refinement): that
    move is the one draw of their scatter there is, added in quadrature
    (docs/benchmarks-uncertainty.md, "What the passes add").
    """
    s_target = np.log(targets) / sample_time_s
    return np.abs(s_target) / (2 * np.pi) - own[0], -s_target.real / np.abs(s_target) - own[1]


def _realized_poles(fit: ArxFit, gram: StateGram, start: np.ndarray, hankel_rows: int, hankel_cols: int,
                    n_states: int) -> np.ndarray:
    """Poles (n,) of ``fit`` realized as the replicates are.

    Its Hankel matrix, the leading subspace from ``start`` with the past weighting of ``gram``,
    the state regression of order n.
    """
    h0 = block_hankel(fit.observer_markov, hankel_rows, hankel_cols)
    left, values = _leading_subspace(h0, gram.past_weight(), start, n_states)
    return _regressed_poles(gram, h0, left, values, n_states)


def _regressed_poles(gram: StateGram, h0: np.ndarray, left: np.ndarray, values: np.ndarray, n_states: int
                     ) -> np.ndarray:
    """Poles (n,) of the state-equation regression of order n on the ERA states of ``h0`` (the screening's).

    ``left`` (rows, >= n) and ``values`` (>= n,) are the leading singular pairs of the weighted
    Hankel matrix; orders whose singular values fall below 1e-12 of the largest are left out.
    """
    values = values[:n_states]
    top = int(np.sum(values > values[0] * 1e-12)) if values.size else 0
    gram.set_states((left[:, :top].T @ h0).T / np.sqrt(values[:top]))
    return gram.regress(top, stabilize=False).eigenvalues


def attach_jackknife_std(identified, arx: ArxFit, u: np.ndarray, y: np.ndarray, *, hankel_size: tuple[int, int],
                         options, valid: np.ndarray | None = None) -> UncertaintyResult:
    """Fill the modes' standard deviations of an identified model by :func:`realization_jackknife`.

    ``identified`` is the chain's model (``modes``, ``A``, ``sample_time_s``, ``uncertainty``
    saying why the covariance did not run), in the frame of ``u`` and ``y``; ``options`` its
    :class:`~okid_ros.core.options.RealizationOptions`. When the jackknife cannot run either, the
    modes keep NaN and the result gives both reasons.
    """
    targets = np.array([mode.eigenvalue for mode in identified.modes], dtype=complex)
    try:
        f_std, z_std, reason = realization_jackknife(
            arx, u, y, targets, identified.A.shape[0], identified.sample_time_s, hankel_rows=hankel_size[0],
            hankel_cols=hankel_size[1], valid=valid, n_segments=options.jackknife_segments)
    except (ValueError, linalg.LinAlgError, np.linalg.LinAlgError) as exc:  # never fails the identification
        f_std = z_std = None
        reason = f"not computed: {exc}"
    if reason:
        return UncertaintyResult(False, f"{identified.uncertainty.reason}; jackknife {reason}")
    for mode, fs, zs in zip(identified.modes, f_std, z_std):
        mode.frequency_hz_std, mode.damping_ratio_std = float(fs), float(zs)
    return UncertaintyResult(True, method="jackknife")
