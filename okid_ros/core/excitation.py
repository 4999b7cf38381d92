"""Does the input excite the system, do the outputs respond? Dead channels named, such windows refused.

OKID learns how the inputs drive the outputs; an input channel without variance in the window
(all zeros, a constant, a sensor or actuator that stopped) tells it nothing, and a window where
no input varies has nothing to identify from: the ARX fit then explains the outputs by their own
past only and the model's input paths are noise. This module says which channels those are and
what to do; the identification (:mod:`okid_ros.core.pipeline`) warns about dead channels and
refuses a window without excitation, the service's diagnostics can call
:func:`input_excitation` on the window's samples.

A channel is *dead* when its standard deviation is at most :data:`NEGLIGIBLE_RELATIVE_SPREAD`
of its largest magnitude (a constant, or a constant plus rounding) or it is all zeros. The test
is relative to the channel's own level because the units of each channel are unknown.

Outputs (:func:`output_problem`): a dead output channel, or one that is a linear combination of
the others (a channel recorded twice, a derived channel), leaves the innovation covariance
singular: no predictor weighting, change test or uncertainty can be formed. Both are refused
with the channel named, before any fit. After the fit, :func:`unexplained_warnings` says when
the model predicts almost none of the outputs (outputs unrelated to the inputs and to their own
past: a wrong topic or column, a sensor reading only its noise).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import linalg

from okid_ros.core.arx import ArxFit, NormalEquations
from okid_ros.core.channels import channel_std, column_peaks
from okid_ros.core.identified_model import IdentifiedModel
from okid_ros.core.least_squares import NEGLIGIBLE_RELATIVE_SPREAD, constant_columns

__all__ = ["NEGLIGIBLE_RELATIVE_SPREAD", "Excitation", "LiveInputs", "dead_channels", "input_excitation",
           "excitation_warnings", "output_problem", "unexcited_reason", "unexplained_warnings",
           "window_excitation_warnings", "window_output_problem", "frozen_output_warnings", "longest_held_run",
           "dependent_inputs", "entering_excitation_text", "leaving_excitation_text", "window_columns"]


#: Outputs are linearly dependent when a combination of the unit-spread channels has at most this
#: fraction of the spread of the largest (10 copies of a channel with 1 % independent noise each:
#: 1e-2; a channel recorded twice: 1e-8 or less).
DEPENDENT_OUTPUT_RATIO = 1e-5

#: A channel whose standard deviation exceeds its normalized median absolute deviation this many
#: times holds a spike (a Gaussian record: about 1; a lightly damped response: a few).
SPIKE_SPREAD_RATIO = 100.0
#: ... and at most this share of its samples (at least one) lie beyond a tenth of that ratio.
SPIKE_SHARE = 0.01

#: A model whose one-step prediction explains less than this share of every output's variance
#: identified no dynamics (outputs of white noise, 4000 samples, ARX orders 40 and automatic:
#: at most 0.4-1.2 % in each of 12 records; the paper model's records: above 99 %).
MIN_EXPLAINED_VARIANCE = 0.02
#: ... or less than this many samples' worth of it (the share times the record's length): what a
#: fit explains of white noise by chance shrinks as 1 / N. White inputs and outputs (N 500-6000,
#: ARX orders 20-100 and automatic, 1-8 outputs, 1-2 inputs, 20 records each): the best output's
#: share times N at most 32-62, its 90th percentile 19-41; a 1000-sample window of white noise
#: was explained up to 4.6 % and listed modes in 17-65 % of the records.
CHANCE_EXPLAINED_SAMPLES = 100.0
#: ... with N at least this (the calibration's shortest record: 20 % below it, not 100 / N).
CHANCE_MIN_SAMPLES = 500

#: A run of samples in which every output repeats the sample before, at least this share of the
#: record and :data:`FROZEN_MIN_SAMPLES` long, is named in a warning: a recorder that wrote zeros
#: (or held values) before its sensors delivered, a stalled acquisition. Sensors that deliver
#: differ in some channel from one sample to the next (noise, the least bit of a converter).
FROZEN_SHARE = 0.05
FROZEN_MIN_SAMPLES = 50

_WHAT_TO_DO = ("check the sensor or actuator and its topic/column mapping, or, if the input is not "
               "measured, use output-only identification (identify --output-only)")


@dataclass
class Excitation:
    """The excitation of each input channel of a window.

    Attributes
    ----------
    std : (m,) standard deviation of each input channel.
    level : (m,) largest magnitude of each input channel.
    dead : indices of the channels without (or with negligible) variance.
    constant_value : value of each dead channel (its mean), by index.
    """

    std: np.ndarray
    level: np.ndarray
    dead: list[int] = field(default_factory=list)
    constant_value: dict[int, float] = field(default_factory=dict)

    @property
    def n_inputs(self) -> int:
        return int(self.std.size)

    @property
    def excited(self) -> bool:
        """Whether at least one input varies (there are inputs and not all are dead)."""
        return self.n_inputs > 0 and len(self.dead) < self.n_inputs

    def channel_text(self, index: int) -> str:
        value = self.constant_value.get(index, 0.0)
        return f"input {index} ({_constant_text(value, float(self.std[index]))})"


def dead_channels(x: np.ndarray) -> np.ndarray:
    """Indices of the columns of ``x`` (N, c), N >= 1, without (or with negligible) variance."""
    level = column_peaks(x)
    return np.flatnonzero((level == 0) | (channel_std(x) <= NEGLIGIBLE_RELATIVE_SPREAD * level))


def _constant_value(column: np.ndarray) -> float:
    """The value of a dead channel (its mean, without overflow near the float64 limits)."""
    level = float(np.max(np.abs(column)))
    return float(np.mean(column / level)) * level if level > 0 else 0.0


def output_problem(y: np.ndarray) -> str:
    """Why the outputs ``y`` (N, p) cannot be identified from (module docstring), or "".

    Checked: a dead channel (constant or all zeros), then linearly dependent channels (the
    eigenvalues of the correlation matrix of the outputs; ``N p^2`` flops).
    """
    y = np.asarray(y, dtype=float)
    if y.shape[0] == 0:
        return ""
    if y.shape[0] < y.shape[1] + 2:  # every channel "constant", or "dependent", by the count alone
        n, p = y.shape
        return f"{n} sample{'s' * (n != 1)} of {p} output{'s' * (p != 1)}: far too few to identify from"
    dead = dead_channels(y)
    if dead.size:
        j = int(dead[0])
        return _dead_output(j, _constant_value(y[:, j]), float(channel_std(y[:, j : j + 1])[0]))
    if y.shape[1] < 2 or y.shape[0] < y.shape[1]:
        return ""
    x = _unit_centred(y)
    dependent = _dependent_outputs(x.T @ x)
    if dependent:
        # One sample far beyond the rest in every channel (a glitch) also makes the outputs collinear.
        deviation = np.abs(x - np.median(x, axis=0))
        robust = 1.4826 * np.median(deviation, axis=0)
        ratio = x.std(axis=0) / np.maximum(robust, np.finfo(float).tiny)
        # A spike is a few samples far out; a channel of two levels (alternating +-1) has no
        # median deviation either, but half its samples are "far".
        few_far = np.sum(deviation > SPIKE_SPREAD_RATIO / 10 * robust, axis=0) <= max(1.0, SPIKE_SHARE * x.shape[0])
        if np.max(np.where(few_far, ratio, 0.0)) > SPIKE_SPREAD_RATIO:
            j = int(np.argmax(np.where(few_far, ratio, 0.0)))
            return (f"output channel {j} holds samples far beyond its usual range (standard deviation "
                    f"{ratio[j]:.3g} times its median absolute deviation), enough to make the outputs look "
                    f"linearly dependent: a spike or a glitch? remove or repair those samples")
    return dependent


def window_output_problem(normal: NormalEquations, n_inputs: int, n_outputs: int) -> str:
    """:func:`output_problem` of a window known only by its normal equations (the live service).

    Columns ``m .. m + p`` of the regressor are ``y_(k-1)``: their sums and Gram give each
    output's level, spread and the outputs' covariance in the window.
    """
    cols = slice(n_inputs, n_inputs + n_outputs)
    square, mean, _, dead = window_columns(normal, cols)
    if dead.any():
        j = int(np.flatnonzero(dead)[0])
        return _dead_output(j, float(mean[j]), None)
    if n_outputs < 2:
        return ""
    return _dependent_outputs(normal.R[cols, cols] / max(normal.n_rows, 1) - np.outer(mean, mean))


def window_columns(normal: NormalEquations, cols: slice
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean square, mean, variance and the dead mask of regressor columns ``cols`` of a window."""
    n = max(normal.n_rows, 1)
    # A sliding window's downdates can leave an all-zero column's sum of squares at -1e-17.
    square = np.maximum(np.diag(normal.R)[cols] / n, 0.0)
    width = square.size
    mean = normal.phi_sum[cols] / n if normal.phi_sum is not None else np.zeros(width)
    variance = np.maximum(square - mean**2, 0.0)
    return square, mean, variance, constant_columns(square, variance)


