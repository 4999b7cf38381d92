"""Finding the bags of a campaign and planning them without reading a message.

A path given is a bag (a rosbag2 directory, i.e. one holding ``metadata.yaml``; a bare
``.mcap`` or ``.db3`` file; a ROS 1 ``.bag``) or a directory searched recursively for them.
Hidden entries and the campaign's own output directory are not searched, so that a campaign
written inside the folder of its bags never picks up its own output bags; an output bag of
`okid-ros process` found there (another campaign's, its metadata names ``okid_ros.process``)
is left out with a warning.

The plan of a rosbag2 directory comes from its ``metadata.yaml`` alone (the C YAML loader
when available: about 0.3 ms a bag); other bags are opened with the rosbags reader, which
reads the MCAP summary, the sqlite3 index or the ROS 1 index, never the messages.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from okid_ros.errors import OkidError, OkidWarning, one_line, shown_path, special_file_kind

__all__ = ["BAG_SUFFIXES", "BagPlan", "bag_fingerprint", "bag_label", "find_bags", "plan_bag"]

#: Suffixes of single-file bags.
BAG_SUFFIXES = (".mcap", ".db3", ".bag")


@dataclass
class BagPlan:
    """What the metadata says about one bag.

    Attributes
    ----------
    path : the bag as found.
    start_s : stamp of the first message [s since the epoch]; NaN when unknown.
    duration_s : last minus first message stamp [s]; NaN when unknown.
    topics : topic -> message type.
    counts : topic -> message count.
    error : one line when the metadata could not be read ('' otherwise).
    """

    path: Path
    start_s: float = float("nan")
    duration_s: float = float("nan")
    topics: dict[str, str] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    error: str = ""

    def message_count(self, topics: list[str] | None = None) -> int:
        """Messages on ``topics`` (all when None)."""
        return sum(n for t, n in self.counts.items() if topics is None or t in topics)


def _is_rosbag2_dir(path: Path, unreadable: list[Path] | None = None) -> bool:
    """Whether ``path`` is a rosbag2 directory; a folder that cannot be looked into is not (noted in ``unreadable``)."""
    try:
        return path.is_dir() and (path / "metadata.yaml").is_file()
    except OSError:  # no permission to look inside
        if unreadable is not None:
            unreadable.append(path)
        return False


def find_bags(paths: list[str | Path], *, exclude: Path | None = None) -> list[Path]:
    """Every bag given or found under the directories given, each once, in path order.

    Parameters
    ----------
    paths : bags or directories to search.
    exclude : a directory not to search (the campaign's output).

    Raises
    ------
    OkidError
        a path that does not exist, or a file that is not a bag.
    """
    excluded = exclude.resolve() if exclude is not None else None
    found: dict[Path, Path] = {}
    outputs: list[Path] = []
    for given in paths:
        path = Path(given)
        if not path.exists():
            raise OkidError(f"{shown_path(path)}: no such bag or directory")
        if kind := special_file_kind(path):  # was searched as a folder: "cannot be read (no permission?)"
            raise OkidError(f"{shown_path(path)}: not a regular file ({kind}); a bag is a rosbag2 folder or a "
                            "storage file")
        if path.is_file():
            if path.suffix not in BAG_SUFFIXES:
                raise OkidError(f"{shown_path(path)}: not a bag (expected a rosbag2 directory, "
                                f"{', '.join(BAG_SUFFIXES)})")
            found.setdefault(path.resolve(), path)
            continue
        for bag in _search(path, excluded):
            if bag != path and _is_process_output(bag):  # found in a directory, not given
                outputs.append(bag)
            else:
                found.setdefault(bag.resolve(), bag)
    # A rosbag2 directory and its own storage file are one recording: its modes were counted twice.
    inside = sorted(str(found.pop(r)) for r in [r for r in found if r.is_file() and r.parent in found])
    if inside:
        warnings.warn(f"left out {', '.join(inside)}: the storage file of a bag directory given or found too "
                      f"(one recording, processed once)", OkidWarning, stacklevel=2)
    if outputs:
        warnings.warn(f"left out {len(outputs)} output bag(s) of okid-ros process found in the directories "
                      f"(another campaign's? their metadata.yaml names okid_ros.process), the first "
                      f"{min(outputs, key=str)}", OkidWarning, stacklevel=2)
    return sorted(found.values(), key=lambda p: str(p))


def _search(root: Path, excluded: Path | None) -> list[Path]:
    """Bags under ``root`` (a rosbag2 directory counts as one bag, not searched further)."""
    unreadable: list[Path] = []
    if _is_rosbag2_dir(root, unreadable):
        return [root]
    out: list[Path] = []
    for dirpath, dirnames, filenames in os.walk(root, onerror=lambda exc: unreadable.append(Path(exc.filename))):
        here = Path(dirpath)
        keep = []
        for name in sorted(dirnames):
            sub = here / name
            if name.startswith(".") or (excluded is not None and sub.resolve() == excluded):
                continue
            if _is_rosbag2_dir(sub, unreadable):
                out.append(sub)
            elif sub not in unreadable:
                keep.append(name)
        dirnames[:] = keep
        out.extend(here / n for n in sorted(filenames) if n.endswith(BAG_SUFFIXES) and not n.startswith("."))
    if unreadable:
        warnings.warn(f"left out {len(unreadable)} folder(s) under {root} that cannot be read (no permission?), "
                      f"the first {min(unreadable, key=str)}", OkidWarning, stacklevel=3)
    return out


def _is_process_output(path: Path) -> bool:
    """Whether ``path`` is an output bag of `okid-ros process` (a rosbag2 directory whose metadata says so)."""
    from okid_ros.tools.bagio import PROCESS_KEY

    if not _is_rosbag2_dir(path):
        return False
    try:
        custom = _metadata(path).get("custom_data")
    except Exception:  # noqa: BLE001 - unreadable metadata: the bag is planned and fails as such
        return False
    return isinstance(custom, dict) and PROCESS_KEY in custom


def bag_fingerprint(path: Path) -> tuple[int, int]:
    """``(size in bytes, newest modification time in ns)`` of a bag file or directory."""
    if path.is_file():
        st = path.stat()
        return int(st.st_size), int(st.st_mtime_ns)
    size, mtime = 0, int(path.stat().st_mtime_ns)
    for entry in os.scandir(path):
        if entry.is_file():
            st = entry.stat()
            size += int(st.st_size)
            mtime = max(mtime, int(st.st_mtime_ns))
    return size, mtime


def bag_label(path: Path) -> str:
    """Folder name of a bag's outputs: its name and a hash of its absolute path (unique, stable)."""
    digest = hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:10]
    name = path.name[: -len(path.suffix)] if path.suffix in BAG_SUFFIXES else path.name
    return f"{name}-{digest}"


