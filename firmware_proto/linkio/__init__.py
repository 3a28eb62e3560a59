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
sub-package imports it (docs/linkio.md).
"""

from __future__ import annotations

from typing import Any

from firmware_proto.linkio.can_endpoint import CanEndpoint
from firmware_proto.linkio.endpoint import CONTROLLER, HOST, SIDES, Endpoint, Side
from firmware_proto.linkio.errors import LinkBusyError, LinkError, LinkUrlError
from firmware_proto.linkio.serial_endpoint import SerialEndpoint
from firmware_proto.linkio.urls import is_can_url

__all__ = [
    "CONTROLLER",
    "HOST",
    "SIDES",
    "CanEndpoint",
    "Endpoint",
    "LinkBusyError",
    "LinkError",
    "LinkUrlError",
    "SerialEndpoint",
    "Side",
    "open_endpoint",
]


def open_endpoint(url: str, side: Side, **options: Any) -> Endpoint:
    """Build (not open) the endpoint a link URL names (:mod:`firmware_proto.linkio.urls`):
    a :class:`~firmware_proto.linkio.can_endpoint.CanEndpoint` for ``can://``, else a
    :class:`~firmware_proto.linkio.serial_endpoint.SerialEndpoint`. ``options`` go to
    their ``for_url`` (``baud``, ``node``, ``recorder``, bus options).

    Raises:
        LinkUrlError: the URL is malformed or names nothing known.
    """
    if is_can_url(url):
        return CanEndpoint.for_url(side, url, **options)
    return SerialEndpoint.for_url(side, url, **options)
