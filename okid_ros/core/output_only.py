"""Output-only (ambient) identification: modes and an innovation model from outputs alone.

:func:`identify_output_only` turns a record ``y`` (N, p) with no measured input into the
project's :class:`~okid_ros.core.identified_model.IdentifiedModel` with m = 0 (``B`` (n, 0),
``D`` (p, 0)), ``A``, ``C``, ``K`` (paper convention, predictor gain ``A K``) and the innovation
covariance, in normalized modal form, with its physical modes and their standard deviations.

Steps (one module each):

1. means removed; reference channels and the lag window from the data
   (:mod:`.output_covariance`);
2. ``method="ssi-cov"`` (default): output correlations of consecutive segments, block Hankel,
   ERA (:mod:`.stochastic_realization`); ``method="var"``: a vector AR whose stochastic Markov
   parameters ``C A^(k-1) A K`` are realized by the same ERA (the paper's route);
3. the poles of every order, stable ones clustered into modes (:mod:`.output_only_modes`);
4. the model at the lowest order holding every mode; its innovation model by the stochastic
   Riccati equation (ssi-cov) or read from the VAR (var);
5. modes' standard deviations by the jackknife over the record's segments (the mode
   re-identified at the model order with each segment left out), ``method="ssi-cov"``; the
   spread of the cluster across orders otherwise.
"""

from __future__ import annotations

import numpy as np
from scipy import linalg

from okid_ros.core.era import decompose_hankel
from okid_ros.core.identified_model import IdentificationError, IdentifiedModel
from okid_ros.core.modal import modal_form
from okid_ros.core.options import ModeCriteria
from okid_ros.core.output_covariance import choose_block_rows, output_correlations, reference_channels
from okid_ros.core.output_only_modes import (
    ModeCluster,
    cluster_modes,
    collect_poles,
    lowest_complete_order,
    mark_stable,
)
from okid_ros.core.output_only_support import (
    jackknife_std,
    match_clusters,
    output_only_diagram,
    prepare_outputs,
)
from okid_ros.core.stochastic_realization import (
    OrderRealizer,
    covariance_decomposition,
    fit_var,
    forward_innovation,
    gain_from_markov,
    stochastic_markov_from_var,
)
from okid_ros.core.uncertainty import UncertaintyResult

__all__ = ["OUTPUT_ONLY_METHODS", "identify_output_only"]

OUTPUT_ONLY_METHODS = ("ssi-cov", "var")
#: Most Hankel columns' channels (references); more outputs are represented by the best spread.
MAX_REFERENCES = 12
#: Highest model order tried by default, and the damping limit of a candidate pole.
DEFAULT_MAX_STATES = 100
MAX_DAMPING = 0.1
#: Segments of the record for the correlations' jackknife.
N_SEGMENTS = 8
#: The VAR of route (a) keeps at most this many coefficients per output (and N / 10).
MAX_VAR_COEFFICIENTS = 1500


def identify_output_only(
    y: np.ndarray,
    sample_time_s: float,
    *,
    method: str = "ssi-cov",
    max_states: int | None = None,
    block_rows: int | None = None,
    offsets: str = "remove",
    uncertainty: bool = True,
) -> IdentifiedModel:
    """Identify an innovation model and its modes from outputs alone.

    Parameters
    ----------
    y : (N, p) outputs (accelerations, strains, ...), finite.
    sample_time_s : sample time in seconds.
    method : "ssi-cov" (covariance-driven SSI / NExT-ERA, default) or "var" (vector AR and the
        OKID recursion, the paper's route).
    max_states : highest model order tried (default :data:`DEFAULT_MAX_STATES`, less when the
        Hankel is smaller).
    block_rows : Hankel block rows (default from the data: several periods of the slowest mode).
    offsets : "remove" (default, the means are kept with the model) or "none".
    uncertainty : compute the modes' standard deviations.

    Returns
    -------
    IdentifiedModel with ``n_inputs == 0``; ``modes`` are the selected modes.

    Raises
    ------
    IdentificationError with a one-line reason.
    """
    if method not in OUTPUT_ONLY_METHODS:
        raise IdentificationError(f"output-only method must be one of {OUTPUT_ONLY_METHODS}, got {method!r}")
    y, offset, warnings = prepare_outputs(y, sample_time_s, offsets)
    n_samples, p = y.shape
    references = reference_channels(y, MAX_REFERENCES)
    top = int(max_states or DEFAULT_MAX_STATES)
    if block_rows is None:
        block_rows, _ = choose_block_rows(y, sample_time_s, n_references=references.size, max_states=top)
    block_rows = int(block_rows)
    if 2 * block_rows + 1 > n_samples // 4:
        raise IdentificationError(f"too few samples ({n_samples}) for {block_rows} Hankel block rows")
    correlations = output_correlations(y, 2 * block_rows, N_SEGMENTS)
    r_mean = correlations.mean
    var = None
    if method == "ssi-cov":
        decomposition = covariance_decomposition(r_mean, references, block_rows)
    else:
        var, decomposition = _var_decomposition(y, block_rows, p)
    top = int(min(top, decomposition.max_states, references.size * block_rows if var is None else top))
    top -= top % 2
    if top < 2:
        raise IdentificationError("the Hankel matrix has rank below 2: no mode can be identified")
    realizer = OrderRealizer(decomposition, top)
    poles = collect_poles(realizer.realize, range(2, top + 1, 2), sample_time_s,
                          max_damping=MAX_DAMPING, max_frequency_hz=0.475 / sample_time_s)
    mark_stable(poles)
    modes, _ = cluster_modes(poles)
    n_model = lowest_complete_order(modes)
    if n_model is None:
        raise IdentificationError("no stable mode found across model orders: is the record long and excited enough?")
    A, C, gamma = realizer.realize(n_model)
    if var is None:
        L, Re = _covariance_innovation(A, C, gamma, r_mean, block_rows)
    else:
        L, Re = gain_from_markov(A, C, var[1]), var[0].residual_covariance
    model = _package(A, C, L, Re, poles, modes, n_model, sample_time_s, offset, warnings,
                     method=method, arx=None if var is None else var[0], diagram=output_only_diagram(poles),
                     singular_values=decomposition.s)
    if uncertainty and method == "ssi-cov" and correlations.segments.shape[0] >= 3:
        jackknife_std(model, correlations, references, block_rows, n_model)
        model.uncertainty = UncertaintyResult(True, "", 0, int(correlations.segments.shape[0]))
    else:
        model.uncertainty = UncertaintyResult(True, "", 0, 0)  # the clusters' spread across orders
    return model


