"""The one place that turns topic names into full names: the rig namespace.

Every topic of the nodes (inputs, ``arx_model``, ``state_space_model``, ``modal_states``, and any
topic added later) is a *relative* name resolved in the rig namespace:

- the node's namespace (``-r __ns:=/rig1``, ``okid-ros up --namespace /rig1``, the launch
  argument ``namespace:=/rig1``) when it has one: ``/rig1/io_sample``, ``/rig1/modal_states``;
- :data:`DEFAULT_NAMESPACE` (``/okid``) when the node runs in the root namespace, so that the
  default names stay ``/okid/io_sample``, ``/okid/arx_model``, ``/okid/state_space_model`` and
  ``/okid/modal_states``; services stay under the node names (``/okid_arx_identifier/reset``,
  or ``/rig1/okid_arx_identifier/reset`` in a namespace).

An absolute name in a parameter (``/my/imu``) is used as it is and does not move with the
namespace. Every resolved name must be a valid ROS 2 topic name
(:func:`topic_name_problem`): a bad one is a ParameterError up front, not a bag or a publisher
with a name no ROS tool accepts. The offline tools (``process``, ``replay``, ``monitor``, ``record``, ``demo``) resolve
the same names with their ``--namespace`` option through :func:`resolve_topic`.

No rclpy here: the nodes and the offline tools share it.
"""

from __future__ import annotations

import re

from okid_ros.errors import ParameterError

__all__ = [
    "DEFAULT_NAMESPACE",
    "IO_SAMPLE",
    "ARX_MODEL",
    "STATE_SPACE_MODEL",
    "MODAL_STATES",
    "STRUCTURAL_CHANGE",
    "OUTPUT_TOPICS",
    "rig_namespace",
    "validate_namespace",
    "resolve_topic",
    "topic_name_problem",
    "output_topics",
]

#: Rig namespace of nodes that run in the root namespace.
DEFAULT_NAMESPACE = "/okid"

# Relative names of the nodes' topics (the defaults of the topic parameters).
IO_SAMPLE = "io_sample"
ARX_MODEL = "arx_model"
STATE_SPACE_MODEL = "state_space_model"
MODAL_STATES = "modal_states"
STRUCTURAL_CHANGE = "structural_change"

#: Relative output topic -> message type, of both nodes.
OUTPUT_TOPICS: dict[str, str] = {
    ARX_MODEL: "okid_msgs/msg/ArxModel",
    STATE_SPACE_MODEL: "okid_msgs/msg/StateSpaceModel",
    MODAL_STATES: "okid_msgs/msg/ModalStates",
    STRUCTURAL_CHANGE: "okid_msgs/msg/StructuralChange",
}

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
# rmw's RMW_TOPIC_MAX_NAME_LENGTH (255 less the DDS prefix "rt/" and room for suffixes).
_MAX_TOPIC_LENGTH = 247


def validate_namespace(namespace: str) -> str:
    """Return ``namespace`` as an absolute name without a trailing slash, or raise ValueError.

    ``"rig1"`` -> ``"/rig1"``; ``"/plant/rig1/"`` -> ``"/plant/rig1"``; ``"/"`` stays ``"/"``.
    """
    text = str(namespace).strip()
    if text in ("", "/"):
        return "/"
    parts = text.strip("/").split("/")
    bad = [p for p in parts if not _TOKEN.match(p)]
    if bad or "//" in text:
        raise ValueError(
            f"namespace {namespace!r} is not valid: use /name[/name...] with letters, digits and "
            "underscores, each part not starting with a digit"
        )
    return "/" + "/".join(parts)


def rig_namespace(node_namespace: str | None) -> str:
    """The namespace relative topic names resolve in: the node's, or /okid for the root one."""
    ns = validate_namespace(node_namespace or "/")
    return DEFAULT_NAMESPACE if ns == "/" else ns


def resolve_topic(name: str, namespace: str | None = None, parameter: str | None = None) -> str:
    """Full name of a topic: absolute names unchanged, relative ones under the rig namespace.

    Parameters
    ----------
    name : topic name, relative (``io_sample``, ``sensors/imu``) or absolute (``/my/imu``).
    namespace : the node's namespace (``/`` or None: :data:`DEFAULT_NAMESPACE`).
    parameter : the parameter the name comes from, for the error message.

    Raises
    ------
    ParameterError
        the full name is not a valid ROS 2 topic name (names ``parameter``).
    """
    text = str(name).strip()
    full = text if text.startswith("/") else f"{rig_namespace(namespace).rstrip('/')}/{text}"
    problem = topic_name_problem(full) if text else "it is empty"
    if problem:
        where = f"parameter {parameter}: " if parameter else ""
        raise ParameterError(f"{where}{str(name)!r} is not a valid topic name ({problem})")
    return full


def topic_name_problem(full_name: str) -> str | None:
    """Why ``full_name`` is not a valid fully qualified ROS 2 topic name, or None.

    The rules of ``rcl``'s ``validate_full_topic_name``, checked here rather than with
    ``rclpy.validate_full_topic_name`` because the offline tools must work without rclpy.
    ``~`` (private) and ``{node}`` substitutions are not expanded by :func:`resolve_topic`,
    so they are refused too.
    """
    if not full_name.startswith("/"):
        return "it must be absolute"
    if len(full_name) > _MAX_TOPIC_LENGTH:
        return f"longer than {_MAX_TOPIC_LENGTH} characters"
    if full_name.endswith("/"):
        return "it ends with '/'"
    if "//" in full_name:
        return "it holds '//'"
    bad = sorted({c for c in full_name if not (c.isascii() and (c.isalnum() or c in "_/"))})
    if bad:
        return (f"character(s) {' '.join(repr(c) for c in bad)} not allowed: use letters, digits, '_' and '/'"
                + ("; '~' and '{}' substitutions are not supported" if set(bad) & set("~{}") else ""))
    if any(token[0].isdigit() for token in full_name[1:].split("/")):
        return "a part starts with a digit"
    return None


def output_topics(namespace: str | None = None) -> dict[str, str]:
    """Full output topic name -> message type of both nodes with the default topic names."""
    return {resolve_topic(name, namespace): msg_type for name, msg_type in OUTPUT_TOPICS.items()}
