"""The identification chain, from a record (or an ARX window) to a modal innovation model.

Two methods share the steps of the paper:

``method="okid"`` (default, robust; each step is a module)
    1. Offsets: the record's means are removed (``offsets="remove"``) and kept with the model;
       a record's drift (a straight-line trend holding 2 % of a channel) is removed first,
       clipped channels are named (:mod:`.sensor_faults`), and harmonic lines of the outputs
       that the inputs do not hold (a disturbance) are removed (:mod:`.output_only_harmonics`).
    2. ARX of order q, ridge-regularized with the penalty chosen by GCV; q itself chosen by GCV
       unless given (:mod:`.arx`).
    3. Observer Markov parameters ``C Abar^{i-1} [L, Bbar]`` = the ARX lag blocks (:mod:`.markov`).
    4. ERA on them, with the Hankel matrix weighted on the right by a square root of the
       covariance of the past data (:mod:`.era`): ``Abar`` and ``C`` for every candidate order.
    5. Completion into ``(A, B, C, D, K)`` for each order: least-squares refit of the predictor
       (:mod:`.refit`, few outputs) or regressions on the state sequence with a stable ``A``
       and the Riccati gain (:mod:`.state_completion`, many outputs, and whenever the refit
       leaves ``A`` unstable or ``gain="riccati"``); the order with the lowest BIC wins, the
       search going past ``max_states`` while BIC is lowest at the limit.
    6. Optional prediction-error refinement that keeps ``A`` and the predictor stable
       (:mod:`.refine`); the chosen order's state sequence re-estimated (:mod:`.state_completion`).
    7. Modes in normalized modal form (:mod:`.modal`), physical only when stable across the
       neighbouring orders (:mod:`.stabilization`); the full-order predictor is kept; the
       standard deviation of each mode's frequency and damping (:mod:`.uncertainty`; with tens
       of outputs :mod:`.mode_jackknife`).
    8. The model is checked (stable ``A``, stable predictor, finite) before it is returned.

``method="paper"`` (the paper as published)
    Unregularized ARX, system Markov parameters by Eq. (24), ERA on them, ``D = B_0`` and K by
    AR whitening and polynomial inversion. It fails when the input leaves part of the band
    unexcited (``docs/method.md``); kept for comparison, and checked like every model.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import linalg

from okid_ros.core.arx import ArxFit
from okid_ros.core.arx_order import arx_order_for_realization, choose_arx_order
from okid_ros.core.channels import channel_mean, channel_std
from okid_ros.core.era import decompose_hankel, default_hankel_size
from okid_ros.core.excitation import frozen_output_warnings, unexplained_warnings
from okid_ros.core.gain import gain_by_whitening
from okid_ros.core.gap_fill import fit_and_fill
from okid_ros.core.identified_model import IdentificationError, IdentifiedModel
from okid_ros.core.markov import markov_from_arx
from okid_ros.core.modal import modal_form
from okid_ros.core.mode_jackknife import attach_jackknife_std
from okid_ros.core.options import AUTO, OFFSETS, ArxOrderOptions, RealizationOptions
from okid_ros.core.order_search import Completer, OrderSearch, choose_completion, complete_chosen, search_orders
from okid_ros.core.record_checks import check_record_length, checked_record
from okid_ros.core.refine import refine_prediction_error, refinement_flops, refinement_size
from okid_ros.core.refit import PredictorFit
from okid_ros.core.regressors import check_io_arrays
from okid_ros.core.scaling import IdentificationFrame
from okid_ros.core.sensor_faults import record_faults
from okid_ros.core.slow_pole_span import spanning_slowest_pole
from okid_ros.core.stabilization import stability_judge, stabilization_diagram
from okid_ros.core.state_gram import StateGram
from okid_ros.core.statespace import InnovationModel, one_step_prediction, spectral_radius
from okid_ros.core.uncertainty import (
    attach_mode_uncertainty,
    noisy_poles,
    same_pole,
    steady_poles,
    uncertainty_problem,
)

__all__ = ["IdentifiedModel", "IdentificationError", "choose_arx_order", "identify", "identify_from_arx"]

# The prediction-error refinement's cost per iteration (core/refine.refinement_flops: the Gram of
# its filtered signals and the normal equations from it): skip it for models where that gets
# slow; the paper case needs 3e7 flops per iteration. (The bound was first set for the tall
# Jacobian's J^T J, N p x parameters^2 flops, which skipped 6 outputs at 15000 samples.)
MAX_REFINE_PARAMETERS = 400
MAX_REFINE_FLOPS_PER_ITERATION = 2e9
# An offset this large against the channel's standard deviation is worth a warning.
LARGE_OFFSET_FRACTION = 0.1


def _remove_offsets(
    u: np.ndarray, y: np.ndarray, offsets: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Means removed (``offsets="remove"``) or zero offsets; warnings for large offsets."""
    if offsets not in OFFSETS:
        raise IdentificationError(f"offsets must be one of {OFFSETS}, got {offsets!r}")
    u_mean, y_mean = channel_mean(u), channel_mean(y)
    warnings = []
    for name, mean, data in (("input", u_mean, u), ("output", y_mean, y)):
        std = channel_std(data)  # np.std squares: overflows for values beyond 1e154
        large = np.flatnonzero(np.abs(mean) > LARGE_OFFSET_FRACTION * np.maximum(std, np.finfo(float).tiny))
        if large.size:
            listed = ", ".join(
                f"{name} {i}: {mean[i]:.4g} ({abs(mean[i]) / max(std[i], 1e-300):.2f} std)" for i in large[:4]
            )
            action = "removed" if offsets == "remove" else "NOT removed (offsets='none')"
            warnings.append(f"large offsets {action}: {listed}{' ...' if large.size > 4 else ''}")
    if offsets == "none":
        return u, y, np.zeros(u.shape[1]), np.zeros(y.shape[1]), warnings
    return u - u_mean, y - y_mean, u_mean, y_mean, warnings


