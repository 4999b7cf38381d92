"""The package's shape, as docs/architecture.md states it.

Modules of one role (at most 500 lines), short functions (at most 80 lines), options
keyword-only (at most 6 positional parameters), and layers that import only downward:

    errors, jsonio  <-  core  <-  records (record_csv), sim  <-  service  <-  nodes, tools  <-  commands  <-  cli
"""

from __future__ import annotations

import ast
from pathlib import Path

from test_imports import _graph as import_graph

PACKAGE = Path(__file__).resolve().parent.parent / "okid_ros"
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80
MAX_POSITIONAL = 6
# Rank of each layer: a module may import modules of its own rank or lower.
LAYERS = {"errors": 0, "jsonio": 0, "core": 1, "records": 2, "record_csv": 2, "record_keys": 2, "sim": 2, "service": 3,
          "nodes": 4, "tools": 4, "commands": 5, "cli": 6, "__init__": 6}


def _modules() -> dict[str, Path]:
    return {".".join(p.relative_to(PACKAGE.parent).with_suffix("").parts): p for p in PACKAGE.rglob("*.py")}


def _layer(module: str) -> int:
    return LAYERS[module.split(".")[1] if "." in module else "__init__"]


def _functions(tree: ast.AST):
    return [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]


def test_no_module_over_the_limit():
    long = {name: len(path.read_text().splitlines()) for name, path in _modules().items()}
    assert {k: v for k, v in long.items() if v > MAX_MODULE_LINES} == {}


def test_no_function_over_the_limit():
    found = {}
    for name, path in _modules().items():
        for fn in _functions(ast.parse(path.read_text())):
            size = fn.end_lineno - fn.lineno + 1
            if size > MAX_FUNCTION_LINES:
                found[f"{name}:{fn.name}"] = size
    assert found == {}


def test_options_are_keyword_only():
    found = {}
    for name, path in _modules().items():
        for fn in _functions(ast.parse(path.read_text())):
            positional = [a.arg for a in fn.args.posonlyargs + fn.args.args if a.arg not in ("self", "cls")]
            if len(positional) > MAX_POSITIONAL:
                found[f"{name}:{fn.name}"] = len(positional)
    assert found == {}


def test_layers_import_only_downward():
    upward = {}
    for name, imported in import_graph().items():
        if name == "okid_ros":
            continue
        bad = sorted(m for m in imported if m != "okid_ros" and _layer(m) > _layer(name))
        if bad:
            upward[name] = bad
    assert upward == {}


def test_the_layer_check_knows_every_folder():
    assert {_layer(name) for name in _modules()} <= set(LAYERS.values())
