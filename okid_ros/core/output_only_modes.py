"""Automatic mode selection of output-only identification: stable poles, clustered across orders.

The stabilization diagram without clicks:

1. every order ``n = 2, 4, ..`` contributes its stable complex poles below the band limit and
   the damping limit, with their output shapes (:func:`collect_poles`);
2. a pole is *stable* when the order just below or just above has a pole within
   ``FREQUENCY_TOLERANCE`` in frequency, ``DAMPING_TOLERANCE`` (relative) in damping and with
   MAC >= ``MAC_TOLERANCE`` (:func:`mark_stable`);
3. stable poles are grouped by average-linkage hierarchical clustering
   (``scipy.cluster.hierarchy``) on the distance ``|df| / f + (1 - MAC)``, cut at
   ``CLUSTER_DISTANCE`` (:func:`cluster_modes`); a cluster holding two poles at ``MIN_ORDERS``
   orders or more whose two families differ in damping by ``TWIN_DAMPING_FACTOR`` is split
   (a mode has one pole per order; :func:`_families`), and so is one whose two families are a
   resolved close pair, two modes (:func:`_resolved_pair`);
4. a cluster is a mode when it holds a pole in at least ``MIN_ORDER_FRACTION`` of the orders from its first
   one on, in ``MIN_TOTAL_FRACTION`` of all orders and in ``MIN_ORDERS``, its median damping is at least
   ``MIN_DAMPING`` (a harmonic disturbance is an undamped, perfectly stable pole), with 3 or more outputs
   its median MPC is at least ``MIN_MPC`` (with many outputs: what half the shapes of noise alone exceed,
   :func:`mpc_floor`; or a close candidate's shape mixed in, :func:`_mixed_with_neighbour`), its median
   share of the correlations' energy (modal singular value relative to the order's strongest pole) is at least
   ``MIN_ENERGY`` (0: a weak structural mode, 0.4 % on the coloured simulation, carries no more than some noise
   poles; the jackknife of :mod:`.output_only` tells them apart), and its frequency scatters across orders
   by less than ``MAX_FREQUENCY_SPREAD_PER_DAMPING`` times its half-power bandwidth-like width ``zeta f``
   (a structural pole stays put; a split or noise pole wanders).
   A cluster that fails only the first test still is a mode (the one with the most orders first) when no
   accepted one lies within ``zeta f / 2`` of it and the orders with a stable pole that near its frequency
   pass it: at high orders a mode's poles may fall into other clusters (damping and shape pulled by noise
   poles beside them), which left no cluster of that mode at all (:func:`_persists_near`).

Each mode keeps one pole per order (the one nearest the cluster's median); the model order is the lowest
at which every mode has its pole. Of two modes of one shape within their half-power bands the weaker goes
(a mode listed twice) unless the two hold poles side by side across the orders (a close pair,
:func:`drop_listed_twice`). Of two close listed modes of one estimated shape the weaker is listed with
the part of its shape its partner's leaves, a stronger that took in its weaker's likewise (:mod:`.output_only_twins`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.cluster import hierarchy
from scipy.spatial.distance import squareform

from okid_ros.core.modal import modes_listed_once, mpc
from okid_ros.core.output_only_pair_plane import pair_plane_floor, share_in_real_plane

__all__ = ["PoleSet", "ModeCluster", "collect_poles", "mark_stable", "cluster_modes", "lowest_complete_order",
           "drop_listed_twice"]

FREQUENCY_TOLERANCE = 0.01
DAMPING_TOLERANCE = 0.3
MAC_TOLERANCE = 0.9
CLUSTER_DISTANCE = 0.02
MIN_ORDER_FRACTION = 0.5
MIN_TOTAL_FRACTION = 0.3
MIN_ORDERS = 5
MIN_DAMPING = 5e-4
#: Low enough for one mode of a close pair whose true shapes are orthogonal (two mistuned chains): its
#: estimated shape mixes in its partner's, out of phase, and its cluster's median MPC reads 0.38 at
#: 20-35 orders (bench/okid_bench/physical_cases.py); noise clusters are screened after (jackknife, share).
#: With many outputs the floor is lowered to :func:`noise_mpc_floor` (:func:`mpc_floor`).
MIN_MPC = 0.3
#: A shape of independent complex Gaussian components (noise alone) at ``p`` outputs has an MPC above ``x``
#: with probability ``(1 - x) ** ((p - 1) / 2)``; a cluster's median MPC is read as no evidence against a
#: mode where this share of such shapes reads more: 0.293 at 5 outputs (about ``MIN_MPC``), 0.06 at 23.
NOISE_MPC_SHARE = 0.5
#: A cluster below the MPC floor is a close-pair member whose partner's shape is mixed into its own when
#: the partner lies within this many ``zeta f`` (:func:`_mixed_with_neighbour`).
NEIGHBOUR_WIDTHS = 3.0
MIN_ENERGY = 0.0
#: A candidate that fails the spectral share and is not steady is a mode when, of what the other
#: candidates' poles leave of the spectrum, it holds this share (``output_only._drop_noise_modes``).
#: Candidates read so on physical structures 0-59, random records 0-239 and the 20-seed records: true
#: modes 0.49-0.97; a noise pole 7 % above a building's top mode and a noise twin of its neighbour's
#: shape beside a chain mode 0.41-0.42, a pole 0.8 % off a one-output mode 0.44 (0.4 listed them).
MIN_REMAINING_DOMINANCE = 0.45
MAX_FREQUENCY_SPREAD_PER_DAMPING = 1.0
MIN_OUTPUTS_FOR_MPC = 3
#: Times a linkage cluster may be split into families of poles (:func:`_families`).
MAX_SPLITS = 2
#: Two families of one cluster are a mode and its noise twin only when their median dampings differ by this
#: factor (the 186.5 Hz mode of docs/benchmarks-output-only.md: 3.1 % and 0.2 %). Closer, they are one mode's
#: poles scattered by noise: split, the family kept was the worse estimate on 2 of 120 random records the
#: rule was not built on (10.43 Hz against 10.49 true, the cluster's median 10.51).
TWIN_DAMPING_FACTOR = 3.0
#: Two families of one cluster, close in damping, are a resolved close pair (two modes) when each holds one
#: pole per order, they hold a pole each at this share of the orders from their first common one to the
#: cluster's last (a pair once resolved stays resolved as the order grows; a mode split by noise into two
#: families comes and goes), and their median frequencies lie ``PAIR_SEPARATION_PER_SPREAD`` times their
#: summed frequency scatters apart (each family stays put). Twin chains and buildings 60-119: the six pairs
#: one cluster held at every order from 10-16 on, 6-34 scatters apart.
PAIR_COMMON_ORDERS = 0.9
PAIR_SEPARATION_PER_SPREAD = 5.0
#: Two candidates within the listed-twice band and of one shape are two modes, not one listed twice,
#: when the weaker is steady in the jackknife and they hold distinct poles together at this share of
#: the orders the one with more orders holds (the persistence test's share; and at ``MIN_ORDERS``), the
#: first such order among the first ``MIN_ORDERS`` either holds (:func:`drop_listed_twice`). Read on every
#: bench set (docs/benchmarks-output-only.md, forty-fourth session): the ssi-cva noise twins 0.34-0.48,
#: together first at the 10th-22nd order, none steady; the true pairs 0.82-1.0, at the 1st or 2nd, four
#: of five steady; one mode split in two under ssi-cov (beam 83) 0.82 from the 2nd, not steady.
TWIN_COEXISTENCE = MIN_ORDER_FRACTION


@dataclass
class PoleSet:
    """The poles of every order, flattened.

    Attributes
    ----------
    order : (P,) model order of each pole; frequency_hz, damping_ratio : (P,);
    eigenvalue : (P,) complex discrete pole (upper half plane); shape : (P, p) complex output
    shapes, unit norm; stable : (P,) bool, set by :func:`mark_stable`.
    """

    order: np.ndarray
    frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    eigenvalue: np.ndarray
    shape: np.ndarray
    energy: np.ndarray
    stable: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    unstable_orders: set = field(default_factory=set)

    def __len__(self) -> int:
        return int(self.order.size)


@dataclass
class ModeCluster:
    """One mode found across orders: the index of its pole at each order (``members[order]``)."""

    members: dict[int, int]
    frequency_hz: float
    damping_ratio: float
    frequency_hz_spread: float
    damping_ratio_spread: float
    mpc: float
    energy: float
    #: Which mode the poles are of: the families one linkage cluster holds of one mode (a mode and its
    #: noise twin, :func:`_families`) share it; the two modes of a resolved pair do not.
    group: int = -1


def collect_poles(realize, orders, sample_time_s: float, *, max_damping: float, max_frequency_hz: float,
                  eigen=None) -> PoleSet:
    """Stable complex poles of the model of each order.

    Parameters
    ----------
    realize : ``realize(n) -> (A, C, G)``, e.g. :meth:`OrderRealizer.realize`.
    orders : the orders to realize.
    max_damping : poles with a larger damping ratio are left out; max_frequency_hz : so are
        poles at or above this frequency.
    eigen : ``eigen(n) -> (eigenvalues, right eigenvectors)`` of that ``A`` (e.g.
        :meth:`OrderRealizer.eigen`, which keeps them); default ``numpy.linalg.eig``.
    """
    parts: dict[str, list] = {"order": [], "f": [], "z": [], "ev": [], "shape": [], "energy": []}
    unstable = set()
    for n in orders:
        A, C, G = realize(n)
        ev, vec = np.linalg.eig(A) if eigen is None else eigen(n)
        if np.max(np.abs(ev)) >= 1.0:
            unstable.add(int(n))
        # Modal share of the correlations (the MSV): |C psi| |chi G| / sqrt(1 - |z|^2), relative.
        gains = np.linalg.norm(C @ vec, axis=0) * np.linalg.norm(np.linalg.solve(vec, G), axis=1)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            energy = gains / np.sqrt(np.maximum(1.0 - np.abs(ev) ** 2, 1e-12))
            energy = energy / max(float(np.max(energy[np.abs(ev) < 1.0], initial=0.0)), np.finfo(float).tiny)
        keep = (ev.imag > 0) & (np.abs(ev) < 1.0)
        ev, vec, energy = ev[keep], vec[:, keep], energy[keep]
        s = np.log(ev) / sample_time_s
        w = np.abs(s)
        zeta = -s.real / w
        f = w / (2 * np.pi)
        ok = (zeta > 0) & (zeta < max_damping) & (f < max_frequency_hz)
        shapes = (C @ vec[:, ok]).T
        shapes /= np.maximum(np.linalg.norm(shapes, axis=1, keepdims=True), np.finfo(float).tiny)
        parts["order"].append(np.full(int(ok.sum()), n))
        parts["f"].append(f[ok])
        parts["z"].append(zeta[ok])
        parts["ev"].append(ev[ok])
        parts["shape"].append(shapes)
        parts["energy"].append(energy[ok])
    p = parts["shape"][0].shape[1] if parts["shape"] else 0
    cat = {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in parts.items() if k != "shape"}
    shapes = np.vstack(parts["shape"]) if parts["shape"] else np.zeros((0, p), complex)
    return PoleSet(cat["order"].astype(int), cat["f"], cat["z"], cat["ev"].astype(complex), shapes,
                   cat["energy"], np.zeros(cat["order"].size, bool), unstable)


def _mac_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """MAC of every pair of unit-norm shapes (rows of a and b)."""
    mac = np.abs(np.conj(a) @ b.T)
    return np.square(mac, out=mac)  # in place: the clustering's is a million entries


def mark_stable(poles: PoleSet) -> None:
    """Set ``poles.stable``: a pole matched in frequency, damping and shape at an adjacent order."""
    orders = np.unique(poles.order)
    stable = np.zeros(len(poles), bool)
    for a, b in zip(orders[:-1], orders[1:]):
        ia, ib = np.flatnonzero(poles.order == a), np.flatnonzero(poles.order == b)
        if ia.size == 0 or ib.size == 0:
            continue
        fa, fb = poles.frequency_hz[ia][:, None], poles.frequency_hz[ib][None, :]
        za, zb = poles.damping_ratio[ia][:, None], poles.damping_ratio[ib][None, :]
        close = (np.abs(fa - fb) <= FREQUENCY_TOLERANCE * fa) & (np.abs(za - zb) <= DAMPING_TOLERANCE * za)
        close &= _mac_matrix(poles.shape[ia], poles.shape[ib]) >= MAC_TOLERANCE
        stable[ia[close.any(axis=1)]] = True
        stable[ib[close.any(axis=0)]] = True
    poles.stable = stable


def _median(values) -> float:
    """``np.median`` of a short 1-D array, the same value without its generic machinery.

    A dozen medians of a few to a hundred poles per cluster, hundreds of clusters per record:
    ``np.median``'s overhead was a seventh of the selection's time.
    """
    ordered = np.sort(np.asarray(values, dtype=float))
    half = ordered.size // 2
    if ordered.size % 2:
        return float(ordered[half])
    return 0.5 * float(ordered[half - 1] + ordered[half]) if ordered.size else float("nan")


def _robust_spread(values: np.ndarray) -> float:
    """Normalized median absolute deviation (the standard deviation of a normal sample)."""
    return _median_and_spread(values)[1]


def _median_and_spread(values: np.ndarray) -> tuple[float, float]:
    """:func:`_median` and :func:`_robust_spread` of ``values``, the median taken once (NaN, NaN if empty)."""
    if not values.size:
        return float("nan"), float("nan")
    median = _median(values)
    return median, float(1.4826 * _median(np.abs(values - median)))


def _cluster(poles: PoleSet, index: np.ndarray, n_outputs: int) -> ModeCluster:
    """One pole per order (nearest the median frequency), outliers in damping dropped."""
    f_med = _median(poles.frequency_hz[index])
    ranked = index[np.argsort(np.abs(poles.frequency_hz[index] - f_med))]
    _, first = np.unique(poles.order[ranked], return_index=True)  # each order's first, i.e. nearest, pole
    chosen = np.sort(ranked[first])
    z = poles.damping_ratio[chosen]
    z_median, spread = _median_and_spread(z)
    inliers = np.abs(z - z_median) <= 3.0 * max(spread, 1e-12) + 1e-12
    chosen = chosen[inliers]
    members = dict(zip(poles.order[chosen].tolist(), chosen.tolist()))
    shapes_mpc = [mpc(poles.shape[i]) for i in chosen] if n_outputs >= MIN_OUTPUTS_FOR_MPC else [1.0]
    frequency, frequency_spread = _median_and_spread(poles.frequency_hz[chosen])
    damping, damping_spread = _median_and_spread(poles.damping_ratio[chosen])
    return ModeCluster(
        members=members,
        frequency_hz=frequency,
        damping_ratio=damping,
        frequency_hz_spread=frequency_spread,
        damping_ratio_spread=damping_spread,
        mpc=float(_median(shapes_mpc)),
        energy=float(_median(poles.energy[chosen])),
    )


def _families(poles: PoleSet, index: np.ndarray, depth: int = MAX_SPLITS) -> list[list[np.ndarray]]:
    """The poles of one linkage cluster as the modes it holds, each a list of families: one mode has one pole per order.

    A cluster with two poles at :data:`MIN_ORDERS` orders or more may hold two families (a mode and a noise
    pole beside it with nearly its shape, or two modes of a close pair): it is split in two by Ward linkage
    on log frequency, in units of the cluster's damping ratio (half-power bandwidths), and log damping. When
    the parts' dampings differ by :data:`TWIN_DAMPING_FACTOR` they are one mode's families (a mode and its
    noise twin: the screening keeps one); else when they are a resolved pair (:func:`_resolved_pair`) two
    modes; each part is looked at again.
    """
    if depth == 0 or index.size < 2 * MIN_ORDERS:  # too few poles for two at MIN_ORDERS orders
        return [[index]]
    _, counts = np.unique(poles.order[index], return_counts=True)
    if np.sum(counts >= 2) < MIN_ORDERS:
        return [[index]]
    zeta = poles.damping_ratio[index]
    features = np.column_stack([np.log(poles.frequency_hz[index]) / max(_median(zeta), MIN_DAMPING), np.log(zeta)])
    labels = hierarchy.fcluster(hierarchy.linkage(features, method="ward"), t=2, criterion="maxclust")
    parts = [index[labels == label] for label in (1, 2)]
    low, high = sorted(_median(poles.damping_ratio[part]) for part in parts)
    if high >= TWIN_DAMPING_FACTOR * low:
        return [[family for part in parts for mode in _families(poles, part, depth - 1) for family in mode]]
    if _resolved_pair(poles, parts[0], parts[1], index):
        return [mode for part in parts for mode in _families(poles, part, depth - 1)]
    return [[index]]  # one mode's poles scattered by noise: their median estimates it best


def _resolved_pair(poles: PoleSet, first: np.ndarray, second: np.ndarray, index: np.ndarray) -> bool:
    """Whether two families of a linkage cluster (``index``) are two modes of a resolved close pair.

    Each holds one pole per order, the two hold one each at :data:`PAIR_COMMON_ORDERS` of the
    orders from their first common one to the cluster's last, and their median frequencies lie
    :data:`PAIR_SEPARATION_PER_SPREAD` times their summed robust spreads apart.
    """
    held = [np.unique(poles.order[part]) for part in (first, second)]
    if any(orders.size < part.size for orders, part in zip(held, (first, second))):
        return False  # a family with two poles at an order is no one mode
    common = np.intersect1d(*held)
    if common.size < MIN_ORDERS:
        return False
    orders = np.unique(poles.order)
    span = np.count_nonzero((orders >= common[0]) & (orders <= poles.order[index].max()))
    if common.size < PAIR_COMMON_ORDERS * span:
        return False
    (f1, spread1), (f2, spread2) = (_median_and_spread(poles.frequency_hz[part]) for part in (first, second))
    return abs(f1 - f2) >= PAIR_SEPARATION_PER_SPREAD * (spread1 + spread2)


def cluster_modes(poles: PoleSet, *, min_damping: float = MIN_DAMPING, keep_rejected: bool = True
                  ) -> tuple[list[ModeCluster], list[ModeCluster]]:
    """Group the stable poles into modes (module docstring).

    ``keep_rejected=False``: a linkage cluster whose poles span fewer orders than a mode needs
    (:func:`_too_few_orders`) is neither split nor summarized, so it is missing from ``rejected``;
    the modes are the same (on the low-mode simulation 174 of 190 clusters are such, and
    summarizing them was most of the clustering's time).

    Returns
    -------
    modes : the accepted clusters by frequency; rejected : the others (for reports).
    """
    index = np.flatnonzero(poles.stable)
    if index.size < 2:
        return [], []
    f = poles.frequency_hz[index]
    # In place (the same operations): a thousand stable poles make million-entry matrices.
    distance = np.subtract.outer(f, f)
    np.abs(distance, out=distance)
    distance /= np.maximum.outer(f, f)
    shape_distance = _mac_matrix(poles.shape[index], poles.shape[index])
    distance += np.subtract(1.0, shape_distance, out=shape_distance)
    np.fill_diagonal(distance, 0.0)
    tree = hierarchy.linkage(squareform(np.maximum(distance, 0.0, out=distance), checks=False), method="average")
    labels = hierarchy.fcluster(tree, t=CLUSTER_DISTANCE, criterion="distance")
    orders = np.unique(poles.order)
    p = poles.shape.shape[1]
    accepted, rejected = [], []
    clusters = []
    labels_kept = np.unique(labels) if keep_rejected else _labels_with_orders(labels, poles.order[index], orders.size)
    for label in labels_kept:
        for k, mode in enumerate(_families(poles, index[labels == label])):
            for family in mode:  # the families of one mode share a group; two modes of a pair do not
                clusters.append(_cluster(poles, family, p))
                clusters[-1].group = int(label) * 2 ** MAX_SPLITS + k  # at most 2 ** MAX_SPLITS modes a label
    persisting_elsewhere = []  # clusters that fail only the persistence test
    passes = [not _too_few_orders(len(c.members), orders.size) and c.damping_ratio >= min_damping
              and c.energy >= MIN_ENERGY
              and c.frequency_hz_spread <= MAX_FREQUENCY_SPREAD_PER_DAMPING * c.damping_ratio * c.frequency_hz
              for c in clusters]  # every test but the MPC floor
    candidates = [c for c, ok in zip(clusters, passes) if ok]
    floor = mpc_floor(p)
    for cluster, ok in zip(clusters, passes):
        count = len(cluster.members)
        ok = ok and (cluster.mpc >= floor or _mixed_with_neighbour(poles, cluster, candidates))
        persistent = count >= MIN_ORDER_FRACTION * np.sum(orders >= min(cluster.members))
        (accepted if ok and persistent else rejected).append(cluster)
        if ok and not persistent:
            persisting_elsewhere.append(cluster)
    # The largest first, and each one rescued counts as accepted for the next: of two pieces of
    # one mode the one with more orders is taken.
    stable_hz, stable_order = poles.frequency_hz[index], poles.order[index]
    for cluster in sorted(persisting_elsewhere, key=lambda c: (-len(c.members), min(c.members))):
        if _persists_near(cluster, stable_hz, stable_order, orders, accepted):
            rejected.remove(cluster)
            accepted.append(cluster)
    accepted.sort(key=lambda c: c.frequency_hz)
    return accepted, rejected


def noise_mpc_floor(n_outputs: int, share: float = NOISE_MPC_SHARE) -> float:
    """The MPC that a shape of noise alone at ``n_outputs`` outputs exceeds with probability ``share``.

    The real and imaginary parts of ``n_outputs`` independent complex Gaussian components form a
    2 x 2 Wishart matrix of ``n_outputs`` degrees of freedom; its MPC ``((l1 - l2) / (l1 + l2)) ** 2``
    is one minus the sphericity ratio, whose tail is ``(1 - x) ** ((n_outputs - 1) / 2)``.
    """
    return float(1.0 - share ** (2.0 / max(n_outputs - 1, 1)))


def mpc_floor(n_outputs: int) -> float:
    """The clustering's MPC floor at ``n_outputs`` outputs: ``MIN_MPC``, or the noise's where that is lower.

    A weak mode seen well by some of many outputs has its estimated shape read in all of them, the
    others' noise included: its MPC falls with the number of outputs as a noise shape's does (two
    torsion-frame modes at 23 outputs, true MPC 1.000, read 0.15 and 0.20), and the MPC tells it from
    noise no better than that; the jackknife and the spectral share screen the clusters after.
    """
    return min(MIN_MPC, noise_mpc_floor(n_outputs))


def _mixed_with_neighbour(poles: PoleSet, cluster: ModeCluster, candidates: list[ModeCluster]) -> bool:
    """Whether a cluster's complex shape is its nearest close candidate's mixed in: coherent once that is taken out.

    A close-pair member's estimated shape is its own plus its partner's, out of phase. The partner is the
    nearest candidate within ``NEIGHBOUR_WIDTHS`` times the larger ``zeta f`` of the two, side by side with it
    (:func:`_side_by_side`: a group's pole beside a pair's member is not); projected out at each common
    order, the rest's median MPC must exceed half the noise shapes' at one output fewer, or (a complex partner:
    two real modes' mixes) its median share in the partner's real plane pass :func:`.pair_plane_floor`.
    """
    near = [o for o in candidates if o is not cluster and abs(o.frequency_hz - cluster.frequency_hz)
            <= NEIGHBOUR_WIDTHS * max(o.damping_ratio * o.frequency_hz, cluster.damping_ratio * cluster.frequency_hz)]
    neighbour = min(near, key=lambda o: abs(o.frequency_hz - cluster.frequency_hz)) if near else None
    if neighbour is None or not _side_by_side(cluster, neighbour):  # before the shapes' work at each common order
        return False
    common = sorted(cluster.members.keys() & neighbour.members.keys())
    rest, plane, p = [], [], poles.shape.shape[1]
    for own, other in ((poles.shape[cluster.members[n]], poles.shape[neighbour.members[n]]) for n in common):
        other = other / np.linalg.norm(other)
        rest.append(mpc(own - other * np.vdot(other, own)))
        plane.append(share_in_real_plane(own, other))
    return _median(rest) >= noise_mpc_floor(p - 1) or _median(plane) > pair_plane_floor(p)


def _too_few_orders(count: int | np.ndarray, n_orders: int) -> bool | np.ndarray:
    """Whether a cluster with poles at ``count`` orders (of ``n_orders`` in the diagram) is too small to be a mode."""
    return count < max(MIN_ORDERS, MIN_TOTAL_FRACTION * n_orders)


def _labels_with_orders(labels: np.ndarray, order: np.ndarray, n_orders: int) -> np.ndarray:
    """The linkage labels (ascending) whose poles span enough orders to hold a mode (:func:`_too_few_orders`).

    ``labels``, ``order`` (S,): each stable pole's linkage label and model order.

    A family split from a cluster, and the one-pole-per-order members of its summary, span no
    more orders than the cluster: a cluster that fails here fails the acceptance test whatever
    its summary holds, and is no candidate for :func:`_persists_near` either.
    """
    distinct = np.unique(np.column_stack([labels, order]), axis=0)  # (label, order) pairs, once each
    kept, counts = np.unique(distinct[:, 0], return_counts=True)
    return kept[~_too_few_orders(counts, n_orders)]


def _persists_near(cluster: ModeCluster, frequency_hz: np.ndarray, order: np.ndarray, orders: np.ndarray,
                   accepted: list[ModeCluster]) -> bool:
    """Whether a mode no accepted cluster holds persists as stable poles near its frequency (step 4).

    ``frequency_hz``, ``order`` (S,): the stable poles; ``orders``: every order of the diagram.
    Near: within half the cluster's ``zeta f``, where a close pair's other mode (two widths away
    at 1 % apart and 0.5 % damping) does not reach; an accepted cluster is near within the larger
    of the two half widths.
    """
    def width(mode: ModeCluster) -> float:
        return 0.5 * mode.damping_ratio * mode.frequency_hz

    if any(abs(other.frequency_hz - cluster.frequency_hz) <= max(width(cluster), width(other)) for other in accepted):
        return False
    first = min(cluster.members)
    near = (np.abs(frequency_hz - cluster.frequency_hz) <= width(cluster)) & (order >= first)
    present = len(set(order[near].tolist()) | set(cluster.members))
    return present >= MIN_ORDER_FRACTION * np.sum(orders >= first)


def lowest_complete_order(modes: list[ModeCluster], unstable_orders=frozenset()) -> int | None:
    """The lowest order (not in ``unstable_orders``) where the most modes have a pole (usually all); None if none."""
    orders = sorted({n for mode in modes for n in mode.members} - set(unstable_orders))
    if not orders:
        return None
    counts = [sum(n in mode.members for mode in modes) for n in orders]
    best = max(counts)
    return next(n for n, c in zip(orders, counts) if c == best)


def drop_listed_twice(modes: list[ModeCluster], shares: list[float], shapes: list[np.ndarray], *,
                      steady: list[bool] | None = None) -> list[ModeCluster]:
    """The modes with each mode listed once: of two twins the one with the smaller spectral share goes.

    :func:`.modal.modes_listed_once` (its band and MAC measured on the output-only records), but a
    steady weaker one that holds poles of its own side by side with its partner's across the
    orders (:func:`_side_by_side`) is the other mode of a close pair, not the partner listed twice.

    Parameters
    ----------
    modes : selected modes; shares : (M,) their spectral shares; shapes : (M,) their (p,) complex
        output shapes at their home orders; steady : (M,) whether the jackknife places each one's
        pole steadily (``output_only._drop_noise_modes``); None: none is.
    """
    steady = [False] * len(modes) if steady is None else steady
    kept = modes_listed_once(modes, shares, shapes,
                             distinct=lambda weaker, j: steady[weaker] and _side_by_side(modes[weaker], modes[j]))
    return sorted((modes[i] for i in kept), key=lambda mode: mode.frequency_hz)


def _side_by_side(a: ModeCluster, b: ModeCluster) -> bool:
    """Whether two modes hold distinct poles together from their first orders on (:data:`TWIN_COEXISTENCE`).

    A mode listed twice is a mode and a noise pole the surplus states of high orders place beside
    it: the twin's poles come in many orders after the mode's. The two modes of a close pair are
    poles of the orders that resolve them, together from (nearly) the first.
    """
    together = sorted(n for n in a.members.keys() & b.members.keys() if a.members[n] != b.members[n])
    either = sorted(a.members.keys() | b.members.keys())
    return (len(together) >= max(MIN_ORDERS, TWIN_COEXISTENCE * max(len(a.members), len(b.members)))
            and together[0] in either[:MIN_ORDERS])
