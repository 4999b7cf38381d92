"""Taking bags out of a campaign (`okid-ros batch --forget BAG... --out DIR`): a bad run, a test recording.

The tables hold every bag of the journal (runner), so a bag leaves them only when its journal line
goes. A bag is named by its path (the journal's key, resolved as the command's paths are; the bag
itself may be gone), its name (the last part of its path, when one bag of the journal has it) or its
folder under ``DIR/bags`` (the ``outputs`` column of ``summary.csv``). Its folder is kept unless
``--force`` is given: outputs are never lost without it.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from okid_ros.errors import OkidError, shown_path
from okid_ros.tools.campaign.manifest import Manifest
from okid_ros.tools.campaign.stored import label_problem

__all__ = ["forget_entries", "journaled_entries"]

#: Journaled names listed in the refusal of a name the journal does not hold; more are counted.
_MAX_LISTED = 10


def _matches(manifest: Manifest, name: str) -> list[dict]:
    """The journal entries ``name`` names: by path first, else by bag name or output folder."""
    entry = manifest.entries.get(Manifest.key(Path(name)))
    if entry is not None:
        return [entry]
    bare = name.rstrip("/")  # a shell's completion of a bag folder ends in /
    folder = bare.removeprefix("bags/")
    return [e for key, e in manifest.entries.items() if bare == Path(key).name or folder == e.get("label")]


def journaled_entries(manifest: Manifest, names: list[str], out_dir: Path) -> list[dict]:
    """The journal entries of the bags ``names`` (each once, in the order named).

    Raises
    ------
    OkidError
        a name no bag of the journal has (the names it holds, if few), or one that several have.
    """
    chosen: dict[str, dict] = {}
    for name in names:
        matches = _matches(manifest, name)
        if len(matches) > 1:
            raise OkidError(f"--forget {shown_path(name)}: names {len(matches)} bags of the campaign "
                            f"{shown_path(out_dir)} ({', '.join(sorted(shown_path(e['key']) for e in matches))}); "
                            "give the one's path")
        if not matches:
            held = sorted(shown_path(Path(key).name) for key in manifest.entries)
            listed = (f"its journal holds {', '.join(held)}" if len(held) <= _MAX_LISTED
                      else f"its journal holds {len(held)} bags, summary.csv lists them") if held \
                else "its journal holds no bag"
            raise OkidError(f"--forget {shown_path(name)}: no bag of the campaign {shown_path(out_dir)} has that "
                            f"path, name or output folder ({listed})")
        chosen.setdefault(matches[0]["key"], matches[0])
    return list(chosen.values())


def forget_entries(manifest: Manifest, entries: list[dict], out_dir: Path, *, remove: bool) -> None:
    """Drop ``entries`` from the journal (rewritten at once); their folders removed when ``remove``, else kept.

    Says which, one line each.
    """
    for entry in entries:
        manifest.forget(entry["key"])
    manifest.compact()
    folders = [out_dir / "bags" / e["label"] for e in entries if not label_problem(e.get("label"))]
    folders = [folder for folder in folders if folder.is_dir() and not folder.is_symlink()]
    forgotten = ", ".join(shown_path(e["key"]) for e in entries)
    print(f"okid-ros batch: forgot {len(entries)} bag(s) of the campaign: {forgotten}", file=sys.stderr)
    if not folders:
        return
    names = ", ".join(shown_path(folder.name) for folder in folders)
    if remove:
        for folder in folders:
            shutil.rmtree(folder, ignore_errors=True)
        print(f"okid-ros batch: removed their outputs under {shown_path(out_dir / 'bags')} (--force): {names}",
              file=sys.stderr)
    else:
        print(f"okid-ros batch: kept their outputs under {shown_path(out_dir / 'bags')}: {names} "
              "(--force removes them)",
              file=sys.stderr)
