"""The application layer the gate and the live view share: Starlette's router, one
middleware of ours, and exception handlers that word every error in the server's body.

:func:`build_app` makes a Starlette application from a server's routes and an
:class:`AccessPolicy`. Each request passes, in order:

1. :class:`Guard` (pure ASGI middleware):

   - a method nobody defines is 501; a known one the path does not take falls through
     to the router's 405;
   - ``Host`` must name this server (421 ``misdirected_request``): against DNS rebinding;
   - the token: with one required, a request without it is 401; one that presents it is
     *trusted* (``request.state.trusted``), which outranks anonymous clients where the
     server ranks them;
   - the *lane* (:class:`Lane`): at most ``lane_per_turn`` ordinary requests start per
     turn of the event loop, the rest wait in order; ``priority`` paths (STOP) skip it,
     so a flood never delays them (docs/view.md, "STOP never waits");
   - security headers on every answer, and ``Connection: close`` after an error that
     leaves the connection in doubt (408, 5xx but 503) or while draining;
   - an unexpected exception is logged and answered 500.
2. Starlette's exception middleware: :class:`~.errors.StatusError` and the router's own
   404/405 are worded by the server's :data:`ErrorBody`.
3. Starlette's :class:`~starlette.routing.Router` (no slash redirects).

Threads: everything here runs on the server's event loop; ``on_error`` is called there.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field

from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import BaseRoute
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from firmware_proto.http.bindpolicy import HostPolicy, bearer_token, token_matches
from firmware_proto.http.connection import CONNECTION_EXTENSION, ConnectionMark
from firmware_proto.http.errors import ClientGoneError, StatusError

__all__ = [
    "API_HEADERS",
    "DEFAULT_SECURITY_HEADERS",
    "KNOWN_METHODS",
    "AccessPolicy",
    "ErrorBody",
    "Guard",
    "Lane",
    "build_app",
    "require_same_origin",
]

logger = logging.getLogger(__name__)

KNOWN_METHODS = frozenset(
    ("CONNECT", "DELETE", "GET", "HEAD", "OPTIONS", "PATCH", "POST", "PUT", "QUERY", "TRACE")
)
"""Methods HTTP defines (RFC 9110, QUERY): one a known path does not take is 405, others 501."""

DEFAULT_SECURITY_HEADERS: tuple[tuple[str, str], ...] = (
    ("X-Frame-Options", "DENY"),
    ("Content-Security-Policy", "default-src 'none'; frame-ancestors 'none'"),
    ("X-Content-Type-Options", "nosniff"),
    ("Referrer-Policy", "no-referrer"),
    ("Cross-Origin-Resource-Policy", "same-origin"),
    ("Cache-Control", "no-store"),
)
"""Added to every answer lacking the header: no other origin's page may frame, sniff or read it."""

API_HEADERS: tuple[tuple[str, str], ...] = (
    ("Content-Security-Policy", "default-src 'none'; frame-ancestors 'none'"),
    ("X-Content-Type-Options", "nosniff"),
    ("Cache-Control", "no-store"),
)
"""The same, shorter, for a JSON API no browser renders (each header costs h11 checks)."""


ErrorBody = Callable[[StatusError], tuple[str, bytes]]
"""``error -> (content_type, body)``: how a server words an error answer."""


@dataclass(frozen=True)
class AccessPolicy:
    """Who may use an application.

    Attributes:
        hosts: the ``Host`` values that name this server.
        token: the bearer token, or ``None``.
        token_required: requests without the token are refused (401); else they are
            served, anonymous.
        query_token: ``?token=`` is accepted besides ``Authorization: Bearer`` (the
            view: a browser's ``EventSource`` cannot set headers).
        realm: the realm of the ``WWW-Authenticate`` challenge.
    """

    hosts: HostPolicy
    token: str | None = field(default=None, repr=False)
    token_required: bool = False
    query_token: bool = False
    realm: str = "rover"

    def __post_init__(self) -> None:
        if self.token_required and self.token is None:
            raise ValueError("a required token needs a token")

    def presented(self, scope: Scope) -> str | None:
        """The token a request presents (header, then query when allowed), or ``None``."""
        header: str | None = None
        for name, value in scope["headers"]:
            if name == b"authorization":
                header = value.decode("latin-1")
                break
        given = bearer_token(header)
        if given is None and self.query_token and scope.get("query_string"):
            given = Request(scope).query_params.get("token")
        return given


