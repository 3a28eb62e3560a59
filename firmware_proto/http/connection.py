"""What the connection layer and the application share about one connection: a
:class:`ConnectionMark`, put in each request's ASGI scope under
``extensions[CONNECTION_EXTENSION]`` by :class:`~firmware_proto.http.protocol.GuardedH11Protocol`.

Plain data and an :class:`asyncio.Event`; touched on the server's event loop only.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field

__all__ = ["CONNECTION_EXTENSION", "ConnectionMark"]

CONNECTION_EXTENSION = "rover.connection"
"""Key in the ASGI scope's ``extensions`` holding the connection's :class:`ConnectionMark`."""


@dataclass(eq=False)
class ConnectionMark:
    """One connection as both layers see it.

    Attributes:
        address: the peer's address.
        trusted: a request on it presented the token (set by the application; a trusted
            connection is never evicted for an anonymous one).
        closed: the peer has closed its end (or the connection is lost); the application
            may stop work for it (:meth:`when_closed`).
    """

    address: str = ""
    trusted: bool = False
    closed: bool = False
    _waiter: asyncio.Future[None] | None = field(default=None, repr=False)

    def close(self) -> None:
        """The connection layer: the peer has closed (idempotent)."""
        self.closed = True
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(None)

    def when_closed(self) -> asyncio.Future[None]:
        """A future done once the peer has closed (for :func:`asyncio.wait`: no task to
        start, nothing to cancel). On the event loop."""
        if self._waiter is None:
            self._waiter = asyncio.get_running_loop().create_future()
            if self.closed:
                self._waiter.set_result(None)
        return self._waiter
