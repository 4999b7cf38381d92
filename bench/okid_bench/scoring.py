"""Metrics of an identified model against a known true system.

Independent of ``okid_ros.core`` on purpose (a second implementation of the modal
computation is a check on the first).

* :func:`modes_of` -- continuous modes of a discrete A (one per complex pair);
* :func:`match_modes` -- per true mode: frequency error (%), damping error (percentage
  points), missed true modes, spurious physical identified modes;
* :func:`prediction_error_ratio` -- one-step prediction-error power of a model on held-out
  data divided by the oracle predictor's on the same data (1.0 is the limit);
* :func:`stochastic_markov_error` -- relative error of ``C A^i K`` (i = 1..n_terms), which is
  invariant to similarity transforms.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Optional, Union

import numpy as np
import scipy.optimize

from okid_bench.oracle import kalman_predictor, one_step_predictions
from okid_ros.core.statespace import InnovationModel
from okid_ros.sim.models import NoisyStateSpace

__all__ = [
    "Mode",
    "ModeMatch",
    "modes_of",
    "physical_modes",
    "assign_by_frequency",
    "match_modes",
    "prediction_error_ratio",
    "stochastic_markov_error",
    "model_matrices",
]


@dataclass(frozen=True)
class Mode:
    """One complex mode of a discrete-time A.

    Attributes
    ----------
    z : discrete eigenvalue (upper half plane).
    frequency_rad_s : natural frequency ``|s|``, ``s = ln(z) / dt``.
    frequency_hz : ``|s| / (2 pi)``.
    damping_ratio : ``-Re(s) / |s|`` (fraction; negative for an unstable pole).
    """

    z: complex
    frequency_rad_s: float
    frequency_hz: float
    damping_ratio: float

    @property
    def magnitude(self) -> float:
        return abs(self.z)


def modes_of(A: np.ndarray, sample_time_s: float, imag_tol: float = 1e-9) -> list[Mode]:
    """Continuous modes of a discrete state matrix, one per complex-conjugate pair.

    ``s = ln(z) / dt`` for each eigenvalue ``z`` with ``Im z > imag_tol * max(|z|, 1)``
    (real eigenvalues, including negative real ones that map to the Nyquist frequency, are
    not oscillatory modes and are dropped).

    Parameters
    ----------
    A : (n, n) discrete state matrix.
    sample_time_s : sample period in seconds.

    Returns
    -------
    list of :class:`Mode`, sorted by frequency.
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    if A.size == 0:
        return []
    z = np.linalg.eigvals(A)
    z = z[z.imag > imag_tol * max(1.0, float(np.max(np.abs(z))))]
    modes = []
    for zi in z:
        s = np.log(complex(zi)) / sample_time_s
        wn = abs(s)
        modes.append(Mode(complex(zi), wn, wn / (2 * np.pi), -s.real / wn))
    modes.sort(key=lambda md: md.frequency_rad_s)
    return modes


def physical_modes(modes: list[Mode], sample_time_s: float, max_damping: float = 0.2
                   ) -> list[Mode]:
    """Modes a user would call structural.

    Physical means: stable (``|z| < 1``, i.e. damping > 0), damping ratio below
    ``max_damping``, and natural frequency in ``(0, Nyquist)`` with Nyquist ``pi / dt`` rad/s.
    """
    nyq = np.pi / sample_time_s
    return [md for md in modes
            if md.magnitude < 1.0 and 0.0 < md.damping_ratio < max_damping
            and 0.0 < md.frequency_rad_s < nyq]


@dataclass
class ModeMatch:
    """Result of :func:`match_modes`.

    Attributes
    ----------
    true_modes : the reference modes (order of all per-mode arrays).
    matched : for each true mode, the matched identified :class:`Mode` or ``None`` (missed).
    frequency_error_pct : (n_true,) ``100 (f_id - f_true) / f_true``, NaN where missed.
    damping_error_pp : (n_true,) ``100 (zeta_id - zeta_true)`` in percentage points, NaN where
        missed.
    missed : number of true modes without a match.
    spurious : physical identified modes not matched to any true mode.
    """

    true_modes: list
    matched: list
    frequency_error_pct: np.ndarray
    damping_error_pp: np.ndarray
    missed: int
    spurious: list = field(default_factory=list)

    @property
    def n_spurious(self) -> int:
        return len(self.spurious)