def plan_bag(path: Path) -> BagPlan:
    """The plan of one bag from its metadata (never raises: ``error`` says what went wrong)."""
    try:
        if _is_rosbag2_dir(path):
            return _plan_from_metadata(path)
        return _plan_from_reader(path)
    except Exception as exc:  # noqa: BLE001 - any unreadable metadata is a plan error, reported in one line
        text = one_line(exc) or type(exc).__name__
        return BagPlan(path=path, error=text if shown_path(path) in text else f"{shown_path(path)}: {text}")


def _metadata(path: Path) -> dict:
    """The ``rosbag2_bagfile_information`` of a rosbag2 directory's metadata.yaml (ValueError if none)."""
    import yaml

    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    with open(path / "metadata.yaml", encoding="utf-8") as stream:
        document = yaml.load(stream, Loader=loader)
    info = (document or {}).get("rosbag2_bagfile_information")
    if not isinstance(info, dict):
        raise ValueError("metadata.yaml has no rosbag2_bagfile_information")
    return info


def _stored_integer(value: object, what: str) -> int:
    """A count or time of metadata.yaml as rosbag2 stores it: an integer from 0 to 2**63 - 1 (ValueError if not)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2**63:
        raise ValueError(f"metadata.yaml: {what} is {value!r}, not an integer from 0 to 2**63 - 1 as rosbag2 "
                         "writes it")
    return value


def _plan_from_metadata(path: Path) -> BagPlan:
    info = _metadata(path)
    plan = BagPlan(path=path)
    for entry in info.get("topics_with_message_count") or []:
        meta = entry["topic_metadata"]
        name, known = str(meta["name"]), plan.topics.get(str(meta["name"]))  # a topic stored with two types: both
        plan.topics[name] = str(meta["type"]) if known in (None, str(meta["type"])) else f"{known} and {meta['type']}"
        count = _stored_integer(entry["message_count"], f"the message_count of {name}")
        plan.counts[name] = plan.counts.get(name, 0) + count
    if plan.message_count() > 0:
        plan.start_s = _stored_integer(info["starting_time"]["nanoseconds_since_epoch"], "starting_time") * 1e-9
        plan.duration_s = _stored_integer(info["duration"]["nanoseconds"], "duration") * 1e-9
    return plan


def _plan_from_reader(path: Path) -> BagPlan:
    from okid_ros.tools.bagio import open_bag

    with open_bag(path) as bag:
        plan = BagPlan(path=path, topics=dict(bag.topics))
        for topic in bag.topics:
            plan.counts[topic] = bag.message_count([topic])
        if plan.message_count() > 0:
            plan.start_s = bag.start_ns * 1e-9
            plan.duration_s = bag.duration_s
    return plan
