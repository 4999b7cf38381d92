"""A close pair's member whose complex shape lies in the real plane its partner's shape spans: two real modes' mix.

Two real modes closer than their half-power bands (a tower's two bending modes of one order, 0.2-1 %
apart, in two principal directions) are each estimated as a complex mix of both true shapes: the
two estimated shapes differ, neither is real, and both lie in the real plane of the two true shapes.
The partner's real and imaginary parts span that plane; a noise shape lies in a fixed plane at ``p``
outputs only by chance (:func:`pair_plane_floor`). The clustering's MPC floor keeps such a member
(:func:`.output_only_modes._mixed_with_neighbour`); its frequency and damping are its own family's
(docs/benchmarks-output-only.md, "Towers' close bending pairs (forty-ninth session)").
"""

from __future__ import annotations

import numpy as np
from scipy import stats

__all__ = ["PAIR_PLANE_NOISE_SHARE", "pair_plane_floor", "share_in_real_plane"]

#: A shape lies in its partner's real plane as one of a pair when noise alone would lie in it as much only this
#: often (:func:`pair_plane_floor`): 0.94 of its energy at 4 outputs, 0.78 at 6, 0.64 at 8. Towers of
#: families-2 seeds 0-89: the members the MPC floor refused read 0.99-1.00 at 4-8 outputs.
PAIR_PLANE_NOISE_SHARE = 0.01


def share_in_real_plane(own: np.ndarray, partner: np.ndarray) -> float:
    """Share of ``own``'s energy in the real plane spanned by ``partner``'s real and imaginary parts (0..1)."""
    basis, _ = np.linalg.qr(np.column_stack([partner.real, partner.imag]))
    return float(np.linalg.norm(basis.T @ own) ** 2 / max(np.vdot(own, own).real, np.finfo(float).tiny))


def pair_plane_floor(n_outputs: int, share: float = PAIR_PLANE_NOISE_SHARE) -> float:
    """The share of a fixed real plane a noise shape at ``n_outputs`` outputs exceeds with probability ``share``.

    A shape of independent complex Gaussian components holds a Beta(2, p - 2) share of its energy in a
    fixed real plane (its real and imaginary parts two chi-square(2) there, of chi-square(2p) in all).
    At 2 outputs or fewer every shape lies in the plane: 1 (no shape passes above it).
    """
    rest = n_outputs - 2
    if rest <= 0:
        return 1.0
    return float(stats.beta.isf(share, 2, rest))
