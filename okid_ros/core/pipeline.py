"""The identification chain, from a record (or an ARX window) to a modal innovation model.

Two methods share the steps of the paper:

``method="okid"`` (default, robust)
    1. ARX of order q, ridge-regularized with the penalty chosen by GCV (:mod:`.arx`).
    2. Observer Markov parameters ``C Abar^{i-1} [L, Bbar]`` = the ARX lag blocks (:mod:`.markov`).
    3. ERA on them, with the Hankel matrix weighted on the right by a square root of the
       covariance of the past data (:mod:`.era`): ``Abar`` and ``C`` for every candidate order.
    4. ``L``, ``Bbar``, ``D``, ``x0`` refitted by least squares for each order (:mod:`.refit`);
       the order with the lowest BIC of the refitted predictor wins (or the order given).
    5. ``A = Abar + L C``, ``B = Bbar + L D``, ``K = A^{-1} L``; normalized modal form
       (:mod:`.modal`); the full-order predictor is kept, only physical modes are listed.
    Optionally ``gain="whitening"`` replaces the refitted K by the paper's method (:mod:`.gain`).

``method="paper"`` (the paper as published)
    Unregularized ARX, system Markov parameters by Eq. (24), ERA on them, ``D = B_0`` and K by
    AR whitening and polynomial inversion. It fails when the input leaves part of the band
    unexcited (see ``../shared/identification-findings.md``); kept for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import linalg

from okid_ros.core.arx import ArxFit, fit_from_normal_equations, normal_equations
from okid_ros.core.era import HankelDecomposition, decompose_hankel, default_hankel_size
from okid_ros.core.gain import gain_by_whitening
from okid_ros.core.markov import markov_from_arx, stochastic_markov_from_state_space
from okid_ros.core.modal import ModalForm, Mode, modal_form
from okid_ros.core.refine import refine_prediction_error, refinement_size
from okid_ros.core.refit import PredictorFit, fit_from_states, refit_predictor
from okid_ros.core.regressors import arx_regressors, check_io_arrays, regressor_length
from okid_ros.core.statespace import one_step_prediction

__all__ = ["IdentifiedModel", "IdentificationError", "identify", "identify_from_arx"]

METHODS = ("okid", "paper")
GAINS = ("refit", "whitening")
COMPLETIONS = ("auto", "predictor", "states")
# Above this many flops for the refit's normal equations, "auto" completes from states instead
# (2e10 is ~1 s here; the paper case needs 2e8, 28 outputs need 3e11).
PREDICTOR_REFIT_FLOP_LIMIT = 2e10
# The prediction-error refinement forms J^T J (N p residuals x parameters^2 flops) per iteration:
# skip it for models where that gets slow (measured: 6 outputs, 15000 samples, 312 parameters
# took 3 minutes); the paper case needs 4e7 flops per iteration.
MAX_REFINE_PARAMETERS = 400
MAX_REFINE_FLOPS_PER_ITERATION = 2e9
# The automatic order search stops this many states past the best BIC so far.
ORDER_SEARCH_PATIENCE = 8


class IdentificationError(ValueError):
    """The data or the options cannot give a model; the message says why."""


@dataclass
class IdentifiedModel:
    """An identified innovation-form model in normalized modal form (paper convention).

    ``x_{k+1} = A x_k + B u_k + A K e_k``, ``y_k = C x_k + D u_k + e_k``, ``cov(e) =
    innovation_covariance``. The first ``2 len(modes)`` states are the physical modes' blocks.
    """

    sample_time_s: float
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray
    innovation_covariance: np.ndarray
    hankel_singular_values: np.ndarray
    modes: list[Mode]
    arx: ArxFit
    method: str = "okid"
    gain_method: str = "refit"
    order_scores: dict = field(default_factory=dict)
    x0: np.ndarray | None = None
    system_markov: np.ndarray | None = None
    completion: str = "predictor"
    refined: bool = False

    @property
    def n_states(self) -> int:
        return int(self.A.shape[0])

    @property
    def n_physical_states(self) -> int:
        return 2 * len(self.modes)

    def stochastic_markov(self, n_terms: int) -> np.ndarray:
        """``C A^i K`` for i = 1..n_terms: (n_terms, p, p) (paper Fig. 3)."""
        return stochastic_markov_from_state_space(self.A, self.C, self.K, n_terms)

    def to_json_dict(self) -> dict:
        """The ``identify --json`` document (nested lists, damping ratios as fractions)."""
        return {
            "sample_time_s": float(self.sample_time_s),
            "n_states": self.n_states,
            "n_inputs": int(self.B.shape[1]),
            "n_outputs": int(self.C.shape[0]),
            "method": self.method,
            "gain_method": self.gain_method,
            "completion": self.completion,
            "refined": self.refined,
            "arx_order": int(self.arx.order),
            "arx_regularization": self.arx.regularization,
            "arx_penalty": float(self.arx.penalty),
            "condition_number": float(self.arx.condition_number),
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
            "D": self.D.tolist(),
            "K": self.K.tolist(),
            "K_convention": "x[k+1] = A x[k] + B u[k] + A K e[k]; y[k] = C x[k] + D u[k] + e[k]",
            "innovation_covariance": self.innovation_covariance.tolist(),
            "hankel_singular_values": [float(s) for s in self.hankel_singular_values],
            "order_scores": {str(k): float(v) for k, v in self.order_scores.items()},
            "modes": [m.as_dict() for m in self.modes],
        }


def _past_data(u: np.ndarray, y: np.ndarray, n_cols: int, valid: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Past-data vectors ``z_k = [v_{k-1}; ...; v_{k-c}]`` and a square root of their covariance.

    Returns
    -------
    z : (M, (p + m) c) one row per usable sample; rows : (M,) their sample indices;
    weight : lower Cholesky factor of ``z^T z / M``.
    """
    m = u.shape[1]
    phi, _, rows = arx_regressors(u, y, n_cols, valid)
    z = phi[:, m:]
    cov = z.T @ z / max(z.shape[0], 1)
    jitter = 1e-10 * max(np.trace(cov) / cov.shape[0], np.finfo(float).tiny)
    return z, rows, linalg.cholesky(cov + jitter * np.eye(cov.shape[0]), lower=True)


