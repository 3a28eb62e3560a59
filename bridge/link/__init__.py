"""The host side of the controller link: the pure protocol core (``linkcore``), its
threaded shell (``controllerlink``), the serial and CAN transports, odometry and the
operator's link lines (docs/bridge.md).
"""