def _var_decomposition(y: np.ndarray, block_rows: int, p: int):
    """Route (a): VAR over the lag window (at most the coefficient budget), stochastic Markov, SVD."""
    budget = min(MAX_VAR_COEFFICIENTS, y.shape[0] // 10)
    order = int(max(2, min(2 * block_rows, budget // p)))
    var = fit_var(y, order)
    markov = stochastic_markov_from_var(var, 2 * block_rows + 1)
    return (var, markov), decompose_hankel(markov, block_rows, block_rows)


def _covariance_innovation(A, C, gamma, correlations, block_rows):
    """``L``, ``Re`` of the forward innovation model of the covariance model at this order."""
    p = C.shape[0]
    stacked = correlations[1 : block_rows + 1].reshape(block_rows * p, p)  # [R_1; ..; R_i], all columns
    G = linalg.lstsq(gamma, stacked)[0]
    solved = forward_innovation(A, C, G, correlations[0])
    if solved is None:
        # Not positive real (a pole of the model fits the correlations' noise): the gain that
        # best reproduces the correlations' free decay, still checked for a stable predictor.
        raise IdentificationError("the covariance model is not positive real: no forward innovation model")
    return solved


def _package(A, C, L, Re, poles, modes: list[ModeCluster], n_model, sample_time_s, offset, warnings, *,
             method, arx, diagram, singular_values) -> IdentifiedModel:
    """Modal form of the model at ``n_model``, its physical modes those matched to a cluster."""
    n, p = A.shape[0], C.shape[0]
    K = linalg.solve(A, L)
    chosen = match_clusters(modes, poles, n_model)
    criteria = ModeCriteria(max_damping=MAX_DAMPING, min_msv=0.0, min_mpc=0.0)

    def selected(mode) -> float:
        return 1.0 if any(abs(mode.eigenvalue - ev) < 1e-9 for ev, _ in chosen) else 0.0

    # The stochastic input (L) stands for B in the modal indicators: it is what excites the modes.
    form = modal_form(A, L, C, K, sample_time_s, None, criteria=criteria, stability=selected)
    for i, mode in enumerate(form.modes):
        mode.id = i
        cluster = next(c for ev, c in chosen if abs(mode.eigenvalue - ev) < 1e-9)
        mode.frequency_hz_std = cluster.frequency_hz_spread
        mode.damping_ratio_std = cluster.damping_ratio_spread
        mode.extras = {"orders": len(cluster.members), "cluster_frequency_hz": cluster.frequency_hz,
                       "cluster_damping_ratio": cluster.damping_ratio}
    model = IdentifiedModel(
        A=form.A, B=np.zeros((n, 0)), C=form.C, D=np.zeros((p, 0)), K=form.K, innovation_covariance=Re,
        sample_time_s=sample_time_s, modes=form.modes, arx=arx, method=method,
        gain_method="riccati" if method == "ssi-cov" else "var", completion="output-only",
        hankel_singular_values=singular_values, stabilization=diagram, x0=np.zeros(n),
        input_offset=np.zeros(0), output_offset=offset, warnings=warnings,
        order_scores={}, max_states_reached=False,
    )
    problem = model.stability_problem()
    if problem:
        raise IdentificationError(f"refused: {problem}")
    return model
