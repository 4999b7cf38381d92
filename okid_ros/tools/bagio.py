"""Bag input and output on the `rosbags` library: any rosbag2 in, new rosbag2 out, no ROS needed.

Reading (:class:`BagReader`, :func:`open_bag`) goes through rosbags' ``AnyReader``: rosbag2 directories with sqlite3
or MCAP storage (also a bare ``.mcap`` / ``.db3`` file, the only storage file of a bag directory read as that
directory, with its metadata, and a directory named ``*.bag``) and ROS 1 bags, deserialized with the definitions
stored in the bag (bags without definitions fall back to :func:`okid_typestore`). Every failure of the third-party
readers, up to a corrupt file in the middle of the messages, becomes a one-line :class:`BagReadError` naming the
path. A recording that was not closed (an MCAP file cut off, or without its ``metadata.yaml``) is read as far as it
is whole, with a warning (:mod:`okid_ros.tools.mcap_salvage`). Messages are counted as the storage holds them
(:mod:`okid_ros.tools.bag_counts`).

Writing (:class:`BagWriter`) creates a rosbag2 of format version 9 (Jazzy) with the message definitions embedded, so
any reader can decode it, and refuses an existing path unless ``force`` is given (then it only removes what is
recognizably a bag, see :func:`prepare_output`). Messages are built with the typestore's classes (the nodes'
:mod:`okid_ros.nodes.conversions` accepts them) and serialized by rosbags, not by
``rclpy.serialization.serialize_message``: rmw_fastrtps sizes that buffer by an upper-bound estimate and does not
clear it, so for messages with empty arrays (an invalid ArxModel: 132 bytes for 124 bytes of CDR) the bytes end in
uninitialized memory, which strict CDR readers (rosbags' own ``deserialize_cdr`` among them) reject as a size
mismatch. Bytes taken from the wire (an rclpy subscription with ``raw=True``) have their exact size and are written
as they are (:meth:`BagWriter.write_raw`).

Custom data: rosbag2 metadata (version >= 6) has a ``custom_data`` map of strings; the tools store JSON documents
there under keys starting with ``okid_ros.`` (the simulated truth: :data:`TRUTH_KEY`).
"""

from __future__ import annotations

import functools
import os
import shutil
import sys
import warnings
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

from okid_ros.errors import OkidWarning, one_line, os_reason, shown_path, special_file_kind
from okid_ros.tools import mcap_salvage
from okid_ros.tools.bag_counts import stored_connections
from okid_ros.tools.errors import BagReadError, BagWriteError
from okid_ros.tools.interrupts import deferred
from okid_ros.tools.output_paths import bag_folder, prepare_output

__all__ = [
    "OKID_MSGS_PACKAGE",
    "STORAGES",
    "TRUTH_KEY",
    "BagReader",
    "BagWriter",
    "StoredMessage",
    "message_definition_dir",
    "okid_typestore",
    "open_bag",
]

OKID_MSGS_PACKAGE = "okid_msgs"
#: Storage plugins of the writer, as named by rosbag2 (`ros2 bag record -s ...`).
STORAGES = ("mcap", "sqlite3")
#: custom_data key of the simulated truth (JSON, see okid_ros.tools.simulate_bag).
TRUTH_KEY = "okid_ros.truth"
#: custom_data key under which `process` records its source bag and parameters (JSON).
PROCESS_KEY = "okid_ros.process"
#: custom_data key under which `process` records the last model's stabilization data (JSON list).
STABILIZATION_KEY = "okid_ros.stabilization"

_REPO_MSG_DIR = Path(__file__).resolve().parents[2] / "msg_defs" / "msg"


def message_definition_dir() -> Path:
    """Directory with the okid_msgs ``.msg`` files.

    The installed interface package comes first (``share/okid_msgs/msg`` under each prefix of
    ``AMENT_PREFIX_PATH`` and under this interpreter's prefix), since its definitions are the
    ones the rclpy classes were generated from; the repository's ``msg_defs/msg`` is the
    fallback for a source checkout without a build.

    Raises
    ------
    BagReadError
        no definitions anywhere.
    """
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    for prefix in prefixes:
        candidate = Path(prefix) / "share" / OKID_MSGS_PACKAGE / "msg"
        if any(candidate.glob("*.msg")):
            return candidate
    if any(_REPO_MSG_DIR.glob("*.msg")):
        return _REPO_MSG_DIR
    raise BagReadError(f"no okid_msgs message definitions found (looked in share/{OKID_MSGS_PACKAGE}/msg of "
                       f"AMENT_PREFIX_PATH and {sys.prefix}, and in {_REPO_MSG_DIR})")


