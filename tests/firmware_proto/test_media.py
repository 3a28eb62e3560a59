"""One registry from a link URL to its medium: every scheme names a medium that has an
endpoint (and a bridge transport), and an unknown scheme is one error listing them."""

from __future__ import annotations

import importlib

import pytest

from bridge.errors import TransportUrlError
from bridge.link.transport import TRANSPORTS, open_transport
from firmware_proto.linkio.endpoint import HOST
from firmware_proto.linkio.errors import LinkUrlError, UnknownSchemeError
from firmware_proto.linkio.media import ENDPOINTS, MEDIA, SCHEMES, medium_of, open_endpoint
from firmware_proto.linkio.urls import SERIAL_SCHEMES


def test_every_medium_has_an_endpoint_and_a_transport_and_every_scheme_a_medium() -> None:
    assert tuple(ENDPOINTS) == MEDIA == tuple(TRANSPORTS)
    assert set(SCHEMES.values()) == set(MEDIA)
    assert set(SCHEMES) == {"can", *SERIAL_SCHEMES}
    for registry in (ENDPOINTS, TRANSPORTS):
        for module, name in registry.values():
            assert isinstance(getattr(importlib.import_module(module), name), type)


@pytest.mark.parametrize(
    ("url", "medium"),
    [
        ("can://virtual/rover?node=2", "can"),
        ("/dev/ttyACM0", "serial"),
        ("/dev/pts/7?baud=9600", "serial"),
        ("socket://127.0.0.1:7000", "serial"),
        ("loop://", "serial"),
    ],
)
def test_a_url_names_its_medium_by_its_scheme(url: str, medium: str) -> None:
    assert medium_of(url) == medium


def test_an_unknown_scheme_is_one_error_that_lists_the_known_ones() -> None:
    with pytest.raises(UnknownSchemeError) as err:
        medium_of("warp://x")
    text = str(err.value)
    assert text.startswith("unknown link scheme 'warp' in 'warp://x'; known: ")
    assert all(f"{s}://" in text for s in SCHEMES if s) and text.endswith("a device path")
    assert isinstance(err.value, LinkUrlError) and isinstance(err.value, ValueError)
    with pytest.raises(UnknownSchemeError):
        open_endpoint("warp://x", HOST)
    with pytest.raises(TransportUrlError, match="unknown link scheme 'warp'") as bridge:
        open_transport("warp://x")
    assert isinstance(bridge.value.__cause__, UnknownSchemeError)
