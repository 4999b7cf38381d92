"""The numerical method without ROS: one module per step of the paper (docs/architecture.md)."""
