"""Exceptions raised by :mod:`bridge`.

Everything this package raises derives from :class:`BridgeError`::

    BridgeError
     +-- RosPortError       the ROS port failed (subclasses: bridge/ros/rosport/errors.py)
     +-- TransportError     a device or bus cannot be opened, read or written; also OSError
     |    +-- TransportUrlError   the URL is malformed: permanent; also ValueError
     |    +-- DeviceBusyError     another process holds the device exclusively
     +-- ParameterError     a bridge parameter is missing or out of range; also ValueError
     +-- ConformanceError   the conformance suite cannot run (no link, a silent control port)
          +-- RuleFailedError   a controller broke a rule (reported, never raised out of the suite)
          +-- RuleNotRunError   a rule needs what the device lacks: "not run", never passed
"""

from __future__ import annotations

from firmware_proto.linkio.errors import LinkBusyError, LinkError, LinkUrlError

__all__ = [
    "BridgeError",
    "ConformanceError",
    "DeviceBusyError",
    "ParameterError",
    "RosPortError",
    "RuleFailedError",
    "RuleNotRunError",
    "TransportError",
    "TransportUrlError",
]


class BridgeError(Exception):
    """Root of every exception raised by the bridge package."""


class RosPortError(BridgeError):
    """The ROS port (any backend) cannot do what was asked."""


class TransportError(BridgeError, LinkError):
    """The link to the controller cannot be opened, read or written."""


class TransportUrlError(TransportError, LinkUrlError):
    """A transport URL is malformed (unknown scheme, missing host or port, bad option).

    Permanent: raised when the transport is built, before anything is opened.
    """


class DeviceBusyError(TransportError, LinkBusyError):
    """Another process holds the device's exclusive lock: a second bridge (or bench, or
    conformance run) on the same controller. ``rover bridge`` refuses to start on it."""


class ParameterError(BridgeError, ValueError):
    """A bridge parameter is missing, malformed or out of range; names the parameter."""


class ConformanceError(BridgeError):
    """The conformance suite cannot do what was asked (bridge.tools.conformance)."""


class RuleFailedError(ConformanceError):
    """A controller broke one rule: says what was expected and what came instead."""


class RuleNotRunError(ConformanceError):
    """A rule cannot run against this device; says what it needs."""
