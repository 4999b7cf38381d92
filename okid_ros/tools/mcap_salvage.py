"""Read what a cut-off MCAP recording holds.

A recorder stopped before it closes its MCAP file (killed, power lost, disk full) leaves the
file without its summary and footer, and the bag directory usually without ``metadata.yaml``
(rosbag2 writes it on closing). rosbags reads an MCAP file from its footer and refuses such a
file, so the whole recording was lost to every command. Yet every record before the cut is
whole: an MCAP file is the magic, then records ``opcode (1 byte), length (uint64 LE), body``,
and a chunk compresses its messages as one record. :func:`whole_records_end` finds the end of
the last whole record; :func:`write_closed_copy` writes the file up to there, closed by a
DataEnd record and a Footer that points to no summary (MCAP specification, "Footer": a summary
start of 0 means none), which rosbags then reads by scanning its records.

Why by hand: rosbags has no recovery; the Foxglove ``mcap`` package streams cut files but is
not a dependency of the product and would be a second message path beside rosbags; ``mcap
recover`` (Go) and ``ros2 bag reindex`` are not available to a pip install.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import NamedTuple

__all__ = ["Cut", "single_mcap_file", "whole_records_end", "write_closed_copy"]

MAGIC = b"\x89MCAP0\r\n"
_OP_FOOTER = 0x02
_OP_DATA_END = 0x0F
_RECORD_HEAD = 9  # opcode + uint64 length
_FOOTER_LENGTH = 20  # summary start, summary offset start (uint64 each), summary CRC (uint32)


class Cut(NamedTuple):
    """Where an MCAP file without its end can be closed."""

    whole_bytes: int  #: the offset after the last whole record of the data section
    data_complete: bool  #: the cut fell after the data section (in the summary): no message lost


def whole_records_end(path: Path) -> Cut | None:
    """Where the data section of a cut-off MCAP file ends (its last whole record).

    Returns
    -------
    None when the file is not MCAP (no leading magic) or is closed (ends with the magic).
    """
    with path.open("rb") as stream:
        if stream.read(len(MAGIC)) != MAGIC:
            return None
        size = stream.seek(0, 2)
        if size >= 2 * len(MAGIC) and stream.seek(size - len(MAGIC)) and stream.read(len(MAGIC)) == MAGIC:
            return None
        position = len(MAGIC)
        while position + _RECORD_HEAD <= size:
            stream.seek(position)
            opcode, length = struct.unpack("<BQ", stream.read(_RECORD_HEAD))
            if opcode in (_OP_DATA_END, _OP_FOOTER):
                return Cut(position, True)
            if position + _RECORD_HEAD + length > size:
                break  # the cut falls inside this record
            position += _RECORD_HEAD + length
        return Cut(position, False)


def single_mcap_file(path: Path) -> Path | None:
    """The MCAP file of ``path``: itself if a ``.mcap`` file, else a directory's only ``.mcap`` file.

    Of a split recording (several files) the files before the last are closed; joining them to
    a cut last file is not done here (None).
    """
    if path.is_file():
        return path if path.suffix == ".mcap" else None
    files = sorted(path.glob("*.mcap")) if path.is_dir() else []
    return files[0] if len(files) == 1 else None


def write_closed_copy(path: Path, whole_bytes: int, target: Path) -> None:
    """Write the first ``whole_bytes`` of ``path`` to ``target``, closed by DataEnd, Footer, magic."""
    with path.open("rb") as source, target.open("wb") as out:
        remaining = whole_bytes
        while remaining > 0:
            block = source.read(min(remaining, 1 << 24))
            if not block:
                break
            out.write(block)
            remaining -= len(block)
        out.write(struct.pack("<BQI", _OP_DATA_END, 4, 0))  # data section CRC 0: not checked
        out.write(struct.pack("<BQQQI", _OP_FOOTER, _FOOTER_LENGTH, 0, 0, 0))
        out.write(MAGIC)

