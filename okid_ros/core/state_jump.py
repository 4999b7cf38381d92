"""The state-jump test: is an excursion of the innovations the free response to a jump of the state.

The change test (:mod:`okid_ros.core.change_detection`) and the divergence watchdog look at the
innovations' power. Two things raise it: a structural change (the reference model's predictor
is wrong from then on) and a jump of the state with the structure unchanged (an impact whose
response lasts the modes' decay time, a bag replayed in a loop, the estimator's state lost).
A jump ``nu`` of the predicted state's error at sample ``theta`` leaves, for ``k >= theta``,::

    z_k = Cw F^(k - theta) nu + eps_k,        F = A - A K C,  Cw = L^{-1} C

in the whitened innovations (``eps`` as without the jump), because the predictor's error
evolves by ``F``. This is the state-jump hypothesis of the generalized likelihood ratio test of
Willsky & Jones (1976, "A generalized likelihood ratio approach to the detection and estimation
of jumps in linear systems"): fit ``nu`` by least squares to the excursion's whitened
innovations and look at what remains. A jump leaves the power of the calibration; a changed
structure leaves most of its excess, because its innovations keep coming from the new dynamics
and the free response of the old predictor cannot follow them for long.

The judgement (:class:`StateJumpTest`): the regressors of each sample are the jump's response
and a constant per output (a record's offsets step too where it is looped or a sensor is
re-zeroed; the change test's tracked mean takes the fitted constant). Over ``L`` samples from the
onset, the power before ``P0 = |z|^2 / (L p)`` and after ``P1 = RSS / (L p - n - p)`` (per degree
of freedom: the fit takes ``n + p`` of white residuals' energy by chance), both over the
baseline power ``b`` of the calibration. The excursion is a state jump when it is large
(``P0 / b >= min_power``, twice the baseline: smaller excursions are left to the model-error
check) and what remains is a small part of the excess there was and below ``min_power``::

    P1 / b - 1  <=  max_remaining * (P0 / b - 1),        P1 / b < min_power

with ``L >= min_samples`` (50, and several times ``n / p``: over fewer samples the free response
of ``n`` states follows the first samples of a change, whose innovations grow slowly). Any
``theta`` at or after the true onset fits (the error at ``theta`` is again a state), so the onset
is searched over ``ONSET_CANDIDATES`` samples around where the excursion's loud samples (``|z|^2
/ b`` above the 1e-4 quantile of white innovations) up to its alarm begin: the run of them
around the loudest one if that is ten times the level (the CUSUM's change point may lie tens or
thousands of samples before a jump, in a noisier stretch), else the first one, else the first
sample; the best fit is taken;
not anywhere: a jump's excursion starts with its largest innovations, and a fit that may start
anywhere finds a stretch that a free response follows in the tail of any excursion.

Measured (``bench/change_detection.py --part jump --seeds 0 1 2``, docs/benchmarks-change.md):
the change bench's systems looped back on themselves leave 0.91-1.10 of the baseline (out of
5-61 before) over 90-150 samples, the steel subframe 0.71-0.73; none of 45 structural changes
(frequency drops of 0.5-6 %, damping x1.1-x3, storey stiffness losses of 2-30 %) is taken for a
jump at any of those lengths, and where their power doubled at least 48 % of the excess remains.

Scipy's Cholesky solves the fits; nothing in scipy or the field's libraries tests a state jump
of a given predictor.

No rclpy; numpy and scipy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg, stats

__all__ = [
    "DEFAULT_MAX_REMAINING",
    "DEFAULT_MIN_JUMP_SAMPLES",
    "DEFAULT_MIN_JUMP_POWER",
    "ONSET_CANDIDATES",
    "StateJump",
    "StateJumpTest",
    "jump_responses",
]

DEFAULT_MAX_REMAINING = 0.1  # part of the excess power a state jump may leave unexplained
DEFAULT_MIN_JUMP_SAMPLES = 50  # fewest samples fitted (and at least 4 n / p)
DEFAULT_MIN_JUMP_POWER = 2.0  # excursions below twice the baseline power are not judged as jumps
ONSET_CANDIDATES = 16  # onsets tried, around where the excursion's loud samples begin
_LOUD_PROBABILITY = 1e-4  # a sample whose |z|^2 a white innovation exceeds this rarely is loud
_JUMP_LOUDNESS = 10.0  # a sample this many times the loud level marks where a jump's response begins


@dataclass(frozen=True)
class StateJump:
    """The fit of a state jump to an excursion of whitened innovations.

    Attributes
    ----------
    onset_index : sample ``theta`` of the fitted jump (the first fitted sample).
    last_index : last fitted sample.
    jump : (n,) the predicted state's error at ``theta``.
    offset : (p,) the whitened innovations' mean over the fitted samples.
    power_before, power_after : ``P0 / b`` and ``P1 / b`` (module docstring).
    explained : the excursion is a state jump (``power_after`` within the allowance).
    loud_index : the first sample of the excursion's loud run (where an output's step lies), or
        -1 when not known.
    """

    onset_index: int
    last_index: int
    jump: np.ndarray
    offset: np.ndarray
    power_before: float
    power_after: float
    explained: bool
    loud_index: int = -1

    def correction(self, F: np.ndarray, next_index: int) -> np.ndarray:
        """(n,) what to add to the predicted state of sample ``next_index`` (> ``onset_index``)."""
        return np.linalg.matrix_power(F, int(next_index - self.onset_index)) @ self.jump


def jump_responses(F: np.ndarray, C: np.ndarray, samples: int) -> np.ndarray:
    """``C F^k`` for ``k = 0 .. samples - 1``: (samples, p, n)."""
    out = np.empty((int(samples),) + C.shape)
    row = np.array(C, dtype=float)
    for k in range(int(samples)):
        out[k] = row
        row = row @ F
    return out


class StateJumpTest:
    """Judge excursions of one predictor's whitened innovations (see the module docstring).

    Parameters
    ----------
    F : (n, n) the predictor's state matrix ``A - A K C``.
    C_whitened : (p, n) ``L^{-1} C``, the output matrix in whitened innovations.
    max_remaining : part of the excess a state jump may leave.
    min_samples : fewest samples fitted; raised to ``4 n / p`` when that is more.
    min_power : excursions whose power is below this many times the baseline are no jump.

    Attributes
    ----------
    needed_samples : samples from the onsets' first on that a judgement needs (the fit's and
        room for the onset search).
    max_samples : most samples fitted from an onset (4 ``min_samples``).
    """

    def __init__(self, F: np.ndarray, C_whitened: np.ndarray, *, max_remaining: float = DEFAULT_MAX_REMAINING,
                 min_samples: int = DEFAULT_MIN_JUMP_SAMPLES, min_power: float = DEFAULT_MIN_JUMP_POWER) -> None:
        if not 0.0 <= max_remaining < 1.0 or not min_power > 1.0:
            raise ValueError(f"need 0 <= max_remaining < 1 and min_power > 1, got {max_remaining}, {min_power}")
        self.F = np.asarray(F, dtype=float)
        self.C_whitened = np.asarray(C_whitened, dtype=float)
        p, n = self.C_whitened.shape
        self.max_remaining, self.min_power = float(max_remaining), float(min_power)
        self.min_samples = max(int(min_samples), math.ceil(4 * n / p))
        self.needed_samples = self.min_samples + ONSET_CANDIDATES - 1
        self.max_samples = 4 * self.min_samples
        self._loud = float(stats.chi2.isf(_LOUD_PROBABILITY, p))  # |z|^2 / b of a sample far above the baseline
        self._responses = np.empty((0, p, n))

    def _rows(self, samples: int) -> np.ndarray:
        if self._responses.shape[0] < samples:  # grown by doubling, kept for later judgements
            self._responses = jump_responses(self.F, self.C_whitened, max(samples, 2 * self._responses.shape[0]))
        return self._responses[:samples]

    def judge(self, z: np.ndarray, first_index: int, *, baseline_power: float = 1.0,
              loud_until: int | None = None) -> StateJump | None:
        """Fit a jump to whitened innovations ``z`` (L, p) of samples ``first_index ..``.

        ``baseline_power``: the mean ``|z|^2 / p`` of the calibration (1 for an exact model).
        ``loud_until``: the last sample searched for the excursion's loud ones (the alarm's:
        a judgement that waits for samples keeps its onsets); None: every sample of ``z``.
        Only the first ``max_samples`` from each onset are fitted (a jump's response has decayed
        or been fitted by then). Returns None when there are fewer than ``needed_samples``; a
        baseline that is not positive or innovations that are not finite are no jump.
        """
        z = np.asarray(z, dtype=float)
        p, n = z.shape[1], self.F.shape[0]
        if not baseline_power > 0.0 or not np.all(np.isfinite(z)):
            return StateJump(first_index, first_index + z.shape[0] - 1, np.zeros(n), np.zeros(p), math.nan,
                             math.nan, False)
        # The onsets tried surround where the loud samples begin (a jump's largest innovations
        # come first; where the excursion began is not known to the sample).
        head = z if loud_until is None else z[:max(int(loud_until) - int(first_index) + 1, 0)]
        loud = self._loud_start(np.einsum("kp,kp->k", head, head) / (self._loud * baseline_power))
        lo = max(loud - ONSET_CANDIDATES // 2, 0)
        loud_index = first_index + loud
        z, first_index = z[lo:lo + self.max_samples + ONSET_CANDIDATES - 1], first_index + lo
        L = z.shape[0]
        if L < self.needed_samples:
            return None
        # Each sample's regressors: the jump's response and a constant per output (the record's
        # offsets step too where it is looped or a sensor is re-zeroed; the tracked mean of the
        # change test takes the fitted constant).
        rows = self._rows(min(L, self.max_samples))
        rows = np.concatenate([rows, np.broadcast_to(np.eye(p), (rows.shape[0], p, p))], axis=2)
        k = n + p
        # Normal equations of every onset from prefix sums of the regressors' Grams (the designs
        # of later onsets are leading rows of the first's): one (k, k) Cholesky per onset
        # instead of a QR of (L p, k) each. A tiny ridge keeps unobservable directions finite.
        grams = np.concatenate([np.zeros((1, k, k)), np.cumsum(rows.transpose(0, 2, 1) @ rows, axis=0)])
        best = None
        for offset in range(min(ONSET_CANDIDATES, L - self.min_samples + 1)):
            samples = min(L - offset, self.max_samples)
            target = z[offset:offset + samples]
            normal = grams[samples]
            rhs = np.einsum("kpi,kp->i", rows[:samples], target)
            ridge = 1e-12 * max(float(np.trace(normal)) / k, 1e-300)
            solution = linalg.cho_solve(linalg.cho_factor(normal + ridge * np.eye(k), check_finite=False), rhs,
                                        check_finite=False)
            energy = float(np.einsum("kp,kp->", target, target))
            rss = max(energy - 2.0 * float(rhs @ solution) + float(solution @ normal @ solution), 0.0)
            before = energy / (samples * p) / baseline_power
            after = rss / (samples * p - k) / baseline_power
            if best is None or after < best[2]:
                best = (offset, before, after, solution, samples)
        offset, before, after, solution, samples = best
        explained = (before >= self.min_power and after < self.min_power
                     and after - 1.0 <= self.max_remaining * (before - 1.0))
        return StateJump(first_index + offset, first_index + offset + samples - 1, solution[:n], solution[n:],
                         before, after, bool(explained), loud_index)

    @staticmethod
    def _loud_start(loudness: np.ndarray) -> int:
        """Where the excursion's jump would start: ``loudness`` (L,) is ``|z|^2`` over the loud level.

        The start of the run of loud samples around the loudest one when that is far above the
        level (a jump's first innovations; an excursion may have begun long before, in a noisier
        stretch), else the first loud sample (a change grows: its first loud samples are as good
        as any), else the first sample.
        """
        loud = np.flatnonzero(loudness > 1.0)
        if not loud.size:
            return 0
        peak = int(np.argmax(loudness))
        if loudness[peak] < _JUMP_LOUDNESS:
            return int(loud[0])
        quiet = np.flatnonzero(np.diff(loud[loud <= peak]) > ONSET_CANDIDATES // 2)  # gaps between runs
        return int(loud[loud <= peak][quiet[-1] + 1]) if quiet.size else int(loud[0])

    def response(self, jump: StateJump, first_index: int, samples: int) -> np.ndarray:
        """(samples, p) the jump's whitened response at samples ``first_index ..`` (>= its onset)."""
        lo = int(first_index - jump.onset_index)
        return self._rows(lo + int(samples))[lo:] @ jump.jump
