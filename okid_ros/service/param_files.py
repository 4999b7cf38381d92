"""ROS parameter files read as rcl reads them, and the names in them no node knows.

A section of a parameter file applies to a node when its key matches the node's fully
qualified name (``/okid_arx_identifier``, or ``/rig1/okid_arx_identifier`` in a namespace) the
way rcl matches it: a key without a leading slash is in the root namespace, ``/*`` stands for
one name token and ``/**`` for any number of them. So ``/**`` applies to every node,
``/**/okid_arx_identifier`` to that node in every namespace, and a bare ``okid_arx_identifier``
*only* in the root namespace (config/okid.yaml therefore keys its sections ``/**/NODE``).

:func:`file_report` lists what a user most likely got wrong and rcl passes over in silence:
parameters no node declares (``arx: {ordr: 50}``), sections naming a node of this package
that do not apply to it (a bare node name with a namespace), sections that apply to no node
(a misspelt node name, ``/**/okid_arx_identifer``: the closest node name is suggested) and a
key given twice in one mapping (rcl, like YAML loaders, keeps the last). The nodes log it as warnings (or
refuse to start with ``strict_parameters``), ``okid-ros process`` prints it (or refuses with
``--strict-params``). A parameter given twice in one section in two spellings, dotted and
nested (``inputs.sources`` and ``inputs: {sources}``), is refused by :func:`read_parameter_file`
for both: rcl keeps the later in silence, which the writer of the other one did not mean.

YAML that rcl does not read is refused by :func:`load_yaml_as_rcl`, naming the line: an alias
(``*name``) anywhere (rcl: "Will not support aliasing"; an anchor alone is read) and a merge key
``<<``. Every command and ``up`` therefore refuse such a file before a node does.

No rclpy here.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from okid_ros.errors import ParameterError, shown_path, special_file_kind

__all__ = [
    "ROS_STANDARD_PARAMETERS",
    "load_yaml_as_rcl",
    "rcl_scalar",
    "node_fqn",
    "read_parameter_file",
    "not_a_parameter_file",
    "files_for_nodes",
    "ParameterTree",
    "section_matches",
    "flatten",
    "node_values_from_tree",
    "file_report",
    "params_files_from_args",
]

#: Names (or prefixes ending in '.') every rclpy node accepts besides its own parameters.
ROS_STANDARD_PARAMETERS = ("use_sim_time", "start_type_description_service", "qos_overrides.")


def node_fqn(node: str, namespace: str | None = None) -> str:
    """``/NAMESPACE/NODE`` (root namespace: ``/NODE``)."""
    ns = (namespace or "/").rstrip("/")
    return f"{ns}/{node}"


def section_matches(key: str, fqn: str) -> bool:
    """True when the parameter-file section ``key`` applies to the node ``fqn`` (rcl's rules)."""
    key = str(key)
    if not key.startswith("/"):
        key = "/" + key
    pattern = ""
    for token in key.split("/")[1:]:
        if token == "**":
            pattern += r"(/[^/]+)*"
        elif token == "*":
            pattern += r"/[^/]+"
        else:
            pattern += "/" + re.escape(token)
    return re.fullmatch(pattern, fqn) is not None


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested keys -> dotted names (``{arx: {order: 100}}`` -> ``{"arx.order": 100}``).

    Raises
    ------
    ParameterError
        A name given twice, dotted and nested (``inputs.sources: [...]`` and ``inputs: {sources:
        [...]}``, or ``a.b: {c: 1}`` and ``a: {b.c: 2}``): one of the two values would be lost
        without a word (a key repeated in one mapping is :func:`load_yaml_as_rcl`'s, a warning).
    """
    out: dict[str, Any] = {}
    spelling: dict[str, str] = {}
    for path, value in _leaves(tree):
        name = prefix + ".".join(path)
        if name in spelling:
            raise ParameterError(f"parameter {name} is given twice, as {spelling[name]} and as {_spelt(path)}: "
                                 "give it once")
        out[name], spelling[name] = value, _spelt(path)
    return out


def _leaves(tree: Mapping[str, Any], path: tuple[str, ...] = ()) -> Iterable[tuple[tuple[str, ...], Any]]:
    """``(keys from the top, value)`` of every value that is not a mapping, depth first."""
    for key, value in tree.items():
        if isinstance(value, Mapping):
            yield from _leaves(value, (*path, str(key)))
        else:
            yield (*path, str(key)), value


def _spelt(path: tuple[str, ...]) -> str:
    """How a parameter file spells the keys ``path``: ``'inputs.sources'``, ``'inputs: {sources}'``."""
    return "'" + ": {".join(path) + "}" * (len(path) - 1) + "'"


def _walk(tree: Mapping, prefix: str = "") -> Iterable[tuple[str, dict[str, Any] | None]]:
    """``(key, parameters)`` of every node section as rcl reads the file, its nested form too.

    ``ns: {node: {ros__parameters: ...}}`` is the section ``ns/node`` (``/**: {node: ...}``:
    ``/**/node``). ``parameters`` is None where rcl refuses the file: a value that is not a
    mapping on the way (``/**: {sample_time_s: 0.01}``, or under a misspelt ``ros_parameters``);
    ``key`` is then what holds it.
    """
    for key, section in tree.items():
        name = f"{prefix.rstrip('/')}/{str(key).strip('/')}" if prefix else str(key)
        if not isinstance(section, Mapping) or not section:
            yield prefix or name, None
        elif "ros__parameters" not in section:
            yield from _walk(section, name)
        elif isinstance(section["ros__parameters"], Mapping):
            try:
                yield name, flatten(section["ros__parameters"])
            except ParameterError as exc:
                raise ParameterError(f"section {name!r}: {exc}") from None
        else:
            yield name, None


def _sections(tree: Mapping) -> Iterable[tuple[str, dict[str, Any]]]:
    """``(key, parameters)`` of every node section (:func:`_walk`); the offline tools read them as the nodes do."""
    return ((key, values) for key, values in _walk(tree) if values is not None)


def _without_parameters(tree: Mapping) -> list[str]:
    """Keys that are neither a node section nor a namespace of them (:func:`_walk`), each once."""
    return list(dict.fromkeys(key for key, values in _walk(tree) if values is None))


def node_values_from_tree(tree: Mapping, fqn: str) -> dict[str, Any]:
    """Every parameter the file sets for the node ``fqn``.

    The matching sections, wildcard
    sections first, then exact ones (a node-specific value overrides a shared one).
    """
    wildcard: dict[str, Any] = {}
    exact: dict[str, Any] = {}
    for key, values in _sections(tree):
        if section_matches(key, fqn):
            (wildcard if "*" in key else exact).update(values)
    return {**wildcard, **exact}


def _standard(name: str) -> bool:
    return any(name == p or (p.endswith(".") and name.startswith(p)) for p in ROS_STANDARD_PARAMETERS)


def file_report(tree: Mapping, label: str, nodes: Mapping[str, Iterable[str]],
                namespace: str | None = None, for_node: str | None = None) -> list[str]:
    """Problems of a parameter file that rcl would pass over silently, one sentence each.

    Parameters
    ----------
    tree : the file's YAML tree.
    label : the file's name, for the messages.
    nodes : node name -> the parameter names it declares (the nodes that read the file).
    namespace : the nodes' namespace (None: the root namespace).
    for_node : report only sections that apply to this node or name it (a node reporting on
        the files it was started with); None: every section.
    """
    known = {node: set(names) for node, names in nodes.items()}
    fqns = {node: node_fqn(node, namespace) for node in known}
    problems = [f"{label}: section {key!r} holds no 'ros__parameters' mapping: nothing in it is read (rcl "
                "refuses such a file)" for key in _without_parameters(tree)]
    problems += [f"{label}: {note}" for note in getattr(tree, "repeated", ())]
    for key, values in _sections(tree):
        applies = [node for node, fqn in fqns.items() if section_matches(key, fqn)]
        last = str(key).rstrip("/").split("/")[-1]
        near = last if last in known else _near_node(last, known)
        if for_node is not None and for_node not in applies and near != for_node:
            continue
        if not applies:
            problems.append(_no_node_problem(label, str(key), last, near, fqns))
            continue
        names = set().union(*(known[node] for node in applies))
        unknown = sorted(n for n in values if n not in names and not _standard(n))
        if unknown:
            where = ", ".join(applies)
            problems.append(f"{label}: section {key!r}: unknown parameter(s) {', '.join(unknown)} "
                            f"(not declared by {where})")
    return problems


def _near_node(name: str, known: Iterable[str]) -> str | None:
    """The node name ``name`` most likely misspells (``okid_arx_identifer``), or None."""
    import difflib

    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.8)
    return close[0] if close else None


def _no_node_problem(label: str, key: str, last: str, near: str | None, fqns: Mapping[str, str]) -> str:
    """The sentence for a section that applies to none of the nodes (a misspelt node name: rcl reads it for none)."""
    if near == last:
        return (f"{label}: section {key!r} does not apply to {fqns[last]} (a node name without "
                f"'/**/' is in the root namespace); key it '/**/{last}' to apply in every namespace")
    text = f"{label}: section {key!r} applies to no node ({', '.join(fqns.values())}): nothing in it is read"
    if near is not None:
        text += f" (did you mean {key.rstrip('/')[:-len(last)] + near!r}?)"
    return text


def params_files_from_args(args: Sequence[str]) -> list[str]:
    """The ``--params-file FILE`` paths among ROS arguments (``--ros-args ... [--]``), in order."""
    files: list[str] = []
    in_ros = False
    it = iter(args)
    for arg in it:
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--" and in_ros:
            in_ros = False
        elif in_ros and arg == "--params-file":
            path = next(it, None)
            if path is not None:
                files.append(path)
    return files


_RCL_TRUE = frozenset("Y y yes Yes YES true True TRUE on On ON".split())
_RCL_FALSE = frozenset("N n no No NO false False FALSE off Off OFF".split())
_RCL_SPECIAL_FLOATS = {f"{sign}.{word}": float(f"{sign}{word}")
                       for sign in ("", "+", "-") for word in ("inf", "Inf", "INF")}
_RCL_SPECIAL_FLOATS.update({".nan": float("nan"), ".NaN": float("nan"), ".NAN": float("nan")})
_STRTOL = re.compile(r"\s*[+-]?(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)")
_INT64 = (-(2 ** 63), 2 ** 63 - 1)


def rcl_scalar(text: str) -> bool | int | float | str:
    """A plain (unquoted) YAML scalar typed as rcl types parameter values.

    rcl_yaml_param_parser (the parser of ``--params-file`` and ``-p name:=value``) tries, in order:
    its bool words, ``strtol(text, 0)`` over the whole text (``010`` is 8, ``0x1F`` 31), then
    ``strtod`` (``1e-3`` is a double, which YAML 1.1 and so PyYAML read as a string), then keeps
    the text. A number beyond the C types' range stays a string there, as here.
    """
    if text in _RCL_TRUE or text in _RCL_FALSE:
        return text in _RCL_TRUE
    match = _STRTOL.fullmatch(text)
    if match:
        digits = match.group(1)
        value = int(digits, 16 if digits[:2] in ("0x", "0X") else 8 if digits.startswith("0") else 10)
        value = -value if text.strip().startswith("-") else value
        if _INT64[0] <= value <= _INT64[1]:
            return value
    if text in _RCL_SPECIAL_FLOATS:
        return _RCL_SPECIAL_FLOATS[text]
    if "_" not in text:  # Python's float() reads 1_000; strtod does not
        try:
            value = float(text)
        except ValueError:
            if not re.fullmatch(r"\s*[+-]?0[xX].*", text):  # strtod's hexadecimal floats need the 0x
                return text
            try:
                value = float.fromhex(text)
            except (ValueError, OverflowError):
                return text
        if math.isfinite(value) or text.strip().lstrip("+-").lower().startswith(("inf", "nan")):
            return value  # strtod overflows to an error (a string in rcl), Python to inf
    return text


class ParameterTree(dict):
    """A parameter file's YAML tree, with the keys it gives twice in one mapping (``repeated``)."""

    def __init__(self, tree: Mapping, repeated: Sequence[str] = ()) -> None:
        super().__init__(tree)
        self.repeated = tuple(repeated)


def _not_for_rcl(label: str, line: int, what: str) -> ParameterError:
    """The error for YAML that rcl does not read (an alias, a merge key): the file, the line, what to write instead."""
    return ParameterError(f"{label}: line {line}: {what}")


def load_yaml_as_rcl(text: str, label: str = "the YAML text", *, repeated: list[str] | None = None) -> Any:
    """``yaml.safe_load(text)`` with each plain scalar typed by :func:`rcl_scalar`, as a node would see it.

    ``repeated``: when given, a sentence for each key given twice in one mapping is appended
    (the last value counts, as in rcl).

    Raises
    ------
    ParameterError
        Nesting too deep for PyYAML; an alias (``*name``) anywhere, or a merge key ``<<``: rcl
        refuses the alias ("Will not support aliasing at line N", in a file and in ``-p``) and
        reads an inline ``<<: {...}`` as parameters named ``<<.NAME``, so a node would not start
        or not get the values. An anchor alone (``&name``) is read, as rcl reads it. The message
        starts with ``label`` and names the line.
    yaml.YAMLError
        Not YAML.
    """
    import yaml

    tag = "tag:okid_ros,2026:rcl"

    def merge_key(line: int) -> ParameterError:
        return _not_for_rcl(label, line, "the YAML merge key '<<' is not read by rcl: a node refuses the alias it "
                                         "merges ('Will not support aliasing') and takes an inline '<<: {...}' for "
                                         "parameters named '<<.NAME'; write the parameters out in the section")

    class Loader(yaml.SafeLoader):
        def compose_node(self, parent, index):
            # Refused where it stands, before PyYAML shares the anchored node: no alias bomb or
            # recursive alias is ever expanded.
            if self.check_event(yaml.AliasEvent):
                alias = self.peek_event()
                line = alias.start_mark.line + 1
                if isinstance(index, yaml.ScalarNode) and index.value == "<<" and index.style is None:
                    raise merge_key(line)
                raise _not_for_rcl(label, line, f"the YAML alias '*{alias.anchor}' is not read by rcl: "
                                                "a node refuses the file ('Will not support aliasing'); write the "
                                                "values out where the alias stands")
            return super().compose_node(parent, index)

        def construct_mapping(self, node, deep=False):
            lines: dict[str, int] = {}
            for key, _ in node.value:  # keys are names, never typed
                if isinstance(key, yaml.ScalarNode) and key.value == "<<" and key.style is None:
                    raise merge_key(key.start_mark.line + 1)
                if isinstance(key, yaml.ScalarNode) and key.tag == tag:
                    key.tag = "tag:yaml.org,2002:str"
                if repeated is not None and isinstance(key, yaml.ScalarNode):
                    line = key.start_mark.line + 1
                    if key.value in lines:
                        where = f"line {line}" if lines[key.value] == line else f"lines {lines[key.value]} and {line}"
                        repeated.append(f"key {key.value!r} is given twice in one mapping ({where}): the last value "
                                        f"counts, as rcl reads it")
                    lines[key.value] = line
            return super().construct_mapping(node, deep)

    Loader.yaml_implicit_resolvers = {}  # no YAML 1.1 typing; plain scalars go to rcl_scalar
    Loader.add_implicit_resolver(tag, re.compile(r".*", re.DOTALL), None)
    Loader.add_constructor(tag, lambda loader, node: rcl_scalar(loader.construct_scalar(node)))
    loader = Loader(text)
    try:
        return loader.get_single_data()
    except RecursionError:  # PyYAML composes and constructs recursively
        raise ParameterError(f"{label} is nested too deeply") from None
    finally:
        loader.dispose()


def read_parameter_file(path: str | Path) -> Mapping:
    """The YAML tree of a ROS parameter file (node sections at the top, keys it repeats noted), or ParameterError."""
    import yaml

    path = Path(path)
    if kind := special_file_kind(path, pipe=True):  # a FIFO would be waited on for ever; <(cmd) is read
        raise ParameterError(f"parameter file {shown_path(path)}: not a regular file ({kind})")
    repeated: list[str] = []
    try:
        tree = load_yaml_as_rcl(path.read_text(encoding="utf-8"), f"parameter file {shown_path(path)}",
                                repeated=repeated)
    except OSError as exc:
        raise ParameterError(f"cannot read parameter file {shown_path(path)}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise ParameterError(f"parameter file {shown_path(path)} is not UTF-8 text ({exc.reason} at byte "
                             f"{exc.start})") from None
    except yaml.YAMLError as exc:
        raise ParameterError(f"parameter file {shown_path(path)} is not valid YAML: "
                             f"{' '.join(str(exc).split())}") from None
    if not isinstance(tree, Mapping):  # None: nothing but blanks and comments (a zero-byte file, "got NoneType")
        got = "an empty file" if tree is None else type(tree).__name__
        raise ParameterError(f"parameter file {shown_path(path)} has no node sections (expected a mapping "
                             f"'NODE: {{ros__parameters: {{...}}}}', got {got})")
    try:
        list(_walk(tree))  # a name given twice, dotted and nested, is refused here, before any use
    except ParameterError as exc:
        raise ParameterError(f"parameter file {shown_path(path)}: {exc}") from None
    if what := not_a_parameter_file(tree):
        raise ParameterError(f"{shown_path(path)} is not a parameter file: {what}")
    return ParameterTree(tree, repeated)


#: Top-level keys every `okid-ros identify --json` model has (IdentifiedModel.to_json_dict), to name such a file.
_IDENTIFY_MODEL_KEYS = frozenset(("sample_time_s", "n_states", "A", "C", "modes"))


def not_a_parameter_file(tree: Mapping) -> str | None:
    """What a YAML mapping none of whose top-level keys is a node section looks like, or None for a parameter file.

    A top-level key is a node section when a ``ros__parameters`` mapping is under it (``NODE``,
    ``/**/NODE``, a namespace holding them) or it is spelt as a node name with a leading slash
    (``/**``: a section with a mistake in it, which :func:`file_report` names key by key). A
    file with no such key (a model JSON passed as ``--params``) is refused whole, by every
    command and ``up`` alike, instead of a warning for each of its keys and a run on defaults.
    """
    def is_section(key: Any, value: Any) -> bool:
        return str(key).startswith("/") or any(values is not None for _, values in _walk({key: value}))

    if not tree or any(is_section(key, value) for key, value in tree.items()):
        return None
    keys = [str(key) for key in tree]
    shown = ", ".join(repr(key) for key in keys[:3]) + (", ..." if len(keys) > 3 else "")
    text = (f"none of its {len(keys)} top-level key(s) ({shown}) is a node section "
            "('/**/NODE: {ros__parameters: {...}}')")
    if _IDENTIFY_MODEL_KEYS <= set(keys):
        text += "; it looks like a model written by `okid-ros identify --json`"
    return text


def read_files(paths: Sequence[str | Path]) -> list[tuple[str, Mapping]]:
    """(label, YAML tree) of each file; ParameterError when one cannot be read."""
    return [(str(p), read_parameter_file(p)) for p in paths]


def files_for_nodes(paths: Sequence[str | Path]) -> list[str]:
    """The absolute paths of parameter files node processes will read themselves (`up`, `demo`), each read here first.

    Read as every command reads one (:func:`read_parameter_file`), so a file that is missing, a
    folder, not YAML or not a parameter file is refused in one line before a node starts (was:
    "does not exist" for a folder or a device; rcl's parse error from each node, after the demo's
    simulation). A pipe is refused too: read here, it would be empty for the two nodes. So is a file
    with a key that is not a node section (``/**: {a: 1}``, a typo ``ros_parameters:``): rcl refuses
    the whole file, where the commands only warn of it (:func:`file_report`).

    Raises
    ------
    ParameterError naming the file and what is wrong.
    """
    checked = []
    for path in paths:
        if kind := special_file_kind(path):
            raise ParameterError(f"parameter file {shown_path(path)}: not a regular file ({kind}); each node reads "
                                 "it itself")
        if bare := _without_parameters(read_parameter_file(path)):
            # Only a warning for the commands that read the file themselves: rcl refuses the whole file
            raise ParameterError(f"parameter file {shown_path(path)}: section {bare[0]!r} holds no 'ros__parameters' "
                                 "mapping: a node refuses the file (rcl: 'Cannot have a value before "
                                 "ros__parameters'); put its values under '<node>: ros__parameters:' or remove it")
        checked.append(str(Path(path).resolve()))
    return checked
