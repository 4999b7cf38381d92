"""A bag of the campaign given at a new path (moved to an archive disk): its journal line follows it.

The journal knows a bag by its absolute path. A bag moved (its folder renamed, the bags moved to an
archive disk with their times) is the same recording under another key; what the journal records
besides the path tells it: the bag's name, size and newest modification time (the rule by which the
tables already count such a bag once, ``runner._kept_from_journal``). Given at its new path it was
processed again and its old journal line stayed: after any later change of the bag (a reindex, a
touch) that line no longer matched it and came back as a second bag of the campaign, its rows
twice in the tables.

Now, with the parameters it was identified with, the bag's outputs are taken as they are: its
folder under ``DIR/bags`` is renamed to the new path's label (a new recording at the old path gets
the old label: it must not write over them), its ``result.json`` names the new path and its journal
line moves to the new path. Processed again (``--force``, other parameters, ``--retry-failed``),
its new result replaces the old line (and, when ok, the old folder), as a bag redone at its own
path replaces its own.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from okid_ros.errors import one_line, shown_path
from okid_ros.tools.campaign.discovery import bag_label
from okid_ros.tools.campaign.manifest import Manifest, atomic_write_bytes, replace_directory
from okid_ros.tools.campaign.stored import label_problem

__all__ = ["drop_replaced", "journaled_elsewhere", "take_moved"]


def journaled_elsewhere(manifest: Manifest, bag: Path, fingerprint: tuple[int, int], given: set[str]) -> dict | None:
    """The newest journal entry of ``bag`` at another path not ``given`` this run (same name, size, time), or None."""
    key = Manifest.key(bag)
    identity = (Path(key).name, *fingerprint)
    for other, entry in reversed(manifest.entries.items()):
        if other != key and other not in given and (Path(other).name, entry.get("size"),
                                                    entry.get("mtime_ns")) == identity:
            return entry
    return None


def take_moved(manifest: Manifest, entry: dict, result: dict, bag: Path, fingerprint: tuple[int, int],
               out_dir: Path) -> dict | None:
    """``result``, the stored result of the journal ``entry``, made the bag at ``bag``'s (module docstring).

    Returns the result at its new path and label, or None (with a warning) when its folder cannot
    be renamed: the bag is then processed again.
    """
    label = bag_label(bag)
    moved = {**result, "bag": str(bag), "label": label}
    if entry["status"] == "ok":
        folder = out_dir / "bags" / label
        try:
            replace_directory(out_dir / "bags" / entry["label"], folder)
            atomic_write_bytes(folder / "result.json", json.dumps(moved, allow_nan=True).encode())
        except OSError as exc:
            print(f"okid-ros batch: warning: {shown_path(bag)}: cannot take the outputs of the same bag journaled at "
                  f"{shown_path(entry['key'])} ({one_line(exc.strerror or exc)}); processing it again", file=sys.stderr)
            return None
    manifest.record(bag, *fingerprint, entry["params_hash"], moved)
    manifest.forget(entry["key"])
    print(f"okid-ros batch: {shown_path(bag)}: the bag journaled at {shown_path(entry['key'])} (same name, size "
          "and modification time): its outputs reused, its journal line moved to the new path", file=sys.stderr)
    return moved


def drop_replaced(manifest: Manifest, entry: dict, out_dir: Path, result: dict) -> None:
    """Drop the journal line of ``entry``, a bag processed again at a new path into ``result``; its folder if ok."""
    manifest.forget(entry["key"])
    label = entry.get("label")
    if result["status"] == "ok" and not label_problem(label) and label != result["label"]:
        shutil.rmtree(out_dir / "bags" / label, ignore_errors=True)
