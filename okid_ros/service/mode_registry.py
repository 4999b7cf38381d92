"""Persistent mode ids across model updates (node 2).

A mode of a new model keeps the id of a mode seen in the last ``mode_memory`` accepted models
when it matches it (relative frequency change below ``max_frequency_change`` and MAC of the
shapes at least ``min_mac``, :func:`okid_ros.core.modal.match_modes`), the most recently seen
first; other modes get fresh ids. ``mac_previous`` of a kept mode is its MAC to the mode it continues.

After a structural change the memory is not used: the first model of the new structure is
matched against the modes of the model before the change only (:meth:`ModeRegistry.match`
with ``against``), and every remembered mode it does not match is retired
(:meth:`ModeRegistry.retire_except`), so that an id never comes back for a mode of the old
structure.
"""

from __future__ import annotations

import math
from dataclasses import replace

from okid_ros.core.modal import Mode, mac, match_modes

__all__ = ["ModeRegistry"]


class ModeRegistry:
    """Mode ids and the recently seen modes.

    Parameters
    ----------
    max_frequency_change : relative frequency change up to which a mode keeps its id.
    min_mac : smallest MAC of the shapes for a mode to keep its id.
    mode_memory : accepted models a mode that disappeared keeps its id for.
    """

    def __init__(self, *, max_frequency_change: float, min_mac: float, mode_memory: int) -> None:
        self.configure(max_frequency_change=max_frequency_change, min_mac=min_mac, mode_memory=mode_memory)
        self.reset()

    def configure(self, *, max_frequency_change: float, min_mac: float, mode_memory: int) -> None:
        """New matching criteria, used from the next :meth:`match` on (ids and memory are kept)."""
        self.max_frequency_change = float(max_frequency_change)
        self.min_mac = float(min_mac)
        self.mode_memory = int(mode_memory)

    def reset(self) -> None:
        """Forget every mode; ids restart at 0."""
        self._seen: dict[int, tuple[Mode, int]] = {}  # id -> (mode, accepted-model count when last seen)
        self._next_id = 0
        self.accepted = 0
        self.retired = 0

    def match(self, modes: list[Mode], against: list[Mode] | None = None) -> list[tuple[int, Mode] | None]:
        """For each mode, the ``(id, matched mode)`` it continues, or None if it is new.

        ``against``: match only these modes (with their ids) instead of the memory.
        """
        if against is not None:
            return self._match_one_group(modes, [(mode.id, mode) for mode in against])
        # The most recently seen first: a mode continues the latest mode it matches, so an older id of
        # the same mode (given up when the criteria were stricter, or lost for a few models) cannot
        # take its place.
        groups: dict[int, list[tuple[int, Mode]]] = {}
        for mid, (mode, seen) in self._seen.items():
            if self.accepted - seen <= self.mode_memory:
                groups.setdefault(seen, []).append((mid, mode))
        result: list[tuple[int, Mode] | None] = [None] * len(modes)
        for seen in sorted(groups, reverse=True):
            open_ = [i for i, match in enumerate(result) if match is None]
            if not open_:
                break
            for i, match in zip(open_, self._match_one_group([modes[i] for i in open_], groups[seen])):
                result[i] = match
        return result

    def _match_one_group(self, modes: list[Mode], memory: list[tuple[int, Mode]]) -> list[tuple[int, Mode] | None]:
        matches = match_modes([mode for _, mode in memory], modes, self.max_frequency_change, self.min_mac)
        return [None if j is None else memory[j] for j in matches]

    def assign(self, modes: list[Mode], matches: list[tuple[int, Mode] | None]) -> list[Mode]:
        """Give ``modes`` their ids (kept or fresh) and ``mac_previous``; remember them.

        Call once per accepted model, with the result of :meth:`match`.
        """
        self.accepted += 1
        out: list[Mode] = []
        for mode, match in zip(modes, matches):
            if match is None:
                mode.id = self._next_id
                self._next_id += 1
                mode.mac_previous = math.nan
            else:
                mode.id = match[0]
                mode.mac_previous = mac(mode.shape, match[1].shape)
            self._seen[mode.id] = (replace(mode), self.accepted)
            out.append(mode)
        return out

    def retire_except(self, keep_ids: set[int]) -> list[int]:
        """Forget every remembered mode whose id is not in ``keep_ids``; returns their ids."""
        gone = sorted(mid for mid in self._seen if mid not in keep_ids)
        for mid in gone:
            del self._seen[mid]
        self.retired += len(gone)
        return gone

    def __len__(self) -> int:
        return len(self._seen)
