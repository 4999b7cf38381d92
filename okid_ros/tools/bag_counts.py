"""A bag's messages counted as its storage holds them, not as its ``metadata.yaml`` says.

rosbags' reader of a rosbag2 folder takes each topic's ``message_count`` from ``metadata.yaml``,
which a tool or a hand can spoil (``-90000``) while the storage files hold and play every
message. Each storage file's own reader counts them itself (sqlite3: ``count(messages.id)``;
MCAP: its summary's statistics, or a scan of a file without one), at no further cost: those are
the counts here. A storage file read alone and a ROS 1 bag have no other count than their own.
"""

from __future__ import annotations

from typing import Any

__all__ = ["stored_connections"]


def stored_connections(reader: Any) -> list:
    """The connections of an open rosbags reader (``AnyReader`` or one of its readers), each with its stored count."""
    found = []
    for sub in getattr(reader, "readers", [reader]):
        files = getattr(getattr(sub, "storage", None), "storages", None)
        # A rosbag2 folder: each storage file's connections; a file alone or a ROS 1 bag: the reader's own.
        found += [c for storage in files for c in storage.connections] if files else list(sub.connections)
    return found