def _dead_output(channel: int, value: float, spread: float | None) -> str:
    """Why a dead output channel is refused; ``spread`` its standard deviation (None: not known)."""
    return (f"output channel {channel} carries no response ({_constant_text(value, spread)}): check the sensor "
            f"and its topic/column mapping, or leave the channel out")


def _constant_text(value: float, spread: float | None) -> str:
    """A dead channel's value in words; a variation above rounding is named with what it suggests.

    ``spread`` is the channel's standard deviation, None where only a window's sums are known
    (their variance at such a level is rounding).
    """
    if value == 0.0:
        return "all zeros"
    if spread is None:
        return f"constant {value:.6g}, or varying by less than {NEGLIGIBLE_RELATIVE_SPREAD:.0e} of that level"
    relative = spread / abs(value)
    if relative <= 64 * np.finfo(float).eps:
        return f"constant {value:.6g}"
    # y + 1e12 with a spread of 5 was "constant 1e+12": true to 5e-12, but it hid the variation.
    return (f"constant {value:.6g} but for a variation of {relative:.1g} of that level, below any converter's "
            f"resolution: a small signal on a large offset? subtract the offset before the data reach okid_ros")


def _dependent_outputs(gram: np.ndarray) -> str:
    """Why outputs whose (centred) Gram or covariance is ``gram`` (p, p) are linearly dependent, or ""."""
    dependent = _dependent_columns(gram)
    if dependent is None:
        return ""
    listed = ", ".join(str(int(j)) for j in dependent[0])
    return (f"outputs {listed} are linearly dependent (one is a combination of the others: a channel recorded "
            f"twice? a derived channel? or a spike far larger than the rest in all of them): the innovation "
            f"covariance would be singular; {_leave_out(dependent[1])}")


