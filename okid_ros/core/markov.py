"""Markov parameters from ARX coefficients.

Two sequences can be read off an identified ARX model:

System Markov parameters (paper Eq. 24)
    With ``A_i``, ``B_i`` the ARX output and input coefficients and ``B_0 = D``,

        C A^j B = B_{j+1} + sum_{i=1..j} A_i C A^{j-i} B + A_{j+1} D,      j = 0 .. q-1,

    which yields the pulse response ``D, CB, CAB, ..., CA^{q-1}B``. The paper proves Eq. (24)
    holds with process and measurement noise. Its continuation beyond ``q`` (Eq. 28,
    ``C A^j B = sum_i A_i C A^{j-i} B``) holds only **without process noise**, so by default
    only ``q + 1`` terms are returned. This is the paper's route to ERA; it amplifies junk ARX
    input coefficients in unexcited bands (see ``docs/method.md``).

Observer (Kalman-predictor) Markov parameters
    In the innovation form ``x_{k+1} = A x_k + B u_k + A K e_k`` the optimal predictor is
    ``x_{k+1} = Abar x_k + Bbar u_k + L y_k`` with ``L = A K``, ``Abar = A - L C``,
    ``Bbar = B - L D``, and for large ``q`` the ARX lag blocks approach

        [A_i, B_i] = C Abar^{i-1} [L, Bbar],        i = 1 .. q,

    which decay at the rate of the predictor, not of the structure. These are what OKID realizes.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.window_samples import MAX_SAMPLE_MAGNITUDE

__all__ = [
    "markov_from_arx",
    "markov_problem",
    "markov_from_state_space",
    "stochastic_markov_from_state_space",
]


def markov_from_arx(arx: ArxFit, n_terms: int | None = None, extend_noise_free: bool = False) -> np.ndarray:
    """System Markov parameters ``Y_0 = D, Y_{j+1} = C A^j B`` by paper Eq. (24).

    Parameters
    ----------
    arx : the identified ARX model (order q).
    n_terms : number of terms to return (default ``q + 1``: ``D`` and ``C A^j B``, j < q).
    extend_noise_free : allow ``n_terms > q + 1`` by Eq. (28). Valid only without process noise.

    Returns
    -------
    (n_terms, p, m) array; entry 0 is ``D``.
    """
    q, p, m = arx.order, arx.n_outputs, arx.n_inputs
    n_terms = q + 1 if n_terms is None else int(n_terms)
    if n_terms > q + 1 and not extend_noise_free:
        raise ValueError(
            f"Eq. 24 gives {q + 1} terms for ARX order {q}; Eq. 28 would extend it but does not hold "
            "with process noise (pass extend_noise_free=True to accept that)"
        )
    a_coef = arx.output_coefficients  # (q, p, p)
    b_coef = arx.input_coefficients  # (q, p, m)
    d = arx.D
    markov = np.zeros((n_terms, p, m))
    markov[0] = d
    for j in range(n_terms - 1):  # markov[j + 1] = C A^j B
        acc = np.zeros((p, m))
        if j < q:
            acc += b_coef[j] + a_coef[j] @ d
        k = min(j, q)
        if k:  # sum_{i=1..k} A_i Y_{j-i+1}, one contraction instead of k small products
            acc += np.tensordot(a_coef[:k], markov[j - k + 1 : j + 1][::-1], axes=([0, 2], [0, 1]))
        markov[j + 1] = acc
    return markov


def markov_problem(arx: ArxFit) -> str:
    """Why the Markov parameters of ``arx`` cannot be realized ("" if they can): beyond :data:`MAX_SAMPLE_MAGNITUDE`.

    The realization starts from them (:func:`markov_from_arx`, ``q + 1`` terms); beyond the bound of a
    sample their squares overflow float64 in it (the Hankel matrix's Gram, the modes' fit to them).
    Coefficients of 1e150 (finite) overflow in the recursion itself, each term multiplying the last by
    the output coefficients.
    """
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is the answer, not a warning to print
        largest = float(np.max(np.abs(markov_from_arx(arx)), initial=0.0))
    if largest <= MAX_SAMPLE_MAGNITUDE:
        return ""
    size = "overflow float64" if not np.isfinite(largest) else f"reach {largest:.3g}"
    return (f"its Markov parameters (paper Eq. 24, {arx.order + 1} terms) {size}, beyond "
            f"{MAX_SAMPLE_MAGNITUDE:g}: their squares overflow float64 in the realization")


def markov_from_state_space(
    A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, n_terms: int
) -> np.ndarray:
    """Markov parameters ``D, CB, CAB, ...`` of a state-space model: (n_terms, p, m)."""
    p, m = D.shape
    out = np.zeros((n_terms, p, m))
    out[0] = D
    x = B.copy()
    for j in range(1, n_terms):
        out[j] = C @ x
        x = A @ x
    return out


def stochastic_markov_from_state_space(A: np.ndarray, C: np.ndarray, K: np.ndarray, n_terms: int) -> np.ndarray:
    """Stochastic Markov parameters ``C A^i K``, i = 1..n_terms, of the innovation form: (n_terms, p, p).

    These are the MA coefficients of paper Eq. (39) (the paper's Fig. 3); ``K`` is the paper's
    gain (predictor gain ``A K``).
    """
    return markov_from_state_space(A, A @ K, C, np.eye(C.shape[0]), n_terms + 1)[1:]
