"""okid_ros: online observer/Kalman filter identification (OKID) for ROS 2 Jazzy.

Importing the package is cheap and never imports rclpy: the numerical core and most
commands work without ROS.
"""

__version__ = "0.1.0"  # kept equal to package.xml by test/commands/test_cli.py
