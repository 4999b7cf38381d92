"""Where a command may write.

Never over its input, never two outputs on one path, nothing replaced without ``--force`` and
nothing but an output even with it.

Paths are compared resolved (symlinks, ``..``); an input file inside a rosbag2 directory
(``run/run_0.mcap``) counts as that directory, whose metadata.yaml belongs to it.
:func:`check_output_paths` runs in ``identify``, ``track`` and ``process`` before any work,
whatever ``--force`` says; :func:`prepare_output` before each output is written that replaces
an old one by removing it first (a bag), :func:`prepare_file_outputs` before the work for a file
renamed over the old one (``identify``'s and ``track``'s outputs). ``process``'s bag and JSON
lines replace existing ones only once complete (:class:`StagedOutput`: written beside, renamed
over at the end, kept when interrupted): ``--force`` never costs the previous output for a run
that fails. The missing parent folders of an output are made before the work (a folder that
cannot be made is said at once), and a command that fails removes again those still empty
(:func:`made_folders_removed_on_failure`, around every command in ``cli.run_command``).
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator, Sequence
from pathlib import Path

from okid_ros.errors import OutputError, is_special_file, name_beside, one_line, shown_path, special_file_kind
from okid_ros.tools.errors import BagWriteError, OutputExistsError

__all__ = ["StagedOutput", "bag_folder", "check_file_name", "check_file_outputs", "check_folder_option",
           "check_output_paths", "check_replaceable", "made_folders_removed_on_failure", "prepare_file_outputs",
           "prepare_output", "output_exists"]

#: Files a rosbag2 directory may hold; --force removes nothing else.
_BAG_SUFFIXES = {".db3", ".mcap", ".yaml", ".zstd", ".db3-shm", ".db3-wal"}
#: The folders :func:`_make_folder` made within :func:`made_folders_removed_on_failure` (None outside it).
#: A context variable: a command run in another thread keeps its own.
_MADE_FOLDERS: contextvars.ContextVar[list[Path] | None] = contextvars.ContextVar("made_folders", default=None)


def check_output_paths(input_path: str | Path, input_kind: str, outputs: Sequence[tuple[str | Path, str]]) -> None:
    """OutputError for an output that is, holds or lies in the input, or that overlaps an earlier output.

    Parameters
    ----------
    input_path : the record or bag read; input_kind : what it is, for the message ("input bag").
    outputs : ``(path, kind)`` of every output the command will write, in the order given.
    """
    data, root = _input_root(Path(input_path))
    where = f"the {input_kind} {shown_path(input_path)}"
    where += f" (its directory {shown_path(root)})" if root != data else ""
    resolved = [(Path(path), kind, _resolved(Path(path))) for path, kind in outputs]
    for path, kind, real in resolved:
        relation = _relation(real, root)
        if relation:
            raise OutputError(f"{shown_path(path)}: the {kind} cannot {relation} {where}, not even with --force")
    for i, (path, kind, real) in enumerate(resolved):
        for earlier, earlier_kind, earlier_real in resolved[:i]:
            relation = _relation(real, earlier_real)
            if relation and not (is_special_file(path) and is_special_file(earlier)):  # /dev/null twice
                raise OutputError(f"{shown_path(path)}: the {kind} cannot {relation} the {earlier_kind} "
                                  f"{shown_path(earlier)} (one would replace the other)")


def _relation(path: Path, other: Path) -> str | None:
    """How resolved ``path`` overlaps resolved ``other``: "be", "contain", "be inside", or None."""
    if path == other:
        return "be"
    if other.is_relative_to(path):
        return "contain"
    if path.is_relative_to(other):
        return "be inside"
    return None


def _resolved(path: Path) -> Path:
    try:
        return path.resolve()
    except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop (Python < 3.13)
        raise OutputError(f"{shown_path(path)}: cannot resolve the path ({one_line(exc)})") from None


def _input_root(path: Path) -> tuple[Path, Path]:
    """The resolved input, and what of it outputs must keep clear of (its rosbag2 directory for a file in one)."""
    data = _resolved(path)
    return data, bag_folder(data)


def bag_folder(path: Path) -> Path:
    """The rosbag2 directory of a storage file in one (``run/run.mcap`` -> ``run``), else ``path``."""
    try:
        in_bag_dir = path.suffix in _BAG_SUFFIXES and path.is_file() and (path.parent / "metadata.yaml").is_file()
    except OSError:  # unreadable: the reader says why later
        in_bag_dir = False
    return path.parent if in_bag_dir else path


def _is_bag_directory(path: Path) -> bool:
    entries = list(path.iterdir())
    return (path / "metadata.yaml").is_file() and all(
        e.is_file() and (e.suffix in _BAG_SUFFIXES or "".join(e.suffixes[-2:]) in {".db3.zstd", ".mcap.zstd"})
        for e in entries
    )


def prepare_output(path: str | os.PathLike, force: bool, kind: str = "bag") -> Path:
    """Make sure ``path`` can be created: refuse an existing one unless ``force``.

    With ``force`` an existing file is removed, and an existing directory only if it is a
    rosbag2 directory (``metadata.yaml`` and storage files, nothing else) or empty; anything
    else is refused even with ``force``, so a typo cannot delete other work (for a bag, no file
    either). A device or FIFO (``/dev/null``) is left for the writer to write into.

    Parameters
    ----------
    path : output path.
    force : allow replacing an existing output.
    kind : what the output is, for the message ("bag", "JSON lines file", ...).

    Returns
    -------
        The path.

    Raises
    ------
    OutputExistsError
        it exists and may not be replaced.
    BagWriteError
        the path cannot be checked or replaced, or its parent folder cannot be created.
    """
    out = Path(path)
    if check_replaceable(out, force=force, kind=kind):
        try:
            if out.is_dir() and not out.is_symlink():
                shutil.rmtree(out)
            else:
                out.unlink()
        except OSError as exc:
            raise BagWriteError(f"{shown_path(out)}: cannot replace the {kind} "
                                f"({one_line(exc.strerror or exc)})") from None
    _make_folder(out.parent, out)
    return out


def prepare_file_outputs(outputs: Sequence[tuple[str | os.PathLike, str]], *, force: bool) -> None:
    """Check before the work that file outputs may be written, then create their parent folders.

    Each file is written later by :func:`okid_ros.errors.replacing` (a temporary file renamed over
    the old one), so ``force`` removes nothing here: a failed or interrupted run leaves the old
    output as it was, and a symlink there is replaced, never what it points to. Refused, with or
    without ``force``: a name that ends as a folder's (``out/``, ``out/.``: a file named like the
    folder was written) and an existing folder. Every output is checked before any folder is
    made; the parent folders are made with ``force`` too (a rerun with it was refused where the
    first run succeeded), and removed again if the command fails while they are empty
    (:func:`made_folders_removed_on_failure`). Each folder must then take a new file: one that
    refuses it fails here, before the work and before any output is written.

    Parameters
    ----------
    outputs : ``(path, kind)`` of each file: the path as given (a str keeps its trailing ``/``), what
        it is for the messages ("JSON model", "JSON lines file", ...).
    force : allow replacing an existing file.

    Raises
    ------
    OutputError
        a folder's name or a folder; a folder that takes no new file.
    OutputExistsError, BagWriteError
        as :func:`prepare_output`.
    """
    check_file_outputs(outputs, force=force)
    for path, kind in outputs:
        _make_folder(Path(path).parent, Path(path))
        _check_folder_takes_files(Path(path), kind)


def check_file_outputs(outputs: Sequence[tuple[str | os.PathLike, str]], *, force: bool) -> None:
    """Check, making nothing, what :func:`prepare_file_outputs` checks before it makes the folders.

    For a command that reads a long input before it may make anything (``identify``: an option's
    error leaves no folder): a name of a folder, an output not to be replaced, a file where a folder
    must be, or a nearest existing folder this user may not write in, each refused before the read.
    The nameless temporary file of :func:`prepare_file_outputs` still tries each folder once made
    (a pseudo file system, a quota, root's writes that a mode does not stop).

    Raises
    ------
    OutputError, OutputExistsError, BagWriteError : as :func:`prepare_file_outputs`.
    """
    for path, kind in outputs:
        check_file_name(path, kind)
        check_replaceable(Path(path), force=force, kind=kind)
        _check_writable_folder(Path(path), kind)


def _check_writable_folder(out: Path, kind: str) -> None:
    """BagWriteError when the nearest existing folder above ``out`` is no folder, or not one this user may write in."""
    if is_special_file(out):  # a device is written into
        return
    if found := _non_folder(out.parent):
        raise BagWriteError(f"{shown_path(out)}: {shown_path(found[0])} is {found[1]}, not a folder")
    folder = next((part for part in out.parents if _is_dir(part)), None)
    if folder is None or os.access(folder, os.W_OK | os.X_OK):
        return
    made = "" if folder == out.parent else f"its folder {shown_path(out.parent)} cannot be made: "
    raise BagWriteError(f"{shown_path(out)}: {made}cannot write the {kind} in the folder {shown_path(folder)} "
                        "(not writable by this user)")


def _check_folder_takes_files(out: Path, kind: str) -> None:
    """OutputError unless a new file can be made beside ``out``, as its temporary file will be.

    A folder that refuses new files (``/proc``, read-only) was found only when the output was
    written, after the work and after the outputs written before it. A device is written into.
    """
    if is_special_file(out):
        return
    try:
        with tempfile.TemporaryFile(dir=out.parent):  # no name left behind, whatever happens
            pass
    except OSError as exc:
        raise OutputError(f"{shown_path(out)}: cannot write the {kind} in the folder {shown_path(out.parent)} "
                          f"({one_line(exc.strerror or exc)})") from None


def check_file_name(path: str | os.PathLike, kind: str) -> None:
    """Refuse a file output named as a folder (``out/``, ``out/.``) or an existing folder: OutputError.

    ``path`` as given: a str keeps its trailing ``/``, which ``Path`` drops (a file named like the
    folder was written).
    """
    text, out = os.fspath(path), Path(path)
    if os.path.basename(text) in ("", ".", ".."):
        raise OutputError(f"{shown_path(text)}: names a folder; the {kind} is a file: give a file name")
    if _is_dir(out):  # found only after the work otherwise (IsADirectoryError)
        raise OutputError(f"{shown_path(out)}: a folder; the {kind} is a file: give a file name")


def check_replaceable(path: str | os.PathLike, *, force: bool, kind: str = "bag") -> bool:
    """Whether ``path`` holds something :func:`prepare_output` will remove; raises where it may not.

    Removes nothing: a command checks every output with it before it replaces any (``--force``
    never costs one output for another's refusal).

    Raises
    ------
    OutputExistsError, BagWriteError : as :func:`prepare_output`.
    """
    out = Path(path)
    if not output_exists(out) or (kind != "bag" and is_special_file(out)):  # /dev/null is written into
        return False
    if not force:
        raise OutputExistsError(f"{shown_path(out)}: exists already, not overwriting "
                                f"(use --force to replace the {kind})")
    try:
        if out.is_symlink():
            return True  # the link goes, never what it points to
        if (kind == "bag" and not out.is_dir()) or (out.is_dir() and any(out.iterdir()) and not _is_bag_directory(out)):
            raise OutputExistsError(f"{shown_path(out)}: exists and is not a rosbag2 directory; not removing it "
                                    "even with --force")
    except OSError as exc:
        raise BagWriteError(f"{shown_path(out)}: cannot replace the {kind} ({one_line(exc.strerror or exc)})") from None
    return True


class StagedOutput:
    """An output that replaces an existing one (``--force``) only once it is complete.

    Replacing an output first and failing late (an input with no complete sample, found at its
    end) lost the previous good output for nothing. Where there is an output to replace, the new
    one is written as ``.NAME.tmp-XXXXXXXX/NAME`` beside it (its own name inside: a rosbag2
    directory names its storage file after itself) and :meth:`commit` renames it over ``path``
    (what may be replaced: :func:`check_replaceable`); :meth:`discard` removes it and leaves the
    old one. A new path is written in place (JSON lines can be followed as they come) and removed
    by :meth:`discard`; a device or FIFO (``/dev/null``) is written into.

    Not :func:`okid_ros.errors.replacing` (the file outputs of ``identify``, ``track``, ``export``),
    for a reason: a bag is a folder, which cannot be renamed over another, so the old output is
    moved aside first (and put back if the new one cannot take its place); a new path is written
    in place, where ``process``'s JSON lines are followed as they come and ``record`` keeps what it
    recorded when interrupted; and the ``--force`` rule is checked here, as each output is made,
    where ``replacing``'s callers check every output before the work (:func:`prepare_file_outputs`).

    Parameters
    ----------
    path : the output's path.
    force : allow replacing an existing output.
    kind : what the output is, for the messages ("bag", "JSON lines file", ...).

    Raises
    ------
    OutputExistsError, BagWriteError : as :func:`prepare_output`; also when the folder beside it cannot be made.
    """

    def __init__(self, path: str | os.PathLike, *, force: bool, kind: str = "bag") -> None:
        self.path, self.kind = Path(path), kind
        self._folder: Path | None = None
        replacing = check_replaceable(self.path, force=force, kind=kind)
        self.staged = self.path
        self._created = not output_exists(self.path)  # False for a device: never removed
        _make_folder(self.path.parent, self.path)
        if not replacing:
            return
        folder = name_beside(self.path, f"tmp-{uuid.uuid4().hex[:8]}")
        try:
            folder.mkdir()
        except OSError as exc:
            raise BagWriteError(f"{shown_path(self.path)}: cannot write beside it "
                                f"({one_line(exc.strerror or exc)})") from None
        self._folder, self.staged, self._created = folder, folder / self.path.name, False

    def commit(self) -> Path:
        """Put the complete output at ``path``, replacing the old one; returns ``path``."""
        if self._folder is None:
            self._created = False
            return self.path
        old = self._folder / f".old-{self.path.name}"  # aside first: put back if the rename fails
        try:
            os.replace(self.path, old)
        except OSError as exc:
            raise BagWriteError(f"{shown_path(self.path)}: cannot replace the {self.kind} "
                                f"({one_line(exc.strerror or exc)})") from None
        try:
            os.replace(self.staged, self.path)
        except OSError as exc:
            os.replace(old, self.path)
            raise BagWriteError(f"{shown_path(self.path)}: cannot put the new {self.kind} in place "
                                f"({one_line(exc.strerror or exc)})") from None
        self.discard()  # the old output and the emptied folder
        return self.path

    def discard(self) -> None:
        """Remove what was written (an output that was there before stays as it was)."""
        if self._folder is not None:
            shutil.rmtree(self._folder, ignore_errors=True)
            self._folder = None
        elif self._created:
            self._created = False
            if self.path.is_dir() and not self.path.is_symlink():
                shutil.rmtree(self.path, ignore_errors=True)
            elif output_exists(self.path):
                self.path.unlink()


@contextlib.contextmanager
def made_folders_removed_on_failure() -> Iterator[None]:
    """When the block fails, remove the output folders made in it that are still empty (deepest first).

    Outputs' parent folders are made before the work (:func:`prepare_file_outputs`,
    :class:`StagedOutput`) so that one that cannot be made is refused at once; a run that then failed
    (the record unreadable, the identification refused) left them behind empty. Only ``rmdir``: a
    folder that holds anything (an output written before the failure, a file put there meanwhile)
    stays, and so does every folder that existed before.
    """
    made: list[Path] = []
    token = _MADE_FOLDERS.set(made)
    try:
        yield
    except BaseException:
        for folder in reversed(made):
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    finally:
        _MADE_FOLDERS.reset(token)


def check_folder_option(option: str, path: str | os.PathLike) -> None:
    """OutputError ``--out-dir X: is a file, not a folder`` when ``path`` or a folder above it is no folder.

    The one check of every option naming a folder to write into (``identify --plot-dir``, ``plot
    --out-dir``, ``demo --out-dir``, ``batch --out``), before the work: its mkdir said only
    ``cannot create the parent folder (File exists)``.
    """
    if found := _non_folder(Path(path)):
        part, kind = found
        where = "" if part == Path(path) else f"{shown_path(part)} "
        raise OutputError(f"{option} {shown_path(path)}: {where}is {kind}, not a folder")


def _non_folder(path: Path) -> tuple[Path, str] | None:
    """``path`` or the nearest path above it that exists, when it is no folder, and what it is ("a file")."""
    for part in (path, *path.parents):
        try:
            if not (part.exists() or part.is_symlink()):
                continue
            if part.is_dir():
                return None
        except OSError:  # a name too long, no permission: its mkdir says why
            return None
        return part, "a link to nothing" if not part.exists() else special_file_kind(part) or "a file"
    return None


def _make_folder(folder: Path, out: Path) -> None:
    """``mkdir -p folder``, removing the folders it made when a deeper one fails (a name too long)."""
    todo = []
    while not _is_dir(folder) and folder != folder.parent:
        todo.append(folder)
        folder = folder.parent
    made: list[Path] = []
    try:
        for folder in reversed(todo):
            folder.mkdir(exist_ok=True)
            made.append(folder)
    except OSError as exc:
        for folder in reversed(made):
            with contextlib.suppress(OSError):
                folder.rmdir()  # made just now; rmdir, not rmtree: never more than an empty folder
        if found := _non_folder(folder):  # was "cannot create the parent folder (File exists)"
            raise BagWriteError(f"{shown_path(out)}: {shown_path(found[0])} is {found[1]}, not a folder") from None
        raise BagWriteError(f"{shown_path(out)}: cannot create the parent folder "
                            f"({one_line(exc.strerror or exc)})") from None
    watching = _MADE_FOLDERS.get()
    if watching is not None:
        watching.extend(made)


def _is_dir(path: Path) -> bool:
    try:
        return path.is_dir()
    except OSError:  # a name too long: not there, its mkdir says why
        return False


def output_exists(path: str | os.PathLike) -> bool:
    """Whether ``path`` exists (a dangling symlink too); BagWriteError when that cannot be checked.

    ``Path.exists`` raises OSError for a name too long or a folder that may not be entered.
    """
    out = Path(path)
    try:
        return out.exists() or out.is_symlink()
    except OSError as exc:
        raise BagWriteError(f"{shown_path(out)}: cannot write there ({one_line(exc.strerror or exc)})") from None
