"""The link-I/O layer: both ends of the wire, on a serial line or a CAN bus
(docs/linkio.md).

It sits on the pure folders and below both users of the wire, the bridge (the host's
end) and the emulator (the controller's end), which never import each other: the
:class:`~.endpoint.Endpoint` and its serial and CAN implementations, the link-URL parser,
traffic logs, the replaying peer, a raw pty pair. Nothing else in ``firmware_proto``
imports it. Importing the package loads neither pyserial nor python-can.
"""

from __future__ import annotations

from firmware_proto.linkio.endpoint import CONTROLLER, HOST, SIDES, Endpoint, Side
from firmware_proto.linkio.errors import LinkBusyError, LinkError, LinkUrlError

__all__ = [
    "CONTROLLER",
    "HOST",
    "SIDES",
    "Endpoint",
    "LinkBusyError",
    "LinkError",
    "LinkUrlError",
    "Side",
]
