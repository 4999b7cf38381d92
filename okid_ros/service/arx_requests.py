"""Node 2's rules for an ARX fit it is offered: which it refuses, and why.

:meth:`~okid_ros.service.estimation.ModalEstimationService.submit_arx` judges a fit by them on
arrival, :meth:`~okid_ros.service.estimation.ModalEstimationService.take_job` the waiting one by
its stamp again when it is due. With nothing buffered there is no sample to judge a stamp by:
the request waits for the first samples (node 2 started after node 1, or lags it by its input
queue). Each refusal is a :class:`~okid_ros.service.results.RefusedArx` phrase with the reason.
"""

from __future__ import annotations

import math

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.realization_window import run_breaks
from okid_ros.core.window_minimum import realization_minimum
from okid_ros.service.options import MAX_ARX_LEAD_S, MAX_BUFFER_SAMPLES, ModalEstimationParams
from okid_ros.service.results import RefusedArx
from okid_ros.service.sample_buffer import SampleBuffer

__all__ = ["held_refusal", "stamp_refusal", "unbuffered_refusal", "window_refusal"]


def stamp_refusal(stamp_end_s: float, buffer: SampleBuffer) -> tuple[str, str] | None:
    """Why a window ending at ``stamp_end_s`` is refused for its stamp, as (``RefusedArx`` phrase, reason); or None.

    No stamp, or an end beyond ``MAX_ARX_LEAD_S`` after the newest sample ``buffer`` holds (not judged
    with nothing buffered).
    """
    if not math.isfinite(stamp_end_s):
        return RefusedArx.STAMP, "ARX model without a stamp"
    if stamp_end_s > (newest := buffer.newest_stamp()) + MAX_ARX_LEAD_S:  # nan: nothing buffered
        return RefusedArx.FUTURE, (f"ARX window ends at {stamp_end_s:.3f} s, more than MAX_ARX_LEAD_S "
                                   f"{MAX_ARX_LEAD_S:g} s after the newest sample here ({newest:.3f} s)")
    return None


def unbuffered_refusal(stamp_end_s: float, buffer: SampleBuffer, sample_time_s: float) -> tuple[str, str] | None:
    """Why a window ending at ``stamp_end_s`` will never be buffered (``RefusedArx.NO_SAMPLE``, reason), or None.

    It ends before the first sample ``buffer`` holds (of the newest timeline); not judged with nothing
    buffered. On arrival judged after :func:`window_refusal` has grown the buffer to the window: a node 2
    whose ring let the first window's end go would otherwise never grow it, and refuse every later
    window for the same lag.
    """
    if (first := buffer.timeline_start_stamp()) > stamp_end_s + 0.5 * sample_time_s:  # nan: nothing buffered
        return RefusedArx.NO_SAMPLE, (f"ARX window ends at {stamp_end_s:.3f} s, before the first sample node 2 holds "
                                      f"({first:.3f} s, since any time jump): its window will never be buffered here")
    return None


def window_refusal(fit: ArxFit, rows: int, params: ModalEstimationParams, buffer: SampleBuffer
                   ) -> tuple[str, str] | None:
    """Why the window of ``rows`` regressor rows of ``fit`` is refused for its size, as (phrase, reason); or None.

    Shorter than a realization needs (:func:`realization_minimum`: four times the order), or more than
    ``buffer`` can hold; with ``estimator.buffer_length`` 0 the buffer follows the ARX window, grown to it
    within node 2's bounds.
    """
    need = rows + fit.order
    if need < (least := realization_minimum(fit.order, need)):
        return RefusedArx.SHORT, (f"its window of {need} samples (rows + order) is shorter than the {least} (4 x "
                                  f"order {fit.order}) a realization needs")
    if params.buffer_length <= 0:
        problem = buffer.grow_for(need, MAX_BUFFER_SAMPLES, "estimator.buffer_length")
        return (RefusedArx.BUFFER, f"ARX model refused: {problem}") if problem else None
    if buffer.cap < least:  # else "a gap", none there
        return RefusedArx.BUFFER, (f"ARX model refused: its window of {need} samples (rows + order) needs at least "
                                   f"{least} buffered, more than estimator.buffer_length {buffer.cap} keeps")
    return None


def held_refusal(skipped: np.ndarray, *, need: int, order: int, max_gap: int) -> tuple[str, str] | None:
    """Why the samples node 2 holds of a window of ``need`` (``skipped`` (N,): theirs, the newest) are too few, or None.

    None too when a gap longer than ``max_gap`` or a time restart lies among them: that is the reason then
    (:func:`newest_run_start`). Without one, node 2 started (or was reset) within the window, and the
    reason was said to be a gap.
    """
    if skipped.size >= (least := realization_minimum(order, need)) or run_breaks(skipped, max_gap).size:
        return None
    return RefusedArx.NOT_HELD, (f"node 2 holds {skipped.size} of the ARX window's {need} samples (rows + order), "
                                 f"having started or been reset within it; the realization needs at least {least}")
