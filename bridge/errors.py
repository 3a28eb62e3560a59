"""Exceptions raised by :mod:`bridge`.

Everything this package raises derives from :class:`BridgeError`::

    BridgeError
     +-- RosPortError       the ROS port (bridge.rosport) failed; its subclasses are drawn
                            in bridge/rosport/errors.py

Parts of the bridge add their own subclasses of :class:`BridgeError` beside
:class:`RosPortError`; this root stays the one thing callers need to catch.
"""

from __future__ import annotations

__all__ = ["BridgeError", "RosPortError"]


class BridgeError(Exception):
    """Root of every exception raised by the bridge package."""


class RosPortError(BridgeError):
    """The ROS port (any backend) cannot do what was asked."""
