"""The identified model: an innovation model in modal form with what the chain learned.

:class:`IdentifiedModel` is what :func:`okid_ros.core.pipeline.identify` returns and what the
service, the command line and the messages read; :class:`IdentificationError` is the error of
the chain (a one-line reason the user can act on).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.markov import stochastic_markov_from_state_space
from okid_ros.core.modal import Mode
from okid_ros.core.stabilization import StabilizationOrder
from okid_ros.core.statespace import InnovationModel

__all__ = ["IdentificationError", "IdentifiedModel"]


class IdentificationError(ValueError):
    """The data or the options cannot give a model; the message says why."""


@dataclass
class IdentifiedModel(InnovationModel):
    """An identified innovation model in normalized modal form (paper convention).

    ``x_{k+1} = A x_k + B u_k + A K e_k``, ``y_k = C x_k + D u_k + e_k`` for the offset-free
    signals ``u - input_offset``, ``y - output_offset``; ``cov(e) = innovation_covariance``.
    The first ``2 len(modes)`` states are the physical modes' blocks, mode ``i``'s at states
    ``2 i, 2 i + 1``: every consumer (modal coordinates, shapes, the units' re-normalization) reads
    a mode's block by its place in the list, so a mode leaves the list by :meth:`keep_modes`.

    Attributes (beyond :class:`~okid_ros.core.statespace.InnovationModel`)
    ----------
    hankel_singular_values : singular values of the weighted Hankel matrix.
    modes : the physical modes, in state order (changed by :meth:`keep_modes` only).
    arx : the ARX fit it was realized from.
    order_scores : BIC of each model order tried: of the completed model for the orders in
        ``completed_orders``, else of the screening from the window's Gram (output-equation
        residuals of the ERA states, :mod:`okid_ros.core.state_gram`). The order is chosen
        among the completed ones.
    completed_orders : the orders completed (refitted) during the search.
    stabilization : the poles of each order tried, marked by the stabilization criteria.
    x0 : (n,) the predicted state at the first sample of the record (modal coordinates).
    input_offset, output_offset : (m,), (p,) the means removed before identification.
    max_states_reached : BIC was lowest at the largest order the search could try.
    warnings : what the user should know (large offsets, the order limit).
    uncertainty : how the modes' standard deviations were obtained (or why not).
    """

    hankel_singular_values: np.ndarray = field(default_factory=lambda: np.zeros(0))
    modes: list[Mode] = field(default_factory=list)
    arx: ArxFit | None = None
    method: str = "okid"
    gain_method: str = "refit"
    order_scores: dict = field(default_factory=dict)
    completed_orders: list = field(default_factory=list)
    stabilization: list[StabilizationOrder] = field(default_factory=list)
    x0: np.ndarray | None = None
    system_markov: np.ndarray | None = None
    completion: str = "predictor"
    refined: bool = False
    input_offset: np.ndarray | None = None
    output_offset: np.ndarray | None = None
    max_states_reached: bool = False
    arx_order_scores: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    uncertainty: Any = None  # core.uncertainty.UncertaintyResult of the modes' standard deviations

    @property
    def n_physical_states(self) -> int:
        return 2 * len(self.modes)

    def keep_modes(self, kept: list[Mode]) -> None:
        """List only ``kept`` (some of :attr:`modes`, in their order), each still at its own block, renumbered.

        The states are permuted (exact; the model's response unchanged): the kept modes' blocks lead
        in their order, the others' follow them as non-physical pairs.
        """
        position = {id(mode): i for i, mode in enumerate(self.modes)}
        listed = [position[id(mode)] for mode in kept]
        listed_once = set(listed)
        unlisted = [i for i in range(len(self.modes)) if i not in listed_once]
        if unlisted:
            order = np.r_[[state for i in listed + unlisted for state in (2 * i, 2 * i + 1)],
                          np.arange(self.n_physical_states, self.n_states)].astype(int)
            self.A, self.B = self.A[np.ix_(order, order)], self.B[order]
            self.C, self.K = self.C[:, order], self.K[order]
            self.x0 = None if self.x0 is None else self.x0[order]
        self.modes = list(kept)
        for i, mode in enumerate(self.modes):
            mode.id = i

    def stochastic_markov(self, n_terms: int) -> np.ndarray:
        """``C A^i K`` for i = 1..n_terms: (n_terms, p, p) (paper Fig. 3)."""
        return stochastic_markov_from_state_space(self.A, self.C, self.K, n_terms)

    def to_json_dict(self) -> dict:
        """The ``identify --json`` document (nested lists, damping ratios as fractions)."""
        arx = self.arx
        return {
            "sample_time_s": float(self.sample_time_s),
            "n_states": self.n_states,
            "n_inputs": self.n_inputs,
            "n_outputs": self.n_outputs,
            "method": self.method,
            "gain_method": self.gain_method,
            "completion": self.completion,
            "refined": self.refined,
            "arx_order": int(arx.order) if arx else None,
            "arx_order_scores": {str(k): float(v) for k, v in self.arx_order_scores.items()},
            "arx_regularization": arx.regularization if arx else None,
            "arx_penalty": float(arx.penalty) if arx else None,
            "condition_number": float(arx.condition_number) if arx else None,
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
            "D": self.D.tolist(),
            "K": self.K.tolist(),
            "K_convention": "x[k+1] = A x[k] + B u[k] + A K e[k]; y[k] = C x[k] + D u[k] + e[k]",
            "innovation_covariance": self.innovation_covariance.tolist(),
            "spectral_radius": self.spectral_radius(),
            "predictor_spectral_radius": self.predictor_spectral_radius(),
            "input_offset": None if self.input_offset is None else self.input_offset.tolist(),
            "output_offset": None if self.output_offset is None else self.output_offset.tolist(),
            "hankel_singular_values": [float(s) for s in self.hankel_singular_values],
            "order_scores": {str(k): float(v) for k, v in self.order_scores.items()},
            "completed_orders": [int(n) for n in self.completed_orders],
            "max_states_reached": bool(self.max_states_reached),
            "warnings": list(self.warnings),
            "modes": [m.as_dict() for m in self.modes],
            "stabilization": [entry.as_dict() for entry in self.stabilization],
        }
