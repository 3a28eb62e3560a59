"""The live view's HTTP server: one static page, a Server-Sent Events stream, STOP.

A Starlette application on the gate's HTTP stack and application layer
(:mod:`firmware_proto.http`, :mod:`firmware_proto.http.app`); the page is one file
shipped with the package (nothing fetched from elsewhere).

======================  ========================================================
``GET /``               the page
``GET /events``         the push channel (``text/event-stream``; see :mod:`.hub`)
``GET /state``          the state a new client starts from, as JSON
``POST /stop``          emergency stop, exactly as Ctrl-C (202)
``POST /clear_stop``    release the latch: 409 unless a re-plan was approved since
                        the STOP
======================  ========================================================

Anything else gets a JSON error and the server goes on.

STOP skips the lane every other request shares (:data:`LANE_PER_TURN` per turn of the
event loop) and runs on its own thread (``view-stop``). STOP and clear-STOP need
:data:`ACTION_HEADER` and are refused from another origin whatever the token; ``Host``
must name this server; binding and tokens follow :mod:`firmware_proto.http.bindpolicy`.
At most ``max_clients`` browsers: a newcomer evicts the worst one it outranks
(:meth:`_Viewer.rank`), else gets a ``busy`` stream. Streams wait on their queues on a
small pool (``view-events``), never on the event loop. Details: docs/view.md "Never in
the mission's way", "Binding and tokens".
"""

from __future__ import annotations

import asyncio
import json
import logging
import secrets
import socket
import threading
import time
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from importlib import resources
from typing import Any
from urllib.parse import quote

from starlette.requests import Request
from starlette.responses import Response, StreamingResponse
from starlette.routing import Route
from starlette.types import Scope

from firmware_proto.http import (
    HttpService,
    RequestBodyError,
    ServeLimits,
    read_body,
)
from firmware_proto.http.app import (
    DEFAULT_SECURITY_HEADERS,
    AccessPolicy,
    build_app,
    require_same_origin,
)
from firmware_proto.http.bindpolicy import HostPolicy, check_bind, is_wildcard
from firmware_proto.http.errors import StatusError
from firmware_proto.http.limits import DEFAULT_MAX_CONNECTIONS
from planner.view.hub import ClientQueue, ViewHub

__all__ = [
    "ACTION_HEADER",
    "CLEAR_HEADER",
    "LANE_PER_TURN",
    "STATE_MAX_AGE_S",
    "ViewConfig",
    "ViewServer",
]

logger = logging.getLogger(__name__)

ACTION_HEADER = "X-Rover-View"
"""Header (value ``1``) STOP and clear-STOP must carry: no form or ``no-cors`` fetch can send it."""
CLEAR_HEADER = ACTION_HEADER
"""The same header, under the name it had when only clear-STOP needed it."""
LANE_PER_TURN = 4
"""Requests other than STOP and clear-STOP started per event-loop turn (the rest wait): keeps each
turn short and STOP a few short turns from its answer, whatever the flood."""
STATE_MAX_AGE_S = 0.1
"""``GET /state`` may answer a state this old, s (the ``tick`` period): encoded at most so often."""
RETRY_MS = 1000
"""The push channel's reconnect hint to a browser (``retry:``)."""
STALLED_S = 2.0
"""A stream whose last write has not completed for this long counts as stalled."""
_MAX_BODY = 4096
_KEEPALIVE_S = 1.0
PAGE_HEADERS: tuple[tuple[str, str], ...] = (
    (
        "Content-Security-Policy",
        "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
        "connect-src 'self'; img-src 'self' data:; base-uri 'none'; form-action 'none'; "
        "frame-ancestors 'none'",
    ),
)
"""The page's own policy: inline script and style, connections to this server only, no frames."""