# ----------------------------------------------------------------------------- the chain


def _refine(
    best: PredictorFit, u: np.ndarray, y: np.ndarray, arx: ArxFit, options: RealizationOptions
) -> PredictorFit | None:
    """Step 6: the prediction-error refinement, when affordable (None: not run or no gain)."""
    model = best.model
    n_par = refinement_size(model.n_states, model.n_outputs, model.n_inputs)
    flops = refinement_flops(model.n_states, model.n_outputs, model.n_inputs, y.shape[0])
    if not options.refine or n_par > MAX_REFINE_PARAMETERS or flops > MAX_REFINE_FLOPS_PER_ITERATION:
        return None
    return refine_prediction_error(model, u, y, burn_in=arx.order)


def _package(
    model: InnovationModel,
    x0: np.ndarray,
    sample_time_s: float,
    arx: ArxFit,
    *,
    reference_markov: np.ndarray,
    options: RealizationOptions,
    stability=None,
    steady=None,
    noisy=None,
    **fields: Any,
) -> IdentifiedModel:
    """Step 7-8: normalized modal form, physical modes, the final checks."""
    form = modal_form(model.A, model.B, model.C, model.K, sample_time_s, reference_markov,
                      criteria=options.modes, stability=stability, steady=steady, noisy=noisy, once=True,
                      D=model.D)
    for i, mode in enumerate(form.modes):
        mode.id = i
    identified = IdentifiedModel(
        A=form.A, B=form.B, C=form.C, D=model.D, K=form.K,
        innovation_covariance=model.innovation_covariance, sample_time_s=sample_time_s,
        modes=form.modes, arx=arx, x0=linalg.solve(form.T, x0), **fields,
    )
    problem = identified.stability_problem()
    if problem:
        raise IdentificationError(f"refused: {problem}")
    return identified


