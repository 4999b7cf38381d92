"""Who called what: a log line for every call of the nodes' ``reset``/``enable`` and parameter services.

The nodes' topics and services are open to anyone on the ROS domain (docs/security.md); this
module makes the calls that change a running node visible in its log:

    call of /okid_arx_identifier/reset by /okid_probe: request {} -> {success=True, message='...'}
    call of /okid_arx_identifier/set_parameters by /tuner: request {arx.penalty=2.0} -> [ok]

(the node's own line ``parameters set: arx.penalty: 1.0 -> 2.0`` gives the old value).
"""

from __future__ import annotations

import time
from typing import Any

from rclpy.node import Node
from rclpy.parameter import Parameter

__all__ = ["log_calls", "caller_of"]


def log_calls(node: Node, service: Any) -> None:
    """Log every call of ``service``: the caller, the request and the answer (docs/security.md).

    Written when the answer is sent (the request, kept by the wrapped callback, and the
    response together). The caller: :func:`caller_of`. Without SROS2 the name is what the caller
    claims to be; with SROS2 enforced only enclaves allowed to call the service can.

    A client created just before its call can reach the service before discovery has told
    this node the client's node name (the endpoint is known, its node is
    ``_NODE_NAME_UNKNOWN_``); the line then waits, polled by a timer, up to
    ``CALLER_WAIT_S`` for the name. The answer itself is never held back.
    """
    send = service.send_response

    def send_response(response: Any, header: Any) -> None:
        try:
            what = f"request {_brief(getattr(service, '_okid_request', None))} -> {_brief(response)}"
            _log_when_named(node, service.service_name, what)
        except Exception as exc:  # the log line must never cost the answer
            node.get_logger().warning(f"call of {service.service_name}: not logged ({exc!r})")
        send(response, header)

    callback = service.callback

    def keep_request(request: Any, response: Any) -> Any:
        service._okid_request = request
        return callback(request, response)

    service.callback = keep_request
    service.send_response = send_response


CALLER_WAIT_S = 2.0
"""How long a call's log line waits for discovery to name the caller's node."""

_CALLER_POLL_S = 0.05


def _log_when_named(node: Node, service_name: str, what: str) -> None:
    """Log the call (``what``: request and answer) now if the caller is named, else once it is."""
    names = _client_nodes(node, service_name)
    if _all_named(names):
        node.get_logger().info(f"call of {service_name} by {_caller_text(names)}: {what}")
        return
    deadline = time.monotonic() + CALLER_WAIT_S
    timer = None

    def poll() -> None:
        try:
            current = _client_nodes(node, service_name)
            if not _all_named(current) and time.monotonic() < deadline:
                return
            node.get_logger().info(f"call of {service_name} by {_caller_text(current)}: {what}")
        except Exception as exc:  # a timer callback that raises would stop the node's executor
            node.get_logger().warning(f"call of {service_name}: not logged ({exc!r})")
        timer.cancel()
        node.destroy_timer(timer)

    timer = node.create_timer(_CALLER_POLL_S, poll)


def _all_named(names: list[str]) -> bool:
    """Whether discovery has named the node of every client (and there is one)."""
    return bool(names) and not any("_NODE_NAME_UNKNOWN_" in name for name in names)


def _client_nodes(node: Node, service_name: str) -> list[str]:
    infos = node.get_publishers_info_by_topic(f"rq{service_name}Request", no_mangle=True)
    return sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos})


def _caller_text(names: list[str]) -> str:
    if not names:
        return "a client not in the graph"
    return names[0] if len(names) == 1 else "one of " + ", ".join(names)


def caller_of(node: Node, service_name: str) -> str:
    """The node(s) with a client of ``service_name`` in the graph: who can have called.

    rclpy's request header carries no caller (only a sequence number and time stamps), and DDS
    names no sender, so the clients of the service that discovery knows at the time of the call
    are named: one in the usual case (clients are created for the call), else all of them. A
    client whose node discovery has not named yet is listed as ``_NODE_NAME_UNKNOWN_``.
    """
    return _caller_text(_client_nodes(node, service_name))


def _brief(msg: Any) -> str:
    """A one-line text of a request or response (parameter values as name=value)."""
    if msg is None:
        return "?"
    if hasattr(msg, "parameters"):
        return "{" + ", ".join(f"{p.name}={Parameter.from_parameter_msg(p).value!r}" for p in msg.parameters) + "}"
    if hasattr(msg, "results"):
        return "[" + ", ".join("ok" if r.successful else f"refused: {r.reason}" for r in msg.results) + "]"
    if hasattr(msg, "result"):
        r = msg.result
        return "ok" if r.successful else f"refused: {r.reason}"
    fields = getattr(msg, "get_fields_and_field_types", dict)()
    return "{" + ", ".join(f"{name}={getattr(msg, name)!r}" for name in fields) + "}"
