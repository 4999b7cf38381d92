"""Lines per module and per function or class of okid_ros, largest first.

Run:  python scripts/code_sizes.py [--min-lines N] [PATH ...]   (default: okid_ros, N = 40)

The measure the architecture issue checks (docs/architecture.md): modules of one role, a few
hundred lines each, and no long functions.
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def sizes(paths: list[Path]) -> tuple[list[tuple[int, str]], list[tuple[int, str]]]:
    """``(lines, module)`` of every module and ``(lines, module:name)`` of every def and class."""
    modules, defs = [], []
    for path in paths:
        for file in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            source = file.read_text()
            name = str(file.resolve().relative_to(ROOT))
            modules.append((len(source.splitlines()), name))
            for node in ast.walk(ast.parse(source)):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    kind = "class" if isinstance(node, ast.ClassDef) else "def"
                    defs.append((node.end_lineno - node.lineno + 1, f"{name}:{node.name} ({kind})"))
    return sorted(modules, reverse=True), sorted(defs, reverse=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="*", type=Path, default=[ROOT / "okid_ros"])
    parser.add_argument("--min-lines", type=int, default=40, help="list defs and classes from this size")
    args = parser.parse_args()
    modules, defs = sizes(args.paths)
    print("| lines | module |\n|---|---|")
    for n, name in modules:
        print(f"| {n} | {name} |")
    print(f"\n| lines | def or class (>= {args.min_lines} lines) |\n|---|---|")
    for n, name in defs:
        if n >= args.min_lines:
            print(f"| {n} | {name} |")


if __name__ == "__main__":
    main()
