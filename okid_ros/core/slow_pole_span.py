"""An ARX order spanning the slowest mode, for a model the refinement did not correct.

The ARX order chosen by GCV predicts best, but a lightly damped mode slower than the ARX model's
span (its order in samples) is placed by the realization alone: 0.5-2 % off on random structures
with 6 or more outputs, where the prediction-error refinement exceeds its cost bound and does not
run (docs/benchmarks-realization.md, "An ARX order spanning the slowest mode"). Where it runs,
the refinement corrects such a pole, and the longer order then gained little and cost a second
identification on half the records, so only an unrefined model is identified again.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from okid_ros.core.arx_order import longest_arx_order
from okid_ros.core.identified_model import IdentificationError, IdentifiedModel
from okid_ros.core.modal import continuous_poles
from okid_ros.core.options import ArxOrderOptions

__all__ = ["MIN_PERIODS_IN_RECORD", "arx_order_spanning_slowest_pole", "spanning_slowest_pole"]

#: A pole with fewer periods than this in the record is no mode to span (a drift, an offset's
#: pole): it would only raise the order to the cost limit. Random structures hold 300 or more.
MIN_PERIODS_IN_RECORD = 10


def arx_order_spanning_slowest_pole(A: np.ndarray, sample_time_s: float, order: int, *, n_outputs: int,
                                    n_inputs: int, n_samples: int, max_damping: float,
                                    arx_orders: ArxOrderOptions | None = None) -> tuple[int, float]:
    """The ARX order spanning one period of the slowest lightly damped pole of ``A``, if above ``order``.

    A mode slower than the ARX model's span (``order`` samples) is placed by the realization
    alone, 0.5-2 % off at 6 or more outputs (measured on random structures,
    docs/benchmarks-realization.md); the prediction-error refinement corrects it where it runs.
    The order returned is the next of ``arx_orders.candidates`` at or above the period, at most
    what the cost limit and the record allow.

    Parameters
    ----------
    A : (n, n) the identified model's state matrix; sample_time_s : its sample time.
    order : the ARX order the model came from.
    n_outputs, n_inputs, n_samples : the record's size.
    max_damping : poles damped more than this (fraction) are not modes and do not count, nor are
        poles with fewer than :data:`MIN_PERIODS_IN_RECORD` periods in the record.

    Returns
    -------
    order : the longer ARX order, or 0 when ``order`` spans the period or no longer order fits;
    frequency_hz : the slowest lightly damped pole's frequency (NaN when there is none).
    """
    arx_orders = arx_orders or ArxOrderOptions()
    s = continuous_poles(np.linalg.eigvals(A), sample_time_s)
    with np.errstate(invalid="ignore"):
        frequency_hz = np.abs(s) / (2.0 * np.pi)  # undamped, as the modes report it
        light = frequency_hz[(s.imag > 0) & (-s.real < max_damping * np.abs(s))
                             & (frequency_hz * n_samples * sample_time_s >= MIN_PERIODS_IN_RECORD)]
    if not light.size:
        return 0, float("nan")
    slowest = float(light.min())
    period = 1.0 / (slowest * sample_time_s)
    if period <= order:
        return 0, slowest
    wanted = min([q for q in arx_orders.candidates if q >= period], default=int(np.ceil(period)))
    p, m = n_outputs, n_inputs
    # The largest order within GCV's own limits: m + q (p + m) coefficients, rows per coefficient.
    affordable = min((arx_orders.max_coefficients - m) // (p + m),
                     longest_arx_order(n_samples, p, m, min_rows_per_coefficient=arx_orders.min_rows_per_coefficient))
    longer = int(min(wanted, affordable))
    return (longer if longer > order else 0), slowest


def spanning_slowest_pole(model: IdentifiedModel, identify_at: Callable[[int], IdentifiedModel],
                          sample_time_s: float, *, max_damping: float, n_samples: int,
                          arx_orders: ArxOrderOptions | None = None) -> IdentifiedModel:
    """The model again from an ARX order spanning its slowest mode's period (for an unrefined model).

    The order by GCV predicts best, but a mode slower than the ARX model's span is placed by the
    realization alone (:func:`arx_order_spanning_slowest_pole`); the prediction-error refinement
    corrects it where it runs, so the caller asks this only of an unrefined model.
    ``identify_at(q)``: the record identified from its ARX fit of order q. The first model stays
    when the second is refused (its reason among the warnings).
    """
    q = model.arx.order
    longer, slowest_hz = arx_order_spanning_slowest_pole(
        model.A, sample_time_s, q, n_outputs=model.n_outputs, n_inputs=model.n_inputs, n_samples=n_samples,
        max_damping=max_damping, arx_orders=arx_orders)
    if not longer:
        return model
    samples = 1.0 / (slowest_hz * sample_time_s)
    period = f"one period of the slowest lightly damped pole, {slowest_hz:.4g} Hz, is {samples:.0f} samples"
    try:
        again = identify_at(longer)
    except IdentificationError as exc:
        model.warnings.append(f"ARX order {longer} ({period}) refused: {exc}")
        return model
    again.warnings.append(f"ARX order {longer} instead of {q} (chosen by GCV): {period} and the model is not refined")
    return again
