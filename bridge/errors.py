"""Exceptions raised by :mod:`bridge`.

Everything this package raises derives from :class:`BridgeError`::

    BridgeError
     +-- RosPortError       the ROS port (bridge.rosport) failed; its subclasses are drawn
     |                      in bridge/rosport/errors.py
     +-- TransportError     a device or bus cannot be opened, read or written; also OSError
     |    +-- TransportUrlError   the URL itself is malformed: permanent, never retried;
     |                            also ValueError
     +-- ParameterError     a bridge parameter is missing or out of range; also ValueError

Parts of the bridge add their own subclasses of :class:`BridgeError` beside
:class:`RosPortError`; this root stays the one thing callers need to catch.
"""

from __future__ import annotations

__all__ = [
    "BridgeError",
    "ParameterError",
    "RosPortError",
    "TransportError",
    "TransportUrlError",
]


class BridgeError(Exception):
    """Root of every exception raised by the bridge package."""


class RosPortError(BridgeError):
    """The ROS port (any backend) cannot do what was asked."""


class TransportError(BridgeError, OSError):
    """The link to the controller cannot be opened, read or written."""


class TransportUrlError(TransportError, ValueError):
    """A transport URL is malformed (unknown scheme, missing host or port, bad option).

    Permanent: raised when the transport is built, before anything is opened, and no
    reconnect can fix it. Everything that can change by itself (a device not there yet,
    a refused connection, a bus that is down) is a plain :class:`TransportError`.
    """


class ParameterError(BridgeError, ValueError):
    """A bridge parameter is missing, malformed or out of range; names the parameter."""
