"""The link-I/O layer: both ends of the wire, on a serial line or a CAN bus.

``firmware_proto`` proper is pure: message definitions, codec, CAN map, plan schema,
rover description; no I/O, no threads, no python-can (a test holds it to that). This
sub-package sits on it and below both users of the wire, the bridge (the host's end)
and the emulator (the controller's end), which never import each other:

- :mod:`~firmware_proto.linkio.endpoint`: :class:`Endpoint`, one side's end of the link
  on one medium (``side`` decides what is taken in and which way frames are logged),
  with listeners for every frame;
- :mod:`~firmware_proto.linkio.serial_endpoint` and
  :mod:`~firmware_proto.linkio.can_endpoint`: the one serial and the one CAN
  implementation;
- :mod:`~firmware_proto.linkio.urls`: the one link-URL parser;
- :mod:`~firmware_proto.linkio.trafficio`: traffic logs, the listener that records;
- :mod:`~firmware_proto.linkio.replay_peer`: the replaying peer of both replays;
- :mod:`~firmware_proto.linkio.ptypair`: a raw pty pair.

It is a sub-package rather than a top-level one because the repository's top-level
layout is fixed; the arrows still point down: nothing in ``firmware_proto`` outside this
sub-package imports it (docs/linkio.md). Importing the package loads neither pyserial nor
python-can: each medium's module does, when it is used.
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
