"""Model switching with persistent mode ids (node 2).

:class:`ModelSelection` decides whether a realized model is taken and gives its modes their
ids (:class:`okid_ros.service.mode_registry.ModeRegistry`):

- after a structural change, a model from a window that spans the change point is refused;
  the first model of post-change data is matched against the modes before the change only,
  and the modes it does not match are retired;
- otherwise modes are not to be lost: at least ``min_matched_fraction`` of the current model's
  modes are found again (frequency within ``max_frequency_change``, MAC >= ``min_mac``).
  After ``max_consecutive_rejections`` models rejected in a row for lost modes, the next
  stable one is accepted (the structure changed).

:class:`SwitchJump` measures the step of the matched modes' coordinates at each switch,
relative to their RMS amplitude (``last_switch_jump``): there should be none, since the new
estimator starts from the state its own predictor reaches over the buffered samples. A switch
made while no samples arrive (an idle switch) is measured at the next sample (:meth:`SwitchJump.defer`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from okid_ros.core.modal import Mode
from okid_ros.core.pipeline import IdentifiedModel
from okid_ros.core.statespace import InnovationPredictor
from okid_ros.service.mode_registry import ModeRegistry
from okid_ros.service.options import ModalEstimationParams
from okid_ros.service.realization import bridge_state
from okid_ros.service.results import ActiveModel, EstimationStats, StructuralChangeEvent

__all__ = ["ModelSelection", "SwitchJump"]


class ModelSelection:
    """Acceptance of realized models and their mode ids (see the module docstring)."""

    def __init__(self, params: ModalEstimationParams, stats: EstimationStats) -> None:
        self.registry = ModeRegistry(max_frequency_change=params.max_frequency_change, min_mac=params.min_mac,
                                     mode_memory=params.mode_memory)
        self.params = params
        self._stats = stats

    def configure(self, params: ModalEstimationParams) -> None:
        """Take run-time options at once (the next model is matched with them)."""
        self.params = params
        self.registry.configure(max_frequency_change=params.max_frequency_change, min_mac=params.min_mac,
                                mode_memory=params.mode_memory)

    def select(self, model: IdentifiedModel, window_first: int, active: ActiveModel | None,
               change: StructuralChangeEvent | None) -> list[Mode] | None:
        """The modes of ``model`` with their ids if it is taken, else None (the reason in the stats).

        ``window_first``: buffer index of its window's first sample; ``change``: the change
        waiting for its model (its ``retired_ids`` and ``modes_after`` are filled on acceptance).
        """
        st = self._stats
        if change is not None and window_first < change.change_index:
            st.models_rejected += 1
            st.windows_refused_for_change += 1
            st.last_reason = "model identified from a window that spans the structural change"
            return None
        # After a change: match against the modes before it only (no memory, no lost-mode check).
        matches = self.registry.match(model.modes, None if change is None else change.modes_before)
        if change is None and active is not None and active.modes and not self._enough_found(active, matches):
            return None
        st.consecutive_rejections = 0
        st.last_accepted = True
        st.last_reason = ""
        modes = self.registry.assign(model.modes, matches)
        st.models_accepted += 1
        if change is not None:
            kept = {mode.id for mode in modes}
            self.registry.retire_except(kept)
            change.retired_ids = [mode.id for mode in change.modes_before if mode.id not in kept]
            change.modes_after = [replace(mode) for mode in modes]
            st.modes_retired += len(change.retired_ids)
        return modes

    def _enough_found(self, active: ActiveModel, matches: list) -> bool:
        """Whether enough of the current modes are found again (or the rejections forced it)."""
        st, prm = self._stats, self.params
        current_ids = {mode.id for mode in active.modes}
        found = len(current_ids & {match[0] for match in matches if match is not None})
        if found / len(current_ids) >= prm.min_matched_fraction:
            return True
        if 0 < prm.max_consecutive_rejections <= st.consecutive_rejections:
            st.forced_accepts += 1
            return True
        st.models_rejected += 1
        st.consecutive_rejections += 1
        st.last_reason = (
            f"modes lost: {found} of the current model's {len(current_ids)} modes found in the new "
            f"model (tracking.min_matched_fraction {prm.min_matched_fraction:g})"
        )
        return False


class SwitchJump:
    """The step of the modal coordinates at a model switch, relative to each mode's RMS amplitude."""

    def __init__(self, stats: EstimationStats) -> None:
        self._stats = stats
        self._power: dict[int, float] = {}
        self._reference: dict[int, np.ndarray] | None = None
        self._deferred: ActiveModel | None = None  # the model before an idle switch

    def cancel(self) -> None:
        """Forget the reference of a switch not measured (an outcome is being applied)."""
        self._reference = None
        self._deferred = None

    def defer(self, old: ActiveModel) -> None:
        """A switch from ``old`` between samples: its reference is taken at the next sample.

        ``old``'s estimator has stepped the newest sample, so it holds its state for the next
        one, where :meth:`measure_deferred` compares it as :meth:`before_switch` does at a sample.
        """
        self._deferred = old

    def measure_deferred(self, u: np.ndarray, y: np.ndarray, skipped: int, u_prev: np.ndarray | None,
                         max_gap: int) -> bool:
        """At the first sample after a deferred switch, its reference (:meth:`before_switch`); whether there was one."""
        old, self._deferred = self._deferred, None
        if old is None:
            return False
        self.before_switch(old, u, y, skipped, u_prev, max_gap)
        return True

    def before_switch(self, old: ActiveModel, u: np.ndarray, y: np.ndarray, skipped: int,
                      u_prev: np.ndarray | None, max_gap: int) -> None:
        """The old model's modal states for the sample of the switch (on a copy of its estimator)."""
        x = old.estimator.state
        if skipped:
            x = bridge_state(old.model, x, u_prev, int(skipped), max_gap)
        innovation = InnovationPredictor(old.model, x).step(u, y, advance=False)  # offset-free signals
        x_post = x + old.estimator.K_steady @ innovation
        coords = x_post[: 2 * old.n_modes].reshape(old.n_modes, 2)
        self._reference = {mode.id: coords[i] for i, mode in enumerate(old.modes)}

    def after_sample(self, active: ActiveModel, coords: np.ndarray, switched: bool) -> None:
        """The modal states of a published sample: measure the jump at a switch, track the power."""
        if switched and self._reference is not None:
            self._measure(active, coords)
        self._reference = None if switched else self._reference
        sq = np.einsum("ij,ij->i", coords, coords)
        for i, mode in enumerate(active.modes):  # exponential average over about 1000 samples
            old = self._power.get(mode.id)
            self._power[mode.id] = float(sq[i]) if old is None else old + 1e-3 * (float(sq[i]) - old)

    def _measure(self, active: ActiveModel, coords: np.ndarray) -> None:
        previous, self._reference = self._reference, None
        jumps = []
        for i, mode in enumerate(active.modes):
            old = previous.get(mode.id)
            power = self._power.get(mode.id)
            if old is None or not power:
                continue
            jumps.append(float(np.linalg.norm(coords[i] - old)) / math.sqrt(power))
        if jumps:
            st = self._stats
            st.last_switch_jump = max(jumps)
            st.max_switch_jump = max(st.max_switch_jump, st.last_switch_jump)
            st.switches_measured += 1