def _package_judged(model: InnovationModel, x0: np.ndarray, sample_time_s: float, arx: ArxFit, u: np.ndarray,
                    y: np.ndarray, *, stability, jackknife=None, **fields: Any) -> IdentifiedModel:
    """:func:`_package` with the stabilization fraction ``stability`` and the modes' standard deviations (step 7b).

    The standard deviations (:func:`.uncertainty.attach_mode_uncertainty` on the offset-free
    data, or where that is out of reach ``jackknife(identified)``, of the listed modes only)
    judge the modes once more: a mode refused by the stabilization fraction alone is kept when
    they say its pole is steady (:func:`.uncertainty.steady_poles`), and a listed mode is refused
    when they say its pole is noise (:func:`.uncertainty.noisy_poles`).
    """
    refused: list[complex] = []

    def judged(mode) -> float:
        fraction = stability(mode)
        if fraction < fields["options"].modes.min_stable_fraction:
            refused.append(mode.eigenvalue)
        return fraction

    identified = _package(model, x0, sample_time_s, arx, stability=judged, **fields)
    # Tens of outputs (no prediction-error covariance): the refused modes stay refused.
    affordable = not uncertainty_problem(model.A.shape[0], *model.D.shape, y.shape[0], burn_in=arx.order)
    every = _package(model, x0, sample_time_s, arx, **fields) if refused and affordable else identified
    every.uncertainty = attach_mode_uncertainty(every, u, y, burn_in=arx.order)  # else NaN, with the reason
    if not every.uncertainty.computed and every.modes and jackknife is not None:
        every.uncertainty = jackknife(every)
    steady = steady_poles(every.modes) if affordable else []
    noisy = noisy_poles(every.modes, y.shape[0] * sample_time_s)
    if any(same_pole(ev, steady) for ev in refused) or any(same_pole(m.eigenvalue, noisy) for m in identified.modes):
        identified = _package(model, x0, sample_time_s, arx, stability=stability,
                              steady=lambda mode: same_pole(mode.eigenvalue, steady),
                              noisy=lambda mode: same_pole(mode.eigenvalue, noisy), **fields)
    if identified is not every:
        stds = {mode.eigenvalue: (mode.frequency_hz_std, mode.damping_ratio_std) for mode in every.modes}
        for mode in identified.modes:
            mode.frequency_hz_std, mode.damping_ratio_std = next(
                (v for ev, v in stds.items() if same_pole(mode.eigenvalue, [ev])), (float("nan"), float("nan")))
    identified.uncertainty = every.uncertainty
    return identified


def _completed(search: OrderSearch, completer: Completer, n: int, options: RealizationOptions) -> PredictorFit:
    """The completed fit of order n (gain, re-estimation passes where screened)."""
    fit = search.fits[n]
    if completer.completion == "states" or (options.state_passes and n in completer.via_states):
        try:
            fit = completer.complete(n, passes=options.state_passes)
        except (ValueError, linalg.LinAlgError, np.linalg.LinAlgError) as exc:
            raise IdentificationError(f"order {n} could not be completed: {exc}") from None
    return fit


def _hankel_size(n_blocks: int, options: RealizationOptions) -> tuple[int, int]:
    """ERA block rows and columns: the options', else all ``n_blocks`` Markov blocks split in two.

    Raises IdentificationError when the options ask for more blocks than the ARX model has.
    """
    rows, cols = default_hankel_size(n_blocks - 1)
    rows, cols = options.hankel_rows or rows, options.hankel_cols or cols
    if rows + cols > n_blocks:
        raise IdentificationError(f"an ERA Hankel of {rows} x {cols} blocks needs an ARX order of at least "
                                  f"{rows + cols}; this ARX model has order {n_blocks}")
    return rows, cols


def _refine_best_orders(search: OrderSearch, completer: Completer, u: np.ndarray, y: np.ndarray, arx: ArxFit,
                        options: RealizationOptions) -> tuple[int, PredictorFit, dict[int, InnovationModel]]:
    """Steps 5b-6: the chosen order completed and refined; the lowest BIC after refinement wins.

    In an automatic search the next best orders by BIC (``options.refined_orders`` in all, none
    the search had to repair) are completed and refined too: the refinement moves each order's
    fit by a different amount, so the winner before it is not always the winner after it.
    A repaired order chosen by its margin (:meth:`.OrderSearch.best_order`) that cannot be completed
    gives way to the unrepaired winner (:func:`.order_search.complete_chosen`).
    Returns the order, its fit and every refined model by order (empty: the fit is not refined).
    """
    n_best = search.best_order() if options.automatic_order else int(options.n_states)
    n_best, best = complete_chosen(n_best, lambda n: _completed(search, completer, n, options),
                                   fallback=search.fallback_order(n_best) if options.automatic_order else None)
    refined = _refine(best, u, y, arx, options)
    if refined is None:
        return n_best, best, {}
    models = {n_best: refined.model}
    if options.automatic_order:
        others = sorted((n for n in search.fits if n != n_best and n not in search.repaired),
                        key=lambda n: (search.fits[n].bic(), n))
        for n in others[: options.refined_orders - 1]:
            try:
                alternative = _refine(_completed(search, completer, n, options), u, y, arx, options)
            except IdentificationError:
                continue
            if alternative is None:
                continue
            models[n] = alternative.model
            if alternative.bic() < refined.bic():
                n_best, refined = n, alternative
    return n_best, refined, models


