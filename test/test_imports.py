"""The package's import structure.

No import cycles among modules (lazy imports included), and the numerical layers (core, sim,
service) import no rclpy, as docs/architecture.md states.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "okid_ros"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Modules imported anywhere in the file (a lazy import inside a function still couples)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def _graph() -> dict[str, set[str]]:
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    return {name: {m for m in _imports(path) if m in modules and m != name} for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    found, state, stack = [], {}, []

    def visit(node: str) -> None:
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                found.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node)
    return found


def test_no_import_cycles():
    graph = _graph()
    assert "okid_ros.sim.models" in graph and "okid_ros.core.recursive" in graph
    # A package imports its submodules (okid_ros.sim -> okid_bench.cases) without forming a cycle.
    cycles = [c for c in _cycles(graph) if not any(a.startswith(b + ".") for a, b in zip(c[1:], c))]
    assert cycles == []


def test_the_cycle_check_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == [["a", "b", "c", "a"]]


def test_numerical_layers_import_no_rclpy():
    for layer in ("core", "sim", "service"):
        for path in (PACKAGE / layer).rglob("*.py"):
            tree = ast.parse(path.read_text())
            imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
            imported |= {node.module or "" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
            assert not {m for m in imported if m.split(".")[0] in ("rclpy", "okid_msgs")}, path


# What each start-up must not import: the parameter table is read by every node and most commands
# (declarations, defaults, checks), node 1 fits ARX windows only. scipy.stats and scipy.signal are
# about 0.8 s of CPU per process (filterpy imports scipy.stats); they belong to node 2's estimator,
# change test and realizations.
_NOT_AT_START = {
    "okid_ros.service.params": ("scipy.stats", "scipy.signal", "scipy.optimize", "filterpy"),
    "okid_ros.nodes.arx_identifier_node": ("scipy.stats", "scipy.signal", "filterpy"),
}


def test_start_ups_import_no_numerical_module_they_do_not_use():
    # One interpreter, the lighter start-up first: what each import added to sys.modules.
    code = "import importlib, sys\n" + "".join(
        f"importlib.import_module({name!r}); print(' '.join(sorted(sys.modules)))\n" for name in _NOT_AT_START)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(PACKAGE.parent), os.environ.get("PYTHONPATH", "")])}
    lines = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env=env).stdout.splitlines()
    loaded = {name: line.split() for name, line in zip(_NOT_AT_START, lines)}
    assert all(name in loaded[name] for name in _NOT_AT_START)
    assert {name: [m for m in heavy if m in loaded[name]] for name, heavy in _NOT_AT_START.items()} == {
        name: [] for name in _NOT_AT_START}
