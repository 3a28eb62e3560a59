"""uvicorn's h11 connection with this project's limits: :class:`GuardedH11Protocol`.

uvicorn serves the ASGI apps and h11 parses HTTP/1.1 strictly. What uvicorn leaves open,
this protocol bounds (the numbers are :class:`~.limits.ServeLimits`; docs/gate.md says
why a subclass):

- *Silent and slow clients.* A connection waits at most ``idle_timeout_s`` for a request
  to start (new connections too), and the head must then arrive whole within
  ``head_timeout_s`` (else 408 and closed; a slowloris costs no thread meanwhile).
- *Readers that stop reading.* A response not taken for ``write_timeout_s`` ends the
  connection.
- *Unread bodies.* After an answer given without reading the body, at most
  ``max_drain_bytes`` of it are read and dropped within the same deadlines, so the
  client reads the answer.
- *Connections.* At most ``max_connections`` open, ``max_connections_per_address`` from
  one address, ``max_connections - reserved_connections`` not shown to hold the token.
  A new connection over a limit evicts the oldest *idle* one under it, never-served ones
  first (one with a request waiting unread is not idle; a token holder is never evicted
  for an anonymous one), else gets 503. One let in over the anonymous limit is served
  one request, then closed unless it showed the token. (Room is kept by evicting, not
  refusing: the token is read only after a head.)
- *Heads* over ``max_head_bytes``: 431, in pieces or whole.
- *A client that half-closes* after its request still gets its answer; one that closes
  mid-body gets 400 ``truncated_body``. Either way the request's
  :class:`~firmware_proto.http.connection.ConnectionMark` says the peer has closed.
- *Ambiguous framing* (both ``Content-Length`` and ``Transfer-Encoding``): 400 and
  closed (smuggling); an HTTP version other than 1.0 or 1.1: 505.
- *Errors the connection answers itself* (400, 408, 431, 503) are worded by the server's
  :data:`~.limits.ErrorRenderer`, so that a JSON API stays JSON.

The hooks overridden are uvicorn's ``asyncio.Protocol`` callbacks and its
``send_400_response``, given through ``uvicorn.Config(http=...)``; ``pyproject.toml``
pins the uvicorn versions tested.
"""

from __future__ import annotations

import array
import asyncio
import fcntl
import logging
import math
import sys
import termios
from http import HTTPStatus
from typing import Any, cast

import h11
import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol
from uvicorn.server import ServerState

from firmware_proto.http.connection import CONNECTION_EXTENSION, ConnectionMark
from firmware_proto.http.limits import ErrorRenderer, ServeLimits

__all__ = ["GuardedH11Protocol", "ServeConfig", "classify_protocol_error"]

logger = logging.getLogger(__name__)

_FRAMING_WORDS = ("content-length", "transfer-encoding", "chunk")


def classify_protocol_error(hint: int, text: str) -> tuple[int, str]:
    """The status and code of a request h11 refused: 431
    ``request_header_fields_too_large`` for a head over the limit, 400 ``bad_framing`` for a
    malformed ``Content-Length``/``Transfer-Encoding`` or chunk (h11's 501 hint for an
    unknown coding included), else 400 ``bad_request``."""
    if hint == 431:
        return 431, "request_header_fields_too_large"
    lowered = text.lower()
    if any(word in lowered for word in _FRAMING_WORDS):
        return 400, "bad_framing"
    return 400, "bad_request"


def _refusal(version: str, names: set[bytes]) -> tuple[int, str, str] | None:
    """What h11 lets through but we refuse: ``(status, code, message)`` or ``None``."""
    if version not in ("1.0", "1.1"):
        return 505, "http_version_not_supported", f"HTTP/{version} is not supported"
    if b"transfer-encoding" in names and b"content-length" in names:
        # h11 lets Transfer-Encoding win (RFC 9112 6.3); a server may refuse instead,
        # and must close: a mismatch between the two is how requests are smuggled.
        return 400, "bad_framing", "both Transfer-Encoding and Content-Length given"
    return None


def _head_bytes(scope: Any) -> int:
    """The size of a request's head as sent (request line and header lines)."""
    line = len(scope["method"]) + len(scope["raw_path"]) + len(scope["query_string"]) + 12
    return line + sum(len(name) + len(value) + 4 for name, value in scope["headers"])


def _unread_bytes(transport: asyncio.BaseTransport) -> int:
    """Bytes the client sent that the server has not read yet (``FIONREAD``; 0 where the
    socket cannot say): a connection accepted while the loop was busy may hold a request."""
    sock = transport.get_extra_info("socket")
    if sock is None:
        return 0
    count = array.array("i", [0])
    try:
        fcntl.ioctl(sock.fileno(), termios.FIONREAD, count)
    except OSError:
        return 0
    return count[0]


