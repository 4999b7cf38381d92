"""Helpers of :mod:`okid_ros.core.output_only`: input checks, the diagram, the jackknife."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy import linalg

from okid_ros.core.channels import channel_mean, channel_std, column_peaks
from okid_ros.core.excitation import output_problem
from okid_ros.core.gap_fill import MAX_GAP_SAMPLES, missing_mask, missing_problem
from okid_ros.core.identified_model import IdentificationError
from okid_ros.core.modal import Mode
from okid_ros.core.mode_jackknife import ITERATIONS, jackknife_std, nearest_modes, nearest_poles
from okid_ros.core.options import OFFSETS, sample_time_problem
from okid_ros.core.output_covariance import OutputCorrelations
from okid_ros.core.output_only_modes import ModeCluster, PoleSet
from okid_ros.core.regressors import real_array
from okid_ros.core.sensor_faults import record_faults
from okid_ros.core.stabilization import StabilizationOrder, StabilizationPole
from okid_ros.core.stochastic_realization import OrderRealizer, covariance_decomposition
from okid_ros.core.window_minimum import OUTPUT_ONLY_MIN_SAMPLES
from okid_ros.core.worker_threads import SERIAL, WorkerThreads

__all__ = ["prepare_outputs", "match_clusters", "output_only_diagram", "Jackknife", "spectral_dominance",
           "check_channel_sizes", "check_output_only_options", "listed_within_limits"]


def prepare_outputs(y, sample_time_s: float, offsets: str, *, valid=None, max_gap: int = MAX_GAP_SAMPLES
                    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, list[str]]:
    """``y`` as (N, p) floats less its means (``offsets="remove"``) and drift, ``valid``, the means, warnings.

    ``valid`` (N,) bool: False at samples filled by prediction (the drift's line leaves them out),
    returned as a bool mask (None when no sample is); held to the input-output record's gap rule
    (:func:`.gap_fill.missing_problem`, runs of at most ``max_gap``). Clipped and drifting
    channels are named (:mod:`.sensor_faults`; a drift is removed unless ``offsets="none"``).

    Raises IdentificationError naming what is wrong (shape, NaN/Inf, a dead channel or one the
    others make up, too short, too much filled, a bad sample time).
    """
    if offsets not in OFFSETS:
        raise IdentificationError(f"offsets must be one of {OFFSETS}, got {offsets!r}")
    try:
        y = real_array("y", y)
    except ValueError as exc:
        raise IdentificationError(str(exc)) from None
    if y.ndim == 1:
        y = y[:, None]
    if y.ndim != 2 or y.shape[1] == 0:
        raise IdentificationError(f"y must be 2-D (N, p) with at least one channel, got shape {y.shape}")
    if problem := sample_time_problem(sample_time_s):
        raise IdentificationError(problem)
    if y.shape[0] < OUTPUT_ONLY_MIN_SAMPLES:
        raise IdentificationError(
            f"too few samples for output-only identification: {y.shape[0]} < {OUTPUT_ONLY_MIN_SAMPLES}")
    try:
        valid = None if valid is None else missing_mask(valid, y.shape[0])
    except ValueError as exc:
        raise IdentificationError(str(exc)) from None
    # fewer: their correlations were 0 / 0, NaN, then a ValueError
    if valid is not None and valid.sum() < OUTPUT_ONLY_MIN_SAMPLES:
        raise IdentificationError(f"too few measured samples for output-only identification: {int(valid.sum())} of "
                                  f"the {valid.size} (valid True) < {OUTPUT_ONLY_MIN_SAMPLES}")
    if valid is not None and (problem := missing_problem(valid, max_gap=max_gap)):  # 90 % filled was taken
        raise IdentificationError(problem)
    if not np.all(np.isfinite(y)):
        bad = np.argwhere(~np.isfinite(y))[0]
        raise IdentificationError(f"y holds NaN or Inf (first at sample {bad[0]}, channel {bad[1]})")
    problem = output_problem(y)  # a dead channel, or one the others make up (the input-output rule)
    if problem:
        raise IdentificationError(problem)
    _, y, _, warnings = record_faults(np.zeros((y.shape[0], 0)), y, valid=valid, detrend=offsets == "remove")
    # The means of what is identified: a removed drift keeps them, a removed level shift keeps the
    # level before it. Neither overflows nor underflows for values near the float64 limits.
    mean = channel_mean(y)
    std = channel_std(y)
    large = np.flatnonzero(np.abs(mean) > 0.1 * std)
    if large.size:
        action = "removed" if offsets == "remove" else "NOT removed (offsets='none')"
        warnings.append(f"large offsets {action} on outputs {', '.join(str(int(i)) for i in large[:6])}")
    if offsets == "none":
        return y, valid, np.zeros(y.shape[1]), warnings
    return y - mean, valid, mean, warnings


def listed_within_limits(modes: list[Mode], scattered) -> list[Mode]:
    """The modes whose standard deviations ``scattered(f_std, z_std, f, zeta)`` takes for no noise.

    The standard deviations are those listed (at the model order, or at the home order where it
    lost the mode's pole). A model lists them by :meth:`.identified_model.IdentifiedModel.keep_modes`
    (each at its own state block).
    """
    return [m for m in modes if not scattered(m.frequency_hz_std, m.damping_ratio_std, m.frequency_hz, m.damping_ratio)]


#: A listed mode whose cluster's shapes are complex (median MPC below this) and whose damping falls as the
#: order rises (:data:`GROUP_DAMPING_FALL`) stands for an unresolved group of modes, not for one
#: (:func:`stands_for_a_group`).
GROUP_MAX_MPC = 0.8
#: The damping at a cluster's highest third of orders below ``1 -`` this of its lowest third's: not converged.
GROUP_DAMPING_FALL = 0.18


def stands_for_a_group(cluster: ModeCluster | None, poles: PoleSet) -> bool:
    """Whether a listed mode's cluster is the pole of an unresolved group of modes rather than a mode.

    Two real modes closer than the record resolves, read as one pole, give it a complex shape
    (their shapes mixed with a phase between them) and a damping that falls as the order rises
    (the model spends more states on the group); a complex structural mode (non-proportional
    damping) keeps its damping across the orders, and a real mode whose damping drifts keeps a
    real shape. Measured on every listed mode of the bench's sets: docs/benchmarks-output-only.md,
    "The last spurious modes (forty-sixth session)".
    """
    if cluster is None or cluster.mpc >= GROUP_MAX_MPC:
        return False
    damping = poles.damping_ratio[[cluster.members[n] for n in sorted(cluster.members)]]
    third = max(damping.size // 3, 1)
    return bool(np.median(damping[-third:]) < (1 - GROUP_DAMPING_FALL) * np.median(damping[:third]))


def match_clusters(modes: list[ModeCluster], poles: PoleSet, n_model: int) -> list[tuple[complex, ModeCluster]]:
    """The eigenvalue of each mode's pole at order ``n_model`` (modes without one are left out)."""
    return [(complex(poles.eigenvalue[mode.members[n_model]]), mode) for mode in modes if n_model in mode.members]


def check_output_only_options(method: str, harmonics: str, *, methods: tuple[str, ...], max_states, block_rows,
                              low_band, workers, max_gap, std_segments=0) -> None:
    """IdentificationError naming an unknown method or harmonics option, a bad count or a non-bool ``low_band``.

    ``max_states`` 0 was taken for the default, a negative one said "the Hankel matrix has rank below
    2", 20.5 or "20" were cut or parsed, and ``low_band="no"`` was taken as True, in silence; ``max_gap``
    -1 said "0 samples are missing in a row ...; at most -1 are filled", "10" a TypeError.
    """
    if method not in methods:
        raise IdentificationError(f"output-only method must be one of {methods}, got {method!r}")
    if harmonics not in ("remove", "keep"):
        raise IdentificationError(f"harmonics must be 'remove' or 'keep', got {harmonics!r}")
    if low_band not in (True, False):
        raise IdentificationError(f"low_band must be True or False, got {low_band!r}")
    for name, value, least, why in (("max_states", max_states, 2, "a mode takes two states; or None"),
                                    ("block_rows", block_rows, 2, "Hankel block rows; or None"),
                                    ("workers", workers, 1, "threads"),
                                    ("max_gap", max_gap, 0, "the longest run of filled samples"),
                                    ("std_segments", std_segments, 0, "the deviations' jackknife's segments")):
        if (value is not None or name in ("workers", "max_gap", "std_segments")) and (
                isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least):
            raise IdentificationError(f"{name} must be an integer >= {least} ({why}), got {value!r}")


#: Largest channel size after the common scale: the Hankel's Gram holds fourth powers of the
#: outputs, and 1e50 keeps them within float64.
MAX_SCALED_OUTPUT = 1e50


def check_channel_sizes(y: np.ndarray) -> None:
    """IdentificationError when the outputs (one common scale) span too many decades to correlate."""
    peak = column_peaks(y)
    if np.max(peak) > MAX_SCALED_OUTPUT:
        sizes = ", ".join(f"{v:.1e}" for v in peak / np.min(peak))
        raise IdentificationError(
            f"the output channels differ too much in size (relative peaks {sizes}): output-only identification "
            f"weighs each channel by its variance, and the correlations of channels so far apart leave float64; "
            f"express them in comparable units")


def output_only_diagram(poles: PoleSet) -> list[StabilizationOrder]:
    """The stabilization diagram in the project's structure (a stable pole meets all criteria)."""
    diagram = []
    for n in np.unique(poles.order):
        index = np.flatnonzero(poles.order == n)
        diagram.append(StabilizationOrder(int(n), [
            StabilizationPole(float(poles.frequency_hz[i]), float(poles.damping_ratio[i]), poles.shape[i],
                              bool(poles.stable[i]), bool(poles.stable[i]), bool(poles.stable[i]))
            for i in index
        ]))
    return diagram


class Jackknife:
    """Delete-one jackknife over the record's segments: the model realized with each segment left out.

    Each left-out set of correlations is decomposed once; :meth:`std` then realizes any order
    from them and reads off, for each target pole, its nearest pole. The jackknife variance is
    ``(S - 1) / S sum_j (theta_j - mean)^2`` over the S segments.

    Parameters
    ----------
    correlations, references, block_rows : as the model was identified.
    max_states : the highest order :meth:`std` will be asked for.
    start : (i r, c) the record's Gram's leading eigenvectors (the model's decomposition's
        ``basis``, :data:`~.mode_jackknife.SPARE_COLUMNS` beyond ``max_states``): a replicate's
        Gram differs from the record's by one segment's share, so its leading pairs are found
        by :data:`~.mode_jackknife.ITERATIONS` block power iterations from them where that is
        cheaper (:func:`.stochastic_realization.covariance_decomposition`). None: each
        replicate's decomposed from scratch.
    threads : the replicates are decomposed, and their poles read, side by side in these
        (:mod:`.worker_threads`; the same values for any number).
    decompose : ``decompose(j)`` the decomposition without segment ``j`` (another realization,
        :func:`.canonical_realization.canonical_replicates`); None: the covariance route's.
    """

    def __init__(self, correlations: OutputCorrelations, references: np.ndarray, block_rows: int,
                 max_states: int, *, start: np.ndarray | None = None, threads: WorkerThreads = SERIAL,
                 decompose: Callable | None = None) -> None:
        def replicate(j: int) -> OrderRealizer:
            decomposition = decompose(j) if decompose is not None else covariance_decomposition(
                correlations.leave_one_out(j), references, block_rows, max_states, start=start, iterations=ITERATIONS)
            return OrderRealizer(decomposition, min(max_states, decomposition.max_states))

        # Started now, read when a mode is screened: the caller's diagram is made meanwhile.
        self._threads = threads
        self._replicates = [threads.submit(replicate, j) for j in range(correlations.segments.shape[0])]

    @property
    def realizers(self) -> list[OrderRealizer]:
        """The replicates' realizers, one per left-out segment (made or waited for on first use)."""
        return [task.result() for task in self._replicates]

    def std(self, targets: np.ndarray, n_model: int, sample_time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Standard deviations ``(frequency_hz_std, damping_ratio_std)``, (M,) each.

        ``targets`` (M,) are poles of the model of order ``n_model``.
        """
        targets = np.asarray(targets, dtype=complex)
        n_seg = len(self.realizers)
        freqs = np.empty((n_seg, targets.size))
        damps = np.empty((n_seg, targets.size))
        values = self._threads.map(lambda r: r.eigenvalues(min(n_model, r.max_states)), self.realizers)
        for j, eigenvalues in enumerate(values):
            freqs[j], damps[j] = nearest_modes(eigenvalues, targets, sample_time_s)
        return jackknife_std(freqs), jackknife_std(damps)

    def shapes(self, target: complex, n_model: int, sample_time_s: float) -> np.ndarray:
        """(S, p) output shapes ``C psi`` (unit norm) of each replicate's pole nearest ``target`` at ``n_model``.

        The pole is the one :meth:`std` reads (:func:`.mode_jackknife.nearest_poles`); a row is NaN
        where a replicate has no complex pole.
        """
        def shape(realizer: OrderRealizer) -> np.ndarray:
            n_states = min(n_model, realizer.max_states)
            eigenvalues, vectors = realizer.eigen(n_states)
            k = int(nearest_poles(eigenvalues, np.array([target]), sample_time_s)[0])
            C = realizer.realize(n_states)[1]
            if k < 0:
                return np.full(C.shape[0], np.nan, dtype=complex)
            column = C @ vectors[:, k]
            return column / np.linalg.norm(column)

        return np.array(self._threads.map(shape, self.realizers))

    def screened_std(self, target: complex, n_model: int, sample_time_s: float, *,
                     scattered: Callable[[float, float], bool]) -> tuple[float, float] | None:
        """:meth:`std` of one pole, or None when ``scattered(frequency_hz_std, damping_ratio_std)``.

        The sum of squares about the mean of all S replicates is at least that about the mean of
        the ones read so far, so once ``(S - 1) / S`` times the latter passes a limit the pole is
        scattered whatever the other replicates hold, and their eigenvalues at ``n_model`` are
        not computed (a third of the replicates' eigenvalues on the low-mode simulation, most of
        whose candidates are noise poles). A bound within 1e-9 of a limit reads on; the full
        values are those of :meth:`std`. The one difference: a replicate not read that has no
        complex pole at all (NaN in :meth:`std`, which no limit catches) is not seen.

        Parameters
        ----------
        target : the pole (discrete, upper half plane) of the model of order ``n_model``.
        scattered : ``scattered(f_std, z_std) -> bool``, growing with both (a limit on each).

        Returns
        -------
        ``(frequency_hz_std, damping_ratio_std)`` floats, or None when scattered.
        """
        realizers = self.realizers
        n_seg, chunk = len(realizers), self._threads.workers
        read = np.empty((n_seg, 2))
        for first in range(0, n_seg, chunk):  # as many replicates at a time as there are threads
            values = self._threads.map(lambda r: r.eigenvalues(min(n_model, r.max_states)),
                                       realizers[first:first + chunk])
            for j, eigenvalues in enumerate(values, first):
                read[j] = [v[0] for v in nearest_modes(eigenvalues, np.array([target]), sample_time_s)]
                # A NaN bound (a replicate without a complex pole) never passes: read on, as std() would.
                bound = np.sqrt((n_seg - 1) / n_seg * np.sum((read[: j + 1] - read[: j + 1].mean(axis=0)) ** 2,
                                                              axis=0))
                if scattered(*(bound / (1.0 + 1e-9))):
                    return None
        f_std, z_std = self.std(np.array([target]), n_model, sample_time_s)  # the eigenvalues are kept
        return None if scattered(f_std[0], z_std[0]) else (float(f_std[0]), float(z_std[0]))


def spectral_dominance(realizer: OrderRealizer, n_states: int, target: complex, r0: np.ndarray,
                       references: np.ndarray, *, others: Sequence[complex] = ()) -> float:
    """Share of the output spectrum at a pole's frequency that the pole's mode accounts for.

    The covariance model of order ``n_states`` gives the output spectrum ``S(w) = R_0 + Z(w) +
    Z(w)^H`` with ``Z(w) = C (e^{iw} I - A)^-1 G`` (reference columns and rows), a sum of one
    term per pole. At the frequency of the pole nearest ``target``, projected on that pole's
    shape (which keeps a close mode of another shape out), the share of its pole pair is near 1
    for a mode that stands out of the spectrum and small or negative for a pole that models
    correlation noise under a flat spectrum (measured: modes 0.57-1.1, noise poles that pass
    every other test -0.15-0.20, ``docs/benchmarks-output-only.md``).

    Parameters
    ----------
    realizer : the record's :class:`OrderRealizer`; n_states : the order to read the pole at;
    target : the pole (discrete, upper half plane); r0 : (p, p) ``R_0``; references : (r,) the
    reference channels (the Hankel's columns); others : poles of other candidate modes (at this
    order, the nearest eigenvalue taken with its conjugate) whose terms are left out of the
    spectrum, so the share is of what they leave (a close mode's or a twin's, not the noise's).
    """
    _, C, G = realizer.realize(n_states)
    C, r0 = C[references], r0[np.ix_(references, references)]
    eigenvalues, vectors = realizer.eigen(n_states)  # the diagram's decomposition of this order
    left = linalg.solve(vectors, G)  # (n, r)
    j = int(np.argmin(np.abs(eigenvalues - target)))
    pair = [j, int(np.argmin(np.abs(eigenvalues - np.conj(eigenvalues[j]))))]
    z = np.exp(1j * np.angle(eigenvalues[j]))
    right = C @ vectors  # (r, n)
    terms = right.T[:, :, None] * left[:, None, :] / (z - eigenvalues)[:, None, None]  # (n, r, r)
    total = terms.sum(axis=0)
    own = terms[pair].sum(axis=0)
    shape = right[:, j] / max(float(np.linalg.norm(right[:, j])), np.finfo(float).tiny)

    def along(matrix: np.ndarray) -> float:
        return float(np.real(np.conj(shape) @ (matrix + matrix.conj().T) @ shape))

    spectrum = float(np.real(np.conj(shape) @ r0 @ shape)) + along(total)
    if len(others):
        rest = set()
        for ev in others:
            k = int(np.argmin(np.abs(eigenvalues - ev)))
            rest.update((k, int(np.argmin(np.abs(eigenvalues - np.conj(eigenvalues[k]))))))
        rest -= set(pair)
        if rest:
            spectrum -= along(terms[sorted(rest)].sum(axis=0))
    return along(own) / spectrum if spectrum > 0 else 0.0