def _choose_completion(completion: str, n_samples: int, n_outputs: int, n_inputs: int, max_states: int) -> str:
    """"predictor" (LS refit) while its normal equations stay cheap, else "states"."""
    if completion != "auto":
        return completion
    flops = n_samples * n_outputs * (max_states * (n_outputs + n_inputs)) ** 2
    return "predictor" if flops <= PREDICTOR_REFIT_FLOP_LIMIT else "states"


def _candidate_orders(n_states: int | str, decomposition: HankelDecomposition, max_states: int) -> list[int]:
    limit = min(decomposition.max_states, max_states)
    if n_states == "auto":
        return list(range(2, limit + 1, 2)) or [1]
    n = int(n_states)
    if not 1 <= n <= decomposition.max_states:
        raise IdentificationError(
            f"--states {n} is not supported: the Hankel matrix of these data has numerical rank "
            f"{decomposition.max_states}"
        )
    return [n]


def _finish(
    fit: PredictorFit,
    arx: ArxFit,
    sample_time_s: float,
    singular_values: np.ndarray,
    gain_method: str,
    scores: dict,
    u: np.ndarray,
    y: np.ndarray,
    ar_order: int | None,
    mode_criteria: dict,
) -> IdentifiedModel:
    """Optional whitening gain, modal form and packaging of the chosen predictor."""
    K, cov = fit.K, fit.innovation_covariance
    if gain_method == "whitening":
        white = gain_by_whitening(fit.A, fit.B, fit.C, fit.D, u, y, ar_order=ar_order or arx.order, x0=fit.x0)
        K, cov = white.K, white.innovation_covariance
    system_markov = markov_from_arx(arx)
    form: ModalForm = modal_form(fit.A, fit.B, fit.C, K, sample_time_s, system_markov[1:], **mode_criteria)
    T_inv = linalg.inv(form.T)
    for i, mode in enumerate(form.modes):
        mode.id = i
    return IdentifiedModel(
        sample_time_s=sample_time_s,
        A=form.A,
        B=form.B,
        C=form.C,
        D=fit.D,
        K=form.K,
        innovation_covariance=cov,
        hankel_singular_values=singular_values,
        modes=form.modes,
        arx=arx,
        method="okid",
        gain_method=gain_method,
        order_scores=scores,
        x0=T_inv @ fit.x0,
        system_markov=system_markov,
    )