@functools.lru_cache(maxsize=1)
def okid_typestore() -> Any:
    """The ROS 2 Jazzy typestore of rosbags with okid_msgs registered (cached)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for path in sorted(message_definition_dir().glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{OKID_MSGS_PACKAGE}/msg/{path.stem}"))
    store.register(types)
    return store


def msgtype_name(msgtype: str) -> str:
    """``pkg/msg/Name`` for ``pkg/Name`` or ``pkg/msg/Name`` (ROS 1 style names too)."""
    parts = msgtype.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return msgtype


# reading ------------------------------------------------------------------------------------


class BagReader:
    """An open bag: topics, types, metadata and deserialized messages in log-time order.

    Use :func:`open_bag`. ``topics`` maps each topic to its message type (``pkg/msg/Name``).
    """

    def __init__(self, path: Path, reader: Any, read_note: str = "") -> None:
        self.path = path
        self._reader = reader
        #: How the bag was read when not as a whole (a cut-off recording, its MCAP file alone).
        self.read_note = read_note
        self.topics: dict[str, str] = {}
        self._read_type: dict[str, str] = {}  # a topic stored with several types: the one read (require_topic)
        for connection in reader.connections:
            self.topics.setdefault(connection.topic, msgtype_name(connection.msgtype))

    def _connections(self, topics: Iterable[str] | None, connections: Iterable | None = None) -> list:
        """The bag's connections (or of ``connections``) on ``topics`` (all when None), of the type read."""
        wanted = None if topics is None else set(topics)
        return [c for c in (self._reader.connections if connections is None else connections)
                if (wanted is None or c.topic in wanted)
                and self._read_type.get(c.topic, msgtype_name(c.msgtype)) == msgtype_name(c.msgtype)]

    @property
    def start_ns(self) -> int:
        return int(self._reader.start_time) if self._reader.message_count else 0

    @property
    def end_ns(self) -> int:
        return int(self._reader.end_time) if self._reader.message_count else 0

    @property
    def duration_s(self) -> float:
        return max(0, self.end_ns - self.start_ns) * 1e-9

    def message_count(self, topics: Iterable[str] | None = None, *, as_metadata: bool = False) -> int:
        """Messages stored on ``topics`` (all when None); ``as_metadata``: as metadata.yaml says (maybe spoilt)."""
        stored = None if as_metadata else stored_connections(self._reader)
        return sum(c.msgcount for c in self._connections(topics, stored))

    @property
    def custom_data(self) -> dict[str, str]:
        """rosbag2 ``custom_data`` of the metadata (empty for bags without it)."""
        data: dict[str, str] = {}
        for sub in getattr(self._reader, "readers", []):
            metadata = getattr(getattr(sub, "storage", None), "metadata", None)
            custom = getattr(metadata, "custom", None)
            if custom:
                data.update(custom)
        return data

    def custom_json(self, key: str) -> dict | None:
        """The JSON document stored under ``key`` in custom_data, or None."""
        import json

        from okid_ros.jsonio import NOT_JSON

        text = self.custom_data.get(key)
        if text is None:
            return None
        try:
            return json.loads(text)
        except NOT_JSON as exc:
            raise BagReadError(f"{shown_path(self.path)}: custom_data {key!r} is not valid JSON "
                               f"({one_line(exc)})") from None

    def require_topic(self, topic: str, msgtypes: Sequence[str]) -> str:
        """Check that ``topic`` exists with one of ``msgtypes``; return its type.

        Raises
        ------
        BagReadError
            the topic is missing or has another type.
        """
        if topic not in self.topics:
            have = ", ".join(f"{shown_path(t)} ({shown_path(m)})" for t, m in sorted(self.topics.items())) or "none"
            raise BagReadError(f"{shown_path(self.path)}: no topic {shown_path(topic)}; the bag has: {have}")
        counts = Counter()  # message type -> messages on the topic
        for c in (c for c in self._reader.connections if c.topic == topic):
            counts[msgtype_name(c.msgtype)] += c.msgcount
        expected = [msgtype_name(m) for m in msgtypes]
        msgtype = next((t for t in counts if t in expected), self.topics[topic])
        if msgtype not in expected:
            raise BagReadError(f"{shown_path(self.path)}: topic {shown_path(topic)} has type "
                               f"{' and '.join(map(shown_path, counts))}, expected {' or '.join(expected)}")
        if len(counts) > 1:  # as live: a subscription of one type receives no message of another
            self._read_type[topic] = msgtype
            others = ", ".join(f"{n} {shown_path(t)}" for t, n in counts.items() if t != msgtype)
            warnings.warn(f"{shown_path(self.path)}: topic {shown_path(topic)} carries {msgtype} and {others} "
                          f"message(s): those passed over, as a node subscribed with {msgtype} receives none",
                          OkidWarning, stacklevel=2)
        return msgtype

    def _stored(self, topics: Iterable[str] | None) -> Iterator[tuple[Any, int, bytes]]:
        """``(connection, log_time_ns, bytes as stored)`` in log-time order, errors as BagReadError."""
        connections = self._connections(topics)
        if not connections:
            return
        try:
            for connection, stamp_ns, raw in self._reader.messages(connections=connections):
                yield connection, int(stamp_ns), raw
        except BagReadError:
            raise
        except Exception as exc:  # corrupt chunk, truncated file, bad compression ...
            raise BagReadError(f"{shown_path(self.path)}: cannot read messages "
                               f"({type(exc).__name__}: {one_line(exc)})") from None

    def _decode(self, connection: Any, stamp_ns: int, raw: bytes) -> Any:
        try:
            return self._reader.deserialize(raw, connection.msgtype)
        except Exception as exc:
            raise BagReadError(f"{shown_path(self.path)}: cannot decode a {connection.msgtype} message on "
                               f"{shown_path(connection.topic)} at {stamp_ns} ns ({one_line(exc)})") from None

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
        """Yield ``(topic, msgtype, log_time_ns, cdr_bytes)`` in log-time order.

        Messages of ROS 1 bags are decoded and serialized again as CDR, so the bytes are always
        what a ROS 2 subscriber expects.
        """
        ros1 = not getattr(self._reader, "is2", True)
        for connection, stamp_ns, raw in self._stored(topics):
            if ros1:
                msg = self._decode(connection, stamp_ns, raw)
                raw = bytes(self._reader.typestore.serialize_cdr(msg, connection.msgtype))
            yield connection.topic, msgtype_name(connection.msgtype), stamp_ns, raw

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, Any]]:
        """Yield ``(topic, log_time_ns, message)``, messages deserialized by rosbags."""
        for connection, stamp_ns, raw in self._stored(topics):
            yield connection.topic, stamp_ns, self._decode(connection, stamp_ns, raw)

    def stored_messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, StoredMessage]]:
        """Yield ``(topic, log_time_ns, StoredMessage)``: the bytes, deserialized by rosbags only if asked."""
        ros1 = not getattr(self._reader, "is2", True)
        for connection, stamp_ns, raw in self._stored(topics):
            yield connection.topic, stamp_ns, StoredMessage(b"" if ros1 else raw,
                                                            functools.partial(self._decode, connection, stamp_ns, raw))