def _evict(candidates: list[GuardedH11Protocol]) -> bool:
    """Close the first to go among ``candidates``: idle, anonymous, never served before
    served, oldest first. Whether one was closed."""
    idle = [c for c in candidates if c._evictable()]
    if not idle:
        return False
    victim = min(idle, key=lambda c: (c._served, c._since))
    logger.info(
        "evicting an idle connection from %s (%s) for a new one",
        victim._mark.address,
        "served before" if victim._served else "never a whole request",
    )
    victim.transport.close()
    victim.connections.discard(victim)  # its place is free now, before its callbacks run
    return True


class ServeConfig(uvicorn.Config):
    """uvicorn's settings for one of our servers, carrying ``limits`` (the connection bounds)
    and ``render_error`` (how connection-level errors are worded) to each connection;
    ``server_name`` is the ``Server`` header, ``host`` only for uvicorn's messages (the
    caller binds the socket)."""

    def __init__(
        self,
        app: Any,
        *,
        host: str,
        limits: ServeLimits,
        render_error: ErrorRenderer,
        server_name: str,
    ) -> None:
        self.limits = limits
        self.render_error = render_error
        super().__init__(
            app,
            host=host,
            http=GuardedH11Protocol,
            ws="none",
            lifespan="off",
            interface="asgi3",
            log_config=None,
            access_log=False,
            proxy_headers=False,
            server_header=False,
            headers=[("Server", server_name)],
            timeout_keep_alive=max(1, math.ceil(limits.idle_timeout_s)),
            timeout_graceful_shutdown=max(1, math.ceil(limits.drain_timeout_s)),
            h11_max_incomplete_event_size=limits.max_head_bytes,
        )