def _leave_out(count: int) -> str:
    return f"leave {'one' if count == 1 else count} of them out"


def _unit_centred(x: np.ndarray) -> np.ndarray:
    """The columns of ``x`` (N, c) each within +-1 (no overflow near the float64 limits), less their means."""
    x = x / column_peaks(x)
    return x - x.mean(axis=0)


def _dependent_columns(gram: np.ndarray) -> tuple[np.ndarray, int] | None:
    """The channels in a linear dependence of those whose centred Gram is ``gram`` (c, c), and how many.

    None when the smallest direction of their correlation matrix holds more than
    :data:`DEPENDENT_OUTPUT_RATIO` of the spread of the largest.
    """
    scale = np.sqrt(np.diag(gram))
    values, vectors = linalg.eigh(gram / np.outer(scale, scale))  # the channels' correlation matrix
    null = vectors[:, values <= DEPENDENT_OUTPUT_RATIO**2 * values[-1]]
    if not null.shape[1]:
        return None
    # The channels each null combination holds (a repeated channel: the two; a derived one: all).
    involved = np.flatnonzero(np.max(np.abs(null), axis=1) > 1e-3 * np.max(np.abs(null)))
    return involved, int(null.shape[1])


def unexplained_warnings(innovation_covariance: np.ndarray, y: np.ndarray) -> list[str]:
    """A warning when a model explains almost none of any output one step ahead; [] otherwise.

    Almost none: less than :data:`MIN_EXPLAINED_VARIANCE`, or than a fit explains of white noise
    of the record's length by chance (:data:`CHANCE_EXPLAINED_SAMPLES` / N).
    ``innovation_covariance`` (p, p) of the model's one-step prediction errors on the record
    ``y`` (N, p) (means removed) it was identified from.
    """
    variance = channel_std(y) ** 2
    explained = 1.0 - np.diag(innovation_covariance) / np.where(variance > 0, variance, np.inf)
    best = float(np.max(explained)) if explained.size else 1.0
    chance = CHANCE_EXPLAINED_SAMPLES / max(y.shape[0], CHANCE_MIN_SAMPLES)
    if best >= max(MIN_EXPLAINED_VARIANCE, chance):
        return []
    by_chance = (f", no more than a fit explains of white noise of {y.shape[0]} samples by chance (up to "
                 f"{100 * chance:.2g} %)"
                 if best >= MIN_EXPLAINED_VARIANCE else "")
    return [f"the model explains at most {100 * max(best, 0.0):.1f} % of any output's variance one step "
            f"ahead{by_chance}: no dynamics identified (are the outputs unrelated to the inputs and to their own "
            f"past? check the channels and their topic/column mapping); modes listed from it are not to be trusted"]