class StoredMessage:
    """One message of a bag: its CDR bytes (empty for a ROS 1 bag's) and its object, decoded on first use.

    Readers of a few fields take them from the bytes (:class:`okid_ros.nodes.raw_inputs.RawSourceReader`)
    and ask for :attr:`message` (rosbags' object; a BagReadError if it cannot be decoded) otherwise.
    """

    __slots__ = ("raw", "_decode", "_message")

    def __init__(self, raw: bytes, decode: Callable[[], Any]) -> None:
        self.raw, self._decode, self._message = raw, decode, None

    @property
    def message(self) -> Any:
        if self._message is None:
            self._message = self._decode()
        return self._message


def _open_reader(paths: Path | list[Path]) -> Any:
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Reader as Rosbag2Reader

    paths = paths if isinstance(paths, list) else [paths]
    reader = AnyReader(paths, default_typestore=okid_typestore())
    if not reader.is2 and all(p.is_dir() for p in paths):
        # AnyReader takes any *.bag for ROS 1 by its suffix; a directory is a rosbag2 bag whatever
        # its name (`simulate --out run.bag`). Its ROS 1 readers only hold the path until open().
        reader.is2, reader.readers = True, [Rosbag2Reader(p) for p in paths]
    reader.open()
    return reader


def _try_open_reader(paths: Path | list[Path]) -> Any:
    try:
        return _open_reader(paths)
    except Exception:  # noqa: BLE001 - the caller reports the first failure
        return None