class Lane:
    """Ordinary requests, ``per_turn`` at most started per turn of the event loop, the
    rest in order of arrival; see the module docstring. On the event loop only."""

    def __init__(self, per_turn: int) -> None:
        if per_turn < 1:
            raise ValueError(f"per_turn must be >= 1, got {per_turn}")
        self.per_turn = per_turn
        self._budget = per_turn
        self._waiting: deque[asyncio.Future[None]] = deque()
        self._armed = False

    @property
    def waiting(self) -> int:
        """Requests waiting for their turn."""
        return len(self._waiting)

    async def enter(self) -> None:
        """Return once this request may start (at once while the budget lasts, nobody waiting)."""
        loop = asyncio.get_running_loop()
        self._arm(loop)
        if self._budget > 0 and not self._waiting:
            self._budget -= 1
            return
        waiter: asyncio.Future[None] = loop.create_future()
        self._waiting.append(waiter)
        try:
            await waiter
        except asyncio.CancelledError:
            if waiter in self._waiting:
                self._waiting.remove(waiter)
            raise

    def _arm(self, loop: asyncio.AbstractEventLoop) -> None:
        if not self._armed:
            self._armed = True
            loop.call_soon(self._turn, loop)

    def _turn(self, loop: asyncio.AbstractEventLoop) -> None:
        """Each turn with traffic: a new budget, spent first on those waiting (start next turn)."""
        self._armed = False
        self._budget = self.per_turn
        while self._budget > 0 and self._waiting:
            waiter = self._waiting.popleft()
            if not waiter.done():
                waiter.set_result(None)
                self._budget -= 1
        if self._waiting:
            self._arm(loop)


def _header(scope: Scope, name: bytes) -> str | None:
    for key, value in scope["headers"]:
        if key == name:
            return str(value.decode("latin-1"))
    return None


class Guard:
    """The shared middleware: methods, ``Host``, token, lane, headers (module
    docstring). Not for use on its own: :func:`build_app` wires it."""

    def __init__(
        self,
        app: ASGIApp,
        *,
        policy: AccessPolicy,
        error_body: ErrorBody,
        on_error: Callable[[Scope, StatusError], None] | None = None,
        headers: Sequence[tuple[str, str]] = DEFAULT_SECURITY_HEADERS,
        priority: Collection[str] = (),
        lane_per_turn: int | None = None,
        closing: Callable[[], bool] | None = None,
    ) -> None:
        self.app = app
        self.policy = policy
        self.error_body = error_body
        self.on_error = on_error
        self.headers = [(k.lower().encode("latin-1"), v.encode("latin-1")) for k, v in headers]
        self.priority = frozenset(priority)
        self.lane = Lane(lane_per_turn) if lane_per_turn is not None else None
        self.closing = closing

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def guarded_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                message = self._with_headers(message)
            await send(message)

        try:
            self._admit(scope)
            if self.lane is not None and scope["path"] not in self.priority:
                await self.lane.enter()
            await self.app(scope, receive, guarded_send)
        except ClientGoneError:
            return  # nobody to answer
        except StatusError as error:
            if started:
                raise
            await self._answer(scope, receive, guarded_send, error)
        except Exception:
            logger.exception("internal error serving %s %s", scope["method"], scope["path"])
            if started:
                raise
            internal = StatusError("internal error; see the server's log")
            await self._answer(scope, receive, guarded_send, internal)

    def _admit(self, scope: Scope) -> None:
        """Refuse what no route may take (raises :class:`StatusError`); mark trust."""
        method = scope["method"]
        if method not in KNOWN_METHODS:
            raise StatusError(
                f"method {method} is not implemented here", status=501, code="not_implemented"
            )
        host = _header(scope, b"host")
        if not self.policy.hosts.allows(host):
            raise StatusError(
                f"this server does not answer to the host {host!r}",
                status=421,
                code="misdirected_request",
            )
        token = self.policy.token
        trusted = token is not None and token_matches(self.policy.presented(scope), token)
        state = scope.setdefault("state", {})
        state["trusted"] = trusted
        mark = scope.get("extensions", {}).get(CONNECTION_EXTENSION)
        if trusted and isinstance(mark, ConnectionMark):
            mark.trusted = True
        if self.policy.token_required and not trusted:
            challenge = f'Bearer realm="{self.policy.realm}"'
            if self.policy.presented(scope):
                raise StatusError(
                    "wrong bearer token",
                    status=401,
                    code="invalid_token",
                    headers={"WWW-Authenticate": challenge + ', error="invalid_token"'},
                )
            how = "'Authorization: Bearer <token>'" + (
                " or ?token=<token>" if self.policy.query_token else ""
            )
            raise StatusError(
                f"this server needs {how}",
                status=401,
                code="unauthorized",
                headers={"WWW-Authenticate": challenge},
            )

    def _with_headers(self, message: Message) -> Message:
        headers = list(message.get("headers", []))
        present = {name.lower() for name, _ in headers}
        headers.extend(h for h in self.headers if h[0] not in present)
        if self.closing is not None and self.closing() and b"connection" not in present:
            headers.append((b"connection", b"close"))
        return {**message, "headers": headers}

    async def _answer(self, scope: Scope, receive: Receive, send: Send, error: StatusError) -> None:
        await error_response(error, self.error_body, scope, self.on_error)(scope, receive, send)


