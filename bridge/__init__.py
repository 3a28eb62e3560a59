"""Rover-side ROS 2 bridge: /wheel_instructions to the wire protocol over USB-serial or
CAN, with a STOP lane, acks, heartbeats, odometry, diagnostics and reconnects; and the
ROS port (rclpy, or in-process for unit tests) that the ground-side executor reuses."""

__all__: list[str] = []
