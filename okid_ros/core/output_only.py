"""Output-only (ambient) identification: modes and an innovation model from outputs alone.

:func:`identify_output_only` turns a record ``y`` (N, p) with no measured input into the
project's :class:`~okid_ros.core.identified_model.IdentifiedModel` with m = 0 (``B`` (n, 0),
``D`` (p, 0)), ``A``, ``C``, ``K`` (paper convention, predictor gain ``A K``) and the innovation
covariance, in normalized modal form, with its physical modes and their standard deviations.

Steps (one module each):

1. means removed; the outputs divided by one power of two (:func:`.channels.group_scales`:
   exact, and no step depends on a common factor; the model is restored to the record's units
   at the end, :func:`.scaling.restore_model`); harmonic lines (a sinusoidal disturbance: a
   spectral line whose band has the kurtosis of a sinusoid) found and removed by least squares
   (:mod:`.output_only_harmonics`); reference channels and the lag window from the data
   (:mod:`.output_covariance`);
2. ``method="ssi-cva"`` (default): the record's correlations, the block Hankel weighted by the
   covariances' Cholesky factors, ERA (:mod:`.canonical_realization`); ``"ssi-cov"``: unweighted
   (:mod:`.stochastic_realization`); ``"var"``: a vector AR's stochastic Markov parameters
   ``C A^(k-1) A K`` realized by the same ERA (the paper's route, :mod:`.output_only_var`; every
   such model carries a warning of what the route lacks);
3. the poles of every order, stable ones clustered into modes (:mod:`.output_only_modes`);
4. each candidate mode re-identified with each segment of the record left out (jackknife; the var route's VAR
   refitted without the segment, its spectral share read with ``G`` fitted to the record's correlations,
   :mod:`.output_only_var`): a mode whose frequency scatters by more than its half-power half-width ``zeta f``
   or whose damping scatters by more than itself is noise and dropped, and so is one that accounts for less
   than ``MIN_SPECTRAL_DOMINANCE`` of the output spectrum at its own frequency along its own shape (a pole
   fitted to correlation noise under a flat spectrum) unless its pole is steady (scatter below ``STEADY_*``);
   of the candidates split from one cluster one is kept, and of two of one shape within their half-power bands
   (a mode listed twice, :func:`.output_only_modes.drop_listed_twice`) unless the two hold poles side by side
   across the orders (a close pair); the jackknife's standard deviations are the modes' (ssi-cva drops one
   listed beyond the limits);
5. the model at the lowest order (with a stable ``A``) holding every mode; its innovation model by the Riccati
   equation or a VAR's, the record's better predictor (ssi-cva, ssi-cov, :mod:`.output_only_gain`), or the VAR's;
6. (ssi-cva, ssi-cov) modes far below the sampling rate re-estimated from the record decimated, with longer lags
   (:mod:`.output_only_low_band`; a slow mode the longer lags resolve into a pair not listed).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy import linalg

from okid_ros.core.canonical_realization import canonical_decomposition, canonical_replicates
from okid_ros.core.channels import group_scales
from okid_ros.core.era import decompose_hankel
from okid_ros.core.gap_fill import MAX_GAP_SAMPLES
from okid_ros.core.identified_model import IdentificationError, IdentifiedModel
from okid_ros.core.modal import modal_form
from okid_ros.core.mode_jackknife import SPARE_COLUMNS
from okid_ros.core.options import OUTPUT_ONLY_METHODS, ModeCriteria
from okid_ros.core.output_covariance import (
    MAX_LAG_FRACTION_OF_SEGMENT,
    RecordSums,
    choose_block_rows,
    output_correlations,
    reference_channels,
)
from okid_ros.core.output_only_gain import covariance_innovation
from okid_ros.core.output_only_harmonics import without_harmonics
from okid_ros.core.output_only_low_band import refine_low_modes
from okid_ros.core.output_only_modes import (
    MIN_REMAINING_DOMINANCE,
    ModeCluster,
    PoleSet,
    cluster_modes,
    collect_poles,
    drop_listed_twice,
    lowest_complete_order,
    mark_stable,
)
from okid_ros.core.output_only_routes import ROUTES
from okid_ros.core.output_only_std import STD_SEGMENTS, attach_finer_std, std_replicates, std_segment_count
from okid_ros.core.output_only_support import (
    Jackknife,
    check_channel_sizes,
    check_output_only_options,
    listed_within_limits,
    match_clusters,
    output_only_diagram,
    prepare_outputs,
    spectral_dominance,
    stands_for_a_group,
)
from okid_ros.core.output_only_twins import separate_twin_shapes
from okid_ros.core.output_only_var import VarCovarianceModel, gain_from_var, var_markov, var_replicates
from okid_ros.core.scaling import restore_model
from okid_ros.core.stochastic_realization import OrderRealizer, covariance_decomposition
from okid_ros.core.uncertainty import UncertaintyResult
from okid_ros.core.worker_threads import SERIAL, WorkerThreads

__all__ = ["OUTPUT_ONLY_METHODS", "identify_output_only"]

#: Most Hankel columns' channels (references); more outputs are represented by the best spread.
MAX_REFERENCES = 12
#: Highest model order tried by default, and the damping limit of a candidate pole.
DEFAULT_MAX_STATES = 100
MAX_DAMPING = 0.1
#: Segments of the record for the correlations' jackknife, and the fewest it is made from.
N_SEGMENTS = 8
MIN_JACKKNIFE_SEGMENTS = 3
#: A mode is noise when its jackknife frequency std exceeds this times ``zeta f``, or its damping
#: std this times ``zeta`` (structural modes: up to 0.9 and 1.0 on the simulated cases and the
#: subframe; noise poles 1-20, nearly always caught by the frequency).
MAX_FREQUENCY_STD_PER_WIDTH = 1.0
MAX_DAMPING_CV = 1.5
#: A mode accounts for at least this share of the output spectrum at its frequency, along its
#: shape (:func:`.output_only_support.spectral_dominance`; modes 0.57-1.1, noise poles below 0.2
#: on 80 simulated records, the koma frame and the subframe).
MIN_SPECTRAL_DOMINANCE = 0.4
#: A candidate whose jackknife damping scatter is below this times ``zeta`` (and its frequency's below
#: its route's ``steady_frequency_std_per_width``, :mod:`.output_only_routes`) needs no spectral share.
STEADY_DAMPING_CV = 0.3


def identify_output_only(
    y: np.ndarray,
    sample_time_s: float,
    *,
    method: str = OUTPUT_ONLY_METHODS[0],
    max_states: int | None = None,
    block_rows: int | None = None,
    offsets: str = "remove",
    harmonics: str = "remove",
    low_band: bool = True,
    valid: np.ndarray | None = None,
    workers: int = 1,
    max_gap: int = MAX_GAP_SAMPLES,
    std_segments: int = STD_SEGMENTS,
) -> IdentifiedModel:
    """Identify an innovation model and its modes from outputs alone.

    Parameters
    ----------
    y : (N, p) outputs (accelerations, strains, ...), finite.
    sample_time_s : sample time in seconds.
    method : "ssi-cva" (default: ssi-cov's steps with the canonical-variate realization of
        :mod:`.canonical_realization`), "ssi-cov" (covariance-driven SSI / NExT-ERA) or "var"
        (vector AR and the OKID recursion, the paper's route).
    max_states : highest model order tried (default :data:`DEFAULT_MAX_STATES`, less when the
        Hankel is smaller).
    block_rows : Hankel block rows (default from the data: a period of the slowest mode).
    offsets : "remove" (default, the means are kept with the model) or "none".
    harmonics : "remove" (default: harmonic lines are found, named in ``warnings`` and removed
        before identification) or "keep" (the record as it is).
    low_band : (ssi-cva, ssi-cov) re-estimate the modes far below the sampling rate from the record
        decimated, with longer lags (:mod:`.output_only_low_band`; default True).
    valid : (N,) bool, False at samples that were missing and are filled in ``y`` by
        prediction (:func:`.gap_fill.fill_missing_outputs`, or node 2's window): the steps that
        need an unbroken record (spectrum, harmonics, gain, decimated band) use the filled
        values, the output correlations (ssi-cva, ssi-cov) leave them out (a prediction lacks the
        innovation's spread and would bias them). None: every sample measured. Held to the
        input-output record's rule (:func:`.gap_fill.missing_problem`): first and last samples
        measured, runs of at most ``max_gap`` filled, at most a tenth of the record.
    max_gap : the longest run of filled samples taken (node 2's ``estimator.max_gap_samples``).
    workers : threads for the orders' and the jackknife's decompositions (:mod:`.worker_threads`):
        the same model for any number, sooner with more cores (``okid-ros identify``: every core).
    std_segments : (ssi-cva) most segments of a second jackknife for the listed modes' deviations
        (:mod:`.output_only_std`); 0 (default) or no more than the screening's 5-8: the screening's.

    Returns
    -------
    IdentifiedModel with ``n_inputs == 0``; ``modes`` are the selected modes.

    Raises
    ------
    IdentificationError with a one-line reason.
    """
    check_output_only_options(method, harmonics, methods=OUTPUT_ONLY_METHODS, max_states=max_states,
                              block_rows=block_rows, low_band=low_band, workers=workers, max_gap=max_gap,
                              std_segments=std_segments)
    y, present, offset, warnings = prepare_outputs(y, sample_time_s, offsets, valid=valid, max_gap=max_gap)
    # One power of two for every output (exact, and every step below is unchanged by a common
    # factor): records near the float64 limits neither overflow nor underflow the correlations.
    scales = group_scales(np.zeros((y.shape[0], 0)), y)
    y = y / scales.output
    check_channel_sizes(y)
    y, removed = without_harmonics(y, sample_time_s) if harmonics == "remove" else (y, [])
    warnings += removed + [ROUTES[method].warning] * bool(ROUTES[method].warning)
    with WorkerThreads(workers) as threads:
        model, replicate_shapes = _identified(
            y, sample_time_s, method=method, top=int(max_states or DEFAULT_MAX_STATES), block_rows=block_rows,
            present=present, low_band=low_band, threads=threads, warnings=warnings, std_segments=std_segments)
        model = restore_model(model, scales)  # one scale for every output: the replicates' shapes keep their ratios
        model.modes = separate_twin_shapes(model.modes, replicate_shapes=replicate_shapes)
    model.output_offset, model.warnings = offset, warnings
    return model


def _identified(y: np.ndarray, sample_time_s: float, *, method: str, top: int, block_rows: int | None,
                present: np.ndarray | None, low_band: bool, threads: WorkerThreads, warnings: list[str],
                std_segments: int = 0) -> tuple[IdentifiedModel, Callable | None]:
    """Steps 2-6 of the module on the prepared record, in its scaled units (its notes added to ``warnings``).

    Also ``replicate_shapes(mode)``, the jackknife's replicates' shapes of a listed mode's pole
    (:meth:`.output_only_support.Jackknife.shapes`; None without a jackknife).
    """
    chosen = _select_modes(y, sample_time_s, method=method, top=top, block_rows=block_rows, present=present,
                           threads=threads, std_segments=std_segments)
    modes, poles, realizer, var, n_model = chosen.modes, chosen.poles, chosen.realizer, chosen.var, chosen.n_model
    if chosen.jackknife is None:
        segment = 2 * chosen.block_rows / MAX_LAG_FRACTION_OF_SEGMENT
        warnings.append(f"the record holds fewer than {MIN_JACKKNIFE_SEGMENTS} segments of {segment:.0f} samples "
                        f"({chosen.block_rows} Hankel block rows): no jackknife, so the modes are not screened for "
                        f"noise poles and their standard deviations are the clusters' spread across orders")
    A, C, gamma = _stable_part(*realizer.realize(n_model)[:2], realizer.observability(n_model))
    if var is None:
        L, Re, gain_method = covariance_innovation(A, C, gamma, chosen.correlations, chosen.block_rows, y)
    else:
        L, Re, gain_method = gain_from_var(A, C, y, *var)
    matched = match_clusters(modes, poles, n_model)
    if ROUTES[method].drops_unresolved_groups:  # left unmatched, not dropped from the list: the modes keep their blocks
        matched = [(pole, cluster) for pole, cluster in matched if not stands_for_a_group(cluster, poles)]
    model = _package(A, C, L, Re, matched, sample_time_s,
                     method=method, gain_method=gain_method, arx=None if var is None else var[0],
                     diagram=output_only_diagram(poles), singular_values=realizer.decomposition.s)
    _attach_std(model, chosen.jackknife, n_model, matched, poles)
    if low_band and ROUTES[method].low_band and chosen.jackknife is not None:
        merged = refine_low_modes(model, y, sample_time_s, lambda low, dt, rows: _mode_values(_select_modes(
            low, dt, method=method, top=top, block_rows=rows, once=False, screened_only=True, threads=threads,
            std_segments=std_segments), dt))
        if merged:  # a pole standing for a pair the longer lags resolve is not a mode
            model.keep_modes([mode for mode in model.modes if all(mode is not pair.mode for pair in merged)])
            warnings += [pair.warning() for pair in merged]
    if chosen.std_jackknife is not None and model.modes:
        by_pole = [(mode.eigenvalue, _cluster_of(mode.eigenvalue, matched)) for mode in model.modes]
        attach_finer_std(model, *_jackknife_std(chosen.std_jackknife, by_pole, poles, n_model, sample_time_s),
                         segments=len(chosen.std_jackknife.realizers))
    if chosen.jackknife is None:
        return model, None
    return model, lambda mode: chosen.jackknife.shapes(mode.eigenvalue, n_model, sample_time_s)


@dataclass
class _Selection:
    """Steps 1-4 of the module: the realizations, the poles and the modes selected."""

    modes: list[ModeCluster]
    poles: PoleSet
    realizer: OrderRealizer
    correlations: np.ndarray  # (L + 1, p, p) the record's
    block_rows: int
    jackknife: Jackknife | None
    var: tuple | None  # the VAR and its stochastic Markov parameters (method "var")
    n_model: int
    std_jackknife: Jackknife | None = None  # the listed modes' standard deviations' (None: ``jackknife``)


def _select_modes(y: np.ndarray, sample_time_s: float, *, method: str, top: int, block_rows: int | None,
                  once: bool = True, screened_only: bool = False, present: np.ndarray | None = None,
                  threads: WorkerThreads = SERIAL, std_segments: int = 0) -> _Selection:
    """Correlations (or the VAR), the realization of every order, the modes selected (steps 2-4).

    ``once``: a mode listed twice is listed once (not in the decimated pass of the low band,
    where a true pair of one shape was taken for twins). ``screened_only``: a selection without
    a jackknife is of no use (the decimated pass's modes take its standard deviations,
    :func:`_mode_values`), so a record of fewer than :data:`MIN_JACKKNIFE_SEGMENTS` segments
    raises IdentificationError before any decomposition. ``present``: (N,) False at samples
    filled in gaps, left out of the correlations (the VAR route fits the filled record).
    ``std_segments``: (ssi-cva) the standard deviations' jackknife's most segments (:mod:`.output_only_std`).
    """
    references = reference_channels(y, MAX_REFERENCES)
    route = ROUTES[method]
    block_rows = _block_rows(y, sample_time_s, references, top, block_rows, canonical=route.canonical_lags)
    correlations = output_correlations(y, 2 * block_rows, N_SEGMENTS, present=present)
    n_segments = correlations.segments.shape[0]
    if screened_only and n_segments < MIN_JACKKNIFE_SEGMENTS:
        raise IdentificationError(f"{n_segments} segments of {block_rows} block rows' lags: no jackknife")
    r_mean = correlations.mean
    var = None
    if method == "ssi-cov":
        decomposition = covariance_decomposition(r_mean, references, block_rows, top, spare=SPARE_COLUMNS)
    elif method == "ssi-cva":  # the whole record's sums, its correlations and its jackknife's replicates
        record = RecordSums.of(y, 2 * block_rows, present)
        decomposition = canonical_decomposition(record.correlations, references, block_rows, top)
    else:
        var = var_markov(y, block_rows)
        decomposition = decompose_hankel(var[1], block_rows, block_rows)
    top = _usable_order(top, decomposition.max_states)
    jackknife = None
    if n_segments >= MIN_JACKKNIFE_SEGMENTS:  # its replicates made beside the diagram
        replicates = None  # ssi-cov: the Jackknife's own, from the correlations' segments
        if method == "ssi-cva":
            replicates = canonical_replicates(record, correlations, references, block_rows, top)
        elif var is not None:
            replicates = var_replicates(y, block_rows, n_segments, top)
        jackknife = Jackknife(correlations, references, block_rows, top, threads=threads, decompose=replicates,
                              start=None if var is not None else decomposition.basis)
    finer = std_segment_count(y.shape[0], 2 * block_rows, std_segments) if method == "ssi-cva" else 0
    std_jackknife = None
    if jackknife is not None and finer > n_segments:
        spans, replicates = std_replicates(record, finer, present, references, block_rows, top)
        std_jackknife = Jackknife(spans, references, block_rows, top, threads=threads, decompose=replicates)
    realizer = OrderRealizer(decomposition, top)
    # The spectral share reads a covariance model: the VAR route's A, C with G from the record's correlations.
    spectrum = realizer if var is None else VarCovarianceModel(realizer, r_mean, references, block_rows)
    realizer.decompose_orders(range(2, top + 1, 2), threads)
    poles = collect_poles(realizer.realize, range(2, top + 1, 2), sample_time_s,
                          max_damping=MAX_DAMPING, max_frequency_hz=0.475 / sample_time_s, eigen=realizer.eigen)
    mark_stable(poles)
    modes, _ = cluster_modes(poles, keep_rejected=False)
    candidates = len(modes)
    if jackknife is not None:
        modes = _drop_noise_modes(modes, poles, jackknife, sample_time_s, once=once,
                                  steady_width=route.steady_frequency_std_per_width,
                                  dominance=partial(spectral_dominance, spectrum, r0=r_mean[0], references=references))
    n_model = lowest_complete_order(modes)
    if n_model is None:
        raise IdentificationError(_no_mode_reason(candidates, route.warning))
    return _Selection(modes, poles, realizer, r_mean, block_rows, jackknife, var, n_model, std_jackknife)


def _no_mode_reason(candidates: int, route_warning: str) -> str:
    """Why no mode is left of ``candidates`` stable across model orders: none, or all screened out as noise.

    The second said "no stable mode found" too, which sent the user to the record's length while
    the screening (the var route's above all: ``route_warning``) had dropped what the orders held.
    """
    if not candidates:
        return "no stable mode found across model orders: is the record long and excited enough?"
    said = (f"no mode found: {candidates} stable across model orders, all screened out as noise (their poles "
            f"scattered across the jackknife's replicates, or held too little of the output spectrum)")
    return f"{said}; {route_warning}" if route_warning else said


def _mode_values(chosen: _Selection, sample_time_s: float) -> list[dict]:
    """Frequency, damping and their jackknife standard deviations of the selected modes at the model order."""
    pairs = match_clusters(chosen.modes, chosen.poles, chosen.n_model)
    if not pairs or chosen.jackknife is None:
        return []
    targets = np.array([ev for ev, _ in pairs])
    f_std, z_std = _jackknife_std(chosen.jackknife, pairs, chosen.poles, chosen.n_model, sample_time_s)
    finer = zip(*(_jackknife_std(chosen.std_jackknife, pairs, chosen.poles, chosen.n_model, sample_time_s)
                  if chosen.std_jackknife is not None else (f_std, z_std)))  # the values the low band lists
    s = np.log(targets) / sample_time_s
    return [{"frequency_hz": abs(si) / (2 * np.pi), "damping_ratio": -si.real / abs(si), "frequency_hz_std": float(fs),
             "damping_ratio_std": float(zs), "finer_std": tuple(map(float, fine))}
            for si, fs, zs, fine in zip(s, f_std, z_std, finer)]


def _block_rows(y: np.ndarray, sample_time_s: float, references: np.ndarray, top: int, block_rows: int | None,
                *, canonical: bool) -> int:
    """The Hankel block rows asked for, or chosen from the data; IdentificationError if they do not fit."""
    if block_rows is None:
        block_rows, _ = choose_block_rows(y, sample_time_s, n_references=references.size, max_states=top,
                                          held_peaks_only=canonical, weighted=canonical)
    block_rows, n_samples = int(block_rows), y.shape[0]
    if block_rows < 2 or 2 * block_rows + 1 > n_samples // 4:
        raise IdentificationError(f"{block_rows} Hankel block rows do not fit a record of {n_samples} samples")
    return block_rows


def _usable_order(top: int, hankel_rank: int) -> int:
    """The highest even order at most ``top`` that the Hankel's rank supports (at least 2)."""
    top = int(min(top, hankel_rank))
    top -= top % 2
    if top < 2:
        raise IdentificationError("the Hankel matrix has rank below 2: no mode can be identified")
    return top


def _attach_std(model: IdentifiedModel, jackknife: Jackknife | None, n_model: int,
                matched: list[tuple[complex, ModeCluster]], poles: PoleSet) -> None:
    """The jackknife's standard deviations (kept: the clusters' spread without one); modes they call noise go."""
    if jackknife is None:
        model.uncertainty = UncertaintyResult(True, "", 0, 0, method="spread across model orders")
        return
    by_pole = [(mode.eigenvalue, _cluster_of(mode.eigenvalue, matched)) for mode in model.modes]
    f_std, z_std = _jackknife_std(jackknife, by_pole, poles, n_model, model.sample_time_s)
    for mode, fs, zs in zip(model.modes, f_std, z_std):
        mode.frequency_hz_std, mode.damping_ratio_std = float(fs), float(zs)
    model.uncertainty = UncertaintyResult(True, "", 0, len(jackknife.realizers), method="jackknife")
    if ROUTES[model.method].screens_listed_std:
        model.keep_modes(listed_within_limits(model.modes, _scattered))


def _jackknife_std(jackknife: Jackknife, matched: list[tuple[complex, ModeCluster | None]], poles: PoleSet,
                   n_model: int, sample_time_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Standard deviations of the poles ``matched`` (eigenvalue at ``n_model``, its cluster).

    Where the replicates lose a mode at the model order (scatter beyond the noise limits: a
    replicate's nearest pole there is another mode's, so the spread says nothing of this one;
    up to 560 widths measured on modes 0.1 width off), the scatter at the mode's home order,
    where the screening found it steady, is taken instead, with the difference between the
    mode's values at the two orders added in quadrature (the model order's own error).
    """
    targets = np.array([ev for ev, _ in matched], dtype=complex)
    f_std, z_std = jackknife.std(targets, n_model, sample_time_s)
    s = np.log(targets) / sample_time_s
    for i, (_, cluster) in enumerate(matched):
        f, zeta = abs(s[i]) / (2 * np.pi), -s[i].real / abs(s[i])
        if cluster is None or not _scattered(f_std[i], z_std[i], f, zeta):
            continue
        n_home = _home_order(cluster)
        home = poles.eigenvalue[cluster.members[n_home]]
        home_f, home_z = jackknife.std(np.array([home]), n_home, sample_time_s)
        if not _scattered(home_f[0], home_z[0], f, zeta):
            s_home = np.log(home) / sample_time_s
            f_std[i] = np.hypot(home_f[0], f - abs(s_home) / (2 * np.pi))
            z_std[i] = np.hypot(home_z[0], zeta + s_home.real / abs(s_home))
    return f_std, z_std


def _cluster_of(eigenvalue: complex, matched: list[tuple[complex, ModeCluster]]) -> ModeCluster | None:
    """The cluster whose pole at the model order is ``eigenvalue`` (the modal form keeps it to rounding)."""
    return next((cluster for ev, cluster in matched if abs(eigenvalue - ev) < 1e-9), None)


def _home_order(mode: ModeCluster) -> int:
    """The median order of a cluster's members, where its pole is judged."""
    return sorted(mode.members)[len(mode.members) // 2]


def _scattered(f_std: float, z_std: float, frequency_hz: float, damping_ratio: float) -> bool:
    """Jackknife scatter beyond the noise limits (:data:`MAX_FREQUENCY_STD_PER_WIDTH`, :data:`MAX_DAMPING_CV`)."""
    return f_std > MAX_FREQUENCY_STD_PER_WIDTH * damping_ratio * frequency_hz or z_std > MAX_DAMPING_CV * damping_ratio


def _drop_noise_modes(modes: list[ModeCluster], poles: PoleSet, jackknife: Jackknife, sample_time_s: float, *,
                      dominance, once: bool, steady_width: float) -> list[ModeCluster]:
    """The candidate modes whose jackknife scatter and spectral share say they are structural (step 4).

    Each candidate is judged at its own median order (a mode's pole is best resolved where its
    cluster lives, not at an order chosen for all of them). ``dominance(n, pole)`` is the
    mode's share of the output spectrum (:func:`.output_only_support.spectral_dominance`), or
    with ``others=`` of what the other candidates' poles leave of it (the second reading). Of
    the families split from one cluster (``group``: nearly one frequency and one shape, a mode
    and the noise pole beside it) the one that passes with the largest share is kept; ``once``:
    and of twins from two clusters too (:func:`.output_only_modes.drop_listed_twice`).
    ``steady_width``: the route's :attr:`.output_only_routes.OutputOnlyRoute.steady_frequency_std_per_width`.
    """
    best: dict[int, tuple[float, ModeCluster, bool]] = {}
    for mode in modes:
        n_home = _home_order(mode)
        target = poles.eigenvalue[mode.members[n_home]]
        stds = jackknife.screened_std(target, n_home, sample_time_s, scattered=partial(
            _scattered, frequency_hz=mode.frequency_hz, damping_ratio=mode.damping_ratio))
        if stds is None:  # scattered (most noise poles: after a few of the replicates)
            continue
        (f_std, z_std), width = stds, mode.damping_ratio * mode.frequency_hz
        share = dominance(n_home, target)
        steady = f_std <= steady_width * width and z_std <= STEADY_DAMPING_CV * mode.damping_ratio
        stands_out = share >= MIN_SPECTRAL_DOMINANCE
        if not (stands_out or steady):
            # Its share may be held by candidates beside it (a close mode, its own twin family), not by
            # a flat noise floor: of what their poles leave, a mode stands out again, a noise pole not.
            others = [poles.eigenvalue[m.members[n_home]] for m in modes if m is not mode and n_home in m.members]
            stands_out = dominance(n_home, target, others=others) >= MIN_REMAINING_DOMINANCE
        if (stands_out or steady) and share > best.get(mode.group, (-np.inf,))[0]:
            best[mode.group] = (share, mode, steady)
    if not once:
        return sorted((mode for _, mode, _ in best.values()), key=lambda mode: mode.frequency_hz)
    shares, modes, steady = (list(column) for column in zip(*best.values())) if best else ([], [], [])
    return drop_listed_twice(modes, shares, [poles.shape[m.members[_home_order(m)]] for m in modes], steady=steady)


def _stable_part(A: np.ndarray, C: np.ndarray, gamma: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, C, Gamma)`` restricted to the invariant subspace of the poles inside the unit circle.

    A realized order can hold a pole on or outside the unit circle that is no selected mode (a
    drift, a noise pole); the ordered real Schur form (``scipy.linalg.schur(sort="iuc")``) keeps
    the rest exactly: ``A Z_1 = Z_1 T_11``.
    """
    T, Z, k = linalg.schur(A, output="real", sort="iuc")
    if k == A.shape[0]:
        return A, C, gamma
    return T[:k, :k], C @ Z[:, :k], gamma @ Z[:, :k]


def _package(A, C, L, Re, chosen: list[tuple[complex, ModeCluster]], sample_time_s: float, *,
             method, gain_method, arx, diagram, singular_values) -> IdentifiedModel:
    """Modal form of the model, its physical modes those matched to a selected cluster."""
    n, p = A.shape[0], C.shape[0]
    K = linalg.solve(A, L)
    # The modes were selected already (their spectral dominance included, step 4): no criterion here.
    criteria = ModeCriteria(max_damping=MAX_DAMPING, min_msv=0.0, min_mpc=0.0, min_dominance=0.0)

    # The stochastic input (L) stands for B in the modal indicators: it is what excites the modes.
    form = modal_form(A, L, C, K, sample_time_s, None, criteria=criteria,
                      stability=lambda mode: 0.0 if _cluster_of(mode.eigenvalue, chosen) is None else 1.0)
    for i, mode in enumerate(form.modes):
        cluster = _cluster_of(mode.eigenvalue, chosen)
        mode.id = i
        mode.stability = len(cluster.members) / max(len(diagram), 1)
        mode.frequency_hz_std, mode.damping_ratio_std = cluster.frequency_hz_spread, cluster.damping_ratio_spread
        mode.extras = {"orders": len(cluster.members), "cluster_frequency_hz": cluster.frequency_hz,
                       "cluster_damping_ratio": cluster.damping_ratio}
    model = IdentifiedModel(
        A=form.A, B=np.zeros((n, 0)), C=form.C, D=np.zeros((p, 0)), K=form.K, innovation_covariance=Re,
        sample_time_s=sample_time_s, modes=form.modes, arx=arx, method=method, gain_method=gain_method,
        completion="output-only", hankel_singular_values=singular_values, stabilization=diagram,
        x0=np.zeros(n), input_offset=np.zeros(0),
    )
    problem = model.stability_problem()
    if problem:
        raise IdentificationError(f"refused: {problem}")
    return model
