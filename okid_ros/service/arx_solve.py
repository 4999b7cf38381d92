"""Node 1's solve: a captured window's regularized ARX problem, and the snapshot ``ArxModel`` carries.

:class:`okid_ros.service.identification.ArxIdentificationService` captures its window
(:class:`WindowCapture`: a copy of the normal equations, cheap, on the thread that pushes
samples); :func:`solve_capture` solves it on any thread (O(d^3), tens of milliseconds at
d = 402) and the service accepts the :class:`SolveResult` into an :class:`ArxSnapshot`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from okid_ros.core.arx import ArxFit, NormalEquations, fit_from_normal_equations
from okid_ros.core.excitation import window_columns, window_excitation_warnings, window_output_problem
from okid_ros.core.least_squares import center_normal_equations
from okid_ros.core.record_checks import BROADBAND_NEEDED
from okid_ros.core.window_conditioning import input_collinearity
from okid_ros.service.options import ArxIdentificationParams

__all__ = ["ArxSnapshot", "SolveCounts", "SolveResult", "WindowCapture", "solve_capture", "condition_refusal",
           "silent_inputs"]


@dataclass
class WindowCapture:
    """A copy of the window's normal equations and counters at one instant.

    ``window_rows`` is the row count and ``window_fill`` the fraction full, as in
    :class:`ArxSnapshot`.
    """

    normal: NormalEquations
    stamp_s: float
    window_rows: int
    window_fill: float
    samples_used: int
    samples_rejected: int
    params: ArxIdentificationParams
    generation: int = -1  # the window's (:meth:`~okid_ros.service.identification.ArxIdentificationService.is_current`)

    @classmethod
    def of_window(cls, window, params: ArxIdentificationParams, *, restarted: bool, stamp_s: float = math.nan,
                  samples_used: int = 0, samples_rejected: int = 0, generation: int = -1) -> WindowCapture:
        """The capture of a :class:`~okid_ros.core.recursive.SlidingWindowArx` now, its fill judged by node 1's rule.

        ``restarted``: the window restarted at a structural change since its reset (then the fill needed is
        :meth:`~okid_ros.service.options.ArxIdentificationParams.fill_needed`'s after a restart).
        """
        status = window.status
        return cls(normal=window.normal_equations(), stamp_s=stamp_s, window_rows=int(status.rows_in_window),
                   window_fill=float(status.window_fill), samples_used=samples_used, samples_rejected=samples_rejected,
                   params=replace(params, min_window_fill=params.fill_needed(restarted)), generation=generation)


@dataclass
class SolveResult:
    """The regularized least-squares solution of a captured window.

    ``fit`` is None when the window could not give a model; ``reason`` says why. ``warning``
    names the inputs without excitation the fit was made without (their coefficients zero), or "".
    """

    fit: ArxFit | None
    condition_number: float
    reason: str
    solve_time_s: float
    warning: str = ""


@dataclass
class SolveCounts:
    """Node 1's counts of the windows its solve judged, under its diagnostics' names (``track`` counts its own so)."""

    snapshots: int = 0  # windows solved (or refused) at a snapshot
    valid_snapshots: int = 0  # those whose fit was taken: the rest were refused, ``reason`` saying why
    silent_input_snapshots: int = 0  # valid ones fitted without an input silent over their window
    last_warning: str = ""  # the last such snapshot's warning, naming the inputs

    def count(self, result: SolveResult) -> None:
        """Count one solved window."""
        self.snapshots, self.valid_snapshots = self.snapshots + 1, self.valid_snapshots + int(result.fit is not None)
        if result.warning:
            self.silent_input_snapshots, self.last_warning = self.silent_input_snapshots + 1, result.warning

    def counts(self) -> dict:
        """The three counts by their diagnostics' names."""
        return {"snapshots": self.snapshots, "valid_snapshots": self.valid_snapshots,
                "silent_input_snapshots": self.silent_input_snapshots}


@dataclass
class ArxSnapshot:
    """What ``ArxModel`` carries: the window's ARX fit and its health.

    Attributes
    ----------
    model_id : increments with every snapshot; 0 after a reset.
    valid : the window is filled enough and its solve was accepted.
    fit : this window's fit when valid, else the last good one (None if there never was one).
    stamp_s : stamp of the newest sample in the window [s] (nan before the first sample).
    reason : why the snapshot is invalid ('' if valid).
    window_length : rows the window holds when full (0 with forgetting only).
    window_rows : rows in the window now (effective number with forgetting); the ``window_fill``
        field of the ``ArxModel`` message carries this count.
    window_fill : the fraction full, window_rows / window_length (with forgetting: of
        1 / (1 - lambda)), as ``WindowStatus.window_fill`` of the core window.
    condition_number : condition number of the column-scaled normal equations of this window
        (nan when not solved). The regressor matrix's own 2-norm condition number is its root.
    penalty : regularization penalty of ``fit`` (the ``regularization`` field of ``ArxModel``;
        the kind of prior is ``ArxIdentificationParams.regularization``).
    samples_used, samples_rejected : since start or reset.
    solve_time_s : seconds the solve took.
    """

    model_id: int
    valid: bool
    fit: ArxFit | None
    stamp_s: float
    reason: str
    sample_time_s: float
    order: int
    n_inputs: int
    n_outputs: int
    window_length: int
    window_rows: int
    window_fill: float
    forgetting_factor: float
    condition_number: float
    penalty: float
    samples_used: int
    samples_rejected: int
    solve_time_s: float = 0.0


def solve_capture(capture: WindowCapture) -> SolveResult:
    """Solve a captured window (pure; safe to run on another thread)."""
    prm = capture.params
    t0 = time.perf_counter()
    if capture.window_rows == 0:
        return SolveResult(None, math.nan, "no regressor rows in the window yet", 0.0)
    if capture.window_fill < prm.min_window_fill:
        return SolveResult(
            None, math.nan,
            f"window fill {capture.window_fill:.2f} below arx.min_window_fill {prm.min_window_fill:.2f}", 0.0,
        )
    penalty: float | str = "gcv" if prm.penalty_by_gcv else prm.penalty
    decay: float | str = "gcv" if prm.penalty_by_gcv else prm.tc_decay
    # An input silent over the whole window (a disconnected sensor) is left out, as identify and
    # track leave it out (core.excitation.LiveInputs): its coefficients are zero, the warning names it.
    silent = silent_inputs(capture.normal, prm.order, prm.n_outputs, prm.n_inputs)
    live = live_columns(prm.order, prm.n_outputs, prm.n_inputs, silent)
    try:
        fit = fit_from_normal_equations(
            _columns(capture.normal, live), prm.order, prm.n_outputs, prm.n_inputs - len(silent),
            prm.regularization, penalty, decay=decay, center=prm.offsets == "remove",
        )
    except (ValueError, np.linalg.LinAlgError) as exc:
        return SolveResult(None, math.nan, f"solve failed: {exc}", time.perf_counter() - t0)
    cond = float(fit.condition_number)
    elapsed = time.perf_counter() - t0
    refusal = condition_refusal(capture, cond) if not cond <= prm.max_condition_number else ""
    if refusal:
        return SolveResult(None, cond, refusal, elapsed)
    if not np.all(np.isfinite(fit.theta)):
        return SolveResult(None, cond, "solution not finite", elapsed)
    if not silent:
        return SolveResult(fit, cond, "", elapsed)
    theta = np.zeros((live.size, fit.theta.shape[1]))
    theta[live] = fit.theta
    warning = window_excitation_warnings(capture.normal, prm.n_inputs)[0]
    return SolveResult(replace(fit, theta=theta, n_inputs=prm.n_inputs), cond, "", elapsed, warning)


def silent_inputs(normal: NormalEquations, order: int, n_outputs: int, n_inputs: int) -> list[int]:
    """The inputs constant in every column of a window (``u_k`` and its ``order`` lags), if some input is not.

    [] when every input varies somewhere in the window, or none does (a window without excitation,
    refused). An input constant in ``u_k`` only (a blow leaving or entering the window) is not silent.
    """
    constant = window_columns(normal, slice(None))[3]
    width = n_outputs + n_inputs
    silent = [i for i in range(n_inputs) if constant[i] and constant[n_inputs + n_outputs + i::width][:order].all()]
    return silent if len(silent) < n_inputs else []


def live_columns(order: int, n_outputs: int, n_inputs: int, silent: list[int]) -> np.ndarray:
    """(m + q (p + m),) bool: the regressor columns (layout of ArxFit.theta) of all outputs and non-silent inputs."""
    live = ~np.isin(np.arange(n_inputs), silent)
    return np.concatenate([live, np.tile(np.concatenate([np.ones(n_outputs, bool), live]), order)])


def _columns(normal: NormalEquations, keep: np.ndarray) -> NormalEquations:
    """The normal equations of the regressor columns ``keep`` (bool) only."""
    if keep.all():
        return normal
    phi_sum = normal.phi_sum[keep] if normal.phi_sum is not None else None
    return replace(normal, R=normal.R[np.ix_(keep, keep)], r=normal.r[keep], phi_sum=phi_sum)


#: Why an output-only window's lags are singular when no output is dead or a copy: a linear
#: recurrence of the outputs holds over the window, as for sinusoids without noise.
DETERMINISTIC_OUTPUTS = ("the outputs' own past predicts them almost exactly (sinusoids alone, or a response without "
                         f"noise): {BROADBAND_NEEDED}")


def condition_refusal(capture: WindowCapture, condition: float) -> str:
    """Why a window whose condition number exceeds the bound is refused, or "" when it is identified all the same.

    Named, in this order: dead inputs (or one excited only in the newest ``q`` samples, all zeros
    before), dead or dependent outputs, then the inputs' columns beyond the bound
    (:func:`~okid_ros.core.window_conditioning.input_collinearity`). When the inputs' columns are
    within it, the condition number is the outputs': a response far above its noise, identified
    (that module's docstring). Without inputs (output-only) the window is refused; with no dead or
    dependent output, the outputs' own past predicts them: :data:`DETERMINISTIC_OUTPUTS`.
    """
    prm = capture.params
    causes = window_excitation_warnings(capture.normal, prm.n_inputs)
    causes += [cause for cause in [window_output_problem(capture.normal, prm.n_inputs, prm.n_outputs)] if cause]
    if not causes and not prm.n_inputs:  # was refused with the condition number alone
        causes = [DETERMINISTIC_OUTPUTS]
    if not causes and prm.n_inputs:
        normal = center_normal_equations(capture.normal) if prm.offsets == "remove" else capture.normal
        cause = input_collinearity(normal, prm.order, prm.n_outputs, prm.n_inputs, bound=prm.max_condition_number)
        if not cause:
            return ""
        causes = [cause]
    return (f"unexcited window: condition number {condition:.3g} > arx.max_condition_number "
            f"{prm.max_condition_number:.3g}" + "".join(f"; {cause}" for cause in causes))
