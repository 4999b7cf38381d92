"""Model-order search: complete the realization of every candidate order, pick one by BIC.

Step 5 of the chain (:mod:`okid_ros.core.pipeline`). Each candidate order of the weighted ERA
is completed into an innovation model, by the least-squares refit of the predictor
(:mod:`.refit`) or from the state sequence (:mod:`.state_completion`); the order with the
lowest BIC wins (one whose refit needed repair only by ``REPAIRED_MARGIN``; where that one cannot
be completed, the unrepaired winner: :func:`complete_chosen`). The automatic search tries every
order up to ``max_states`` (2 apart up to 40 states, about n / 20 apart above) and goes on,
doubling the limit, while BIC is lowest at it, up to ``max_states_limit`` and the Hankel rank,
and says so when it stops there. Given the
order of the previous window's model (the nodes, ``process`` and ``track``), the search is
warm-started: it screens a band of orders around it, widened until BIC has its minimum inside.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg

from okid_ros.core.era import HankelDecomposition
from okid_ros.core.identified_model import IdentificationError
from okid_ros.core.kalman_gain import kalman_gain_from_covariances
from okid_ros.core.options import AUTO, RealizationOptions
from okid_ros.core.refit import PredictorFit, gain_from_predictor, refit_predictor
from okid_ros.core.stabilization import NEIGHBOURS
from okid_ros.core.state_completion import complete_from_states
from okid_ros.core.state_gram import StateGram
from okid_ros.core.statespace import InnovationModel, free_parameters, predictor_states

__all__ = ["Completer", "OrderSearch", "choose_completion", "complete_chosen", "search_orders"]

#: Orders screened each side of the previous window's order in a warm-started search.
WARM_BAND = NEIGHBOURS + 2

#: The refit goes upwards until this many refitted orders in a row (repaired ones not counted)
#: have a higher BIC than the lowest so far.
REFIT_PATIENCE = 4

#: A repaired order (the least-squares refit left ``A`` unstable, completed from states) wins only
#: when its BIC per innovation sample and output beats every unrepaired order's by more than this
#: many nats (:meth:`OrderSearch.best_order`). Measured: where repaired orders beat the unrepaired
#: best on the benchmark cases (80 records, 120 random structures, 3 steel-subframe windows) they
#: did so by at most 0.011; on windows with drifting outputs (node 2 and ``track`` do not remove
#: trends; bench/record_faults.py's drift) where every order from 4 up is repaired, by 3.4-3.9,
#: and the 2 unrepaired states listed no mode. Between the two: a line holding 10 % of each
#: output's variance, where a repaired order won by 0.28 with 4 spurious modes at a margin of 0.1
#: (20 windows: 6 spurious modes at 0.1, 1 at 1.0 as with no margin).
REPAIRED_MARGIN = 1.0

# Above this many flops for the refit's normal equations, "auto" completes from states instead
# (2e10 is ~1 s here; the paper case needs 2e8, 28 outputs need 3e11).
PREDICTOR_REFIT_FLOP_LIMIT = 2e10


def choose_completion(completion: str, n_samples: int, n_outputs: int, n_inputs: int, max_states: int) -> str:
    """"predictor" (LS refit) while its normal equations stay cheap, else "states"."""
    if completion != "auto":
        return completion
    flops = n_samples * n_outputs * (max_states * (n_outputs + n_inputs)) ** 2
    return "predictor" if flops <= PREDICTOR_REFIT_FLOP_LIMIT else "states"


@dataclass
class OrderSearch:
    """What the order search found: the completed fit of each order tried."""

    fits: dict[int, PredictorFit]
    completion: str
    reasons: list[str]
    max_states_reached: bool = False
    limit_reason: str = ""

    repaired: set[int] = field(default_factory=set)
    screened: dict[int, PredictorFit] = field(default_factory=dict)  # every order, from the Gram
    failed: set[int] = field(default_factory=set)

    def diagram_models(self) -> dict[int, InnovationModel]:
        """The model of every order for the stabilization diagram: completed where available."""
        return {**{n: fit.model for n, fit in self.screened.items()}, **{n: fit.model for n, fit in self.fits.items()}}

    def best_order(self) -> int:
        """Lowest BIC among the orders whose refit needed no repair, unless a repaired one is far better.

        A repaired order (its least-squares refit left ``A`` unstable) is completed another way,
        whose in-sample fit is not comparable: on the more-outputs benchmark case such orders
        won BIC and predicted worse on new data. Only a repaired order whose BIC per innovation
        sample and output beats every unrepaired order's by more than ``REPAIRED_MARGIN`` wins
        (a drifting window: every order from 4 up repaired); :meth:`unrepaired_order` is the
        order without that exception, which the pipeline falls back to when the repaired one
        cannot be completed (:meth:`fallback_order`).
        """
        unrepaired = self.unrepaired_order()
        if unrepaired is None:
            return min(self.fits, key=lambda n: (self.fits[n].bic(), n))
        repaired = [n for n in self.fits if n in self.repaired]
        if repaired:
            best_repaired = min(repaired, key=lambda n: (self._bic_per_value(n), n))
            every_other = min(self._bic_per_value(n) for n in self.fits if n not in self.repaired)
            if every_other - self._bic_per_value(best_repaired) > REPAIRED_MARGIN:
                return best_repaired
        return unrepaired

    def unrepaired_order(self) -> int | None:
        """Lowest BIC among the orders whose refit needed no repair (None: every order was repaired)."""
        usable = [n for n in self.fits if n not in self.repaired]
        return min(usable, key=lambda n: (self.fits[n].bic(), n)) if usable else None

    def fallback_order(self, n: int) -> int | None:
        """The order to identify instead when order ``n``, chosen by :meth:`best_order`, cannot be completed.

        The unrepaired winner when ``n`` is a repaired order that won by ``REPAIRED_MARGIN`` (the
        order chosen before that exception); None otherwise (nothing to fall back to).
        """
        unrepaired = self.unrepaired_order()
        return unrepaired if n in self.repaired and unrepaired is not None and unrepaired != n else None

    def _bic_per_value(self, n: int) -> float:
        """BIC of order n per innovation sample and output: orders fitted on other samples compare."""
        fit = self.fits[n]
        n_samples = fit.innovations.shape[0] if fit.innovations is not None else fit.n_samples
        return fit.bic() / max(n_samples * fit.model.n_outputs, 1)


class Completer:
    """Completes the realization of any order into an innovation model (step 5).

    The state-sequence regressions of every order come from one Gram of the window
    (:class:`~okid_ros.core.state_gram.StateGram`), set up once at the largest order the search
    may reach; only the least-squares refit of the predictor passes over the data per order.
    """

    def __init__(self, decomposition: HankelDecomposition, gram: StateGram,
                 u: np.ndarray, y: np.ndarray, completion: str, *, options: RealizationOptions, burn_in: int):
        self.decomposition = decomposition
        self.u, self.y = u, y
        self.completion = completion
        self.options = options
        self.burn_in = burn_in
        self.gram = gram
        if options.automatic_order:
            top = max(options.max_states_limit, options.max_states)
        else:  # the order and the neighbours the stabilization diagram compares it with
            top = int(options.n_states) + 4 * _order_step(int(options.n_states))
        top = min(top, decomposition.max_states)
        dec = decomposition
        # ERA states x_k = S^-1/2 U^T H(0) z_k of every order up to the top one, as a map of z_k.
        gram.set_states((dec.U[:, :top].T @ dec.h0).T / np.sqrt(dec.s[:top]))
        self.eigen: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # eig of each screened A
        self.via_states: set[int] = set()  # orders completed from a state sequence
        self.repaired: set[int] = set()  # of those, orders whose least-squares refit left A unstable

    def screen(self, n: int) -> PredictorFit:
        """The state-sequence regressions of order n from the Gram: poles and BIC, no gain."""
        regression = self.gram.regress(n, max_radius=self.options.max_radius)
        self.eigen[n] = (regression.eigenvalues, regression.eigenvectors)
        p, m = regression.C.shape[0], regression.B.shape[1]
        model = InnovationModel(regression.A, regression.B, regression.C, regression.D, np.zeros((n, p)),
                                regression.output_covariance)
        return PredictorFit(model, np.zeros(n), None, free_parameters(n, p, m), n_samples=regression.n_samples)

    def complete(self, n: int, passes: int = 0, *, screen: bool = False) -> PredictorFit:
        """The completed model of order n (raises ValueError / LinAlgError when impossible).

        ``screen``: with the state completion, only the regressions (no gain), enough to compare
        orders by BIC and to see their poles (:meth:`screen`).
        """
        opts = self.options
        if self.completion == "states":
            return self._from_era_states(n, passes, screen)
        realization = self.decomposition.realize(n)
        if not np.max(np.abs(linalg.eigvals(realization.A))) < 1.0:
            # ERA's predictor is unstable at this order: the refit cannot run, the states can.
            self.repaired.add(n)
            return self._from_era_states(n, passes, screen)
        fit = refit_predictor(realization.A, realization.C, self.u, self.y)
        if opts.gain == "riccati" or not fit.model.spectral_radius() < 1.0:
            # The refit's A = Abar + L C is unstable (or the Riccati gain is asked for): go on from
            # the refitted predictor's state sequence, which gives a stable A and gain.
            states, _ = predictor_states(fit.model, self.u, self.y, fit.x0)
            self.via_states.add(n)
            if opts.gain != "riccati":
                self.repaired.add(n)
            fit = complete_from_states(states, self.u, self.y, passes=passes, burn_in=self.burn_in,
                                       max_radius=opts.max_radius)
        return fit

    def _from_era_states(self, n: int, passes: int, screen: bool) -> PredictorFit:
        """Completion from the ERA state sequence of the samples with a full past.

        The regressions come from the Gram, which leaves missing samples out; the predictor's
        passes run over the window's samples from the first with a full past, contiguous (the
        missing ones filled by prediction, as :func:`identify_from_arx` receives them).
        """
        rows = np.arange(self.gram.rows[0], self.gram.rows[-1] + 1)
        self.via_states.add(n)
        if screen:
            return self.screen(n)
        regression = self.gram.regress(n, max_radius=self.options.max_radius, covariances=True)
        L, Re = kalman_gain_from_covariances(regression.A, regression.C, *regression.noise_covariances())
        first = InnovationModel(regression.A, regression.B, regression.C, regression.D,
                                gain_from_predictor(regression.A, L), Re)
        return complete_from_states(None, self.u[rows], self.y[rows], passes=passes, burn_in=0,
                                    max_radius=self.options.max_radius, first=first)


def _order_step(n: int) -> int:
    """Spacing of the orders tried near ``n``: 2 up to 40 states, then about n / 20 (even)."""
    return max(2, 2 * int(round(n / 40)))


def _orders_to_try(n_states: int | str, limit: int, tried: set[int]) -> list[int]:
    """Orders up to ``limit`` not yet tried (automatic), or the order and its neighbours.

    Above 40 states the orders are spaced wider (:func:`_order_step`): the cost of an order
    grows with its square and neighbouring orders give nearly the same model.
    """
    if n_states == AUTO:
        orders, n = [], 2
        while n <= limit:
            orders.append(n)
            n += _order_step(n)
        return [n for n in orders if n not in tried] or ([1] if not tried else [])
    n = int(n_states)
    step = _order_step(n)
    neighbours = [n + k * step for k in range(-4, 5) if 1 <= n + k * step <= limit]  # for the stabilization
    return sorted(({n} | set(neighbours)) - tried)


def _screen_orders(completer: Completer, options: RealizationOptions, search: OrderSearch,
                   order_hint: int | None = None) -> None:
    """Every candidate order from the Gram; the limit doubles while BIC is lowest at it.

    With ``order_hint`` (the previous window's order, automatic order only) the search is warm
    started: :func:`_screen_band`.
    """
    rank = completer.decomposition.max_states
    limit = min(options.max_states, rank) if options.automatic_order else rank
    limit = min(limit, completer.gram.max_states)
    top = min(options.max_states_limit, rank, completer.gram.max_states)
    band: dict[int, PredictorFit] = {}
    if options.automatic_order and order_hint is not None:
        if _screen_band(completer, search, int(order_hint), limit, top, options):
            return
        # The full search decides, on exactly its own orders; the band's fits are reused.
        band = dict(search.screened)
        search.screened.clear()
        search.reasons.clear()
        search.max_states_reached, search.limit_reason = False, ""
    tried: set[int] = set()
    while True:
        for n in _orders_to_try(options.n_states, limit, tried):
            tried.add(n)
            if n in band:
                search.screened[n] = band[n]
            else:
                _screen(completer, search, n)
        if not options.automatic_order or not search.screened:
            return
        best = min(search.screened, key=lambda n: (search.screened[n].bic(), n))
        if best < max(tried):
            return
        if limit >= top:
            _at_limit(search, rank, options)
            return
        limit = min(2 * limit, top)


def _screen(completer: Completer, search: OrderSearch, n: int) -> None:
    try:
        search.screened[n] = completer.complete(n, screen=True) if completer.completion == "states" \
            else completer.screen(n)
    except (ValueError, linalg.LinAlgError, np.linalg.LinAlgError) as exc:
        search.reasons.append(f"n={n}: {exc}")


def _at_limit(search: OrderSearch, rank: int, options: RealizationOptions) -> None:
    search.max_states_reached = True
    search.limit_reason = (
        f"the Hankel rank {rank}" if rank <= options.max_states_limit
        else f"max_states_limit {options.max_states_limit}"
    )


def _screen_band(completer: Completer, search: OrderSearch, hint: int, limit: int, top: int,
                 options: RealizationOptions) -> bool:
    """The warm-started search: the orders around ``hint``, widened until BIC has a minimum inside.

    The band starts ``WARM_BAND`` orders each side of the hint and grows on a side while the
    winner has fewer than ``NEIGHBOURS + 1`` screened orders there (its modes' stability is
    judged on ``NEIGHBOURS`` each side; one more tells a minimum from the band's edge); at the
    limit, the limit doubles as in the full search. The same minimum gives the same model as
    the full search (each order's screening is independent). A window's order moves little
    from the previous window's, so a minimum within the first band is taken; one the band had to
    widen to reach says the hint was poor (BIC may have another minimum elsewhere): False, and
    the caller runs the full search (the orders screened here are not screened again).
    """
    orders = _orders_to_try(AUTO, top, set())
    at = int(np.argmin(np.abs(np.asarray(orders) - hint)))
    lo, hi = orders[max(0, at - WARM_BAND)], orders[min(len(orders) - 1, at + WARM_BAND)]
    first_band = (lo, hi)
    limit = max(limit, min(hi, top))
    tried: set[int] = set()
    while True:
        in_reach = _orders_to_try(AUTO, limit, set())
        for n in in_reach:
            if lo <= n <= hi and n not in tried:
                tried.add(n)
                _screen(completer, search, n)
        if not search.screened:
            return False
        best = min(search.screened, key=lambda n: (search.screened[n].bic(), n))
        at = in_reach.index(best)
        missing = [n for n in in_reach[max(0, at - NEIGHBOURS - 1) : at + NEIGHBOURS + 2] if n not in tried]
        if missing:
            lo, hi = min(lo, missing[0]), max(hi, missing[-1])
            continue
        if not first_band[0] <= best <= first_band[1]:
            return False
        if best < in_reach[-1]:
            return True
        if limit >= top:
            _at_limit(search, completer.decomposition.max_states, options)
            return True
        limit = min(2 * limit, top)
        hi = limit


def _refit_near(completer: Completer, options: RealizationOptions, search: OrderSearch) -> None:
    """The least-squares refit (a pass over the data per order) only up to the screened winner.

    Refits the orders up to two steps above the order the Gram screening prefers, from the
    lowest, until ``REFIT_PATIENCE`` refitted orders in a row have not lowered BIC (the refit's
    BIC rises past its minimum while the screening's may go on falling: on the more-outputs
    benchmark case the refit's minimum is at 14 states, the screening's at 52); goes on upwards
    while the refitted BIC is lowest at the largest order refitted, and refits the winner's
    ``NEIGHBOURS`` orders above it (the stabilization diagram judges its modes there).
    """
    orders = sorted(search.screened)
    if options.automatic_order and not orders:
        return
    if not options.automatic_order:
        # The order and all its neighbours, as before: the stabilization of its modes is judged
        # on them, and the screened models' poles judged a 2 Hz mode of a 2000-sample window
        # unstable where the refitted ones kept it (test_service_estimation).
        chosen = sorted({int(options.n_states)} | set(orders))
    else:
        start = orders.index(min(orders, key=lambda n: (search.screened[n].bic(), n)))
        # Up to two steps above the screened winner: the screening's BIC keeps improving past
        # the refit's minimum (its states see the whole ARX window), so the refit's minimum lay
        # below it on every benchmark case (6 to 10 orders less, 38 on more-outputs), never
        # above. The refit cost grows with n^2: from the low orders up, stopping past its minimum.
        chosen = orders[: start + 3]

    def run(n: int) -> None:
        if n in search.fits or n in search.failed:
            return
        try:
            search.fits[n] = completer.complete(n, screen=True)
        except (ValueError, linalg.LinAlgError, np.linalg.LinAlgError) as exc:
            search.failed.add(n)
            search.reasons.append(f"n={n}: {exc}")

    since_best, best_bic = 0, np.inf
    for n in chosen:
        run(n)
        if not options.automatic_order or n not in search.fits or n in completer.repaired:
            continue
        bic = search.fits[n].bic()
        since_best = 0 if bic < best_bic else since_best + 1
        best_bic = min(best_bic, bic)
        if since_best >= REFIT_PATIENCE:
            break
    while options.automatic_order and search.fits:
        search.repaired = completer.repaired
        best = orders.index(search.best_order())
        done = sorted(orders.index(n) for n in search.fits)
        if best == done[0] and best > 0:
            run(orders[best - 1])
        elif best == done[-1] and best < len(orders) - 1:
            run(orders[best + 1])
        else:
            break
        if orders.index(search.best_order()) == best:
            break
    while options.automatic_order and search.fits:
        # The winner's neighbours above are refitted too: the stability of its modes is judged
        # on the NEIGHBOURS orders each side (stable_fraction), as when every order was refitted.
        search.repaired = completer.repaired
        best = orders.index(search.best_order())
        above = orders[best + 1 : best + 1 + NEIGHBOURS]
        missing = [n for n in above if n not in search.fits and n not in search.failed]
        if not missing:
            break
        for n in missing:
            run(n)
    search.repaired = completer.repaired


def search_orders(completer: Completer, options: RealizationOptions, *, order_hint: int | None = None) -> OrderSearch:
    """Screen every candidate order from the Gram, complete the best; BIC picks one (step 5).

    The screening goes past ``max_states`` while BIC is lowest at the limit, up to
    ``max_states_limit`` and the Hankel rank. With the state completion the screened fits are
    the completed ones (as before: regressions only); with the predictor refit, the refit runs
    only near the screened winner (:func:`_refit_near`). ``order_hint``: the order of the
    previous window's model, which warm-starts an automatic search (:func:`_screen_band`).
    """
    rank = completer.decomposition.max_states
    if not options.automatic_order and not 1 <= int(options.n_states) <= rank:
        raise IdentificationError(
            f"{options.n_states} states are not supported: the Hankel matrix of these data has "
            f"numerical rank {rank}"
        )
    search = OrderSearch({}, completer.completion, [])
    _screen_orders(completer, options, search, order_hint)
    if completer.completion == "states":
        search.fits = dict(search.screened)
        search.repaired = completer.repaired
    else:
        _refit_near(completer, options, search)
        if search.max_states_reached and search.fits and search.best_order() < max(search.screened):
            # The screening's BIC was lowest at the limit, the refitted one is not: no warning.
            search.max_states_reached, search.limit_reason = False, ""
    if not options.automatic_order and int(options.n_states) not in search.fits:
        raise IdentificationError(
            f"order {options.n_states} gave no usable model: " + "; ".join(search.reasons[:3])
        )
    if not search.fits:
        raise IdentificationError("no model order gave a usable predictor: " + "; ".join(search.reasons[:3]))
    return search


def complete_chosen(n: int, complete: Callable[[int], PredictorFit], *,
                    fallback: int | None = None) -> tuple[int, PredictorFit]:
    """The chosen order's completed fit ``complete(n)``, or the fallback order's where it is not usable.

    Parameters
    ----------
    n : the order chosen (:meth:`OrderSearch.best_order`).
    complete : the completion of an order (raises IdentificationError where impossible).
    fallback : the order to identify when order ``n`` cannot be completed or completes to a model
        that must not be used (:meth:`OrderSearch.fallback_order`: the unrepaired winner when ``n``
        is a repaired order chosen by ``REPAIRED_MARGIN``), or None: ``complete(n)`` as it is.

    Returns
    -------
    The order identified and its completed fit. Where the fallback is taken, the warnings of the
    attempt on ``n`` are dropped with it (on a noise-free record, an ill-conditioned solve of the
    order given up): they are not about the model handed out.
    """
    if fallback is None:
        return n, complete(n)
    # The rule before REPAIRED_MARGIN identified every record it identified from ``fallback``: a
    # margin-chosen order that fails must not fail the record (noise-free: order 16 of 2-24 gave
    # no finite predictions, 6 did).
    with warnings.catch_warnings(record=True) as caught:
        try:
            fit: PredictorFit | None = complete(n)
        except IdentificationError:
            fit = None
    if fit is None or fit.model.stability_problem():
        return fallback, complete(fallback)
    for warning in caught:
        warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    return n, fit