def input_excitation(u: np.ndarray) -> Excitation:
    """Which input channels of ``u`` (N, m) carry no excitation (see the module docstring)."""
    u = np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    if u.shape[0] == 0:
        return Excitation(np.zeros(u.shape[1]), np.zeros(u.shape[1]), list(range(u.shape[1])),
                          dict.fromkeys(range(u.shape[1]), 0.0))
    std = channel_std(u)
    level = column_peaks(u)
    dead = [int(i) for i in dead_channels(u)]
    values = {i: _constant_value(u[:, i]) for i in dead}
    return Excitation(std, level, dead, values)


def excitation_warnings(u: np.ndarray) -> list[str]:
    """Warnings naming the dead input channels of ``u`` (N, m), and live ones that are linearly dependent.

    [] if none. All inputs dead: the one reason :func:`unexcited_reason`.
    """
    report = input_excitation(u)
    if report.dead and not report.excited:
        return [unexcited_reason(report)]
    warnings = excitation_warnings_of(report) if report.dead else []
    live = [i for i in range(report.n_inputs) if i not in report.dead]
    if len(live) > 1 and u.shape[0] >= len(live):
        x = _unit_centred(np.asarray(u, dtype=float)[:, live])
        warnings += [dependent for dependent in [dependent_inputs(x.T @ x, live)] if dependent]
    return warnings


def dependent_inputs(gram: np.ndarray, channels: list[int]) -> str:
    """Why inputs ``channels`` whose (centred) Gram is ``gram`` (c, c) are linearly dependent, or ""."""
    dependent = _dependent_columns(gram)
    if dependent is None:
        return ""
    listed, leave = ", ".join(str(channels[j]) for j in dependent[0]), _leave_out(dependent[1])
    return (f"inputs {listed} are linearly dependent (one is a combination of the others: a channel recorded twice? "
            f"one command sent to two actuators?): the model cannot tell their effects apart and splits them between "
            f"their columns of B and D arbitrarily; {leave}")


def unexcited_reason(report: Excitation) -> str:
    """Why a window whose inputs are all dead is not identified, with what to do."""
    listed = ", ".join(report.channel_text(i) for i in report.dead)
    return f"not identified: no input carries excitation in this window ({listed}); {_WHAT_TO_DO}"