def _diagram(search: OrderSearch, completer: Completer, sample_time_s: float, options: RealizationOptions) -> list:
    """The stabilization diagram of every order searched (screened or completed).

    The screening's eigendecompositions serve the orders whose model is the screened one.
    """
    eigen = {n: e for n, e in completer.eigen.items()
             if search.fits.get(n, search.screened.get(n)) is search.screened.get(n)}
    return stabilization_diagram(search.diagram_models(), sample_time_s, options.modes, eigen=eigen)


def identify_from_arx(
    arx: ArxFit,
    u: np.ndarray,
    y: np.ndarray,
    sample_time_s: float,
    *,
    options: RealizationOptions | None = None,
    valid: np.ndarray | None = None,
    offsets: str = "remove",
    order_hint: int | None = None,
    **option_changes: Any,
) -> IdentifiedModel:
    """Steps 3-8 of the robust chain on an identified ARX model and the data of its window.

    Parameters
    ----------
    arx : the (regularized) ARX model of the window; sample_time_s : sample time in seconds.
    u : (N, m); y : (N, p) the samples of the window, contiguous (used for the weighting, the
        completion and the refinement).
    options : :class:`~okid_ros.core.options.RealizationOptions` (default: its defaults).
    valid : (N,) bool, optional mask of trustworthy samples (for the weighting only).
    offsets : "remove" (the window's means are removed and kept with the model) or "none".
    order_hint : the previous window's model order, which warm-starts the order search.
    option_changes : individual options (``n_states=8``, ``max_damping=0.05``, ...) applied on
        top of ``options``.

    Raises
    ------
    IdentificationError with a one-line reason.
    """
    try:
        options = (options or RealizationOptions()).with_changes(**option_changes)
        u, y = check_io_arrays(u, y)
    except (TypeError, ValueError) as exc:
        raise IdentificationError(str(exc)) from None
    frame = IdentificationFrame.of(u, y)  # live inputs, unit spread; back at the end (core/scaling.py)
    (u, y), arx = frame.enter(u, y), frame.enter_arx(arx)
    u, y, u_offset, y_offset, warnings = _remove_offsets(u, y, offsets)
    blocks = arx.observer_markov  # (q, p, p + m): C Abar^{i-1} [L, Bbar]
    hankel_rows, hankel_cols = _hankel_size(blocks.shape[0], options)
    # One Gram of the window's past data: the ERA weighting and every order's state regressions.
    gram = StateGram(u, y, hankel_cols, valid)
    decomposition = decompose_hankel(blocks, hankel_rows, hankel_cols, gram.past_weight())
    search_top = options.max_states if options.automatic_order else int(options.n_states)
    completion = choose_completion(options.completion, u.shape[0], y.shape[1], u.shape[1], search_top)
    completer = Completer(decomposition, gram, u, y, completion, options=options, burn_in=arx.order)
    search = search_orders(completer, options, order_hint=order_hint)
    n_best, best, refined_models = _refine_best_orders(search, completer, u, y, arx, options)
    refined = bool(refined_models)
    model = best.model
    gain_method = options.gain
    if options.gain == "whitening":
        try:
            white = gain_by_whitening(model.A, model.B, model.C, model.D, u, y,
                                      ar_order=options.ar_order or arx.order, x0=best.x0)
        except (ValueError, np.linalg.LinAlgError, linalg.LinAlgError) as exc:
            raise IdentificationError(f"the whitening gain failed: {exc}") from None
        model = InnovationModel(model.A, model.B, model.C, model.D, white.K, white.innovation_covariance)
    if search.max_states_reached:
        warnings.append(
            f"BIC is lowest at the largest model order the search could try ({max(search.screened or search.fits)} "
            f"states, "
            f"limited by {search.limit_reason}); the model may need more states"
        )
    diagram = _diagram(search, completer, sample_time_s, options)
    system_markov = markov_from_arx(arx)
    identified = _package_judged(
        model, best.x0, sample_time_s, arx, u, y, reference_markov=system_markov[1:], options=options,
        stability=stability_judge(diagram, n_best, options.modes, refined_models, sample_time_s),
        hankel_singular_values=decomposition.s, method="okid", gain_method=gain_method,
        order_scores={n: fit.bic() for n, fit in sorted({**search.screened, **search.fits}.items())},
        completed_orders=sorted(search.fits), stabilization=diagram,
        system_markov=system_markov, completion=completion, refined=refined,
        input_offset=u_offset, output_offset=y_offset, max_states_reached=search.max_states_reached,
        warnings=warnings + frame.warnings + unexplained_warnings(_prediction_error_covariance(model, u, y, best.x0), y)
        + frozen_output_warnings(y),
        jackknife=None if not options.jackknife_segments else lambda identified: attach_jackknife_std(
            identified, arx, u, y, hankel_size=(hankel_rows, hankel_cols), options=options, valid=valid),
    )
    return frame.leave(identified, offsets, offset_warnings=_remove_offsets(*frame.physical, offsets)[4])