class _OpenBag:
    """Context manager behind :func:`open_bag`."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._reader: Any = None
        self._scratch: Path | None = None

    def __enter__(self) -> BagReader:
        path = self.path
        try:
            found = path.exists()
        except OSError as exc:  # a name too long, a folder we may not enter ...
            raise BagReadError(f"{shown_path(path)}: cannot open the bag ({one_line(exc.strerror or exc)})") from None
        if not found:
            raise BagReadError(f"{shown_path(path)}: no such bag")
        _refuse_special_files(path)
        note = ""
        try:
            self._reader = _open_reader(_whole_bag_of(path))
        except Exception as exc:  # the readers raise many kinds; all mean "not a usable bag"
            try:
                self._reader, note, self._scratch = mcap_salvage.read_unclosed(path, _try_open_reader)
            except OSError:  # a data file that cannot be read at all (a folder, no permission): the reader's error
                self._reader = None
            if self._reader is None:
                raise BagReadError(f"{shown_path(path)}: not a readable rosbag2 or ROS 1 bag "
                                   f"({type(exc).__name__}: {one_line(exc)})") from None
            warnings.warn(note, OkidWarning, stacklevel=2)
        return BagReader(path, self._reader, note)

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._reader is not None:
            try:
                self._reader.close()
            except Exception:  # noqa: BLE001 - closing a broken bag must not hide the first error
                pass
            self._reader = None
        if self._scratch is not None:
            shutil.rmtree(self._scratch, ignore_errors=True)
            self._scratch = None


def _whole_bag_of(path: Path) -> Path:
    """What to open for ``path``: its rosbag2 folder when it is that bag's only storage file, else ``path``.

    A storage file read alone has no ``metadata.yaml``: its custom data (a simulation's truth, the
    run `process` recorded, the stabilization data) was lost to `plot BAG/BAG.mcap` and the others.
    The folder holds the same messages and its metadata. A file of a split recording is read alone,
    with a warning naming what is left out.
    """
    folder = bag_folder(path)
    if folder == path:
        return path
    try:
        import yaml

        info = yaml.safe_load((folder / "metadata.yaml").read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        files = [Path(name).name for name in info["relative_file_paths"]]
    except Exception:  # noqa: BLE001 - an unreadable metadata.yaml: the file alone, as before
        return path
    if files == [path.name]:
        return folder
    if path.name in files:
        warnings.warn(f"{shown_path(path)}: one of the {len(files)} storage files of the bag {shown_path(folder)}, "
                      f"read alone: the bag's metadata.yaml (a simulation's truth, the run process recorded) is not "
                      f"read; give {shown_path(folder)} for the whole bag", OkidWarning, stacklevel=3)
    return path


def _refuse_special_files(path: Path) -> None:
    """BagReadError for a bag that is, or whose folder holds, a FIFO, socket or device: its reader waits for ever."""
    kind = special_file_kind(path)
    if kind:
        raise BagReadError(f"{shown_path(path)}: not a regular file ({kind}); a bag is a rosbag2 folder or a "
                           "storage file")
    try:
        entries = sorted(path.iterdir()) if path.is_dir() else []
    except OSError:  # a folder that cannot be listed: the reader says why
        entries = []
    for entry in entries:
        if kind := special_file_kind(entry):
            raise BagReadError(f"{shown_path(path)}: {entry.name} in the bag is not a regular file ({kind})")


def open_bag(path: str | os.PathLike) -> _OpenBag:
    """Open a bag for reading: ``with open_bag(path) as bag: ...``.

    Parameters
    ----------
    path : rosbag2 directory, ``.mcap`` or ``.db3`` file, or ROS 1 ``.bag``.

    Raises
    ------
    BagReadError
        missing path or unreadable bag (one line, names the path).
    """
    return _OpenBag(Path(path))


# writing ------------------------------------------------------------------------------------


class BagWriter:
    """A new rosbag2 (format version 9), used as a context manager.

    Parameters
    ----------
    path : the bag directory to create.
    storage : "mcap" (default, `ros2 bag record`'s default since Iron) or "sqlite3".
    force : replace an existing bag (see :func:`prepare_output`).

    Raises
    ------
    OutputExistsError
        ``path`` exists and ``force`` is false.
    BagWriteError
        the bag cannot be created or written.

    Example::

        with BagWriter("out/run1") as bag:
            bag.add_topic("/okid/io_sample", "okid_msgs/msg/IoSample")
            bag.write("/okid/io_sample", stamp_ns, msg)   # a typestore message
    """

    def __init__(self, path: str | os.PathLike, storage: str = "mcap", force: bool = False) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        if storage not in STORAGES:
            raise BagWriteError(f"storage must be one of {', '.join(STORAGES)}, got {storage!r}")
        self.path = prepare_output(path, force)
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self.typestore = okid_typestore()
        self._writer = Writer(self.path, version=9, storage_plugin=plugin)
        self._connections: dict[str, tuple[Any, str]] = {}
        self.counts: dict[str, int] = {}
        self._open = False

    def __enter__(self) -> BagWriter:
        try:
            self._writer.open()
        except Exception as exc:
            raise BagWriteError(f"{shown_path(self.path)}: cannot create the bag ({os_reason(exc)})") from None
        self._open = True
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        """Write the metadata and close (also after an error: what was written stays readable)."""
        if self._open:
            self._open = False
            try:
                self._writer.close()
            except Exception as exc:
                raise BagWriteError(f"{shown_path(self.path)}: cannot finish the bag ({one_line(exc)})") from None

    def set_custom_data(self, key: str, value: str) -> None:
        """Store a string in the metadata's ``custom_data``."""
        self._writer.set_custom_data(key, value)

    def add_topic(self, topic: str, msgtype: str) -> None:
        """Add a topic of ``msgtype`` (``pkg/msg/Name``; must be known to the typestore)."""
        msgtype = msgtype_name(msgtype)
        if msgtype not in self.typestore.types:
            raise BagWriteError(f"{shown_path(self.path)}: unknown message type {msgtype} for {topic}")
        connection = self._writer.add_connection(topic, msgtype, typestore=self.typestore)
        self._connections[topic] = (connection, msgtype)
        self.counts[topic] = 0

    def write(self, topic: str, stamp_ns: int, msg: Any) -> None:
        """Write a typestore message (see :meth:`msg_class`) on ``topic`` at log time ``stamp_ns``."""
        connection, msgtype = self._connections[topic]
        try:
            raw = self.typestore.serialize_cdr(msg, msgtype)
            with deferred():  # a record is written whole: Ctrl-C or SIGTERM right after it
                self._writer.write(connection, int(stamp_ns), raw)
        except Exception as exc:
            raise BagWriteError(f"{shown_path(self.path)}: cannot write {msgtype} on {shown_path(topic)} "
                                f"({one_line(exc)})") from None
        self.counts[topic] += 1

    def write_raw(self, topic: str, stamp_ns: int, data: bytes) -> None:
        """Write already serialized CDR bytes (e.g. from an rclpy ``raw=True`` subscription)."""
        connection, msgtype = self._connections[topic]
        try:
            with deferred():
                self._writer.write(connection, int(stamp_ns), data)
        except Exception as exc:
            raise BagWriteError(f"{shown_path(self.path)}: cannot write {msgtype} on {shown_path(topic)} "
                                f"({one_line(exc)})") from None
        self.counts[topic] += 1

    def msg_class(self, msgtype: str) -> type:
        """The typestore dataclass of ``msgtype``."""
        return self.typestore.types[msgtype_name(msgtype)]
