"""What a campaign directory already holds, and writing into it without half-written files.

The manifest is a journal, ``DIR/manifest.jsonl``: one JSON line per bag finished (ok or
failed), appended and flushed as soon as the bag is done, so a run killed at any moment
keeps every bag it finished. A line is keyed by the bag's absolute path, its size, its
newest modification time and the hash of the resolved parameters; the last line of a key
wins and a torn last line (a kill during the append) is ignored. At the end of a run the
journal is rewritten compactly (temporary file and rename).

Tables and per-bag folders are written under a temporary name and renamed into place
(:func:`atomic_write_bytes`, :func:`replace_directory`), so a reader never sees half of one.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import uuid
from pathlib import Path
from typing import Any

from okid_ros.jsonio import NOT_JSON

__all__ = ["MANIFEST_NAME", "OLD_PREFIX", "Manifest", "atomic_write_bytes", "parameters_hash", "replace_directory"]

MANIFEST_NAME = "manifest.jsonl"
#: Name start of a folder being replaced (:func:`replace_directory`); a killed run's are removed by the next.
OLD_PREFIX = ".old-"
_VERSION = 1


def parameters_hash(arx_values: dict, est_values: dict, **extra: Any) -> str:
    """SHA-256 (16 hex digits) of the resolved parameters of both nodes and ``extra`` options."""
    document = {"okid_arx_identifier": arx_values, "okid_modal_estimator": est_values, **extra}
    text = json.dumps(document, sort_keys=True, default=str, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``path`` through a temporary file in the same folder and a rename."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        with open(tmp, "wb") as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def replace_directory(new: Path, final: Path) -> None:
    """Put the complete folder ``new`` at ``final``, replacing an older one (renames only)."""
    if final.exists():
        old = final.with_name(f"{OLD_PREFIX}{final.name}-{uuid.uuid4().hex[:8]}")
        os.replace(final, old)
        os.replace(new, final)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(new, final)


class Manifest:
    """The journal of a campaign directory.

    Parameters
    ----------
    directory : the campaign directory (``DIR`` of ``okid-ros batch``).
    """

    def __init__(self, directory: Path) -> None:
        self.path = Path(directory) / MANIFEST_NAME
        self.entries: dict[str, dict] = {}
        #: Whole lines that were not readable entries (not text, not JSON): spoilt, their bags run again.
        self.unreadable = 0
        if self.path.exists():
            self._load()
        self._stream = None

    def _load(self) -> None:
        from okid_ros.errors import DataError, shown_path

        try:
            data = self.path.read_bytes()
        except OSError as exc:
            raise DataError(f"{shown_path(self.path)}: cannot read the campaign's manifest "
                            f"({exc.strerror or exc})") from None
        lines = data.split(b"\n")
        for number, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                entry = json.loads(line.decode("utf-8"))
            except NOT_JSON:
                # The last line without its newline was torn by a kill during its append; others are spoilt.
                self.unreadable += number < len(lines)
                continue
            if isinstance(entry, dict) and entry.get("version") == _VERSION and isinstance(entry.get("key"), str):
                self.entries[entry["key"]] = entry

    @staticmethod
    def key(path: Path) -> str:
        return str(Path(path).resolve())

    def lookup(self, path: Path, size: int, mtime_ns: int, params_hash: str) -> dict | None:
        """The entry of this bag if it was done with the same content and parameters, else None."""
        entry = self.entries.get(self.key(path))
        if entry is None:
            return None
        if (entry.get("size"), entry.get("mtime_ns"), entry.get("params_hash")) != (size, mtime_ns, params_hash):
            return None
        return entry

    def record(self, path: Path, size: int, mtime_ns: int, params_hash: str, result: dict) -> dict:
        """Append (and flush) the entry of a finished bag; returns it."""
        entry = {"version": _VERSION, "key": self.key(path), "size": int(size), "mtime_ns": int(mtime_ns),
                 "params_hash": params_hash, "status": result["status"], "reason": result.get("reason", ""),
                 "label": result.get("label", ""), "summary": {k: v for k, v in result.items() if k != "updates"}}
        self.entries[entry["key"]] = entry
        if self._stream is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._stream = open(self.path, "a", encoding="utf-8")
        self._stream.write(json.dumps(entry, allow_nan=True) + "\n")
        self._stream.flush()
        os.fsync(self._stream.fileno())
        return entry

    def forget(self, key: str) -> dict | None:
        """Drop the entry of ``key`` (an absolute path) from the journal; returns it. Written by :meth:`compact`."""
        return self.entries.pop(key, None)

    def compact(self) -> None:
        """Rewrite the journal with one line per bag (atomically)."""
        self.close()
        text = "".join(json.dumps(e, allow_nan=True) + "\n" for e in self.entries.values())
        atomic_write_bytes(self.path, text.encode())

    def close(self) -> None:
        if self._stream is not None:
            self._stream.close()
            self._stream = None
