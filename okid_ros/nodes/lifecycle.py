"""The managed (``rclpy.lifecycle``) variant of a node: see :mod:`okid_ros.nodes.base`.

*configure* builds, *activate* starts the identification and the publishing, *deactivate*
stops both (samples are dropped, nothing is published, the services still answer), *cleanup*
destroys what configure built, *shutdown* does the same from any state and ends the process
(:func:`~okid_ros.nodes.runner.run_node` returns 0 once the transition is answered).
"""

from __future__ import annotations

from typing import Any

from okid_ros.errors import ParameterError
from okid_ros.nodes.base import OkidNode

__all__ = ["managed_node_class"]


def managed_node_class(cls: type[OkidNode]) -> type:
    """The managed (rclpy.lifecycle) variant of a node class: see the module docstring."""
    from rclpy.impl.implementation_singleton import rclpy_implementation
    from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn

    class Managed(LifecycleNodeMixin, cls):
        def __init__(self, **kwargs: Any) -> None:
            cls.__init__(self, managed=True, **kwargs)
            LifecycleNodeMixin.__init__(self, enable_communication_interface=True)

        def _LifecycleNodeMixin__on_change_state(self, request, response):  # noqa: N802 (the mixin's name)
            # rclpy's ChangeState service raises for a transition the current state does not
            # have (activate twice, activate before configure), and the exception ends the node
            # (ros2/rclpy#1209, fixed upstream after this release): refuse it, state unchanged.
            try:
                return LifecycleNodeMixin._LifecycleNodeMixin__on_change_state(self, request, response)
            except rclpy_implementation.RCLError as exc:
                state = self._state_machine.current_state[1]
                self.get_logger().warning(f"lifecycle transition {request.transition.id} "
                                          f"{request.transition.label!r} refused in state {state}: "
                                          f"{' '.join(str(exc).split())}")
                response.success = False
                return response

        def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
            try:
                self.configure()
            except (ParameterError, ValueError) as exc:
                self.get_logger().error(f"configure failed: {exc}")
                self.teardown()
                return TransitionCallbackReturn.FAILURE
            self.get_logger().info("configured (inactive: no identification, no publishing)")
            return TransitionCallbackReturn.SUCCESS

        def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
            with self.state_lock:
                self.reset_state("activate")  # start from the data that comes from now on
                if self.inputs is not None:
                    self.inputs.reset()
                self.active = True
            self.get_logger().info("active")
            return TransitionCallbackReturn.SUCCESS

        def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
            with self.state_lock:  # after a sample being handled, none is handled or published
                self.active = False
            self.get_logger().info("inactive: no identification, no publishing")
            return TransitionCallbackReturn.SUCCESS

        def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
            self.teardown()
            self.get_logger().info("cleaned up (unconfigured)")
            return TransitionCallbackReturn.SUCCESS

        def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
            self.teardown()
            self.finalized = True  # run_node ends the process (exit 0) once this transition is answered
            self.get_logger().info("shut down (finalized): the process ends")
            return TransitionCallbackReturn.SUCCESS

        def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
            self.teardown()
            return TransitionCallbackReturn.SUCCESS

    Managed.__name__ = Managed.__qualname__ = f"Managed{cls.__name__}"
    return Managed
