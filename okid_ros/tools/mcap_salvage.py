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

A split recording (several files, the last one cut) is read as one: the closed files as they
are, the cut one from its copy, merged by time by rosbags' ``AnyReader``.

Why by hand: rosbags has no recovery; the Foxglove ``mcap`` package streams cut files but is
not a dependency of the product and would be a second message path beside rosbags; ``mcap
recover`` (Go) and ``ros2 bag reindex`` are not available to a pip install.
"""

from __future__ import annotations

import shutil
import struct
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

from okid_ros.errors import shown_path
from okid_ros.tools.errors import BagReadError

__all__ = ["Cut", "mcap_files", "read_unclosed", "whole_records_end", "write_closed_copy"]

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


def mcap_files(path: Path) -> list[Path]:
    """The MCAP files of ``path``: itself if a ``.mcap`` file, else a directory's ``.mcap`` files (split)."""
    if path.is_file():
        return [path] if path.suffix == ".mcap" else []
    return sorted(path.glob("*.mcap")) if path.is_dir() else []


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



def read_unclosed(path: Path, open_reader: Callable[[list[Path]], Any]) -> tuple[Any, str, Path | None]:
    """Open the MCAP files of a recording that was not closed: ``(reader, what was read, scratch)``.

    A cut-off file is read up to its last whole record from a closed copy in the temporary
    directory ``scratch`` (the caller removes it after reading); closed files in a directory
    whose ``metadata.yaml`` is missing or unreadable are read alone (a split recording: its
    files merged by time). ``open_reader`` opens a list of files, None when it cannot. The
    reader is None when ``path`` is not such a recording.

    Raises
    ------
    BagReadError
        the files were cut before any whole message.
    """
    files = mcap_files(path)
    cuts = {file: whole_records_end(file) for file in files}
    cut_files = [file for file in files if cuts[file] is not None]
    if not files or (files == [path] and not cut_files):  # a closed file that failed: its own error
        return None, "", None
    scratch = Path(tempfile.mkdtemp(prefix="okid-salvage-")) if cut_files else None
    readable = []
    for file in files:
        if cuts[file] is None:
            readable.append(file)
        else:
            readable.append(scratch / file.name)
            write_closed_copy(file, cuts[file].whole_bytes, readable[-1])
    reader = open_reader(readable)
    if not cut_files:
        names = ", ".join(shown_path(file.name) for file in files)
        return reader, (f"{shown_path(path)}: metadata.yaml missing or unreadable (a recording that was not closed?): "
                        f"read its MCAP file{'s' if len(files) > 1 else ''} {names} alone"), None
    names, were = ", ".join(shown_path(file.name) for file in cut_files), "were" if len(cut_files) > 1 else "was"
    if reader is None or not reader.message_count:
        if reader is not None:
            reader.close()
        shutil.rmtree(scratch, ignore_errors=True)
        raise BagReadError(f"{shown_path(path)}: the MCAP file {names} {were} cut off (a recording that was not "
                           f"closed) and no message before the cut could be read")
    read = f"read the {reader.message_count} messages, {(reader.end_time - reader.start_time) * 1e-9:.1f} s"
    if all(cuts[file].data_complete for file in cut_files):
        note = f"{shown_path(path)}: the MCAP file {names} {were} cut off in its index: {read}, every message whole"
        return reader, note, scratch
    whole = sum(cuts[file].whole_bytes for file in cut_files) / sum(file.stat().st_size for file in cut_files)
    return reader, (f"{shown_path(path)}: the MCAP file {names} {were} cut off (a recording that was not closed): "
                    f"{read}, of the whole records ({whole:.0%} of the cut file{'s' if len(cut_files) > 1 else ''}); "
                    f"the rest is lost"), scratch
