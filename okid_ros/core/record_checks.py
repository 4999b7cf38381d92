"""The checks of :func:`okid_ros.core.pipeline.identify`'s record and arguments (one-line refusals)."""

from __future__ import annotations

import numpy as np

from okid_ros.core.arx import check_regularization
from okid_ros.core.gap_fill import mark_missing, missing_problem
from okid_ros.core.identified_model import IdentificationError
from okid_ros.core.options import AUTO, OFFSETS, ArxOrderOptions, RealizationOptions, sample_time_problem
from okid_ros.core.regressors import check_io_arrays, regressor_length, samples_for_order

__all__ = ["BROADBAND_NEEDED", "HIGH_MODE_FRACTION", "METHODS", "check_record_length", "checked_record",
           "high_modes_note", "narrowband_note"]

METHODS = ("okid", "paper")
#: The assumption of output-only identification, said where a record or window breaks it.
BROADBAND_NEEDED = ("output-only identification needs the structure driven by broadband forces (wind, traffic, "
                    "random excitation)")
#: A mode above this fraction of the sampling rate is near the Nyquist frequency (half of it).
HIGH_MODE_FRACTION = 0.4


def checked_record(u, y, sample_time_s: float, *, method: str, offsets: str, valid, options: RealizationOptions,
                   changes: dict, order: int | str = AUTO, regularization: str | None = None,
                   arx_orders: ArxOrderOptions | None = None,
                   ) -> tuple[RealizationOptions, np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`~okid_ros.core.pipeline.identify`'s arguments checked, or IdentificationError.

    Returns ``options`` with the ``changes``, ``u`` and ``y`` as (N, m) and (N, p) float arrays
    with 0 at the missing samples, and ``valid`` (None when no sample is missing).
    """
    if method not in METHODS:
        raise IdentificationError(f"method must be one of {METHODS}, got {method!r}")
    if problem := sample_time_problem(sample_time_s):
        raise IdentificationError(problem)
    # An order of 20.5 was cut to 20 and a bool taken for 1, as n_states refuses them.
    integer = isinstance(order, (int, np.integer)) and not isinstance(order, bool)
    if not (integer or (isinstance(order, str) and order == AUTO)):
        raise IdentificationError(f"order must be an integer ARX order or {AUTO!r}, got {order!r}")
    for name, value, kind in (("options", options, RealizationOptions), ("arx_orders", arx_orders, ArxOrderOptions)):
        if not isinstance(value, kind) and (name == "options" or value is not None):  # an AttributeError later
            raise IdentificationError(f"{name} must be of type {kind.__name__}, got {type(value).__name__}")
    try:
        if regularization is not None:
            check_regularization(regularization)
        options = options.with_changes(**changes)
        if valid is not None:
            u, y, valid = mark_missing(u, y, valid)
        u, y = check_io_arrays(u, y)
    except (TypeError, ValueError) as exc:
        raise IdentificationError(str(exc)) from None
    if offsets not in OFFSETS:
        raise IdentificationError(f"offsets must be one of {OFFSETS}, got {offsets!r}")
    if valid is not None and method == "paper":
        raise IdentificationError("the paper's method needs contiguous samples: identify a run without missing ones")
    if valid is not None and (problem := missing_problem(valid)):
        raise IdentificationError(problem)
    return options, u, y, valid


def check_record_length(n_samples: int, order: int, p: int, m: int) -> None:
    """IdentificationError unless an ARX model of ``order`` can be fitted to ``n_samples``."""
    if order < 2:
        raise IdentificationError(f"ARX order must be >= 2, got {order}")
    d = regressor_length(order, p, m)
    needed = samples_for_order(order, p, m)
    if n_samples < needed:
        raise IdentificationError(
            f"too few samples for ARX order {order} with {m} inputs and {p} outputs: {n_samples} "
            f"given, at least {needed} needed ({d} coefficients per output plus {order} lags)"
        )


def narrowband_note(y: np.ndarray, sample_time_s: float, valid: np.ndarray | None = None) -> str:
    """Why an output-only identification of ``y`` (N, p) that found no model may have failed: its harmonic lines.

    Output-only identification assumes the structure is driven by broadband forces; a record whose
    outputs are sinusoids (a machine's rotation alone, a shaker's sine) holds no mode to find. The
    failure said only "no stable mode found ... is the record long and excited enough?" or "the
    reference channels' covariance is not positive definite". "" when the outputs hold no harmonic
    line (:func:`~okid_ros.core.output_only_harmonics.find_harmonics`). ``valid``: False at missing samples.
    """
    from okid_ros.core.channels import channel_mean
    from okid_ros.core.output_only_harmonics import find_harmonics, remove_harmonics

    y = np.asarray(y, float)
    present = np.isfinite(y).all(axis=1) if valid is None else np.asarray(valid, bool) & np.isfinite(y).all(axis=1)
    if present.sum() < 2:
        return ""
    centred = np.where(present[:, None], y - channel_mean(y[present]), 0.0)
    spread = float(np.sqrt(np.mean(centred[present] ** 2)))
    if not spread > 0 or not np.isfinite(spread):
        return ""
    centred /= spread
    lines = find_harmonics(centred, sample_time_s)
    if not lines:
        return ""
    rest = remove_harmonics(centred, sample_time_s, lines, valid=present)[present]
    share = 100.0 * max(0.0, 1.0 - float(np.mean(rest**2)) / float(np.mean(centred[present] ** 2)))
    listed = ", ".join(f"{line.frequency_hz:.5g} Hz" for line in sorted(lines, key=lambda line: line.frequency_hz))
    return f"the outputs hold harmonic lines at {listed} ({share:.3g} % of their variance): {BROADBAND_NEEDED}"


def high_modes_note(frequencies_hz, sample_time_s: float) -> str:
    """A warning when modes of ``frequencies_hz`` lie above :data:`HIGH_MODE_FRACTION` of the sampling rate, or "".

    Near the Nyquist frequency a mode's poles are not listed (the output-only selection keeps poles
    below 0.475 of the rate) and one beyond it folds back to a wrong frequency: of a structure with
    modes at 85, 90 and 95 Hz sampled at 200 Hz two were listed, in silence.
    """
    rate_hz = 1.0 / sample_time_s
    high = [f for f in frequencies_hz if f > HIGH_MODE_FRACTION * rate_hz]
    if not high:
        return ""
    listed = ", ".join(f"{f:.5g}" for f in high)
    return (f"mode(s) at {listed} Hz lie above {HIGH_MODE_FRACTION:g} of the sampling rate ({rate_hz:.5g} Hz): a mode "
            f"nearer the Nyquist frequency ({rate_hz / 2:.5g} Hz) may be missed, and one beyond it appears at a wrong "
            f"frequency (aliasing); sample faster, or check the anti-alias filter")