def assign_by_frequency(identified_hz, true_hz, tol: float = 0.05) -> list[Optional[int]]:
    """One-to-one pairing of identified with true modes by frequency: the index paired with each true mode.

    The assignment minimizes the total relative distance ``|f_id - f_true| / f_true`` (Hungarian
    algorithm); a pair is kept only within ``tol``. One identified mode never stands for two true
    ones (a close pair realized as one mode leaves one true mode unpaired).

    Parameters
    ----------
    identified_hz : (ni,) identified frequencies; true_hz : (nt,) true ones (any one unit).

    Returns
    -------
    list of nt entries: the index into ``identified_hz``, or None.
    """
    fi, ft = np.asarray(identified_hz, float), np.asarray(true_hz, float)
    pairs: list[Optional[int]] = [None] * ft.size
    if ft.size and fi.size:
        cost = np.abs(fi[None, :] - ft[:, None]) / ft[:, None]
        rows, cols = scipy.optimize.linear_sum_assignment(np.where(cost <= tol, cost, 1e6))
        for r, c in zip(rows, cols):
            if cost[r, c] <= tol:
                pairs[r] = int(c)
    return pairs


def match_modes(identified: list[Mode], true: list[Mode], tol: float = 0.05) -> ModeMatch:
    """One-to-one matching of identified modes to true modes by frequency.

    The assignment minimizes the total relative frequency distance
    ``|f_id - f_true| / f_true`` (Hungarian algorithm), and a pair is accepted only if that
    distance is at most ``tol``.  Pass *physical* identified modes (:func:`physical_modes`);
    every identified mode left unmatched is counted as spurious.

    Parameters
    ----------
    identified : identified modes (physical ones).
    true : true modes.
    tol : relative frequency tolerance for a match (0.05 = 5 %).

    Returns
    -------
    ModeMatch
    """
    nt, ni = len(true), len(identified)
    pairs = assign_by_frequency([md.frequency_rad_s for md in identified], [md.frequency_rad_s for md in true], tol)
    matched: list[Optional[Mode]] = [None if c is None else identified[c] for c in pairs]
    used = np.zeros(ni, dtype=bool)
    used[[c for c in pairs if c is not None]] = True
    ferr = np.full(nt, np.nan)
    derr = np.full(nt, np.nan)
    for i, (t, m) in enumerate(zip(true, matched)):
        if m is not None:
            ferr[i] = 100.0 * (m.frequency_rad_s - t.frequency_rad_s) / t.frequency_rad_s
            derr[i] = 100.0 * (m.damping_ratio - t.damping_ratio)
    spurious = [identified[j] for j in range(ni) if not used[j]]
    return ModeMatch(list(true), matched, ferr, derr, sum(m is None for m in matched), spurious)


def model_matrices(model: Any) -> dict:
    """``A, B, C, D`` and the predictor gain ``L`` of an identified model.

    Accepts an object with attributes or a mapping with keys ``A, B, C, D`` and either
    ``predictor_gain`` (``L``, preferred: no inversion of A) or ``K`` (paper's gain,
    ``L = A K``).  ``L`` is ``None`` if neither is given (or given as ``None``).
    """
    get = (lambda k: model.get(k)) if isinstance(model, Mapping) else (lambda k: getattr(model, k, None))
    A = np.atleast_2d(np.asarray(get("A"), dtype=float))
    out = {"A": A, "B": np.asarray(get("B"), dtype=float),
           "C": np.asarray(get("C"), dtype=float), "D": np.asarray(get("D"), dtype=float)}
    L, K = get("predictor_gain"), get("K")
    if L is not None:
        out["L"] = np.asarray(L, dtype=float)
    elif K is not None:
        out["L"] = A @ np.asarray(K, dtype=float)
    else:
        out["L"] = None
    return out


def _error_power(e: np.ndarray, burn_in: int) -> float:
    e = e[burn_in:]
    if not np.all(np.isfinite(e)):
        return np.inf
    return float(np.mean(np.sum(e * e, axis=1)))