def _prediction_error_covariance(model: InnovationModel, u: np.ndarray, y: np.ndarray, x0: np.ndarray | None
                                 ) -> np.ndarray:
    """(p, p) covariance of the model's one-step prediction errors on the record it was identified from.

    What the model explains, whatever its gain claims: the whitening gain's own innovation
    covariance is that of the ARX residuals, and on outputs unrelated to anything (white noise)
    it claimed a fit the predictor does not make, so "no dynamics identified" went unsaid.
    """
    _, errors = one_step_prediction(model, u, y, x0=x0)
    return np.atleast_2d(np.cov(errors, rowvar=False))


def _identify_paper(
    arx: ArxFit, u: np.ndarray, y: np.ndarray, sample_time_s: float, *, options: RealizationOptions,
    u_offset: np.ndarray, y_offset: np.ndarray, warnings: list[str],
) -> IdentifiedModel:
    system_markov = markov_from_arx(arx)  # (q + 1, p, m): D, CB, CAB, ...
    decomposition = decompose_hankel(system_markov[1:], options.hankel_rows, options.hankel_cols)
    if options.automatic_order:
        # The paper counts the significant singular values: take the largest gap.
        s = decomposition.s[: decomposition.max_states]
        n = int(np.argmax(s[:-1] / s[1:]) + 1) if s.size > 1 else 1
    else:
        n = int(options.n_states)
        if not 1 <= n <= decomposition.max_states:
            raise IdentificationError(f"{n} states exceed the Hankel rank {decomposition.max_states}")
    real = decomposition.realize(n)
    rho = spectral_radius(real.A)
    if not rho < 1.0:
        # The whitening filter runs on the free-run residuals, which an unstable A makes diverge.
        raise IdentificationError(f"refused: unstable model: spectral radius of A {rho:.6f} >= 1 "
                                  "(the paper's method has no stability guarantee; the okid method has)")
    try:
        white = gain_by_whitening(real.A, real.B, real.C, arx.D, u, y, ar_order=options.ar_order or arx.order)
    except (ValueError, np.linalg.LinAlgError, linalg.LinAlgError) as exc:
        raise IdentificationError(f"the paper's gain identification failed: {exc}") from None
    model = InnovationModel(real.A, real.B, real.C, arx.D, white.K, white.innovation_covariance)
    identified = _package(
        model, np.zeros(n), sample_time_s, arx, reference_markov=system_markov[1:], options=options,
        hankel_singular_values=decomposition.s, method="paper", gain_method="whitening",
        system_markov=system_markov, input_offset=u_offset, output_offset=y_offset, warnings=warnings,
    )
    identified.uncertainty = attach_mode_uncertainty(identified, u, y, burn_in=arx.order)
    return identified


