"""Exceptions raised by the link-I/O layer (:mod:`firmware_proto.linkio`)::

    LinkError            a medium cannot be opened, read or written; also OSError
     +-- LinkUrlError    a link URL is malformed: permanent, never retried; also ValueError
     +-- LinkBusyError   another process holds the device exclusively

The bridge's transport errors derive from these (:mod:`bridge.errors`), so a caller
of either layer catches what it knows.
"""

from __future__ import annotations

__all__ = ["LinkBusyError", "LinkError", "LinkUrlError"]


class LinkError(OSError):
    """A medium cannot be opened, read or written."""


class LinkUrlError(LinkError, ValueError):
    """A link URL is malformed (unknown scheme, missing host or port, bad option, a CAN
    node id out of range). Raised before anything is opened; no retry can fix it."""


class LinkBusyError(LinkError):
    """Another process holds the device's exclusive lock."""
