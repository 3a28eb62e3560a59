"""The one registry from a link URL to its medium, and the endpoint of each medium.

A link URL's scheme names its medium (:data:`SCHEMES`): ``can://`` is CAN; a device path
or a pyserial URL is serial. Each medium's endpoint class (:data:`ENDPOINTS`) is imported
only when used, so a serial link never loads python-can; the bridge keys its transports
by the same media (``bridge.link.transport.TRANSPORTS``). An unknown scheme is an
:class:`~firmware_proto.linkio.errors.UnknownSchemeError` listing the known ones.
"""

from __future__ import annotations

import importlib
from typing import Any, Final

from firmware_proto.linkio.endpoint import Endpoint, Side
from firmware_proto.linkio.errors import UnknownSchemeError
from firmware_proto.linkio.urls import SERIAL_SCHEMES

__all__ = ["ENDPOINTS", "MEDIA", "SCHEMES", "medium_of", "open_endpoint"]

MEDIA: Final = ("serial", "can")
"""The media of a link, by the names every tool uses (``--medium``, logs, lockstep)."""

ENDPOINTS: Final[dict[str, tuple[str, str]]] = {
    "serial": ("firmware_proto.linkio.serial_endpoint", "SerialEndpoint"),
    "can": ("firmware_proto.linkio.can_endpoint", "CanEndpoint"),
}
"""Medium -> (module, endpoint class), imported when first used."""

SCHEMES: Final[dict[str, str]] = {"can": "can"} | {s: "serial" for s in SERIAL_SCHEMES}
"""URL scheme -> medium (``""``: a device path)."""


def medium_of(url: str) -> str:
    """``serial`` or ``can``: the medium ``url`` names (by its scheme alone; the rest of
    the URL is checked by whoever opens it).

    Raises:
        UnknownSchemeError: a scheme no medium knows (the message lists the known ones).
    """
    scheme = url.split("://", 1)[0] if "://" in url else ""
    medium = SCHEMES.get(scheme)
    if medium is None:
        known = ", ".join([*(f"{s}://" for s in SCHEMES if s), "a device path"])
        raise UnknownSchemeError(f"unknown link scheme {scheme!r} in {url!r}; known: {known}")
    return medium


def open_endpoint(url: str, side: Side, **options: Any) -> Endpoint:
    """Build (not open) the endpoint ``url`` names for ``side``; ``options`` go to its
    ``for_url`` (``recorder``, a serial ``baud`` or ``write_timeout_s``, a CAN ``node``
    or bus options).

    Raises:
        LinkUrlError: the URL names no medium (:class:`UnknownSchemeError`), or is
            malformed (permanent).
    """
    module, name = ENDPOINTS[medium_of(url)]
    cls = getattr(importlib.import_module(module), name)
    endpoint: Endpoint = cls.for_url(side, url, **options)
    return endpoint