def identify(
    u: np.ndarray,
    y: np.ndarray,
    sample_time_s: float,
    *,
    order: int | str = AUTO,
    method: str = "okid",
    regularization: str | None = None,
    offsets: str = "remove",
    options: RealizationOptions | None = None,
    arx_orders: ArxOrderOptions | None = None,
    valid: np.ndarray | None = None,
    **option_changes: Any,
) -> IdentifiedModel:
    """Identify an innovation-form model in modal form from one input/output record.

    Parameters
    ----------
    u : (N, m) inputs; y : (N, p) outputs; sample_time_s : sample time in seconds.
    order : ARX order q (the paper: 100), or "auto" (chosen by GCV, :func:`select_arx_order`).
    method : "okid" (robust, default) or "paper" (as published).
    regularization : ARX regularization "ridge" (okid default), "tc", or "none" (paper default).
    offsets : "remove" (the record's means, kept with the model; default) or "none".
    options : :class:`~okid_ros.core.options.RealizationOptions` of the realization.
    arx_orders : :class:`~okid_ros.core.options.ArxOrderOptions` of ``order="auto"``.
    valid : (N,) bool, optional: False at missing samples (their values, NaN too, ignored), which the
        ARX fit leaves out and the realization fills by its prediction as node 2 does
        (:mod:`.gap_fill`: gaps of at most 10, a tenth of the record). Not for "paper".
    option_changes : individual realization options (``n_states=6``, ``refine=False``, ...).

    Raises
    ------
    IdentificationError with a one-line reason on bad data or options.
    """
    options, u, y, valid = checked_record(u, y, sample_time_s, method=method, offsets=offsets, valid=valid,
                                          options=RealizationOptions() if options is None else options,
                                          changes=option_changes, order=order, regularization=regularization,
                                          arx_orders=arx_orders)
    u, y, valid, fault_warnings = record_faults(u, y, valid=valid, detrend=offsets == "remove",
                                                sample_time_s=sample_time_s, leave_out_spikes=method != "paper")
    p = y.shape[1]
    # Identified from the live inputs, each channel of unit spread, returned to the record's units
    # and inputs: the modes do not depend on the units, 1e+-150 does not overflow (core/scaling.py).
    present = (u, y) if valid is None else (u[valid], y[valid])
    frame = IdentificationFrame.of(*present, refuse_unexcited=False)  # refused below, after the size checks
    u, y = frame.enter(u, y)
    m = u.shape[1]
    # An intercept in the ARX fit, as identify_from_arx removes the means: the live window's model.
    center = offsets == "remove"
    arx_scores, normal, order_warnings = {}, None, []
    if order == AUTO:
        # The order search's normal equations of the chosen order serve its fit (not formed twice).
        try:
            choice, order_warnings = arx_order_for_realization(u, y, options=options, arx_orders=arx_orders,
                                                               center=center, valid=valid)
        except ValueError as exc:
            raise IdentificationError(str(exc)) from None
        order, arx_scores, normal = choice.order, choice.scores, choice.normal
    order = int(order)
    check_record_length(u.shape[0], order, p, m)
    if not frame.excited:
        raise IdentificationError(frame.warnings[0])
    regularization = ("none" if method == "paper" else "ridge") if regularization is None else regularization

    def fitted(q: int) -> tuple[ArxFit, np.ndarray, np.ndarray, np.ndarray | None]:
        return _fit_or_refuse(u, y, valid, q, normal if q == order else None, regularization=regularization,
                              center=center)

    if method == "paper":
        arx, u_fit, y_fit, _ = fitted(order)
        u_fit, y_fit, u_offset, y_offset, warnings = _remove_offsets(u_fit, y_fit, offsets)
        model = _identify_paper(arx, u_fit, y_fit, sample_time_s, options=options, u_offset=u_offset,
                                y_offset=y_offset, warnings=warnings)
    else:
        model = _identify_okid(fitted, order, sample_time_s, options=options, offsets=offsets,
                               order_by_gcv=bool(arx_scores), arx_orders=arx_orders, n_samples=y.shape[0])
    model.arx_order_scores = arx_scores
    # frame.warnings: the dead inputs (identify_from_arx saw only the live ones; the others it gave already)
    model.warnings += [w for w in fault_warnings + order_warnings + frame.warnings if w not in model.warnings]
    return frame.leave(model, offsets, offset_warnings=_remove_offsets(*frame.physical, offsets)[4])


def _fit_or_refuse(u, y, valid, order: int, normal, *, regularization: str, center: bool):
    """:func:`.gap_fill.fit_and_fill`, a failed fit refused (IdentificationError)."""
    try:
        return fit_and_fill(u, y, valid, order, normal, regularization=regularization, center=center)
    except ValueError as exc:
        raise IdentificationError(str(exc)) from None


def _identify_okid(fitted, order: int, sample_time_s: float, *, options: RealizationOptions, offsets: str,
                   order_by_gcv: bool, arx_orders: ArxOrderOptions | None, n_samples: int) -> IdentifiedModel:
    """:func:`identify_from_arx` of ``fitted(order)`` (ARX fit, record); unrefined, perhaps again from a longer order.

    :func:`.slow_pole_span.spanning_slowest_pole`, where GCV chose the order.
    """

    def identify_at(q: int) -> IdentifiedModel:
        arx, u, y, valid = fitted(q)
        return identify_from_arx(arx, u, y, sample_time_s, options=options, offsets=offsets, valid=valid)

    model = identify_at(order)
    if order_by_gcv and not model.refined:
        model = spanning_slowest_pole(model, identify_at, sample_time_s, max_damping=options.modes.max_damping,
                                      n_samples=n_samples, arx_orders=arx_orders)
    return model