class GuardedH11Protocol(H11Protocol):
    """One connection, bounded as the module docstring says; set up by :class:`ServeConfig` only."""

    def __init__(
        self,
        config: uvicorn.Config,
        server_state: ServerState,
        app_state: dict[str, Any],
        _loop: asyncio.AbstractEventLoop | None = None,
    ) -> None:
        super().__init__(config, server_state, app_state, _loop)
        guard = cast(ServeConfig, config)
        self._limits = guard.limits
        self._render = guard.render_error
        self._deadline: asyncio.TimerHandle | None = None
        self._waiting = ""  # "idle" before a request's first byte, "head" after it
        self._write_timer: asyncio.TimerHandle | None = None
        self._drained = 0
        self._peer_eof = False
        self._mark = ConnectionMark()
        self._since = 0.0
        self._served = False  # a request on it has been answered
        self._provisional = False  # let in over the anonymous limit: one request

    # -- the connection ----------------------------------------------------------------
    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._mark.address = self.client[0] if self.client else ""
        self._since = self.loop.time()
        if not self._make_room():
            self._answer_and_close(503, "too_many_connections", "too many open connections")
            return
        self._wait("idle", self._limits.idle_timeout_s)

    def _make_room(self) -> bool:
        """Apply the connection limits to this new connection (module docstring):
        evict what must go; ``False`` when it cannot be let in."""
        limits = self._limits
        address = self._mark.address
        mine = [c for c in self._others() if c._mark.address == address]
        if len(mine) >= limits.max_connections_per_address and not _evict(mine):
            logger.warning("refusing a connection from %s: %d open from it", address, len(mine))
            return False
        others = self._others()  # without the one evicted above
        if len(others) >= limits.max_connections and not _evict(others):
            logger.warning("refusing a connection: %d open", len(others))
            return False
        if limits.reserved_connections:
            anonymous = [c for c in self._others() if not c._mark.trusted]
            if len(anonymous) >= limits.max_connections - limits.reserved_connections:
                self._provisional = not _evict(anonymous)
        return True

    def _others(self) -> list[GuardedH11Protocol]:
        """The server's other open connections (one already closing holds no place)."""
        return [
            c
            for c in self.connections
            if c is not self and isinstance(c, GuardedH11Protocol) and not c.transport.is_closing()
        ]

    def _evictable(self) -> bool:
        """Idle (no request under way or waiting unread), not holding the token, not closing."""
        cycle = self.cycle
        idle = cycle is None or cycle.response_complete
        return (
            idle
            and not self._mark.trusted
            and not self.transport.is_closing()
            and not _unread_bytes(self.transport)
        )

    def connection_lost(self, exc: Exception | None) -> None:
        self._mark.close()
        self._cancel_deadline()
        if self._write_timer is not None:
            self._write_timer.cancel()
            self._write_timer = None
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._waiting == "idle":  # the first byte of the next request (or of a drain)
            self._wait("head", self._limits.head_timeout_s)
        cycle = self.cycle
        if (
            cycle is not None and cycle.response_complete and self.conn.their_state is h11.SEND_BODY
        ):  # the rest of a body we answered without reading
            self._drained += len(data)
            if self._drained > self._limits.max_drain_bytes:
                logger.debug("closing: more than %d bytes of an unread body", self._drained)
                self.transport.close()
                return
        super().data_received(data)

    def handle_events(self) -> None:
        before = self.cycle
        super().handle_events()
        cycle = self.cycle
        if cycle is not before and cycle is not None:  # a request's head arrived whole
            self._cancel_deadline()
            self._drained = 0
            # The application's task exists but has not run: it sees the mark.
            extensions: dict[str, Any] = cast(dict[str, Any], self.scope).setdefault(
                "extensions", {}
            )
            extensions[CONNECTION_EXTENSION] = self._mark
            refusal = _refusal(self.scope["http_version"], {name for name, _ in self.headers})
            if refusal is None and _head_bytes(self.scope) > self._limits.max_head_bytes:
                refusal = (
                    431,
                    "request_header_fields_too_large",
                    f"request head over {self._limits.max_head_bytes} bytes",
                )
            if refusal is not None:
                self._answer_and_close(*refusal)
                cycle.disconnected = True  # the application's answer, if any, is dropped
                cycle.message_event.set()

    def on_response_complete(self) -> None:
        self._served = True
        if self._provisional and not self._mark.trusted:
            self.transport.close()  # one request, then its place is given back
        else:
            self._wait("idle", self._limits.idle_timeout_s)
        super().on_response_complete()
        if self._peer_eof and not self.transport.is_closing():
            self.transport.close()  # the client said it sends nothing more

    def eof_received(self) -> bool | None:  # type: ignore[override]  # asyncio allows a bool
        self._mark.close()
        cycle = self.cycle
        if cycle is None or cycle.response_complete:
            return None  # nothing under way: close
        if self.conn.their_state is h11.SEND_BODY and not cycle.response_started:
            self._answer_and_close(
                400, "truncated_body", "the connection ended before the request body did"
            )
            cycle.disconnected = True
            cycle.message_event.set()
            return None
        self._peer_eof = True  # half-closed after a whole request: answer it first
        return True

    # -- flow control -------------------------------------------------------------------
    def pause_writing(self) -> None:
        super().pause_writing()
        if self._write_timer is None:
            self._write_timer = self.loop.call_later(
                self._limits.write_timeout_s, self._write_stalled
            )

    def resume_writing(self) -> None:
        super().resume_writing()
        if self._write_timer is not None:
            self._write_timer.cancel()
            self._write_timer = None

    def _write_stalled(self) -> None:
        self._write_timer = None
        logger.info(
            "dropping %s: it took nothing for %g s", self.client, self._limits.write_timeout_s
        )
        self.transport.abort()

    # -- errors answered here ------------------------------------------------------------
    def send_400_response(self, msg: str) -> None:
        error = sys.exc_info()[1]  # uvicorn calls this while handling h11's error
        hint = int(getattr(error, "error_status_hint", 400))
        text = str(error) if error is not None else msg
        status, code = classify_protocol_error(hint, text)
        logger.info("malformed request from %s: %s", self.client, text)
        cycle = self.cycle
        if cycle is not None and cycle.response_started and not cycle.response_complete:
            self.transport.close()  # mid-answer: no room for another one
            return
        self._answer_and_close(status, code, f"malformed request: {text}")

    def _answer_and_close(self, status: int, code: str, message: str) -> None:
        """Write an error answer by hand (h11 may be in no state to frame one) and close."""
        if self.transport.is_closing():
            return
        content_type, body = self._render(status, code, message)
        head = (
            f"HTTP/1.1 {status} {HTTPStatus(status).phrase}\r\n"
            f"Content-Type: {content_type}\r\n"
            f"Content-Length: {len(body)}\r\n"
            "Cache-Control: no-store\r\n"
            "Connection: close\r\n\r\n"
        )
        self.transport.write(head.encode("latin-1") + body)
        self.transport.close()

    # -- deadlines -------------------------------------------------------------------------
    def _wait(self, what: str, timeout_s: float) -> None:
        self._cancel_deadline()
        self._waiting = what
        self._deadline = self.loop.call_later(timeout_s, self._expired)

    def _cancel_deadline(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None
        self._waiting = ""

    def _expired(self) -> None:
        waiting, self._waiting, self._deadline = self._waiting, "", None
        if self.transport.is_closing():
            return
        if waiting == "head" and self.conn.their_state is h11.IDLE:
            logger.info("slow request head from %s: 408", self.client)
            self._answer_and_close(
                408,
                "request_timeout",
                f"the request's head did not arrive whole within {self._limits.head_timeout_s:g} s",
            )
            return
        self.transport.close()
