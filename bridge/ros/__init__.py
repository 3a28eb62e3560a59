"""The bridge's ROS 2 side: the node, its parameters and diagnostics, and the ROS
port (``rosport``) the ground station reuses; ``launch/``, ``config/`` and
``resource/`` are the ROS 2 package's data files (docs/ros2.md).
"""