def error_response(
    error: StatusError,
    error_body: ErrorBody,
    scope: Scope,
    on_error: Callable[[Scope, StatusError], None] | None,
) -> Response:
    """The answer to ``error``, worded by ``error_body``; ``on_error`` is told first."""
    if on_error is not None:
        on_error(scope, error)
    content_type, body = error_body(error)
    headers = dict(error.headers)
    if error.status == 408 or (error.status >= 500 and error.status != 503):
        headers["Connection"] = "close"
    return Response(body, error.status, headers, media_type=content_type)


def _as_http_error(scope: Scope, exc: Exception) -> StatusError:
    if isinstance(exc, StatusError):
        return exc
    if isinstance(exc, HTTPException) and exc.status_code == 405:
        allow = sorted(m.strip() for m in (exc.headers or {}).get("Allow", "").split(",") if m)
        return StatusError(
            f"{scope['method']} is not allowed on {scope['path']}",
            status=405,
            code="method_not_allowed",
            headers={"Allow": ", ".join(allow)},
            extra={"allow": allow},
        )
    if isinstance(exc, HTTPException) and exc.status_code == 404:
        return StatusError(f"no such path {scope['path']!r}", status=404, code="not_found")
    status = exc.status_code if isinstance(exc, HTTPException) else 500
    return StatusError(str(exc), status=status, code="http_error")


def build_app(
    routes: Sequence[BaseRoute],
    *,
    policy: AccessPolicy,
    error_body: ErrorBody,
    on_error: Callable[[Scope, StatusError], None] | None = None,
    headers: Sequence[tuple[str, str]] = DEFAULT_SECURITY_HEADERS,
    priority: Collection[str] = (),
    lane_per_turn: int | None = None,
    closing: Callable[[], bool] | None = None,
) -> Starlette:
    """A Starlette application serving ``routes`` (``GET`` brings ``HEAD``) behind
    :class:`Guard`.

    Args:
        policy: hosts and token.
        error_body: how the server words every error answer.
        on_error: told of every error answered (count, log); on the event loop.
        headers: added to every answer that does not set them.
        priority: paths that skip the lane.
        lane_per_turn: ordinary requests started per turn of the event loop (``None``: no
            lane).
        closing: when it returns true, every answer closes its connection (draining).
    """

    async def handle(request: Request, exc: Exception) -> Response:
        return error_response(
            _as_http_error(request.scope, exc), error_body, request.scope, on_error
        )

    app = Starlette(
        routes=list(routes),
        exception_handlers={StatusError: handle, HTTPException: handle},
    )
    app.router.redirect_slashes = False
    app.add_middleware(
        Guard,
        policy=policy,
        error_body=error_body,
        on_error=on_error,
        headers=headers,
        priority=priority,
        lane_per_turn=lane_per_turn,
        closing=closing,
    )
    return app


def require_same_origin(request: Request, *, header: str, value: str = "1") -> None:
    """Refuse a request that a page of another origin could have made: it must carry
    ``header: value`` (a form cannot set a header, and a cross-origin fetch that sets one
    needs a CORS preflight, never granted here); ``Origin``, when sent, must be this server's
    (scheme and ``Host``); ``Sec-Fetch-Site``, when sent, ``same-origin`` or ``none``.

    Raises:
        StatusError: 403 ``cross_origin``.
    """
    headers = request.headers
    origin = headers.get("origin")
    own = f"{request.url.scheme}://{headers.get('host', '')}".lower()
    site = headers.get("sec-fetch-site")
    why = ""
    if origin is not None and origin.lower() != own:
        why = f"the request comes from a page of {origin!r}, not of this server"
    elif site is not None and site.lower() not in ("same-origin", "none"):
        why = f"the browser says the request is {site!r} (Sec-Fetch-Site)"
    elif headers.get(header) != value:
        why = f"it needs the header {header}: {value}"
    if why:
        raise StatusError(f"refused: {why}", status=403, code="cross_origin")
