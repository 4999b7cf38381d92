"""The ROS domain of the commands that talk over DDS, checked before rclpy or a node starts.

rcl refuses a ``ROS_DOMAIN_ID`` that is not an integer with an RCLError (an internal error of
`monitor`, `replay`, `record`, `info --selftest`; a ValueError of `demo`), and Fast DDS cannot
open the UDP ports it derives from one beyond :data:`MAX_DOMAIN_ID` (`monitor` and `up` ended
with status 1 and Fast DDS's own lines). Said once, in one line, for every such command.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

from okid_ros.tools.errors import ToolParameterError

__all__ = ["MAX_DOMAIN_ID", "ros_domain_id", "ros_context"]

#: The largest domain id whose ports Fast DDS can open with the default port base (7400 + 250 id).
MAX_DOMAIN_ID = 232


def ros_domain_id(environ: Mapping[str, str] | None = None) -> int | None:
    """``ROS_DOMAIN_ID`` as an integer, None when it is unset or empty (rcl's default, 0).

    Raises
    ------
    ToolParameterError
        it is not an integer, or beyond :data:`MAX_DOMAIN_ID`.
    """
    text = (os.environ if environ is None else environ).get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return None
    try:
        value = int(text)
    except ValueError:
        raise ToolParameterError(f"ROS_DOMAIN_ID={text!r} is not an integer, which ROS needs: set a number from 0 "
                                 f"to {MAX_DOMAIN_ID} (0 to 101 is safe everywhere), or unset it for 0") from None
    if value > MAX_DOMAIN_ID:
        raise ToolParameterError(f"ROS_DOMAIN_ID={value} is beyond {MAX_DOMAIN_ID}: Fast DDS derives its UDP ports "
                                 "from it and cannot open them (0 to 101 is safe everywhere)")
    return value


def ros_context():
    """A new rclpy context, initialized, once ``ROS_DOMAIN_ID`` is checked (:func:`ros_domain_id`)."""
    import rclpy

    ros_domain_id()
    context = rclpy.Context()
    rclpy.init(context=context, args=[])
    return context
