"""The files a benchmark writes besides its printed table: one rule for all of them.

An existing file is never replaced without ``--force`` (as ``okid-ros`` does with its outputs): a
benchmark run of an hour must not overwrite the table of the run before, nor a page of docs/.
The check runs before the benchmark does, so a refusal costs nothing.
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["add_output_options", "print_table", "refuse_existing", "write_output"]


def _path(text: str) -> Path | None:
    """A path, or None for an empty argument (``--out ""``: no file, as before the paths were typed)."""
    return Path(text) if text else None


def add_output_options(parser: argparse.ArgumentParser, *, json: bool = False,
                       out_help: str = "also write the table (markdown) here") -> None:
    """``--out FILE``, ``--force`` and, with ``json``, ``--json FILE`` (paths, default None)."""
    parser.add_argument("--out", type=_path, default=None, help=out_help)
    if json:
        parser.add_argument("--json", type=_path, default=None, help="also write the raw results (JSON) here")
    parser.add_argument("--force", action="store_true", help="replace existing --out/--json files")


def refuse_existing(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``parser.error`` (status 2) when ``--out`` or ``--json`` names an existing file and ``--force`` is absent."""
    for path in (getattr(args, "out", None), getattr(args, "json", None)):
        if path is not None and path.exists() and not args.force:
            parser.error(f"{path} exists; add --force to replace it")


def write_output(path: Path | None, text: str) -> None:
    """``text`` into ``path`` (its folder made), nothing when ``path`` is None."""
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def print_table(header: list[str], rows, path: Path | None) -> None:
    """A markdown table: its header, then each row of ``rows`` (cells) printed as it comes; all written to ``path``."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    print("\n".join(lines), flush=True)
    for cells in rows:
        lines.append("| " + " | ".join(str(cell) for cell in cells) + " |")
        print(lines[-1], flush=True)
    write_output(path, "\n".join(lines) + "\n")
