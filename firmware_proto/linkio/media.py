"""Which endpoint a link URL names, built for either side.

:func:`open_endpoint` is the link layer's counterpart of the bridge's
``open_transport``: ``can://INTERFACE/CHANNEL?node=N`` gives a
:class:`~firmware_proto.linkio.can_endpoint.CanEndpoint`, a device path or a pyserial
URL (``socket://``, ``rfc2217://``, ``loop://``) a
:class:`~firmware_proto.linkio.serial_endpoint.SerialEndpoint`
(:mod:`firmware_proto.linkio.urls` parses both). The medium's module is imported only
when it is used, so a serial link never loads python-can.
"""

from __future__ import annotations

import importlib
from typing import Any

from firmware_proto.linkio.endpoint import Endpoint, Side
from firmware_proto.linkio.errors import LinkUrlError
from firmware_proto.linkio.urls import SERIAL_SCHEMES, is_can_url

__all__ = ["MEDIA", "medium_of", "open_endpoint"]

MEDIA: dict[str, tuple[str, str]] = {
    "can": ("firmware_proto.linkio.can_endpoint", "CanEndpoint"),
    "serial": ("firmware_proto.linkio.serial_endpoint", "SerialEndpoint"),
}
"""Medium -> (module, endpoint class), imported when first used."""


def medium_of(url: str) -> str:
    """``can`` or ``serial``: the medium ``url`` names.

    Raises:
        LinkUrlError: a scheme no medium knows (the message lists the known ones).
    """
    if is_can_url(url):
        return "can"
    if "://" in url:
        scheme = url.split("://", 1)[0]
        if scheme not in SERIAL_SCHEMES:
            known = ", ".join(["can", *sorted(s for s in SERIAL_SCHEMES if s), "a device path"])
            raise LinkUrlError(f"unknown link scheme {scheme!r} in {url!r}; known: {known}")
    return "serial"


def open_endpoint(url: str, side: Side, **options: Any) -> Endpoint:
    """Build (not open) the endpoint ``url`` names for ``side``; ``options`` go to its
    ``for_url`` (``recorder``, a serial ``baud`` or ``write_timeout_s``, a CAN ``node``
    or bus options).

    Raises:
        LinkUrlError: the URL names no medium, or is malformed (permanent).
    """
    module, name = MEDIA[medium_of(url)]
    cls = getattr(importlib.import_module(module), name)
    endpoint: Endpoint = cls.for_url(side, url, **options)
    return endpoint
