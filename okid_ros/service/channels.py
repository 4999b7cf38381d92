"""Channel names of the sample ``[u; y]``: ``u<i>`` for input i, ``y<j>`` for output j (0-based).

One rule for the source parser (:mod:`okid_ros.service.inputs`) and the sample grid, which both
name channels in their messages.
"""

from __future__ import annotations

import re

__all__ = ["channel_index", "channel_name"]

_CHANNEL = re.compile(r"^(u|y)(\d+)$")


def channel_index(name: str, n_inputs: int, n_outputs: int) -> int:
    """'u1' -> 1, 'y0' -> n_inputs; ValueError for a bad name or an index out of range."""
    match = _CHANNEL.match(name)
    if not match:
        raise ValueError(f"channel {name!r} must be u<i> (input) or y<j> (output)")
    kind, idx = match.group(1), int(match.group(2))
    limit = n_inputs if kind == "u" else n_outputs
    if idx >= limit:
        what = "n_inputs" if kind == "u" else "n_outputs"
        raise ValueError(f"channel {name} is out of range: {what} = {limit}")
    return idx if kind == "u" else n_inputs + idx


def channel_name(channel: int, n_inputs: int) -> str:
    """The name of a channel index of ``[u; y]``: ``u<i>`` or ``y<j>`` (the inverse of :func:`channel_index`)."""
    return f"u{channel}" if channel < n_inputs else f"y{channel - n_inputs}"
