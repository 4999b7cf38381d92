"""Launch both okid_ros nodes with one parameter file (ROS 2 installs with launch_ros).

    ros2 launch okid_ros okid.launch.py
    ros2 launch okid_ros okid.launch.py params_file:=/path/to/my_okid.yaml use_sim_time:=true
    ros2 launch okid_ros okid.launch.py namespace:=/rig1     # /rig1/io_sample, /rig1/modal_states, ...
    ros2 launch okid_ros okid.launch.py node_options:=--lifecycle   # managed nodes

On the pip route (no launch_ros) use ``okid-ros up --params FILE``, which starts the same two
console scripts as separate processes.
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(get_package_share_directory("okid_ros"), "config", "okid.yaml")
    params_file = LaunchConfiguration("params_file")
    use_sim_time = LaunchConfiguration("use_sim_time")
    log_level = LaunchConfiguration("log_level")
    common = {
        "package": "okid_ros",
        # Empty: the root namespace (topics under /okid); /rig1: every topic and service in /rig1.
        "namespace": LaunchConfiguration("namespace"),
        "output": "screen",
        "emulate_tty": True,
        # A launch argument is a string: declare the type so use_sim_time is a bool parameter.
        "parameters": [params_file, {"use_sim_time": ParameterValue(use_sim_time, value_type=bool)}],
        "ros_arguments": ["--log-level", log_level],
        # "--lifecycle" (managed nodes, autostart) or "--lifecycle --no-autostart"; empty: plain nodes
        "arguments": [LaunchConfiguration("node_options")],
    }
    return LaunchDescription([
        DeclareLaunchArgument(
            "params_file", default_value=default_params,
            description="ROS 2 parameter file keyed by node name (okid_arx_identifier, okid_modal_estimator)",
        ),
        DeclareLaunchArgument(
            "use_sim_time", default_value="false",
            description="use /clock for the nodes' timers (bag replay, simulation)",
        ),
        DeclareLaunchArgument("log_level", default_value="info", description="ROS log level of both nodes"),
        DeclareLaunchArgument(
            "node_options", default_value="",
            description="'--lifecycle' runs both as managed nodes (configured and activated at once), "
            "'--lifecycle --no-autostart' leaves them unconfigured for a lifecycle manager",
        ),
        DeclareLaunchArgument(
            "namespace", default_value="",
            description="namespace of both nodes: every topic and service of the rig moves there "
            "(/rig1 -> /rig1/io_sample, /rig1/modal_states, ...); empty: topics under /okid",
        ),
        Node(executable="arx_identifier", name="okid_arx_identifier", **common),
        Node(executable="modal_estimator", name="okid_modal_estimator", **common),
    ])