@dataclass(frozen=True)
class ViewConfig:
    """Where and how the view listens.

    Attributes:
        host: address to bind (default loopback).
        port: TCP port; 0 picks a free one.
        token: bearer token; required when ``host`` is not loopback (and then strong).
        allowed_hosts: further names accepted in ``Host`` (beside its address,
            ``localhost`` on loopback, the machine's name on a wildcard bind).
        client_timeout_s: a browser that takes nothing of its stream for this long is
            dropped, s.
        max_clients: connections to the push channel at once.
        max_clients_per_address: of those, from one address.
        busy_retry_s: the ``retry:`` hint to a browser refused or evicted, s.
        hold_s: how long ``rover demo``/``rover go`` keep the view up after the mission, s.
        wait_s: how long they wait for a browser before the mission starts, s (0: not).

    Raises:
        ValueError: a bad port, token or timeout; a non-loopback host without a strong
            token (:class:`firmware_proto.errors.BindPolicyError`, a ``ValueError``).
    """

    host: str = "127.0.0.1"
    port: int = 0
    token: str | None = field(default=None, repr=False)
    allowed_hosts: tuple[str, ...] = ()
    client_timeout_s: float = 5.0
    max_clients: int = 16
    max_clients_per_address: int = 8
    busy_retry_s: float = 5.0
    hold_s: float = 0.0
    wait_s: float = 0.0

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ValueError(f"view port must be 0..65535, got {self.port}")
        check_bind(
            self.host,
            self.token,
            what="view token",
            hint="--view-token-file (or ROVER_VIEW_TOKEN)",
        )
        if not (
            self.client_timeout_s > 0
            and self.max_clients >= 1
            and self.max_clients_per_address >= 1
            and self.busy_retry_s > 0
            and self.hold_s >= 0
            and self.wait_s >= 0
        ):
            raise ValueError(
                "client_timeout_s and busy_retry_s must be > 0, max_clients and "
                "max_clients_per_address >= 1, hold_s and wait_s >= 0"
            )


def _page() -> bytes:
    return resources.files("planner.view").joinpath("index.html").read_bytes()


def _error_bytes(message: str) -> bytes:
    return json.dumps({"error": message}).encode()


def _error_body(error: StatusError) -> tuple[str, bytes]:
    """The view's wording of an error: ``{"error": message}`` (what the page shows)."""
    return "application/json", _error_bytes(error.message)


def _render_connection_error(status: int, code: str, message: str) -> tuple[str, bytes]:
    """The view's wording of the errors its connection layer answers itself."""
    return "application/json", _error_bytes(message)


@dataclass(eq=False)
class _Viewer:
    """One browser on the push channel, as the server ranks it."""

    queue: ClientQueue
    peer: tuple[str, int]
    trusted: bool
    since: float
    written: float
    """When its last write completed (monotonic s)."""
    evicted: bool = False

    @property
    def address(self) -> str:
        return self.peer[0]

    def rank(self, now: float) -> tuple[bool, bool, bool, float]:
        """Sorts the first to evict first: anonymous, stalled, fell behind, oldest."""
        stalled = now - self.written > STALLED_S
        return (self.trusted, not stalled, self.queue.dropped == 0, self.since)