def identify_from_arx(
    arx: ArxFit,
    u: np.ndarray,
    y: np.ndarray,
    sample_time_s: float,
    n_states: int | str = "auto",
    max_states: int = 40,
    hankel_rows: int | None = None,
    hankel_cols: int | None = None,
    gain: str = "refit",
    valid: np.ndarray | None = None,
    ar_order: int | None = None,
    completion: str = "auto",
    refine: bool = True,
    **mode_criteria,
) -> IdentifiedModel:
    """Steps 2-5 of the robust chain on an identified ARX model and the data of its window.

    Parameters
    ----------
    arx : the (regularized) ARX model of the window.
    u : (N, m); y : (N, p) the samples of the window, contiguous (used for the weighting and the
        least-squares refit).
    sample_time_s : sample time in seconds.
    n_states : model order, or "auto" for the lowest BIC over even orders up to ``max_states``.
    hankel_rows, hankel_cols : ERA block sizes (default: split the q observer Markov blocks).
    gain : "refit" (least squares, default) or "whitening" (the paper's method).
    valid : (N,) bool, optional mask of trustworthy samples (for the weighting only).
    ar_order : order of the whitening filter when ``gain="whitening"`` (default: q).
    completion : how the realization is completed into ``(A, B, C, D, K)``: "predictor"
        (least-squares refit of ``L``, ``Bbar``, ``D`` for the realized ``Abar``, ``C``),
        "states" (regressions on the predictor-based state sequence; fast with many outputs)
        or "auto" (the refit unless it is expensive); see :mod:`okid_ros.core.refit`.
    refine : finish with the prediction-error refinement of :mod:`okid_ros.core.refine` (skipped
        above ``MAX_REFINE_PARAMETERS`` or ``MAX_REFINE_FLOPS_PER_ITERATION``; kept only if it
        lowers the cost).
    mode_criteria : passed to :func:`okid_ros.core.modal.identify_modes`.
    """
    if gain not in GAINS:
        raise IdentificationError(f"gain must be one of {GAINS}, got {gain!r}")
    if completion not in COMPLETIONS:
        raise IdentificationError(f"completion must be one of {COMPLETIONS}, got {completion!r}")
    u, y = check_io_arrays(u, y)
    blocks = arx.observer_markov  # (q, p, p + m): C Abar^{i-1} [L, Bbar]
    if hankel_rows is None or hankel_cols is None:
        rows, cols = default_hankel_size(blocks.shape[0] - 1)
        hankel_rows = rows if hankel_rows is None else hankel_rows
        hankel_cols = cols if hankel_cols is None else hankel_cols
    z, z_rows, weight = _past_data(u, y, hankel_cols, valid)
    decomposition = decompose_hankel(blocks, hankel_rows, hankel_cols, weight)
    orders = _candidate_orders(n_states, decomposition, max_states)
    completion = _choose_completion(completion, u.shape[0], y.shape[1], u.shape[1], max(orders))
    if completion == "states":
        # States of every candidate order at once: xhat_k = S^-1/2 U^T H(0) z_k.
        top = max(orders)
        projected = z @ (decomposition.U[:, :top].T @ decomposition.h0).T
        projected /= np.sqrt(decomposition.s[:top])
        contiguous = np.all(np.diff(z_rows) == 1)
        if not contiguous:
            raise IdentificationError("the state completion needs a contiguous record (no gaps)")
    scores: dict[int, float] = {}
    best: PredictorFit | None = None
    best_score, best_n = np.inf, 0
    reasons = []
    for n in orders:
        try:
            if completion == "states":
                fit = fit_from_states(projected[:, :n], u[z_rows], y[z_rows])
            else:
                realization = decomposition.realize(n)
                fit = refit_predictor(realization.A, realization.C, u, y)
        except (ValueError, linalg.LinAlgError) as exc:
            reasons.append(f"n={n}: {exc}")
            continue
        scores[n] = fit.bic()
        if scores[n] < best_score:
            best, best_score, best_n = fit, scores[n], n
        elif n_states == "auto" and n >= best_n + ORDER_SEARCH_PATIENCE:
            break  # BIC has not improved for a while: larger orders only add spurious states
    if best is None:
        raise IdentificationError("no model order gave a usable predictor: " + "; ".join(reasons[:3]))
    refined = False
    n_par = refinement_size(best.A.shape[0], y.shape[1], u.shape[1])
    if refine and n_par <= MAX_REFINE_PARAMETERS and y.size * n_par**2 <= MAX_REFINE_FLOPS_PER_ITERATION:
        better = refine_prediction_error(best.A, best.B, best.C, best.D, best.K, u, y, burn_in=arx.order)
        if better is not None:
            best, refined = better, True
    if completion == "states":
        # Express x0 at the first sample of the record for the estimator's warm start.
        u, y = u[z_rows], y[z_rows]
    model = _finish(best, arx, sample_time_s, decomposition.s, gain, scores, u, y, ar_order, mode_criteria)
    model.completion = completion
    model.refined = refined
    return model


