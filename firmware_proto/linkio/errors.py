"""Exceptions raised by the link-I/O layer (:mod:`firmware_proto.linkio`)::

    LinkError                  a medium cannot be opened, read or written; also OSError
     +-- LinkUrlError          a link URL is malformed: permanent, never retried; also
     |    |                    ValueError
     |    +-- UnknownSchemeError  its scheme names no medium
     +-- LinkBusyError         another process holds the device exclusively
    ExpectationError           a scripted host's expectation failed (what a test or a
     |                         conformance rule reports, not a fault of the medium)
     +-- NotReceivedError      what it awaited did not come in time; also TimeoutError
     +-- UnexpectedMessageError  what must not come came

The bridge's transport errors derive from these (:mod:`bridge.errors`), so a caller
of either layer catches what it knows.
"""

from __future__ import annotations

__all__ = [
    "ExpectationError",
    "LinkBusyError",
    "LinkError",
    "LinkUrlError",
    "NotReceivedError",
    "UnexpectedMessageError",
    "UnknownSchemeError",
]


class LinkError(OSError):
    """A medium cannot be opened, read or written."""


class LinkUrlError(LinkError, ValueError):
    """A link URL is malformed (unknown scheme, missing host or port, bad option, a CAN
    node id out of range). Raised before anything is opened; no retry can fix it."""


class UnknownSchemeError(LinkUrlError):
    """A link URL's scheme names no medium (:data:`firmware_proto.linkio.media.SCHEMES`);
    the message lists the known ones."""


class LinkBusyError(LinkError):
    """Another process holds the device's exclusive lock."""


class ExpectationError(Exception):
    """A scripted host (:class:`~firmware_proto.linkio.host.ProtocolHost`) did not get
    what it expected; the message says what, and what came instead where it knows."""


class NotReceivedError(ExpectationError, TimeoutError):
    """What the host awaited did not come within its timeout."""


class UnexpectedMessageError(ExpectationError):
    """A message the host required to be absent came."""
