"""A close pair's member listed with its partner's shape: of two close listed modes, the one that took it in.

Applied to the listed modes of :func:`.output_only.identify_output_only` in the record's units (every
route): the weaker of two such modes of one estimated shape (or of a complex mix of the two) is listed
with the part of its shape its partner's leaves, unless the jackknife resolves its likeness to the
partner's; the stronger, when the weaker's likeness is resolved and its own is not
(docs/benchmarks-output-only.md, forty-third to forty-fifth and forty-eighth sessions).
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.modal import mac, phase_reference_row
from okid_ros.core.mode_jackknife import stands_out
from okid_ros.core.output_only_modes import MAC_TOLERANCE, mpc_floor

__all__ = ["separate_twin_shapes"]

#: Two listed modes closer than this many summed half-power half-widths ``zeta1 f1 + zeta2 f2`` whose
#: shapes read as one (:func:`_took_in`) are a close pair whose weaker pole's eigenvector
#: took in its partner's (:func:`separate_twin_shapes`) when they also lie within ``TWIN_SHAPE_DISTANCE``
#: (relative). Twin chains, one chain forced (physical structures 0-59): the six weaker twins listed with
#: the partner's shape stood 0.70-1.24 widths, 1.0-1.7 % apart; a building's true pair of one shape 8 %
#: apart (2.9 % and 1.1 % damping: 2 widths) kept its shapes only with the distance.
TWIN_SHAPE_BAND = 2.0
TWIN_SHAPE_DISTANCE = 0.02
#: Jackknife standard deviations a weaker twin's component along its partner's must reach to be kept
#: (:func:`separate_twin_shapes`). Physical 0-59: the seven twins of orthogonal true shapes 0.2-2.6; random 5, 9.0.
TWIN_COMPONENT_RESOLVED = 3.0
#: MAC of a close pair's two estimated shapes from which one member's component along the other's outweighs
#: the rest of it (MAC 0.5: equal parts). Only then is the stronger a candidate for separation: the bench's
#: close pair (true MAC 0.087) read 0.03-0.19, its stronger's true component unresolved (1.2-2.4 stds);
#: twin-chains 40 and 55, whose stronger took in the weaker's shape, 0.53 and 0.81. The weaker member is a
#: candidate from here too (below :data:`MAC_TOLERANCE`) where its shape is complex below the clustering's floor
#: (:func:`.output_only_modes.mpc_floor`): its own real shape with its partner's mixed in out of phase
#: (twin chains 7's 29.97 Hz: 0.65, MPC 0.12 at 7 outputs); a real shape of MAC 0.5-0.9 with its
#: partner's may be one of a true pair of like shapes (torsion frame 100's 0.634 Hz: 0.85, own MAC 0.98).
TOOK_IN_MAC = 0.5


def separate_twin_shapes(modes: list, *, replicate_shapes=None) -> list:
    """Give a close pair's member whose shape took in its partner's the part of its shape the partner's leaves.

    Of a close pair the eigenvectors are ill-conditioned: the error of the weaker pole's
    eigenvector is mostly along its partner's, divided by the poles' distance, and where the
    partner's response is much the larger (twin chains, the force on one chain: 30 times in
    amplitude) that error outweighs the weaker mode's own shape, which then reads as the partner's
    (twin-chains 7, 63.03 Hz: MAC 0.98 with 64.02 Hz, 0.007 with its own). Where the two estimated
    shapes read as one, or the partner's component outweighs the rest of a complex shape
    (:func:`_took_in`), the weaker pole's shape with the stronger's component removed is what of it
    belongs to that pole (exact for twins: shapes on two chains, orthogonal), unless that component,
    per unit of the rest, stands out of the jackknife's scatter (:data:`TWIN_COMPONENT_RESOLVED`): an
    error changes with the data, a true component of a pair of nearly one shape does not (random 5:
    true MAC 0.955). The stronger
    pole's eigenvector errs along the weaker's too, and of two poles of nearly one strength its error
    can be the larger (twin-chains 55, 191.40 Hz: MAC 0.19 with its own, its partner's own at 1.000):
    where the two shapes' MAC is at least :data:`TOOK_IN_MAC` (the stronger's component
    along the weaker's outweighs the rest of it), the weaker's component along the stronger's is
    resolved (its shape is its own) and the stronger's along the weaker's is not, the stronger is
    listed with its shape less the weaker's component. Only the listed shape changes: the model's
    ``C`` keeps the realization's columns (its fit).

    Parameters
    ----------
    modes : listed modes (:class:`~okid_ros.core.modal.Mode`: ``frequency_hz``, ``damping_ratio``,
        ``msv`` the strength, ``shape`` unit norm, replaced in place) of two or more outputs; pairs
        within :data:`TWIN_SHAPE_BAND` summed widths and :data:`TWIN_SHAPE_DISTANCE`: the weaker separated
        when the weaker's shape took in the stronger's (:func:`_took_in`), the stronger as above.
    replicate_shapes : ``replicate_shapes(mode) -> (S, p)`` the jackknife's S replicates' shapes of the
        mode's pole (:meth:`.output_only_support.Jackknife.shapes`); None: every weaker member of such a
        pair is separated, no stronger one.

    Returns
    -------
    ``modes``, the same objects.
    """
    shapes = [mode.shape for mode in modes]  # as estimated: a shape once separated is no partner's
    separated = set()
    for i, weak in enumerate(modes):
        close = [j for j in _stronger_close(modes, i) if _took_in(weak, shapes[i], shapes[j])]
        if not close:
            continue
        strong = shapes[min(close, key=lambda j: abs(modes[j].frequency_hz - weak.frequency_hz))]
        own = _less_component(shapes[i], strong)
        if own is None or (replicate_shapes is not None
                           and _resolved(shapes[i], strong, own, replicate_shapes(weak))):
            continue
        weak.shape = own
        separated.add(i)
    if replicate_shapes is None:
        return modes
    for i, weak in enumerate(modes):
        close = [j for j in _stronger_close(modes, i)
                 if j not in separated and mac(shapes[i], shapes[j]) >= TOOK_IN_MAC]
        if i in separated or not close:
            continue
        j = min(close, key=lambda j: abs(modes[j].frequency_hz - weak.frequency_hz))
        weak_own, strong_own = _less_component(shapes[i], shapes[j]), _less_component(shapes[j], shapes[i])
        if (weak_own is not None and strong_own is not None
                and _resolved(shapes[i], shapes[j], weak_own, replicate_shapes(weak))
                and not _resolved(shapes[j], shapes[i], strong_own, replicate_shapes(modes[j]))):
            modes[j].shape = strong_own
            separated.add(j)
    return modes


def _took_in(weak, shape: np.ndarray, partner: np.ndarray) -> bool:
    """Whether a weaker member's estimated ``shape`` took in its ``partner``'s: one shape, or a complex mix of the two.

    One shape: MAC at least :data:`MAC_TOLERANCE`; a mix: at least :data:`TOOK_IN_MAC` with the weaker's
    listed MPC below :func:`.output_only_modes.mpc_floor` at its outputs.
    """
    likeness = mac(shape, partner)
    return likeness >= MAC_TOLERANCE or (likeness >= TOOK_IN_MAC and weak.mpc < mpc_floor(shape.size))


def _stronger_close(modes: list, i: int) -> list[int]:
    """The modes stronger than mode ``i`` within :data:`TWIN_SHAPE_BAND` widths and :data:`TWIN_SHAPE_DISTANCE`."""
    weak = modes[i]
    if weak.shape.size < 2:
        return []  # one output: every shape is one shape
    return [j for j, strong in enumerate(modes)
            if j != i and strong.msv > weak.msv
            and abs(strong.frequency_hz - weak.frequency_hz) < min(TWIN_SHAPE_BAND * (
                strong.damping_ratio * strong.frequency_hz + weak.damping_ratio * weak.frequency_hz),
                TWIN_SHAPE_DISTANCE * weak.frequency_hz)]


def _less_component(shape: np.ndarray, partner: np.ndarray) -> np.ndarray | None:
    """``shape`` less its component along ``partner``, unit norm, phase-referenced (None: nothing left)."""
    own = shape - np.vdot(partner, shape) / np.vdot(partner, partner).real * partner
    if not np.linalg.norm(own) > np.sqrt(np.finfo(float).eps):
        return None  # nothing of its own to tell (one shape to rounding)
    own = own / np.linalg.norm(own)
    return own * np.exp(-1j * np.angle(own[phase_reference_row(own)]))


def _resolved(shape: np.ndarray, partner: np.ndarray, own: np.ndarray, replicates: np.ndarray) -> bool:
    """Whether ``shape``'s component along ``partner``, per unit of its ``own`` part, stands out of the replicates'."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = (replicates @ partner.conj()) / (replicates @ own.conj())
    return stands_out(np.vdot(partner, shape) / np.vdot(own, shape), ratios, TWIN_COMPONENT_RESOLVED)
