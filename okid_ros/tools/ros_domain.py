"""The ROS domain of the commands that talk over DDS, checked before rclpy or a node starts.

rcl refuses a ``ROS_DOMAIN_ID`` that is not an integer with an RCLError (an internal error of
`monitor`, `replay`, `record`, `info --selftest`; a ValueError of `demo`), and Fast DDS cannot
open the UDP ports it derives from one beyond :data:`MAX_DOMAIN_ID` (`monitor` and `up` ended
with status 1 and Fast DDS's own lines). An ``RMW_IMPLEMENTATION`` that is not installed ended
them with rcl's own lines and status 102 (:func:`rmw_implementation`, checked with the domain).
Said once, in one line, for every such command.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from pathlib import Path

from okid_ros.tools.errors import ToolParameterError

__all__ = ["MAX_DOMAIN_ID", "check_ros_environment", "installed_rmw_implementations", "rmw_implementation",
           "ros_domain_id", "ros_context"]

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


def installed_rmw_implementations(environ: Mapping[str, str] | None = None) -> tuple[list[str], list[Path]]:
    """The RMW implementations installed, and the folders their libraries may be in.

    Those the ament index lists (``rmw_typesupport``, as ROS's own tools read it, without the
    dispatcher ``rmw_implementation``) under ``AMENT_PREFIX_PATH`` and this interpreter's prefix (the
    wheels); the folders: those prefixes' ``lib`` and ``LD_LIBRARY_PATH``.
    """
    env = os.environ if environ is None else environ
    prefixes = [Path(p) for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [Path(sys.prefix)]
    names = {entry.name for prefix in prefixes
             for entry in _listing(prefix / "share" / "ament_index" / "resource_index" / "rmw_typesupport")}
    folders = [prefix / "lib" for prefix in prefixes]
    folders += [Path(p) for p in env.get("LD_LIBRARY_PATH", "").split(os.pathsep) if p]
    return sorted(names - {"rmw_implementation"}), folders


def _listing(folder: Path) -> list[Path]:
    return list(folder.iterdir()) if folder.is_dir() else []


def rmw_implementation(environ: Mapping[str, str] | None = None) -> str | None:
    """``RMW_IMPLEMENTATION``, None when it is unset or empty (rmw's default).

    Raises
    ------
    ToolParameterError
        it names an implementation neither the ament index lists nor whose library
        (``librmw_NAME.so``) is found (:func:`installed_rmw_implementations`), where the index
        lists some.
    """
    name = (os.environ if environ is None else environ).get("RMW_IMPLEMENTATION", "")
    if not name:
        return None
    installed, folders = installed_rmw_implementations(environ)
    # With no index found (an install laid out otherwise) rcl is left to judge: a refusal here
    # would stop a name it would load.
    if not installed or name in installed or any((folder / f"lib{name}.so").is_file() for folder in folders):
        return name
    raise ToolParameterError(f"RMW_IMPLEMENTATION={name!r} is not installed (installed: "
                             f"{', '.join(installed)}): set one of those, or unset it for the default")


def check_ros_environment(environ: Mapping[str, str] | None = None) -> int | None:
    """``RMW_IMPLEMENTATION`` and ``ROS_DOMAIN_ID`` checked before rclpy loads; the domain id (:func:`ros_domain_id`).

    rcl ends the process (status 102) as soon as it loads an RMW implementation that is not
    installed, so every command that talks over DDS calls this before it imports rclpy.

    Raises
    ------
    ToolParameterError
        as :func:`rmw_implementation` or :func:`ros_domain_id`.
    """
    rmw_implementation(environ)
    return ros_domain_id(environ)


def ros_context():
    """A new rclpy context, initialized, once the environment is checked (:func:`check_ros_environment`)."""
    import rclpy

    check_ros_environment()
    context = rclpy.Context()
    rclpy.init(context=context, args=[])
    return context
