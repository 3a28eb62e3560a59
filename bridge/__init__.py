"""Rover-side ROS 2 bridge: /wheel_instructions to the wire protocol over USB-serial or
CAN, with a STOP lane, acks, heartbeats, odometry, diagnostics and reconnects.

- ``link/``: the controller link (the pure core, its threaded shell, the transports);
- ``ros/``: the node, its parameters and diagnostics, and the ROS port the ground reuses;
- ``onboard/``: the rover's onboard sequencer and drift guard;
- ``tools/``: the lab's tools on the link (conformance, STOP bench, traffic, replay);
- ``cli_bridge``, ``cli_onboard``: ``rover bridge`` and ``rover onboard``.
"""

__all__: list[str] = []