class ViewServer:
    """Serves a :class:`~planner.view.hub.ViewHub`.

    Args:
        hub: the state and its events (started and closed by the caller).
        on_stop: sends the emergency stop (what Ctrl-C does) and says what it did;
            called on the server's STOP thread (``view-stop``), so it must not block for
            long (set the cancel event).
        on_clear: releases the STOP latch; returns whether the rover confirmed it
            (called on the ``view-action`` thread; it may wait for the rover).
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
        self._viewers: list[_Viewer] = []
        self.closing = False
        self.stops = 0
        """STOP requests served."""
        self.rejected = 0
        """Requests answered with an error (each is logged)."""
        self.evicted = 0
        """Push-channel browsers evicted for a new one."""
        self.refused = 0
        """Push-channel browsers refused (nobody they outrank to evict)."""
        self.token = config.token if config.token is not None else secrets.token_urlsafe(18)
        """The printed URL's token: configured or new (then tokenless requests are anonymous)."""
        extra = list(config.allowed_hosts)
        if is_wildcard(config.host):
            extra.append(socket.gethostname())
        policy = AccessPolicy(
            hosts=HostPolicy.for_bind(config.host, extra),
            token=self.token,
            token_required=config.token is not None,
            query_token=True,
            realm="rover-view",
        )
        self.app = build_app(
            [
                Route("/", self._page_endpoint, methods=["GET"]),
                Route("/index.html", self._page_endpoint, methods=["GET"]),
                Route("/events", self._events, methods=["GET"]),
                Route("/state", self._state, methods=["GET"]),
                Route("/stop", self._stop, methods=["POST"]),
                Route("/clear_stop", self._clear, methods=["POST"]),
            ],
            policy=policy,
            error_body=_error_body,
            on_error=self._count_error,
            headers=DEFAULT_SECURITY_HEADERS,
            priority=("/stop", "/clear_stop"),
            lane_per_turn=LANE_PER_TURN,
        )
        self._service = HttpService(
            self.app,
            host=config.host,
            port=config.port,
            # The operator's token always exists here: room is kept for it.
            limits=ServeLimits(
                write_timeout_s=config.client_timeout_s,
                reserved_connections=min(64, DEFAULT_MAX_CONNECTIONS // 4),
            ),
            render_error=_render_connection_error,
            server_name="rover-view",
            thread_name="view-http",
        )
        self._takers = ThreadPoolExecutor(config.max_clients, thread_name_prefix="view-events")
        self._stopper = ThreadPoolExecutor(1, thread_name_prefix="view-stop")
        self._actions = ThreadPoolExecutor(1, thread_name_prefix="view-action")

    @property
    def url(self) -> str:
        """The page's address with ``?token=`` (the operator's); after :meth:`start`."""
        return self._service.url + "/" + f"?token={quote(self.token)}"

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` bound; after :meth:`start`."""
        return self._service.address

    def start(self) -> ViewServer:
        """Bind and serve on a thread of its own (``OSError``: the address cannot be bound)."""
        try:
            self._service.start()
        except BaseException:
            for pool in (self._takers, self._stopper, self._actions):
                pool.shutdown(wait=False)
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

    @property
    def viewers(self) -> int:
        """Browsers on the push channel now."""
        with self._lock:
            return len(self._viewers)

    @property
    def peers(self) -> list[tuple[str, int]]:
        """``(address, port)`` of each browser on the push channel, oldest first."""
        with self._lock:
            return [v.peer for v in self._viewers]

    def viewer_state(self, peer: tuple[str, int]) -> dict[str, Any]:
        """How the server sees one browser: ``trusted``, ``dropped`` (records its queue
        dropped), ``stalled`` (its writes have not completed for :data:`STALLED_S`).

        Raises:
            KeyError: no such browser on the push channel.
        """
        now = time.monotonic()
        with self._lock:
            for v in self._viewers:
                if v.peer == peer:
                    return {
                        "trusted": v.trusted,
                        "dropped": v.queue.dropped,
                        "stalled": now - v.written > STALLED_S,
                    }
        raise KeyError(peer)

    def join(self, peer: tuple[str, int] = ("", 0), *, trusted: bool = False) -> ClientQueue | None:
        """A push-channel client, or ``None`` when closing or when every place is held
        by one it does not outrank (:meth:`_Viewer.rank`); a browser evicted for it has its
        queue closed."""
        viewer = self._join(peer, trusted)
        return None if viewer is None else viewer.queue

    def _join(self, peer: tuple[str, int], trusted: bool) -> _Viewer | None:
        now = time.monotonic()
        address = peer[0]
        with self._lock:
            if self.closing:
                return None
            same = [v for v in self._viewers if v.address == address]
            crowd = None
            if len(same) >= self.config.max_clients_per_address:
                crowd = same
            elif len(self._viewers) >= self.config.max_clients:
                crowd = self._viewers
            if crowd is not None:
                victims = [v for v in crowd if trusted or not v.trusted]
                if not victims:
                    self.refused += 1
                    return None
                victim = min(victims, key=lambda v: v.rank(now))
                victim.evicted = True
                self._viewers.remove(victim)
                self.evicted += 1
                logger.info(
                    "view: evicting a viewer at %s for a new one at %s",
                    victim.address or "?",
                    address or "?",
                )
                self.hub.unsubscribe(victim.queue)
            viewer = _Viewer(self.hub.subscribe(), peer, trusted, now, now)
            self._viewers.append(viewer)
            return viewer

    def leave(self, client: ClientQueue) -> None:
        """A push-channel client is gone."""
        self.hub.unsubscribe(client)
        with self._lock:
            self._viewers = [v for v in self._viewers if v.queue is not client]

    def close(self) -> None:
        """Stop serving; end every push-channel connection (idempotent)."""
        with self._lock:
            if self.closing:
                return
            self.closing = True
            clients = [v.queue for v in self._viewers]
        for client in clients:
            client.close()
        self._service.close()
        for pool in (self._takers, self._stopper, self._actions):
            pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> ViewServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the application ------------------------------------------------------------------
    def _count_error(self, scope: Scope, error: StatusError) -> None:
        with self._lock:
            self.rejected += 1
        logger.info(
            "view: %s %s: %d %s", scope.get("method"), scope.get("path"), error.status, error
        )

    async def _page_endpoint(self, request: Request) -> Response:
        return Response(self.page, 200, dict(PAGE_HEADERS), media_type="text/html; charset=utf-8")

    async def _state(self, request: Request) -> Response:
        return Response(self.hub.state_json(STATE_MAX_AGE_S), media_type="application/json")

    async def _read_body(self, request: Request) -> None:
        declared = request.headers.get("content-length")
        if declared is not None and int(declared) > _MAX_BODY:  # h11 checked the digits
            raise StatusError(f"body over {_MAX_BODY} bytes", status=413, code="payload_too_large")
        try:
            await read_body(request.receive, limit_bytes=_MAX_BODY, timeout_s=10.0)
        except RequestBodyError as exc:
            raise StatusError(exc.message, status=exc.status, code=exc.code) from exc

    async def _stop(self, request: Request) -> Response:
        require_same_origin(request, header=ACTION_HEADER)
        await self._read_body(request)
        try:
            done = await asyncio.get_running_loop().run_in_executor(self._stopper, self.stop)
        except Exception as exc:
            logger.exception("view: STOP failed")
            raise StatusError(f"STOP failed on the ground station: {exc}; use Ctrl-C") from exc
        return _json_response(202, {"stop": done})

    async def _clear(self, request: Request) -> Response:
        require_same_origin(request, header=ACTION_HEADER)
        await self._read_body(request)
        allowed, why = self.hub.clear_allowed()
        if not allowed:
            raise StatusError(f"STOP stays latched: {why}", status=409, code="conflict")
        try:
            cleared = await asyncio.get_running_loop().run_in_executor(self._actions, self.clear)
        except Exception as exc:  # the mission has ended: its ROS port is closed
            logger.warning("view: clear-STOP failed: %s", exc)
            raise StatusError(
                f"the ground station cannot release the latch now: {exc}",
                status=503,
                code="unavailable",
            ) from exc
        if not cleared:
            raise StatusError("the rover did not confirm CLEAR_STOP", status=504, code="timeout")
        return _json_response(200, {"cleared": True})

    async def _events(self, request: Request) -> Response:
        peer = (request.client.host, request.client.port) if request.client else ("", 0)
        viewer = self._join(peer, bool(request.state.trusted))
        if viewer is None:
            return StreamingResponse(
                self._busy(), media_type="text/event-stream", headers={"Cache-Control": "no-store"}
            )
        return StreamingResponse(
            self._stream(viewer),
            media_type="text/event-stream",
            headers={"Cache-Control": "no-store"},
        )

    async def _busy(self) -> AsyncIterator[bytes]:
        """The answer to a browser refused a place: come back later."""
        reason = f"all {self.config.max_clients} places are held by viewers that outrank you"
        logger.info("view: refused a viewer: %s", reason)
        retry_ms = round(self.config.busy_retry_s * 1000)
        yield f"retry: {retry_ms}\nevent: busy\ndata: {json.dumps({'reason': reason})}\n\n".encode()

    async def _stream(self, viewer: _Viewer) -> AsyncIterator[bytes]:
        """The push channel of one browser, until it leaves, is evicted or the view closes."""
        loop = asyncio.get_running_loop()
        client = viewer.queue
        try:
            yield f"retry: {RETRY_MS}\n\n".encode()
            while not self.closing:
                viewer.written = time.monotonic()
                records = await loop.run_in_executor(self._takers, client.take, _KEEPALIVE_S)
                if records:
                    yield b"".join(records)
                if client.closed:
                    if viewer.evicted:
                        why = {"reason": "evicted for a new viewer"}
                        retry_ms = round(self.config.busy_retry_s * 1000)
                        yield (
                            f"retry: {retry_ms}\nevent: evicted\n"
                            f"data: {json.dumps(why)}\n\n".encode()
                        )
                    break
                if not records:
                    yield b": keepalive\n\n"
        finally:
            logger.info("view: a viewer left")
            self.leave(client)


def _json_response(status: int, obj: dict[str, Any]) -> Response:
    return Response(json.dumps(obj).encode(), status, media_type="application/json")
