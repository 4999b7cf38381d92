"""Whether the input bag `plot` draws from is the recording `process` read.

`process` records its input's path (``okid_ros.process`` ``source``) and the fingerprint of its
files (``source_files``, :func:`bag_fingerprint`: absolute path, number of files, bytes, latest
modification time). `plot` draws the measured outputs, the truth and the FRF from that bag by
default: a recording made again at the same path would be drawn against the models of another,
with nothing said. :func:`changed_since` says how the bag differs from what was recorded; a bag
given with ``--input`` at another path is checked by its stamps instead (:func:`stamps_apart`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["bag_fingerprint", "changed_since", "stamps_apart"]


def bag_fingerprint(path: str | Path) -> dict | None:
    """``{"path", "files", "bytes", "mtime_ns"}`` of a bag directory (all its files) or bag file.

    None when the bag or one of its files cannot be listed or read for its size (the readers say
    what is wrong with it).
    """
    path = Path(path)
    try:
        files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
        stats = [file.stat() for file in files]
    except OSError:
        return None
    return {"path": str(path.resolve()), "files": len(stats), "bytes": sum(s.st_size for s in stats),
            "mtime_ns": max((s.st_mtime_ns for s in stats), default=0)}


def changed_since(path: str | Path, recorded: Any) -> str:
    """How the bag at ``path`` differs from the ``recorded`` fingerprint of the same path, or "".

    "" also when nothing usable was recorded (an output of an older `process`, a live recording)
    or ``path`` is another bag than the one recorded.
    """
    if not isinstance(recorded, dict) or not isinstance(recorded.get("path"), str):
        return ""
    now = bag_fingerprint(path)
    if now is None or now["path"] != recorded["path"]:
        return ""
    differ = [f"{recorded.get(key)} {key} then, {now[key]} now" for key in ("files", "bytes")
              if recorded.get(key) != now[key]]
    if not differ and recorded.get("mtime_ns") != now["mtime_ns"]:
        differ.append("the same size, modified since")
    return ", ".join(differ)


def stamps_apart(input_span_ns: tuple, run_span_ns: tuple) -> str:
    """``"its samples (a-b s) and the run's (c-d s) do not overlap"``, or "" when they do (or are unknown)."""
    if len(input_span_ns) != 2 or len(run_span_ns) != 2:
        return ""
    (a, b), (c, d) = input_span_ns, run_span_ns
    if a <= d and c <= b:
        return ""
    return (f"its samples ({a * 1e-9:.3f}-{b * 1e-9:.3f} s) and those of the run that wrote the models "
            f"({c * 1e-9:.3f}-{d * 1e-9:.3f} s) do not overlap")
