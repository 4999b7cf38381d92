"""A weaker twin listed with its partner's shape: of two close listed modes of one estimated shape.

Applied to the listed modes of :func:`.output_only.identify_output_only` in the record's units (every
route): the weaker of two such modes is listed with the part of its shape its partner's leaves, unless
the jackknife resolves its likeness to the partner's (docs/benchmarks-output-only.md, forty-third and
forty-fourth sessions).
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.modal import mac, phase_reference_row
from okid_ros.core.mode_jackknife import stands_out
from okid_ros.core.output_only_modes import MAC_TOLERANCE

__all__ = ["separate_twin_shapes"]

#: Two listed modes closer than this many summed half-power half-widths ``zeta1 f1 + zeta2 f2`` whose
#: shapes read as one (MAC >= :data:`MAC_TOLERANCE`) are a close pair whose weaker pole's eigenvector
#: took in its partner's (:func:`separate_twin_shapes`) when they also lie within ``TWIN_SHAPE_DISTANCE``
#: (relative). Twin chains, one chain forced (physical structures 0-59): the six weaker twins listed with
#: the partner's shape stood 0.70-1.24 widths, 1.0-1.7 % apart; a building's true pair of one shape 8 %
#: apart (2.9 % and 1.1 % damping: 2 widths) kept its shapes only with the distance.
TWIN_SHAPE_BAND = 2.0
TWIN_SHAPE_DISTANCE = 0.02
#: Jackknife standard deviations a weaker twin's component along its partner's must reach to be kept
#: (:func:`separate_twin_shapes`). Physical 0-59: the seven twins of orthogonal true shapes 0.2-2.6; random 5, 9.0.
TWIN_COMPONENT_RESOLVED = 3.0


def separate_twin_shapes(modes: list, *, replicate_shapes=None) -> list:
    """Give the weaker of two close modes of one estimated shape the part of its shape its partner's leaves.

    Of a close pair the eigenvectors are ill-conditioned: the error of the weaker pole's
    eigenvector is mostly along its partner's, divided by the poles' distance, and where the
    partner's response is much the larger (twin chains, the force on one chain: 30 times in
    amplitude) that error outweighs the weaker mode's own shape, which then reads as the partner's
    (twin-chains 7, 63.03 Hz: MAC 0.98 with 64.02 Hz, 0.007 with its own). The weaker pole's
    shape with the stronger's component removed is what of it belongs to that pole (exact for
    twins: shapes on two chains, orthogonal), unless that component, per unit of the rest, stands
    out of the jackknife's scatter (:data:`TWIN_COMPONENT_RESOLVED`): an error changes with the data, a
    true component of a pair of nearly one shape does not (random 5: true MAC 0.955). Only the
    listed shape changes: the model's ``C`` keeps the realization's columns (its fit).

    Parameters
    ----------
    modes : listed modes (:class:`~okid_ros.core.modal.Mode`: ``frequency_hz``, ``damping_ratio``,
        ``msv`` the strength, ``shape`` unit norm, replaced in place) of two or more outputs; pairs
        within :data:`TWIN_SHAPE_BAND` summed widths and :data:`TWIN_SHAPE_DISTANCE` whose shapes' MAC is at
        least :data:`MAC_TOLERANCE`.
    replicate_shapes : ``replicate_shapes(mode) -> (S, p)`` the jackknife's S replicates' shapes of the
        mode's pole (:meth:`.output_only_support.Jackknife.shapes`); None: every such pair is separated.

    Returns
    -------
    ``modes``, the same objects.
    """
    shapes = [mode.shape for mode in modes]  # as estimated: a shape once separated is no partner's
    for i, weak in enumerate(modes):
        if weak.shape.size < 2:
            continue  # one output: every shape is one shape
        partners = [j for j, strong in enumerate(modes)
                    if j != i and strong.msv > weak.msv and mac(shapes[i], shapes[j]) >= MAC_TOLERANCE
                    and abs(strong.frequency_hz - weak.frequency_hz) < min(TWIN_SHAPE_BAND * (
                        strong.damping_ratio * strong.frequency_hz + weak.damping_ratio * weak.frequency_hz),
                        TWIN_SHAPE_DISTANCE * weak.frequency_hz)]
        if not partners:
            continue
        strong = shapes[min(partners, key=lambda j: abs(modes[j].frequency_hz - weak.frequency_hz))]
        own = shapes[i] - np.vdot(strong, shapes[i]) / np.vdot(strong, strong).real * strong
        if not np.linalg.norm(own) > np.sqrt(np.finfo(float).eps):
            continue  # nothing of its own to tell (one shape to rounding)
        own = own / np.linalg.norm(own)
        if replicate_shapes is not None:  # the component along the partner's, per unit of its own part
            replicates = replicate_shapes(weak)
            with np.errstate(divide="ignore", invalid="ignore"):
                ratios = (replicates @ strong.conj()) / (replicates @ own.conj())
            if stands_out(np.vdot(strong, shapes[i]) / np.vdot(own, shapes[i]), ratios, TWIN_COMPONENT_RESOLVED):
                continue
        weak.shape = own * np.exp(-1j * np.angle(own[phase_reference_row(own)]))
    return modes