@dataclass(frozen=True)
class LiveInputs:
    """The excited input channels: identification runs on them, dead ones re-enter with zero effect.

    A dead channel's ARX coefficients are ratios of rounding noise (its centered column is
    ~1e-16 of its level), which the Markov recursion then amplifies; without it the fit is the
    fit of the live inputs, and the model gets zero columns of ``B`` and ``D`` for it.

    Attributes
    ----------
    keep : indices of the live inputs, increasing; n_inputs : m, all inputs.
    """

    keep: tuple[int, ...]
    n_inputs: int

    @classmethod
    def of(cls, u: np.ndarray) -> LiveInputs:
        report = input_excitation(u)
        return cls(tuple(i for i in range(report.n_inputs) if i not in report.dead), report.n_inputs)

    @property
    def all_live(self) -> bool:
        return len(self.keep) == self.n_inputs

    def select(self, u: np.ndarray) -> np.ndarray:
        """The live columns of ``u`` (N, m)."""
        return u if self.all_live else u[:, list(self.keep)]

    def select_arx(self, arx: ArxFit) -> ArxFit:
        """``arx`` without the coefficient rows of the dead inputs (layout of ArxFit.theta)."""
        if self.all_live:
            return arx
        return replace(arx, theta=arx.theta[self._rows(arx)], n_inputs=len(self.keep))

    def _rows(self, arx: ArxFit) -> np.ndarray:
        """(m + q (p + m),) bool: the coefficient rows of the live inputs and of all outputs."""
        live = np.isin(np.arange(self.n_inputs), self.keep)
        return np.concatenate([live, np.tile(np.concatenate([np.ones(arx.n_outputs, bool), live]), arx.order)])

    def restore(self, model: IdentifiedModel, u: np.ndarray, offsets: str) -> IdentifiedModel:
        """``model`` of the live inputs with all ``m`` inputs: zero B, D (and Markov) columns for dead ones.

        ``u`` (N, m) is the full input; a dead input's offset is its mean when offsets are removed.
        """
        if self.all_live:
            return model
        keep, m = list(self.keep), self.n_inputs

        def widen(matrix: np.ndarray | None) -> np.ndarray | None:
            if matrix is None:
                return None
            full = np.zeros(matrix.shape[:-1] + (m,))
            full[..., keep] = matrix
            return full

        offset = np.mean(u, axis=0) if offsets == "remove" else np.zeros(m)
        if model.input_offset is not None:
            offset[keep] = model.input_offset
        arx = model.arx
        if arx is not None:
            rows = self._rows(arx)
            theta = np.zeros((rows.size, arx.theta.shape[1]))
            theta[rows] = arx.theta
            arx = replace(arx, theta=theta, n_inputs=m)
        return replace(model, B=widen(model.B), D=widen(model.D), system_markov=widen(model.system_markov),
                       input_offset=offset, arx=arx)


def window_excitation_warnings(normal: NormalEquations, n_inputs: int) -> list[str]:
    """:func:`excitation_warnings` of a window known only by its normal equations (the live service).

    The first ``m`` regressor columns are ``u_k``: their centered mean squares (from ``R`` and
    the column sums) and the mean magnitudes give each input's spread and level in the window.
    """
    square, mean, variance, dead = window_columns(normal, slice(0, n_inputs))
    report = Excitation(np.sqrt(variance), np.sqrt(square), [int(i) for i in np.flatnonzero(dead)],
                        {int(i): float(mean[i]) for i in np.flatnonzero(dead)})
    if not report.dead:
        return _late_excitation(normal, n_inputs)
    leaving = _leaving_excitation(normal, n_inputs, report)
    still = [i for i in report.dead if i not in leaving]
    if leaving:
        rest = replace(report, dead=still, constant_value={i: report.constant_value[i] for i in still})
        return list(leaving.values()) + (excitation_warnings_of(rest) if still else [])
    return [unexcited_reason(report)] if not report.excited else excitation_warnings_of(report)


def _leaving_excitation(normal: NormalEquations, n_inputs: int, report: Excitation) -> dict[int, str]:
    """Why each dead input of ``report`` whose lagged columns vary is (a blow before the window's oldest row).

    Such an input is constant in the window's own samples (``u_k``) and varies in its lags from
    some ``a`` on: ``a`` or more samples before the oldest row.
    """
    n_coefficients, n_outputs = normal.r.shape
    width = n_outputs + n_inputs
    texts = {}
    for i in report.dead:
        lags = window_columns(normal, slice(n_inputs + n_outputs + i, n_coefficients, width))[3]
        if lags.size and not lags.all():
            own = f"are {_constant_text(report.constant_value[i], None)}"
            texts[i] = leaving_excitation_text(i, int(np.argmin(lags)) + 1, lags.size, own)
    return texts


def leaving_excitation_text(channel: int, first_lag: int, order: int, own: str) -> str:
    """Why input ``channel``, varying only from its lag ``first_lag`` on (a blow leaving the window), is refused.

    ``own`` says what the window's own samples of it hold ("are all zeros", "hold 4e-13 of that mean square").
    """
    return (f"input {channel} varies only {first_lag} or more samples before this window's oldest row (in its lags "
            f"{first_lag}-{order} alone; the window's own samples {own}: a hammer's blow leaving the window): its "
            f"response is in the window, the force at lags 0-{first_lag - 1} is not; it will be past the ARX order's "
            f"{order} lags {order - first_lag + 1} samples on, or take a longer arx.window_length")