def prediction_error_ratio(model: Any, truth: Union[InnovationModel, NoisyStateSpace],
                           u_val: np.ndarray, y_val: np.ndarray, burn_in: int = 500) -> float:
    """One-step prediction-error power of ``model`` divided by the oracle's, on held-out data.

    ``ratio = trace(E_model) / trace(E_oracle)`` with ``E = mean_k e_k e_k^T`` over
    ``k >= burn_in`` (both predictors start from a zero state; the burn-in removes the start-up
    transient).  The second moment about zero is used rather than the covariance about the
    sample mean, so a biased predictor is not excused; for zero-mean data they coincide.
    1.0 is the limit (the oracle is the optimal predictor); values below 1 happen only by
    chance on finite data.

    Parameters
    ----------
    model : identified model (see :func:`model_matrices`); must carry ``K`` or ``predictor_gain``.
    truth : the true system (its oracle predictor is computed with :func:`kalman_predictor`).
    u_val : (N, m) and y_val : (N, p) validation data not used for identification.
    burn_in : samples skipped at the start for both predictors.

    Returns
    -------
    float (``inf`` if the model's predictor diverges).
    """
    mm = model_matrices(model)
    if mm["L"] is None:
        raise ValueError("model has no gain K or L: the prediction ratio is not defined")
    K_o, _ = kalman_predictor(truth)
    _, e_o = one_step_predictions(truth.A, truth.B, truth.C, truth.D, K_o, u_val, y_val)
    try:
        _, e_m = one_step_predictions(mm["A"], mm["B"], mm["C"], mm["D"], None, u_val, y_val,
                                      predictor_gain=mm["L"])
    except (np.linalg.LinAlgError, ValueError):
        return np.inf
    return _error_power(e_m, burn_in) / _error_power(e_o, burn_in)


def stochastic_markov_error(model: Any, truth: Union[InnovationModel, NoisyStateSpace],
                            n_terms: int = 100, weighting: Optional[str] = "innovation") -> float:
    """Relative error of the stochastic Markov parameters ``C A^i K``, i = 1..n_terms.

    ``M_i = C A^i K = C A^{i-1} L`` (``L = A K``) are the coefficients of the noise model
    ``H(z) = I + sum_i M_i z^{-i}`` (paper Eq. 39).  The error is::

        ||W (M_model - M_true) W^{-1}||_F / ||W M_true W^{-1}||_F    over i = 1..n_terms

    with ``W = Re^{-1/2}`` of the true innovation covariance (``weighting="innovation"``,
    default): the error of the noise model with outputs scaled to unit innovation, so it does
    not depend on the units or scales of the outputs (with 6 accelerometers of very different
    noise levels the unweighted norm is dominated by the noisiest channel).  ``weighting=None``
    gives the plain Frobenius ratio.  Invariant to similarity transforms of the model.

    Parameters
    ----------
    model : identified model (see :func:`model_matrices`); must carry ``K`` or ``predictor_gain``.
    truth : true system (oracle gain and innovation covariance for a ``NoisyStateSpace``).
    n_terms : number of terms.
    weighting : ``"innovation"`` or ``None``.
    """
    mm = model_matrices(model)
    if mm["L"] is None:
        raise ValueError("model has no gain K or L")
    K_o, Re = kalman_predictor(truth)
    if weighting == "innovation":
        Lc = np.linalg.cholesky(0.5 * (Re + Re.T))
        left, right = np.linalg.inv(Lc), Lc
    elif weighting is None:
        left = right = np.eye(Re.shape[0])
    else:
        raise ValueError("weighting must be 'innovation' or None")

    def seq(A, C, L):
        out = np.empty((n_terms, C.shape[0], L.shape[1]))
        M = L.copy()
        with np.errstate(over="ignore", invalid="ignore"):
            for i in range(n_terms):
                out[i] = left @ C @ M @ right
                M = A @ M
        return out

    s_true = seq(truth.A, truth.C, truth.A @ K_o)
    s_id = seq(mm["A"], mm["C"], mm["L"])
    if not np.all(np.isfinite(s_id)):
        return np.inf
    return float(np.linalg.norm(s_id - s_true) / np.linalg.norm(s_true))
