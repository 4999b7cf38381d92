"""The input thread of a node: its input subscriptions served apart from the executor.

See :class:`InputThread`; :func:`okid_ros.nodes.runner.run_node` starts it.
"""

from __future__ import annotations

import threading
from contextlib import ExitStack
from typing import TYPE_CHECKING, Any

import rclpy
from rclpy.exceptions import InvalidHandle
from rclpy.executors import SingleThreadedExecutor
from rclpy.guard_condition import GuardCondition

from okid_ros.nodes.common import name_thread, realtime_threads, request_short_slice

if TYPE_CHECKING:
    from okid_ros.nodes.base import OkidNode

__all__ = ["InputThread"]


class _ExecutorWithoutInputs(SingleThreadedExecutor):
    """The executor of all but the node's input subscriptions and their event handlers.

    Those are :class:`InputThread`'s: an event handler of an input subscription left in this
    executor's wait set would wake it at every message of the subscription.
    """

    def __init__(self, node: OkidNode) -> None:
        super().__init__()
        self._okid_node = node

    def can_execute(self, entity: Any) -> bool:
        inputs = self._okid_node.inputs
        if inputs is not None and any(entity is sub or any(entity is h for h in sub.event_handlers)
                                      for sub in inputs.subscriptions):
            return False
        return super().can_execute(entity)


class InputThread:
    """Serves a node's input subscriptions on a thread of their own, ``okid_samples``.

    rclpy's executor builds a new wait set over every entity of the node (services, timers,
    the event handlers of each publisher and subscription, ...) at each wake: 0.2-0.3 ms of
    CPU per message on a 2-core machine, at 1 kHz more than the node's own work per sample,
    and what makes the samples queue when the cores are busy. This thread waits on the input
    subscriptions (and their QoS event handlers) only, with one wait set kept from wait to
    wait (as ``rclpy.wait_for_message`` does; about 0.06 ms per message), and hands what is
    queued to :meth:`~okid_ros.nodes.input_frontend.InputFrontend.take_all` under
    :attr:`OkidNode.state_lock`. The executor of :meth:`executor` serves the rest and leaves
    the inputs out.

    Parameters
    ----------
    node : the node; its ``inputs`` may come and go (lifecycle configure and cleanup).
    timeout_s : longest wait before the thread looks at the node's inputs again.
    """

    def __init__(self, node: OkidNode, timeout_s: float = 0.1) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation

        self._rclpy = rclpy_implementation
        self.node = node
        self.timeout_ns = int(timeout_s * 1e9)
        self.error: Exception | None = None  # what ended the thread, re-raised by run_node
        self._stop = False
        self._wake = GuardCondition(None, None, context=node.context)
        self._thread = threading.Thread(target=self._run, name="okid_samples", daemon=True)
        node.input_thread = self

    @staticmethod
    def supported() -> bool:
        """Whether this rclpy has the wait-set API the thread needs (else the executor serves the inputs)."""
        try:
            from rclpy.impl.implementation_singleton import rclpy_implementation
        except ImportError:
            return False
        return all(hasattr(rclpy_implementation.WaitSet, name) for name in (
            "clear_entities", "add_subscription", "add_guard_condition", "wait", "get_ready_entities"))

    def executor(self) -> SingleThreadedExecutor:
        """An executor for the node that leaves its inputs to this thread."""
        return _ExecutorWithoutInputs(self.node)

    def start(self) -> None:
        self._thread.start()

    def wake(self) -> None:
        """End the current wait (the inputs changed, or the thread is to stop)."""
        try:
            self._wake.trigger()
        except InvalidHandle:
            pass

    def stop(self) -> None:
        """Stop the thread and wait for it (a batch of samples being handled is finished first)."""
        self._stop = True
        self.wake()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self.node.input_thread = None
        self._wake.destroy()

    def _run(self) -> None:
        name_thread("okid_samples")
        priority = int(self.node.values.get("realtime_priority", 0))
        if priority:  # node 2's realtime_priority: the node's other threads have it already
            realtime_threads(priority, only_this_thread=True)
        elif self.node.input_slice_s:
            request_short_slice(self.node.input_slice_s)
        node, context = self.node, self.node.context
        subs: tuple = ()
        events: list = []
        wait_set = None
        try:
            while not self._stop and context.ok():
                frontend = node.inputs
                current = tuple(frontend.subscriptions) if frontend is not None else ()
                if wait_set is None or len(current) != len(subs) or any(a is not b for a, b in zip(current, subs)):
                    subs = current
                    events = [handler for sub in subs for handler in sub.event_handlers]
                    wait_set = self._rclpy.WaitSet(len(subs), 1, 0, 0, 0, len(events), context.handle)
                try:
                    samples, ready_events = self._wait(wait_set, subs, events)
                except InvalidHandle:
                    with node.state_lock:  # a cleanup is destroying the inputs: let it finish
                        pass
                    continue
                for handler, data in ready_events:
                    handler.callback(data)  # QoS events of the inputs (default: a warning in the log)
                if samples and not self._stop:
                    with node.state_lock:
                        if node.inputs is frontend:
                            frontend.take_all()
        except Exception as exc:  # reported by run_node, as an exception in a callback would be
            if context.ok() and not self._stop:
                self.error = exc
                rclpy.try_shutdown(context=context)  # ends the executor's spin

    def _wait(self, wait_set: Any, subs: tuple, events: list) -> tuple[bool, list]:
        """Wait for messages on ``subs`` or a QoS event (or a wake).

        Returns whether a message is ready, and the (handler, event data) of the events taken.
        """
        with ExitStack() as in_use:  # a handle in use is not destroyed under the wait
            for entity in (*(sub.handle for sub in subs), *events, self._wake.handle):
                in_use.enter_context(entity)
            wait_set.clear_entities()
            for sub in subs:
                wait_set.add_subscription(sub.handle)
            for handler in events:
                handler.add_to_wait_set(wait_set)
            wait_set.add_guard_condition(self._wake.handle)
            wait_set.wait(self.timeout_ns)
            taken = [(h, h.take_data()) for h in events if h.is_ready(wait_set)]
            return bool(wait_set.get_ready_entities("subscription")), [(h, d) for h, d in taken if d]