def entering_excitation_text(channel: int, newest: int, order: int, own: str) -> str:
    """Why input ``channel``, varying only in the window's newest ``newest`` samples (a blow entering it), is refused.

    ``own``: what its older samples hold. Said for a constant (:func:`_late_excitation`) or a quiet force before.
    """
    heals = order - newest + 1
    return (f"input {channel} varies only in the newest {newest} samples of this window (its older samples {own}: a "
            f"hammer's blow entering the window): the window does not yet hold its response over the ARX order's "
            f"{order} lags; it will {heals} sample{'s' if heals > 1 else ''} on")


def _late_excitation(normal: NormalEquations, n_inputs: int) -> list[str]:
    """Why a window is singular whose inputs vary only in its newest ``q`` samples (a first hammer blow); [].

    The last ``m`` regressor columns are ``u_(k-q)``: the window's samples but its newest ``q``. An input constant
    there leaves that column (centred: zero) without information; its live lags count its newest varying samples.
    """
    n_coefficients, n_outputs = normal.r.shape
    order = (n_coefficients - n_inputs) // max(n_outputs + n_inputs, 1)
    if n_inputs == 0 or order < 1:
        return []
    _, mean, _, dead = window_columns(normal, slice(n_coefficients - n_inputs, n_coefficients))
    texts = []
    for i in np.flatnonzero(dead):  # its lags 1 .. q: dead from the first its newest samples do not reach
        lags = window_columns(normal, slice(n_inputs + n_outputs + i, n_coefficients, n_outputs + n_inputs))[3]
        own = f"are {_constant_text(float(mean[i]), None)}"
        texts.append(entering_excitation_text(int(i), int(np.argmax(lags)) + 1, order, own))
    return texts


def excitation_warnings_of(report: Excitation) -> list[str]:
    """The warning of :func:`excitation_warnings` for a report of some dead inputs."""
    listed = ", ".join(report.channel_text(i) for i in report.dead)
    return [f"no excitation on {listed} in this window: the model cannot learn "
            f"{'its' if len(report.dead) == 1 else 'their'} effect; {_WHAT_TO_DO}"]


def longest_held_run(repeats: np.ndarray) -> tuple[int, int] | None:
    """The longest run of samples that repeat the one before, if it counts as held; else None.

    ``repeats`` (N - 1,) bool: sample ``k + 1`` equals sample ``k``. Returns ``(first, last)``,
    the held sample and its last repeat, when the run is at least :data:`FROZEN_SHARE` of the N
    samples and :data:`FROZEN_MIN_SAMPLES` long (the rule of :func:`frozen_output_warnings`).
    """
    edges = np.flatnonzero(np.diff(np.concatenate([[0], repeats.astype(np.int8), [0]])))  # starts, ends
    if edges.size == 0:
        return None
    k = int(np.argmax(edges[1::2] - edges[::2]))
    first, last = int(edges[2 * k]), int(edges[2 * k + 1])
    n = repeats.size + 1
    return (first, last) if last - first + 1 >= max(FROZEN_MIN_SAMPLES, FROZEN_SHARE * n) else None


def frozen_output_warnings(y: np.ndarray) -> list[str]:
    """A warning when every output holds its value over a long run of samples; [] otherwise.

    ``y`` (N, p): the record's outputs. The longest run in which each sample repeats the one
    before in every channel, counted when at least :data:`FROZEN_SHARE` of the record and
    :data:`FROZEN_MIN_SAMPLES` samples (NaN never repeats: gaps are reported elsewhere).
    """
    y = np.asarray(y)
    if y.ndim != 2 or y.shape[0] < 2 or y.shape[1] == 0:
        return []
    run = longest_held_run(np.all(y[1:] == y[:-1], axis=1))
    if run is None:
        return []
    first, last = run
    held = last - first + 1
    return [f"samples {first}-{last} ({100 * held / y.shape[0]:.0f} % of the record) hold every output at one "
            f"value: a recorder that had not started or an acquisition that stalled? They are identified with "
            f"the rest; cut them out if they are not the structure's response"]
