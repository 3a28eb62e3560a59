"""The live view's HTTP server: one static page, a Server-Sent Events stream, STOP.

An ASGI application (Starlette's request and response types) on the project's one HTTP
stack, the gate's (:mod:`firmware_proto.http`: uvicorn with h11, one event loop in
a thread of its own, every connection bounded by deadlines). The page is one file
shipped with the package (no build step, nothing fetched from elsewhere) and the push
channel is Server-Sent Events, which a browser's ``EventSource`` reads and reconnects by
itself.

======================  ========================================================
``GET /``               the page
``GET /events``         the push channel (``text/event-stream``; see :mod:`.hub`)
``GET /state``          the state a new client starts from, as JSON
``POST /stop``          emergency stop, exactly as Ctrl-C (202)
``POST /clear_stop``    release the latch: 409 unless a re-plan was approved since
                        the STOP; needs the header ``X-Rover-View: 1`` (a form of
                        another site cannot send it)
======================  ========================================================

Anything else gets a JSON error (400, 404, 405, 408, 413) and the server goes on.

Binding and auth, as the gate does it (:mod:`firmware_proto.http.bindpolicy`): loopback by
default; a non-loopback address is refused without a token; with a token every request
needs ``Authorization: Bearer <token>`` or ``?token=<token>`` (the page passes its own
on; ``EventSource`` cannot set headers), compared in constant time, else 401.

Never in the mission's way: each browser has a bounded queue (drop-oldest) filled by the
hub; a browser that takes nothing of the stream for ``client_timeout_s`` (its socket
full) is cut off by the connection layer, and a closed one only ends its own stream.
Waiting on a browser's queue happens on a thread of a small pool (``view-events``), one
per open stream at most, never on the event loop.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
from collections.abc import AsyncIterator, Awaitable, Callable, MutableMapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from importlib import resources
from typing import Any
from urllib.parse import quote

from starlette.requests import Request
from starlette.responses import Response, StreamingResponse

from firmware_proto.http import (
    ClientGoneError,
    HttpService,
    RequestBodyError,
    ServeLimits,
    read_body,
)
from firmware_proto.http.bindpolicy import bearer_token, check_bind, token_matches
from planner.view.hub import ClientQueue, ViewHub

__all__ = ["CLEAR_HEADER", "ViewConfig", "ViewServer"]

logger = logging.getLogger(__name__)

CLEAR_HEADER = "X-Rover-View"
"""Header a clear-STOP request must carry (value ``1``)."""
_MAX_BODY = 4096
_KEEPALIVE_S = 1.0
_ALLOW = {"Allow": "GET, POST"}

_Scope = MutableMapping[str, Any]
_Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]
_Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]


@dataclass(frozen=True)
class ViewConfig:
    """Where and how the view listens.

    Attributes:
        host: address to bind (default loopback).
        port: TCP port; 0 picks a free one.
        token: bearer token; required when ``host`` is not loopback.
        client_timeout_s: a browser that takes nothing of its stream for this long is
            dropped.
        max_clients: connections to the push channel at once (503 beyond).
        hold_s: how long ``rover demo``/``rover go`` keep the view up after the mission.
        wait_s: how long they wait for a browser to connect before the mission starts
            (0: they do not wait).

    Raises:
        ValueError: a bad port, token or timeout; a non-loopback host without a token
            (:class:`firmware_proto.errors.BindPolicyError`, a ``ValueError``).
    """

    host: str = "127.0.0.1"
    port: int = 0
    token: str | None = field(default=None, repr=False)
    client_timeout_s: float = 5.0
    max_clients: int = 16
    hold_s: float = 0.0
    wait_s: float = 0.0

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ValueError(f"view port must be 0..65535, got {self.port}")
        check_bind(
            self.host, self.token, what="view token", hint="--view-token (or ROVER_VIEW_TOKEN)"
        )
        if not (
            self.client_timeout_s > 0
            and self.max_clients >= 1
            and self.hold_s >= 0
            and self.wait_s >= 0
        ):
            raise ValueError(
                "client_timeout_s must be > 0, max_clients >= 1, hold_s and wait_s >= 0"
            )


def _page() -> bytes:
    return resources.files("planner.view").joinpath("index.html").read_bytes()


def _error_bytes(message: str) -> bytes:
    return json.dumps({"error": message}).encode()


def _render_connection_error(status: int, code: str, message: str) -> tuple[str, bytes]:
    """The view's wording of the errors its connection layer answers itself."""
    return "application/json", _error_bytes(message)


