"""The fewest samples an ARX window must hold for its realization to run (node 2's and ``track``'s rule).

Plain arithmetic: the nodes' parameter checks (:mod:`okid_ros.service.options`) size the window with
it at the start, without importing the realization's numerical modules.

>>> realization_minimum(100, 4100), window_minimum(10, 310, 0)
(2050, 200)
"""

from __future__ import annotations

__all__ = ["OUTPUT_ONLY_MIN_SAMPLES", "realization_minimum", "window_minimum"]

#: Fewest samples per output channel and per Hankel lag worth identifying from without an input.
OUTPUT_ONLY_MIN_SAMPLES = 200


def realization_minimum(order: int, need: int) -> int:
    """Samples a realization needs of an ARX window of ``need`` samples at ARX order ``order``.

    Four times the order (the Markov parameters and the state regression after the ARX's lags),
    and half the window's samples.
    """
    return max(4 * order, need // 2)


def window_minimum(order: int, need: int, n_inputs: int) -> int:
    """Samples a full ARX window of ``need`` samples must hold for its realization to run at all.

    :func:`realization_minimum`, and with no input (``n_inputs`` 0) the fewest samples of an
    output-only identification: a smaller window has every model refused.
    """
    return max(realization_minimum(order, need), OUTPUT_ONLY_MIN_SAMPLES if n_inputs == 0 else 0)
