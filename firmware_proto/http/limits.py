"""What one connection may cost a server: the limits :mod:`~.protocol` enforces.

Every wait has a bound, so that no client, slow or silent, holds a connection (or the
server's shutdown) for longer than the server chose.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

__all__ = [
    "DEFAULT_BODY_TIMEOUT_S",
    "DEFAULT_HEAD_TIMEOUT_S",
    "DEFAULT_IDLE_TIMEOUT_S",
    "DEFAULT_MAX_CONNECTIONS",
    "DEFAULT_MAX_CONNECTIONS_PER_ADDRESS",
    "DEFAULT_MAX_DRAIN_BYTES",
    "DEFAULT_MAX_HEAD_BYTES",
    "DEFAULT_RESERVED_CONNECTIONS",
    "ErrorRenderer",
    "ServeLimits",
]

DEFAULT_IDLE_TIMEOUT_S = 15.0
"""A connection idle this long, s (no request under way, none begun), is closed."""
DEFAULT_HEAD_TIMEOUT_S = 10.0
"""From a request's first byte to the end of its head, s; a slowloris is answered 408 and closed."""
DEFAULT_BODY_TIMEOUT_S = 10.0
"""From the end of a request's head to the end of its body (408 past it)."""
DEFAULT_MAX_CONNECTIONS = 1024
"""Open connections at once; the next is answered 503 and closed (each: a few kB and an fd)."""
DEFAULT_MAX_CONNECTIONS_PER_ADDRESS = 256
"""Open connections from one address; beyond, its oldest idle one makes room, else 503."""
DEFAULT_RESERVED_CONNECTIONS = 64
"""Of :data:`DEFAULT_MAX_CONNECTIONS`, kept for connections that showed the token (if any)."""
DEFAULT_MAX_HEAD_BYTES = 16 * 1024
"""Largest request head (h11's limit): beyond it, 431."""
DEFAULT_MAX_DRAIN_BYTES = 1 << 20
"""Bytes of an unread body (413, 415...) read and dropped after the answer, so that the client gets
it instead of a reset; past it the connection is closed."""

ErrorRenderer = Callable[[int, str, str], tuple[str, bytes]]
"""``(status, code, message) -> (content_type, body)``: how a server words the errors
the connection layer answers by itself (400 malformed request, 408, 431, 503)."""


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number of seconds, got {value}")


@dataclass(frozen=True)
class ServeLimits:
    """The bounds of one server's connections (each default's constant says what it bounds).

    Attributes:
        idle_timeout_s, head_timeout_s, max_connections, max_connections_per_address,
            max_head_bytes, max_drain_bytes: see the ``DEFAULT_*`` constants.
        body_timeout_s: see :data:`DEFAULT_BODY_TIMEOUT_S` (applied by
            :func:`~firmware_proto.http.body.read_body`).
        write_timeout_s: a client that has taken none of the answer for this long is cut off.
        reserved_connections: of ``max_connections``, kept for connections that have shown
            the token; 0 where there is no token (``< max_connections``).
        drain_timeout_s: on shutdown, how long requests under way may take.

    Raises:
        ValueError: a timeout that is not a positive number, a count below 1.
    """

    idle_timeout_s: float = DEFAULT_IDLE_TIMEOUT_S
    head_timeout_s: float = DEFAULT_HEAD_TIMEOUT_S
    body_timeout_s: float = DEFAULT_BODY_TIMEOUT_S
    write_timeout_s: float = DEFAULT_IDLE_TIMEOUT_S
    max_connections: int = DEFAULT_MAX_CONNECTIONS
    max_connections_per_address: int = DEFAULT_MAX_CONNECTIONS_PER_ADDRESS
    reserved_connections: int = 0
    max_head_bytes: int = DEFAULT_MAX_HEAD_BYTES
    max_drain_bytes: int = DEFAULT_MAX_DRAIN_BYTES
    drain_timeout_s: float = 30.0

    def __post_init__(self) -> None:
        for name in (
            "idle_timeout_s",
            "head_timeout_s",
            "body_timeout_s",
            "write_timeout_s",
            "drain_timeout_s",
        ):
            _positive(name, getattr(self, name))
        for name in (
            "max_connections",
            "max_connections_per_address",
            "max_head_bytes",
            "max_drain_bytes",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0 <= self.reserved_connections < self.max_connections:
            raise ValueError(
                f"reserved_connections must be in [0, max_connections), got "
                f"{self.reserved_connections}"
            )