class _AnswerError(Exception):
    """An error answer: status, message, extra headers."""

    def __init__(self, status: int, message: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.headers = dict(headers or {})


class ViewServer:
    """Serves a :class:`~planner.view.hub.ViewHub` (see the module docstring).

    Args:
        hub: the state and its events (started and closed by the caller).
        config: where and how to listen.
        on_stop: sends the emergency stop (what Ctrl-C does) and says what it did;
            called on a worker thread of the server, so it must not block for long (set
            the cancel event).
        on_clear: releases the STOP latch; returns whether the rover confirmed it.
    """

    def __init__(
        self,
        hub: ViewHub,
        config: ViewConfig,
        *,
        on_stop: Callable[[], str],
        on_clear: Callable[[], bool] | None = None,
    ) -> None:
        self.hub = hub
        self.config = config
        self.page = _page()
        self._on_stop = on_stop
        self._on_clear = on_clear
        self._lock = threading.Lock()
        self._clients: set[ClientQueue] = set()
        self.closing = False
        self.stops = 0
        """STOP requests served."""
        self.rejected = 0
        """Requests answered with an error (each is logged)."""
        self._service = HttpService(
            self._asgi,
            host=config.host,
            port=config.port,
            limits=ServeLimits(write_timeout_s=config.client_timeout_s),
            render_error=_render_connection_error,
            server_name="rover-view",
            thread_name="view-http",
        )
        self._takers = ThreadPoolExecutor(config.max_clients, thread_name_prefix="view-events")
        self._actions = ThreadPoolExecutor(2, thread_name_prefix="view-action")

    @property
    def url(self) -> str:
        """The page's address (with ``?token=`` when there is a token); after
        :meth:`start`."""
        url = self._service.url + "/"
        return url + (f"?token={quote(self.config.token)}" if self.config.token else "")

    def start(self) -> ViewServer:
        """Bind and serve on a thread of its own.

        Raises:
            OSError: the address cannot be bound.
        """
        try:
            self._service.start()
        except BaseException:
            self._takers.shutdown(wait=False)
            self._actions.shutdown(wait=False)
            raise
        return self

    def stop(self) -> str:
        """The STOP button: hand the stop to the mission, tell every viewer; returns
        what ``on_stop`` did."""
        with self._lock:
            self.stops += 1
        self.hub.stop_requested("view")
        return self._on_stop()

    def clear(self) -> bool:
        """The clear-STOP control (the hub has allowed it)."""
        return self._on_clear() if self._on_clear is not None else False

    def join(self) -> ClientQueue | None:
        """A push-channel client, or ``None`` when full or closing."""
        with self._lock:
            if self.closing or len(self._clients) >= self.config.max_clients:
                return None
            client = self.hub.subscribe()
            self._clients.add(client)
            return client

    def leave(self, client: ClientQueue) -> None:
        """A push-channel client is gone."""
        self.hub.unsubscribe(client)
        with self._lock:
            self._clients.discard(client)

    def close(self) -> None:
        """Stop serving; end every push-channel connection (idempotent)."""
        with self._lock:
            if self.closing:
                return
            self.closing = True
            clients = list(self._clients)
        for client in clients:
            client.close()
        self._service.close()
        self._takers.shutdown(wait=True, cancel_futures=True)
        self._actions.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> ViewServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the ASGI application ------------------------------------------------------------
    async def _asgi(self, scope: _Scope, receive: _Receive, send: _Send) -> None:
        if scope["type"] != "http":
            return
        request = Request(scope, receive)
        try:
            response = await self._dispatch(request)
        except ClientGoneError:
            return
        except _AnswerError as exc:
            with self._lock:
                self.rejected += 1
            logger.info("view: %s %s: %d %s", request.method, scope["path"], exc.status, exc)
            headers = exc.headers | {"Cache-Control": "no-store"}
            if exc.status in (408, 413):
                headers["Connection"] = "close"
            response = Response(_error_bytes(exc.message), exc.status, headers, "application/json")
        await response(scope, receive, send)

    async def _dispatch(self, request: Request) -> Response:
        path = request.url.path
        if request.method == "GET":
            self._authorise(request)
            if path in ("/", "/index.html"):
                return self._reply(200, self.page, "text/html; charset=utf-8")
            if path == "/events":
                return self._events()
            if path == "/state":
                return self._json(200, self.hub.state())
            raise _AnswerError(404, f"no such page: {path}; try / or /events")
        if request.method == "POST":
            await self._read_body(request)
            self._authorise(request)
            if path == "/stop":
                return await self._stop()
            if path == "/clear_stop":
                return await self._clear(request)
            raise _AnswerError(404, f"no such action: {path}; try /stop or /clear_stop")
        raise _AnswerError(405, f"{request.method} is not served here", _ALLOW)

    # -- checks -----------------------------------------------------------------------------
    def _authorise(self, request: Request) -> None:
        token = self.config.token
        if token is None:
            return
        given = bearer_token(request.headers.get("authorization"))
        if given is None:
            given = request.query_params.get("token")
        if token_matches(given, token):
            return
        challenge = {"WWW-Authenticate": 'Bearer realm="rover-view"'}
        if not given:
            raise _AnswerError(
                401, "this view needs 'Authorization: Bearer <token>' or ?token=<token>", challenge
            )
        raise _AnswerError(401, "wrong token", challenge)

    async def _read_body(self, request: Request) -> None:
        declared = request.headers.get("content-length")
        if declared is not None and int(declared) > _MAX_BODY:  # h11 checked the digits
            raise _AnswerError(413, f"body over {_MAX_BODY} bytes")
        try:
            await read_body(request.receive, limit_bytes=_MAX_BODY, timeout_s=10.0)
        except RequestBodyError as exc:
            raise _AnswerError(exc.status, exc.message) from exc

    # -- answers ----------------------------------------------------------------------------
    @staticmethod
    def _reply(status: int, body: bytes, content_type: str) -> Response:
        return Response(body, status, {"Cache-Control": "no-store"}, content_type)

    def _json(self, status: int, obj: dict[str, Any]) -> Response:
        return self._reply(status, json.dumps(obj).encode(), "application/json")

    async def _in_thread(self, action: Callable[[], Any]) -> Any:
        return await asyncio.get_running_loop().run_in_executor(self._actions, action)

    async def _stop(self) -> Response:
        try:
            done = await self._in_thread(self.stop)
        except Exception as exc:
            logger.exception("view: STOP failed")
            raise _AnswerError(
                500, f"STOP failed on the ground station: {exc}; use Ctrl-C"
            ) from exc
        return self._json(202, {"stop": done})

    async def _clear(self, request: Request) -> Response:
        if request.headers.get(CLEAR_HEADER) != "1":
            raise _AnswerError(403, f"clear-STOP needs the header {CLEAR_HEADER}: 1")
        allowed, why = self.hub.clear_allowed()
        if not allowed:
            raise _AnswerError(409, f"STOP stays latched: {why}")
        try:
            cleared = await self._in_thread(self.clear)
        except Exception as exc:  # the mission has ended: its ROS port is closed
            logger.warning("view: clear-STOP failed: %s", exc)
            raise _AnswerError(
                503, f"the ground station cannot release the latch now: {exc}"
            ) from exc
        if not cleared:
            raise _AnswerError(504, "the rover did not confirm CLEAR_STOP")
        return self._json(200, {"cleared": True})

    def _events(self) -> Response:
        client = self.join()
        if client is None:
            raise _AnswerError(503, f"already {self.config.max_clients} viewers")
        return StreamingResponse(
            self._stream(client),
            media_type="text/event-stream",
            headers={"Cache-Control": "no-store"},
        )

    async def _stream(self, client: ClientQueue) -> AsyncIterator[bytes]:
        """The push channel of one browser, until it leaves or the view closes."""
        loop = asyncio.get_running_loop()
        try:
            yield b"retry: 1000\n\n"
            while not self.closing:
                records = await loop.run_in_executor(self._takers, client.take, _KEEPALIVE_S)
                if client.closed:
                    break
                yield b"".join(records) if records else b": keepalive\n\n"
        finally:
            logger.info("view: a viewer left")
            self.leave(client)
