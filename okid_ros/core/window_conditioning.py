"""Whose columns make a window's normal equations ill-conditioned: its inputs', or only its outputs'.

Node 1 refuses a window as unexcited when the condition number of its column-scaled normal
equations exceeds ``arx.max_condition_number``. A large condition number has two origins:

* the inputs' columns (``u_k`` and its ``q`` lags) are nearly dependent: two inputs carrying one
  force, an input excited in only part of the window's lag span (a hammer's blow in its newest
  ``q`` samples, or in the ``q`` samples before its oldest row), an input not rich enough over
  ``q`` lags (a sinusoid, a narrow band). The data do not determine those coefficients; the window
  is refused and :func:`input_collinearity` says which input and why;
* the inputs' columns are well conditioned and only the outputs' lags are nearly dependent: the
  outputs hold a response far above their noise (an impact hammer's blow of 1e6 over a force of
  0.01 and innovations of 1), and an ARX order beyond what the structure needs makes their lags
  repeat one free decay, dependent up to the noise; the condition number grows as the square of
  the response's ratio to the noise. That is no lack of excitation: the coefficients the outputs
  leave undetermined are the observer's (Juang's OKID: beyond the minimal order the observer
  Markov parameters are not unique, the system's are), which the prior keeps small. Such a window
  is identified (:func:`input_collinearity` returns "").

The inputs' columns are judged with each input's ``q + 1`` columns scaled by one level (their
mean square), not each column by its own: a lag column holding only the quiet force between two
blows, scaled to the blow's level, would look as informative as the lags holding the blow.
"""

from __future__ import annotations

import numpy as np
from scipy import linalg

from okid_ros.core.excitation import dependent_inputs, entering_excitation_text, leaving_excitation_text
from okid_ros.core.least_squares import NormalEquations

__all__ = ["QUIET_LAG_SHARE", "input_collinearity", "input_columns"]

#: An input's lags whose mean square is at most this share of its loudest lags' hold none of its
#: excitation: named as a blow entering or leaving the window's lag span (only in a refusal's text).
QUIET_LAG_SHARE = 1e-2


def input_columns(order: int, n_outputs: int, n_inputs: int) -> np.ndarray:
    """(m, q + 1) the regressor columns of each input: ``u_k``, then ``u_(k-1)`` .. ``u_(k-q)``."""
    m, w = n_inputs, n_outputs + n_inputs
    lagged = m + np.arange(order)[None, :] * w + n_outputs + np.arange(m)[:, None]
    return np.hstack([np.arange(m)[:, None], lagged])


def _input_gram(normal: NormalEquations, columns: np.ndarray) -> np.ndarray:
    """The inputs' block of ``normal.R`` with each input's columns (a row of ``columns``) scaled by one level."""
    block = normal.R[np.ix_(columns.ravel(), columns.ravel())]
    level = np.maximum(np.diag(block).reshape(columns.shape).mean(axis=1), np.finfo(float).tiny)
    scale = np.repeat(1.0 / np.sqrt(level), columns.shape[1])
    return block * np.outer(scale, scale)


def _condition(gram: np.ndarray) -> float:
    """Condition number of ``gram`` as scaled (least_squares.scaled_condition_number scales each column alone)."""
    eig = linalg.eigvalsh(gram)
    return float(eig[-1] / eig[0]) if eig[0] > 0 else float("inf")


def input_collinearity(normal: NormalEquations, order: int, n_outputs: int, n_inputs: int, *, bound: float) -> str:
    """Why a window's inputs' columns are ill-conditioned beyond ``bound``, or "" when they are not.

    "" tells that the window's large condition number is its outputs' (module docstring). Named, in
    this order: linearly dependent inputs; an input excited only in its newest lags or only in its
    oldest (a blow entering or leaving the window's lag span); an input, or the inputs together,
    not rich enough over the ARX order's lags.
    """
    columns = input_columns(order, n_outputs, n_inputs)
    condition = _condition(_input_gram(normal, columns))
    if condition <= bound:
        return ""
    m = n_inputs
    dependent = dependent_inputs(normal.R[:m, :m], list(range(m))) if m > 1 else ""
    if dependent:
        return dependent
    own = [_condition(_input_gram(normal, columns[i : i + 1])) for i in range(m)]
    worst = int(np.argmax(own))
    if own[worst] <= bound:
        return (f"the inputs' columns over the ARX order's {order} lags are nearly dependent together (condition "
                f"number {condition:.3g}, beyond arx.max_condition_number {bound:.3g}; each input's own are not: a "
                f"single blow on each of two inputs fewer than {order} samples apart? one input a delayed or filtered "
                f"copy of another?): strike or drive each input more often and apart, or lower arx.order")
    return _uneven_input(np.maximum(np.diag(normal.R)[columns[worst]], 0.0), worst, order) or (
        f"input {worst} does not vary independently over the ARX order's {order} lags in this window (the condition "
        f"number of its {order + 1} columns is {own[worst]:.3g}, beyond arx.max_condition_number {bound:.3g}: a "
        f"sinusoid or a narrow-band force?): excite it over a broader band, or lower arx.order")


def _uneven_input(square: np.ndarray, channel: int, order: int) -> str:
    """Why input ``channel`` is excited in only its newest or only its oldest lags, or "" if it is not.

    ``square`` (q + 1,): the sums of squares of its columns ``u_k`` .. ``u_(k-q)``. Its lags hold
    the excitation where they lie above the geometric mean of the largest and the smallest.
    """
    held = square > np.sqrt(square.max() * square.min())
    quiet = float(square.min() / square.max())
    first, last = int(np.argmax(held)), int(held.size - 1 - np.argmax(held[::-1]))
    if not held[first : last + 1].all() or (first > 0) == (last < order) or quiet > QUIET_LAG_SHARE:
        return ""
    own = f"hold {quiet:.1g} of that mean square"
    if first == 0:
        return entering_excitation_text(channel, last + 1, order, own)
    return leaving_excitation_text(channel, first, order, own)
