"""Expected failures: raised by commands, printed by the CLI as one line without a traceback.

Also :func:`write_atomically`, so that a command failing half-way leaves no half-written output.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO

_PART_NUMBERS = itertools.count()


class OkidError(Exception):
    """A failure the user can fix (bad input, bad option); `okid-ros` exits with status 2."""


class DataError(OkidError):
    """Input data is missing, unreadable or inconsistent (files, bags, topics, array sizes)."""


class OutputError(DataError):
    """An output cannot be written or may not be replaced; the message names the output."""


class ParameterError(OkidError):
    """A parameter or option value is invalid; the message names it and its valid range."""


class OkidWarning(UserWarning):
    """A problem the work goes on with (a parameter file's unknown name); `okid-ros` prints it as one line."""


def write_atomically(path: str | os.PathLike, write: Callable[[IO[bytes]], object]) -> None:
    """Call ``write(stream)`` on a temporary file beside ``path``, then rename it to ``path``.

    On any failure the temporary file is removed and ``path`` is left as it was: readers never
    see a truncated output, and a failed command leaves nothing half-written behind. A device,
    FIFO or socket (``/dev/null``, ``/dev/stdout``) is written into instead: a rename would put a
    regular file in its place. See :func:`replacing`.
    """
    with replacing(path) as stream:
        write(stream)


@contextlib.contextmanager
def replacing(path: str | os.PathLike) -> Iterator[IO[bytes]]:
    """A binary stream whose bytes replace ``path`` when the block ends without an exception.

    The one rule for a file output, written at once (:func:`write_atomically`) or as it comes
    (``track``'s JSON lines): a temporary file beside ``path`` renamed over it at the end. The
    rename replaces the name only: a symlink at ``path`` goes, never what it points to, and a hard
    link's other names (the record itself) keep their content. An exception (Ctrl-C too) removes
    the temporary file and leaves ``path`` as it was. A device, FIFO or socket is written into.

    Not :class:`okid_ros.tools.output_paths.StagedOutput` (a bag's or ``process``'s outputs), for
    a reason: a file is replaced by one atomic rename and never seen half-written, on a new path
    too (a reader of the JSON model finds it whole or not at all); a folder cannot be renamed over
    another, so StagedOutput moves the old one aside and writes a new path in place.
    """
    target = Path(path)
    if is_special_file(target):
        with open(target, "wb") as stream:
            yield stream
        return
    # open(..., "x") rather than mkstemp: the file gets the usual permissions (umask), not 0600.
    temporary = name_beside(target, f"{os.getpid()}.{next(_PART_NUMBERS)}.part")
    try:
        with open(temporary, "xb") as stream:
            yield stream
        os.replace(temporary, target)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def name_beside(path: Path, tag: str) -> Path:
    """The hidden name ``.NAME.TAG`` beside ``path``, where an output is written before it replaces ``path``.

    NAME is cut to 200 bytes: a legal name of 255 made the temporary one too long to create.
    """
    return path.with_name(f".{os.fsdecode(os.fsencode(path.name)[:200])}.{tag}")


def is_special_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` is written into, never replaced: a device, FIFO or socket (through links).

    Also a link in /dev or /proc (``/dev/stdout``, ``/proc/self/fd/1``): redirected to a file, it
    resolves to a regular one, but a rename would replace the link. A file in /dev/shm is a file.
    """
    if os.path.abspath(path).startswith(("/dev/", "/proc/")) and os.path.islink(path):
        return True
    return special_file_kind(path) is not None


def special_file_kind(path: str | os.PathLike, *, pipe: bool = False) -> str | None:
    """What ``path`` is (through links) when neither a regular file nor a folder: "a FIFO", "a socket", ...

    None for a file, a folder, or a path that cannot be looked at (the reader says why). An input
    that is one is refused before it is opened: opening a FIFO waits for a writer, for ever.
    ``pipe``: None too for a pipe the shell opened for this process (``--reference <(cmd)``:
    ``/dev/fd/63``), whose writer is running: reading it ends when the writer does.
    """
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    with contextlib.suppress(OSError, ValueError):
        if pipe and stat.S_ISFIFO(mode) and os.readlink(path).startswith("pipe:"):
            return None
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "a device"


def one_line(text: object) -> str:
    """``text`` as one line, its line breaks and runs of blanks one space, other unprintable characters escaped.

    An OS error's message may hold line breaks; a message naming a path not given through
    :func:`shown_path` may hold ESC or another control character, written as Python's repr escapes it.
    """
    collapsed = " ".join(str(text).split())
    return collapsed if collapsed.isprintable() else "".join(_escaped(char) for char in collapsed)


def os_reason(exc: BaseException) -> str:
    """What went wrong, without the path an OSError's text repeats (``[Errno 30] ...: 'out/x'``), on one line.

    The message names the path itself, through :func:`shown_path`; another exception is its text.
    """
    return (exc.strerror if isinstance(exc, OSError) and exc.strerror else None) or one_line(exc)


def shown_path(path: str | bytes | os.PathLike) -> str:
    """``path`` or a topic name as a message shows it: as given, or its repr when it holds an unprintable character.

    A line break, tab, ESC, another C0/C1 control character or an undecodable byte (a surrogate)
    was written raw: a message of two lines, a terminal's colours changed, or no message at all
    (a surrogate on a strict UTF-8 stdout: UnicodeEncodeError). Quoted and escaped it is one
    readable line, told apart from a name holding a backslash; an ordinary name is unchanged.
    """
    text = os.fsdecode(path)
    return text if text.isprintable() else repr(text)


def _escaped(char: str) -> str:
    return char if char.isprintable() else repr(char)[1:-1]


@contextlib.contextmanager
def writing(path: str | os.PathLike, kind: str) -> Iterator[None]:
    """An OSError while writing ``path`` (a full disk, a device that refuses) as the one-line OutputError."""
    try:
        yield
    except OSError as exc:
        raise OutputError(f"{shown_path(path)}: cannot write the {kind} ({exc.strerror or exc})") from None
