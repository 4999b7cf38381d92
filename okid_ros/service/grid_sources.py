"""The sources of a sample grid: which channels each fills, and where in a slot's values.

Each source provides a fixed list of channels (indices into ``[u_0 .. u_{m-1}, y_0 .. y_{p-1}]``);
every channel is provided by exactly one source (:func:`grid_sources`, the rule of
:class:`okid_ros.service.sample_grid.SampleGrid`).

No rclpy: the nodes and the offline tools both use this module.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from okid_ros.service.channels import channel_name
from okid_ros.service.grid_samples import GridCounters

__all__ = ["GridSource", "grid_sources"]


@dataclass
class GridSource:
    """One source of the grid: its channels, their place in a slot, its last slot and its counters."""

    channels: np.ndarray
    index: slice | np.ndarray  # where its values go in a slot's: a slice when the channels are a run
    bits: int  # its channels' bits of a slot's ``filled``
    last_slot: int | None = None
    before_jump: bool = False  # still sending stamps from before the last time jump or forward step
    counters: GridCounters = field(default_factory=GridCounters)


def grid_sources(sources: Sequence[Sequence[int]], n_inputs: int, n_channels: int) -> list[GridSource]:
    """Each source's :class:`GridSource`, or ValueError where a channel has no source, or two.

    Parameters
    ----------
    sources : for each source, the channel indices its values fill, in the order of its values.
    n_inputs : m (channel ``c < m`` is ``u_c``, for the messages); n_channels : m + p.
    """
    owner = [-1] * n_channels
    layouts: list[GridSource] = []
    for s, chans in enumerate(sources):
        chans = np.asarray(list(chans), dtype=np.int64)
        if chans.size == 0:
            raise ValueError(f"source {s} provides no channel")
        for c in chans:
            if not 0 <= c < n_channels:
                raise ValueError(f"source {s} names channel {c}; channels are 0..{n_channels - 1}")
            if owner[c] >= 0:
                raise ValueError(f"channel {channel_name(c, n_inputs)} is provided by sources {owner[c]} and {s}; "
                                 "each channel must come from exactly one source")
            owner[c] = s
        index = slice(int(chans[0]), int(chans[-1]) + 1) if np.all(np.diff(chans) == 1) else chans
        layouts.append(GridSource(chans, index, sum(1 << int(c) for c in chans)))
    if missing := [channel_name(c, n_inputs) for c in range(n_channels) if owner[c] < 0]:
        raise ValueError(f"no source provides channel(s) {', '.join(missing)}")
    return layouts
