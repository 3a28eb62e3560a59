"""Rover-side ROS 2 bridge: /wheel_instructions to the wire protocol over USB-serial or
CAN, with a STOP lane, acks, heartbeats, odometry, diagnostics and reconnects.

- ``link/``: the controller link (the pure core, its threaded shell, the transports,
  odometry);
- ``ros/``: the node, its parameters and diagnostics, and the ROS port (rclpy, or
  in-process for unit tests) that the ground station reuses;
- ``tools/``: the lab's tools on the link (conformance suite, STOP bench, traffic
  decoding and replay);
- ``cli_bridge``: ``rover bridge``, which puts the link and the node together.
"""

__all__: list[str] = []
