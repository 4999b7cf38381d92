"""Choice of the ARX order by generalized cross-validation (split from :mod:`okid_ros.core.arx`).

:func:`select_arx_order` scores candidate orders; :func:`arx_order_for_realization` (and
:func:`choose_arx_order`) adds the floor the realization's Hankel matrix needs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from okid_ros.core.arx_gram import arx_normal_equations
from okid_ros.core.least_squares import (
    NormalEquations,
    center_normal_equations,
    channel_mean_square,
    prior_precision,
    solve_normal_equations,
)
from okid_ros.core.options import ArxOrderOptions, RealizationOptions
from okid_ros.core.regressors import check_io_arrays, longest_given_order, regressor_length, samples_for_order
from okid_ros.core.state_gram import fewest_state_samples

__all__ = ["ArxOrderChoice", "arx_order_for_realization", "choose_arx_order", "fewest_samples_to_identify",
           "longest_arx_order", "select_arx_order", "most_states", "states_problem"]

#: A record too short for the whole state search still gets a search of at least one mode.
MIN_SEARCH_STATES = 2


@dataclass
class ArxOrderChoice:
    """Result of :func:`select_arx_order`.

    Attributes
    ----------
    order : the chosen ARX order q.
    scores : GCV score per row of each order tried (q -> score; lower is better).
    limited_by : why larger orders were not tried ("" if the candidates ran out or the
        score rose), e.g. the record length or the cost limit.
    normal : the normal equations of the chosen order (uncentered), for its fit.
    """

    order: int
    scores: dict[int, float]
    limited_by: str = ""
    normal: NormalEquations | None = None  # the chosen order's normal equations (not centered)


def longest_arx_order(n_samples: int, n_outputs: int, n_inputs: int, *, min_rows_per_coefficient: float) -> int:
    """The largest ARX order q a record fits: ``N - q >= rows * (m + q (p + m))`` regressor rows."""
    rows = float(min_rows_per_coefficient)
    return int((n_samples - rows * n_inputs) // (1.0 + rows * (n_outputs + n_inputs)))


def select_arx_order(
    u: np.ndarray,
    y: np.ndarray,
    *,
    candidates: tuple[int, ...],
    min_order: int = 2,
    max_coefficients: int = 2500,
    min_rows_per_coefficient: float = 2.0,
    patience: int = 2,
    center: bool = False,
    valid: np.ndarray | None = None,
) -> ArxOrderChoice:
    """Choose the ARX order by generalized cross-validation of the ridge fit.

    The GCV score ``n rss / (n - dof)^2`` of the ridge fit (penalty itself chosen by GCV)
    estimates the one-step prediction error on new data, so it compares orders fairly. The
    candidates at or above ``min_order`` are tried in increasing order while the regressor
    length ``d = m + q (p + m)`` stays within ``max_coefficients`` and the record gives at
    least ``min_rows_per_coefficient`` rows per coefficient; the search stops ``patience``
    candidates after the best one.

    Parameters
    ----------
    u : (N, m); y : (N, p) one contiguous record.
    candidates : ARX orders to try.
    min_order : smallest order allowed (e.g. what the realization's Hankel matrix needs).
    center : score the fits with an intercept (signals with offsets).
    valid : (N,) bool, optional: False at missing samples (finite placeholders in ``u``, ``y``);
        the regressor rows that reach one are left out (:func:`.arx_gram.arx_normal_equations`).

    Raises
    ------
    ValueError
        If no candidate fits the record.
    """
    u, y = check_io_arrays(u, y)
    m, p = u.shape[1], y.shape[1]
    tried = {max(int(q), 1) for q in candidates if q >= min_order}
    tried = sorted(tried | ({min_order} if min_order > max(candidates) else set()))
    scores: dict[int, float] = {}
    limited_by = ""
    best_q, best_score, since_best = 0, np.inf, 0
    n_present = u.shape[0] if valid is None else int(np.count_nonzero(valid))
    longest = longest_arx_order(n_present, p, m, min_rows_per_coefficient=min_rows_per_coefficient)
    best_normal = None
    for q in tried:
        d = regressor_length(q, p, m)
        if d > max_coefficients:
            limited_by = f"cost: ARX order {q} has {d} coefficients per output (limit {max_coefficients})"
            break
        if q > longest:
            limited_by = f"record length: ARX order {q} needs {int(min_rows_per_coefficient * d) + q} samples"
            break
        uncentered = arx_normal_equations(u, y, q, valid)
        if uncentered.n_rows < min_rows_per_coefficient * d:  # the rows gaps leave (exact without gaps above)
            limited_by = f"record length: ARX order {q} has {uncentered.n_rows} regressor rows between the gaps"
            break
        normal = center_normal_equations(uncentered) if center else uncentered
        precision = prior_precision(q, p, m, channel_mean_square(normal, p, m, q), "ridge")
        _, _, dof, gcv = solve_normal_equations(normal, precision, "gcv")
        scores[q] = float(gcv) / normal.n_rows  # per row: orders differ in row count
        if scores[q] < best_score:
            best_q, best_score, since_best = q, scores[q], 0
            best_normal = uncentered
        else:
            since_best += 1
            if since_best >= patience:
                break
    if not scores:
        raise ValueError(
            f"no ARX order can be fitted to {u.shape[0]} samples with {m} inputs and {p} outputs ({limited_by})"
        )
    return ArxOrderChoice(best_q, scores, limited_by if best_q == max(scores) else "", best_normal)


def choose_arx_order(
    u: np.ndarray,
    y: np.ndarray,
    *,
    options: RealizationOptions | None = None,
    arx_orders: ArxOrderOptions | None = None,
    center: bool = True,
) -> tuple[int, dict]:
    """Step 2a: the ARX order by GCV, at least what the realization's Hankel matrix needs.

    ``center``: the fits take the offsets as an intercept (as ``offsets="remove"`` does).

    Returns
    -------
    order : the chosen q; scores : GCV score per row of each order tried.

    Raises
    ------
    ValueError when no order fits the record.
    """
    choice, _ = arx_order_for_realization(u, y, options=options, arx_orders=arx_orders, center=center)
    return choice.order, choice.scores


def fewest_samples_to_identify(n_outputs: int, n_inputs: int) -> int:
    """The fewest samples identify takes with inputs: the ARX fit of order 2 and the realization of its states.

    At order 2 the Hankel matrix has one block row (``p`` states) and the state search begins at
    :data:`MIN_SEARCH_STATES`, one mode's worth (1 state with one output); their equations are
    regressed on the ``N - 1`` states the order leaves (:func:`~okid_ros.core.state_gram.fewest_state_samples`),
    which needs more than the ARX fit with few inputs (2 inputs and 2 outputs: 14 samples, the fit 13).
    ``export`` refuses a shorter record, and the automatic order's refusal names this number.
    """
    states = min(MIN_SEARCH_STATES, n_outputs)
    return max(samples_for_order(2, n_outputs, n_inputs), fewest_state_samples(states, n_inputs, n_outputs) + 1)


def min_arx_order(states: int, n_outputs: int) -> int:
    """The smallest ARX order whose Hankel matrix holds ``states`` (rows about half the lags)."""
    return 2 * int(np.ceil(states / n_outputs)) + 1


def most_states(n_present: int, n_outputs: int, n_inputs: int, *, arx_orders: ArxOrderOptions) -> tuple[int, str]:
    """The most states a given state order may have on a record of ``n_present`` samples, and what bounds it.

    ``n`` states need the ARX order :func:`min_arx_order` ``(n, p)`` for the realization's Hankel
    matrix, within the cost limit (``arx_orders.max_coefficients``) and the record
    (:func:`longest_arx_order`).
    """
    p, m = n_outputs, n_inputs
    by_cost = (arx_orders.max_coefficients - m) // (p + m)
    by_record = longest_arx_order(n_present, p, m, min_rows_per_coefficient=arx_orders.min_rows_per_coefficient)
    if by_cost <= by_record:
        why = f"the limit of {arx_orders.max_coefficients} ARX coefficients per output"
    else:
        why = f"the {n_present} samples of the fit"
    return max(p * ((min(by_cost, by_record) - 1) // 2), 0), why


def states_problem(states: int, n_present: int, n_outputs: int, n_inputs: int, *,
                   arx_orders: ArxOrderOptions) -> str:
    """Why a given order of ``states`` cannot be realized from an ARX fit of the record, or "".

    The ARX order the Hankel matrix of ``states`` needs must fit (:func:`most_states`); the cost
    of the ARX fit is named only as the reason for the bound on the states.
    """
    most, why = most_states(n_present, n_outputs, n_inputs, arx_orders=arx_orders)
    if states <= most:
        return ""
    needs = (f"needs an ARX order of at least {min_arx_order(states, n_outputs)} for its Hankel matrix with "
             f"{n_outputs} output{'s' if n_outputs > 1 else ''}")
    if most < 1:
        return f"{needs}; no state order fits within {why}"
    return f"{needs}; at most {most} states fit within {why}"


def _too_short_for_a_search(n_present: int, smallest: int, p: int, m: int, arx_orders: ArxOrderOptions) -> str:
    """Why ``n_present`` samples take no automatic ARX order, and which given order they take (or that none does)."""
    needed = int(arx_orders.min_rows_per_coefficient * regressor_length(smallest, p, m)) + smallest
    fewest = fewest_samples_to_identify(p, m)
    given = longest_given_order(n_present, p, m) if n_present >= fewest else 0  # above order 2 the ARX fit needs more
    if given < 2:  # the realization needs two blocks of Markov parameters (ARX order 2)
        return (f"{n_present} samples are too few for any ARX order: the smallest a given order can be, 2 (with {m} "
                f"inputs and {p} outputs), needs {fewest} samples, the automatic order's "
                f"smallest, {smallest} ({MIN_SEARCH_STATES} states' worth), {needed}")
    return (f"{n_present} samples are too few for an automatic ARX order: the smallest it takes, {smallest} "
            f"({MIN_SEARCH_STATES} states' worth), needs {needed} samples; a given order up to {given} fits them")


def arx_order_for_realization(u: np.ndarray, y: np.ndarray, *, options: RealizationOptions | None,
                              arx_orders: ArxOrderOptions | None, center: bool, valid: np.ndarray | None = None
                              ) -> tuple[ArxOrderChoice, list[str]]:
    """:func:`choose_arx_order` with the chosen order's normal equations (for its fit), and warnings.

    With an automatic state order, a record too short for the order that the whole state search
    needs falls back to the orders it can fit (down to one mode's worth): the search then stops
    at that Hankel matrix's rank, and the warning says so. ``valid``: as :func:`select_arx_order`.
    Raises ValueError when no order fits.
    """
    options = options or RealizationOptions()
    arx_orders = arx_orders or ArxOrderOptions()
    p = y.shape[1]
    states = options.max_states if options.automatic_order else int(options.n_states)
    min_order = min_arx_order(states, p)
    if not options.automatic_order:
        n_present = u.shape[0] if valid is None else int(np.count_nonzero(valid))
        if problem := states_problem(states, n_present, p, u.shape[1], arx_orders=arx_orders):
            raise ValueError(f"{states} states: {problem}")

    def choose(floor: int, candidates: tuple[int, ...] = arx_orders.candidates) -> ArxOrderChoice:
        return select_arx_order(
            u, y, candidates=candidates, min_order=floor, max_coefficients=arx_orders.max_coefficients,
            min_rows_per_coefficient=arx_orders.min_rows_per_coefficient, center=center, valid=valid,
        )

    try:
        return choose(min_order), []
    except ValueError:
        n_present = u.shape[0] if valid is None else int(np.count_nonzero(valid))
        longest = longest_arx_order(n_present, p, u.shape[1],
                                    min_rows_per_coefficient=arx_orders.min_rows_per_coefficient)
        if not options.automatic_order:
            raise
        smallest = min_arx_order(MIN_SEARCH_STATES, p)
        if longest < smallest:  # the order cited by select_arx_order was the search's, not the fallback's
            raise ValueError(_too_short_for_a_search(n_present, smallest, p, u.shape[1], arx_orders)) from None
    choice = choose(longest, (longest,))
    return choice, [
        f"{n_present} samples are too few for the ARX order a search up to {states} states needs "
        f"({min_order}): ARX order {choice.order}, the largest the record fits; the state search stops at "
        f"its Hankel matrix's rank"
    ]