def _identify_paper(
    arx: ArxFit,
    u: np.ndarray,
    y: np.ndarray,
    sample_time_s: float,
    n_states: int | str,
    hankel_rows: int | None,
    hankel_cols: int | None,
    ar_order: int | None,
    mode_criteria: dict,
) -> IdentifiedModel:
    system_markov = markov_from_arx(arx)  # (q + 1, p, m): D, CB, CAB, ...
    decomposition = decompose_hankel(system_markov[1:], hankel_rows, hankel_cols)
    if n_states == "auto":
        # The paper counts the significant singular values: take the largest gap.
        s = decomposition.s[: decomposition.max_states]
        n = int(np.argmax(s[:-1] / s[1:]) + 1) if s.size > 1 else 1
    else:
        n = int(n_states)
        if not 1 <= n <= decomposition.max_states:
            raise IdentificationError(f"--states {n} exceeds the Hankel rank {decomposition.max_states}")
    real = decomposition.realize(n)
    A, B, C, D = real.A, real.G, real.C, arx.D
    white = gain_by_whitening(A, B, C, D, u, y, ar_order=ar_order or arx.order)
    form = modal_form(A, B, C, white.K, sample_time_s, system_markov[1:], **mode_criteria)
    for i, mode in enumerate(form.modes):
        mode.id = i
    return IdentifiedModel(
        sample_time_s=sample_time_s,
        A=form.A,
        B=form.B,
        C=form.C,
        D=D,
        K=form.K,
        innovation_covariance=white.innovation_covariance,
        hankel_singular_values=decomposition.s,
        modes=form.modes,
        arx=arx,
        method="paper",
        gain_method="whitening",
        system_markov=system_markov,
    )


def identify(
    u: np.ndarray,
    y: np.ndarray,
    sample_time_s: float,
    order: int = 100,
    n_states: int | str = "auto",
    method: str = "okid",
    regularization: str | None = None,
    gain: str = "refit",
    ar_order: int | None = None,
    max_states: int = 40,
    hankel_rows: int | None = None,
    hankel_cols: int | None = None,
    completion: str = "auto",
    refine: bool = True,
    **mode_criteria,
) -> IdentifiedModel:
    """Identify an innovation-form model in modal form from one input/output record.

    Parameters
    ----------
    u : (N, m) inputs; y : (N, p) outputs; sample_time_s : sample time in seconds.
    order : ARX order q (paper: 100).
    n_states : model order n, or "auto".
    method : "okid" (robust, default) or "paper" (as published).
    regularization : ARX regularization "ridge" (okid default), "tc", or "none" (paper default).
    gain : "refit" or "whitening" (okid method only; the paper method always whitens).
    ar_order : order r of the whitening AR filter (default: q).
    max_states : upper bound of the automatic order search.
    completion : "auto", "predictor" or "states" (see :func:`identify_from_arx`).
    refine : prediction-error refinement as the last step (see :func:`identify_from_arx`).

    Raises
    ------
    IdentificationError with a one-line reason on bad data or options.
    """
    if method not in METHODS:
        raise IdentificationError(f"method must be one of {METHODS}, got {method!r}")
    if not np.isfinite(sample_time_s) or sample_time_s <= 0:
        raise IdentificationError(f"sample_time_s must be a positive number, got {sample_time_s}")
    if order < 2:
        raise IdentificationError(f"ARX order must be >= 2, got {order}")
    try:
        u, y = check_io_arrays(u, y)
    except ValueError as exc:
        raise IdentificationError(str(exc)) from None
    m, p = u.shape[1], y.shape[1]
    d = regressor_length(order, p, m)
    needed = order + d + 1
    if u.shape[0] < needed:
        raise IdentificationError(
            f"too few samples for ARX order {order} with {m} inputs and {p} outputs: {u.shape[0]} "
            f"given, at least {needed} needed ({d} coefficients per output plus {order} lags)"
        )
    if regularization is None:
        regularization = "none" if method == "paper" else "ridge"
    phi, targets, _ = arx_regressors(u, y, order)
    try:
        arx = fit_from_normal_equations(normal_equations(phi, targets), order, p, m, regularization)
    except ValueError as exc:
        raise IdentificationError(str(exc)) from None
    if method == "paper":
        return _identify_paper(arx, u, y, sample_time_s, n_states, hankel_rows, hankel_cols, ar_order, mode_criteria)
    return identify_from_arx(
        arx, u, y, sample_time_s, n_states, max_states, hankel_rows, hankel_cols, gain, ar_order=ar_order,
        completion=completion, refine=refine, **mode_criteria,
    )


def prediction_errors(model: IdentifiedModel, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """One-step prediction errors of an identified model on a record: (N, p)."""
    _, e = one_step_prediction(model.A, model.B, model.C, model.D, model.K, u, y)
    return e
