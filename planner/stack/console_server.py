"""The stack's console: ``rover status``, ``stop``, ``clear-stop`` and ``echo`` answered
by the running stack with no ROS 2 discovery in the command (docs/commands.md, "The
stack's console").

:class:`ConsoleServer` serves what its :class:`~planner.ground.console.RoverConsole` (an
rclpy port on the bridge's own topics, not through the emulated link, matched at start)
knows and does, over :mod:`firmware_proto.http`. The client:
:mod:`planner.ground.console_client`; who it answers: :mod:`planner.stack.consoleaccess`.

======================================  ===================================================
``GET /status``                         the bridge's latest ``/diagnostics``, its age, and
                                        ``plan``: ``rover onboard``'s latest report
                                        (``null``: none; docs/onboard.md)
``POST /stop?timeout=S``                ``true`` on ``emergency_stop`` at once, again
                                        every 0.5 s until the bridge says ``stopped``
``POST /clear_stop?timeout=S``          ``clear_emergency_stop``; the controller's
                                        answer. One at a time: 409 while one waits
``GET /echo?topic=T&count=N&timeout=S``  one JSON line per message of ``T`` (its last
                                        value first, where one is kept), streamed
======================================  ===================================================

STOP never waits: everything but a clear-STOP runs on the event loop (``console-http``)
without blocking it, and ``POST /stop`` publishes the moment it is admitted; a
clear-STOP runs on its own thread (``console-clear``), one at a time. The listener runs
on the ROS port's thread and only schedules a wake-up on the loop. Every wait is bounded
and ends when the server closes.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import secrets
import threading
import time
from collections import Counter, deque
from collections.abc import AsyncIterator, Awaitable, Callable, MutableMapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, TypeVar

from starlette.requests import Request
from starlette.responses import Response, StreamingResponse

from bridge.ros.rosport import STOP_LANE, RosPort, RosPortError, Subscription, qos
from bridge.ros.rosport.contract import STOPPED
from bridge.ros.rosport.msgs import Bool, DiagnosticArray, Empty, Int16MultiArray, Odometry, String
from firmware_proto.http import ClientGoneError, HttpService, RequestBodyError, ServeLimits
from firmware_proto.http import read_body as _read_body
from firmware_proto.http.bindpolicy import check_bind
from planner.ground.cli_console import describe
from planner.ground.console import STOP_REPEAT_S, RoverConsole
from planner.ground.roverstatus import RoverStatus
from planner.record.mcaprec import plain_message
from planner.stack.consoleaccess import ConsoleAccess

__all__ = ["ECHO_KINDS", "ConsoleConfig", "ConsoleServer", "status_json"]

logger = logging.getLogger(__name__)

_MAX_BODY = 1024
_MAX_TIMEOUT_S = 60.0
_ECHO_QUEUE = 256
_MAX_ECHOES = 8
"""Echo streams open at once (503 beyond)."""
_ECHO_KEEPALIVE_S = 1.0
"""An echo stream with nothing to say sends a blank line this often."""

T = TypeVar("T")


def _kinds() -> dict[str, tuple[type[Any], Any]]:
    return {
        "command_status": (String, qos.STATUS),
        "diagnostics": (DiagnosticArray, qos.DIAGNOSTICS),
        "odom": (Odometry, qos.SENSOR),
        "odom_ground": (Odometry, qos.SENSOR),
        "wheel_instructions": (Int16MultiArray, qos.COMMAND),
        "emergency_stop": (Bool, qos.STOP),
        "clear_emergency_stop": (Empty, qos.STOP),
    }


ECHO_KINDS = tuple(_kinds())
"""The topics ``GET /echo`` serves (``rover echo``'s)."""

_Scope = MutableMapping[str, Any]
_Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]
_Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]


@dataclass(frozen=True)
class ConsoleConfig:
    """Where the console listens, and its token.

    Attributes:
        host: address to bind (default loopback).
        port: TCP port; 0 picks a free one.
        token: the bearer token every request must present; made at random when not
            given, which only a loopback bind allows.

    Raises:
        ValueError: a bad port or token; a non-loopback host without a token.
    """

    host: str = "127.0.0.1"
    port: int = 0
    token: str = field(default="", repr=False)

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ValueError(f"console port must be 0..65535, got {self.port}")
        check_bind(
            self.host,
            self.token or None,
            what="console token",
            hint="ROVER_CONSOLE_TOKEN",
        )
        if not self.token:
            object.__setattr__(self, "token", secrets.token_urlsafe(24))


def status_json(status: RoverStatus, age_s: float) -> dict[str, Any]:
    """A status as the client rebuilds it (:func:`planner.ground.console_client`): the
    bridge's parts as it wrote them, plus the derived fields ``rover status --json``
    prints, and how long ago it came (s)."""
    return {
        **status.as_dict(),
        "raw_levels": dict(status.levels),
        "age_s": round(age_s, 3),
    }


class _AnswerError(Exception):
    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


class _Reader:
    """One echo stream's queue: filled from the port's thread through the event loop
    (:meth:`push` runs on the loop), drop-oldest past :data:`_ECHO_QUEUE`."""

    def __init__(self) -> None:
        self.items: deque[tuple[float, Any]] = deque(maxlen=_ECHO_QUEUE)
        self.ready = asyncio.Event()

    def push(self, item: tuple[float, Any]) -> None:
        self.items.append(item)
        self.ready.set()


class _Echo:
    """One topic's subscription on the console's port, its last message, and the
    streams reading it."""

    def __init__(self, port: RosPort, topic: str, loop: asyncio.AbstractEventLoop) -> None:
        msg_type, profile = _kinds()[topic]
        self.topic = topic
        self.last: tuple[float, Any] | None = None
        self._loop = loop
        self._lock = threading.Lock()
        self._readers: set[_Reader] = set()
        lane = STOP_LANE if profile is qos.STOP else "default"
        self._sub: Subscription[Any] = port.subscribe(
            topic, msg_type, self._on_message, profile, lane=lane
        )

    def _on_message(self, msg: Any) -> None:
        item = (time.time(), msg)
        with self._lock:
            self.last = item
            readers = list(self._readers)
        for reader in readers:
            _call_soon(self._loop, reader.push, item)

    def join(self) -> _Reader:
        reader = _Reader()
        with self._lock:
            self._readers.add(reader)
        return reader

    def leave(self, reader: _Reader) -> None:
        with self._lock:
            self._readers.discard(reader)

    def close(self) -> None:
        self._sub.close()


def _call_soon(loop: asyncio.AbstractEventLoop | None, fn: Callable[..., None], *args: Any) -> None:
    """``fn(*args)`` on ``loop``'s thread, from any thread; nothing once it is closed."""
    if loop is None:
        return
    with contextlib.suppress(RuntimeError):  # the loop closed: nobody waits any more
        loop.call_soon_threadsafe(fn, *args)


class ConsoleServer:
    """Serves ``console``, a :class:`RoverConsole` (neither it nor its port is closed
    here); a context manager."""

    def __init__(self, console: RoverConsole, config: ConsoleConfig | None = None) -> None:
        self.console = console
        self.config = config or ConsoleConfig()
        self._acted_seen = 0
        """The bridge's /diagnostics seen when a STOP or clear was last answered: a later status
        waits for a newer one, so that ``rover status`` after ``rover stop`` shows the latch."""
        self._echoes: dict[str, _Echo] = {}
        self._echo_lock = threading.Lock()
        self._closing = False
        self._closed = threading.Event()
        self._service = HttpService(
            self._asgi,
            host=self.config.host,
            port=self.config.port,
            limits=ServeLimits(),
            render_error=lambda status, code, message: (
                "application/json",
                json.dumps({"error": message}).encode(),
            ),
            server_name="rover-console",
            thread_name="console-http",
        )
        self._access: ConsoleAccess | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._waiters: set[asyncio.Future[None]] = set()  # on the loop only
        self._clearer = ThreadPoolExecutor(1, thread_name_prefix="console-clear")
        self._clear_busy = threading.Lock()
        self._streams = 0  # on the loop only
        self.requests = 0
        """Requests served (any answer)."""
        self.refused: Counter[str] = Counter()
        """Requests refused by who they came from (:mod:`planner.stack.consoleaccess`),
        by ``"STATUS METHOD PATH"`` (``"STATUS other"`` for a path not served)."""
        self.stops_published = 0
        """``emergency_stop`` messages this console published."""

    @property
    def url(self) -> str:
        """``http://HOST:PORT`` (after :meth:`start`)."""
        return self._service.url

    @property
    def echo_streams(self) -> int:
        """Echo streams open now."""
        return self._streams

    def start(self) -> ConsoleServer:
        """Bind and serve on a thread of its own (``OSError``: the address cannot be bound)."""
        try:
            self._service.start()
        except BaseException:
            self._clearer.shutdown(wait=False)
            raise
        host, port = self._service.address
        self._access = ConsoleAccess.for_bind(self.config.host or host, port, self.config.token)
        self.console.add_listener(self._on_change)
        return self

    def close(self) -> None:
        """Stop serving: every wait under way ends (a STOP or a status waiting is
        answered 503, an echo stream ends), the clear-STOP thread is joined, the echo
        subscriptions are closed (idempotent)."""
        if self._closing:
            return
        self._closing = True
        self._closed.set()
        self.console.remove_listener(self._on_change)
        _call_soon(self._loop, self._wake)
        self._service.close()
        self._clearer.shutdown(wait=True, cancel_futures=True)
        with self._echo_lock:
            echoes = list(self._echoes.values())
            self._echoes.clear()
        for echo in echoes:
            echo.close()

    def __enter__(self) -> ConsoleServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- waking the loop ------------------------------------------------------------------
    def _on_change(self) -> None:
        """The console heard something (on the port's thread): wake the loop's waits."""
        _call_soon(self._loop, self._wake)

    def _wake(self) -> None:
        for waiter in self._waiters:
            if not waiter.done():
                waiter.set_result(None)
        self._waiters.clear()

    async def _until(self, ready: Callable[[], T | None], timeout_s: float) -> T | None:
        """``ready()`` once it is not ``None``, checked each time the console hears
        something, for at most ``timeout_s``; ``None`` at the deadline or on close."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            value = ready()
            if value is not None:
                return value
            left = deadline - loop.time()
            if left <= 0 or self._closing:
                return None
            waiter: asyncio.Future[None] = loop.create_future()
            self._waiters.add(waiter)
            try:
                await asyncio.wait_for(waiter, left)
            except TimeoutError:
                pass
            finally:
                self._waiters.discard(waiter)

    # -- the ASGI application -------------------------------------------------------------
    async def _asgi(self, scope: _Scope, receive: _Receive, send: _Send) -> None:
        if scope["type"] != "http":
            return
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
        request = Request(scope, receive)
        self.requests += 1
        started = False

        async def tracked(message: MutableMapping[str, Any]) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self._dispatch(request, tracked)
        except ClientGoneError:
            return
        except _AnswerError as exc:
            if started:
                return
            logger.info("console: %s %s: %d %s", request.method, scope["path"], exc.status, exc)
            await _json(exc.status, {"error": exc.message})(scope, receive, tracked)
        except Exception:
            logger.exception("console: %s %s failed", request.method, scope["path"])
            if not started:
                await _json(500, {"error": "internal error; see the stack's log"})(
                    scope, receive, tracked
                )

    async def _dispatch(self, request: Request, send: _Send) -> None:
        self._admit(request)
        path = request.url.path
        if request.method == "POST":
            declared = request.headers.get("content-length")
            if declared is not None and (not declared.isdigit() or int(declared) > _MAX_BODY):
                raise _AnswerError(413, f"body over {_MAX_BODY} bytes")
            try:
                await _read_body(request.receive, limit_bytes=_MAX_BODY, timeout_s=10.0)
            except RequestBodyError as exc:
                raise _AnswerError(exc.status, exc.message) from exc
        timeout_s = _timeout(request)
        route = {
            ("GET", "/status"): self._status,
            ("POST", "/stop"): self._stop,
            ("POST", "/clear_stop"): self._clear,
        }.get((request.method, path))
        if route is not None:
            answer = await route(timeout_s)
            await answer(request.scope, request.receive, send)
            return
        if (request.method, path) == ("GET", "/echo"):
            await self._echo(request, timeout_s, send)
            return
        if path in ("/status", "/stop", "/clear_stop", "/echo"):
            raise _AnswerError(405, f"{request.method} {path} is not served here")
        raise _AnswerError(404, f"no such thing: {path}; try /status, /stop, /clear_stop, /echo")

    def _admit(self, request: Request) -> None:
        """The checks of :mod:`planner.stack.consoleaccess`, on the request's head."""
        assert self._access is not None  # set by start(), before anything is served
        refused = self._access.refusal(request.method, request.headers)
        if refused is not None:
            path = request.url.path
            known = path in ("/status", "/stop", "/clear_stop", "/echo")
            self.refused[
                f"{refused.status} {request.method} {path}" if known else f"{refused.status} other"
            ] += 1
            raise _AnswerError(refused.status, refused.message)

    # -- the answers (on the event loop) ----------------------------------------------------
    def _status_after_action(self) -> RoverStatus | None:
        if self.console.diagnostics_seen <= self._acted_seen:
            return None
        return self.console.latest()

    async def _status(self, timeout_s: float) -> Response:
        # After a STOP or a clear, a newer one than the last seen then (1 Hz): the
        # latch as it is now, not as it was before.
        status = await self._until(self._status_after_action, timeout_s)
        if status is None:
            if self._closing:
                raise _AnswerError(503, "the console is closing")
            raise _AnswerError(
                504, f"no /diagnostics from the bridge within {timeout_s:g} s: is it running?"
            )
        doc = status_json(status, self.console.diagnostics_age_s)
        plan = self.console.onboard  # the plan on board, when rover onboard reports one
        doc["plan"] = json.loads(plan.to_json()) if plan is not None else None
        return _json(200, doc)

    def _publish_stop(self) -> None:
        try:
            self.console.publish_stop()
        except RosPortError as exc:
            logger.error("console: STOP not published: %s", exc)
            raise _AnswerError(
                503, f"the STOP could not be published ({exc}): use 'rover stop --ros'"
            ) from exc
        self.stops_published += 1

    async def _stop(self, timeout_s: float) -> Response:
        since = self.console.mark()
        self._publish_stop()  # at once, on the loop: nothing queues ahead of it
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            left = deadline - loop.time()
            hit = await self._until(
                lambda: self.console.heard_since(since, lambda s: s == STOPPED),
                min(max(left, 0.0), STOP_REPEAT_S),
            )
            if hit is not None:
                self._acted_seen = self.console.diagnostics_seen
                return _json(200, {"stopped": True})
            if self._closing:
                raise _AnswerError(503, "the console is closing; the STOP was published")
            if loop.time() >= deadline:
                raise _AnswerError(504, f"no 'stopped' from the bridge within {timeout_s:g} s")
            self._publish_stop()

    async def _clear(self, timeout_s: float) -> Response:
        if not self._clear_busy.acquire(blocking=False):
            raise _AnswerError(
                409,
                "a clear-STOP is already waiting for the controller's answer; one at a "
                "time: try again once it has answered",
            )

        def clear() -> Any:
            try:
                # The state after comes with the bridge's next /diagnostics (1 Hz): not
                # waited for here, so that the answer comes as soon as the controller's.
                return self.console.clear_stop(timeout_s, after_wait_s=0.0, cancel=self._closed)
            finally:
                self._clear_busy.release()

        try:
            future = self._clearer.submit(clear)
        except RuntimeError as exc:  # shut down: closing
            self._clear_busy.release()
            raise _AnswerError(503, "the console is closing") from exc
        # A clear cancelled before it ran (its client left, the server closed) never
        # reaches its own release.
        future.add_done_callback(self._release_if_cancelled)
        report = await asyncio.wrap_future(future)
        self._acted_seen = self.console.diagnostics_seen
        before = report.before
        return _json(
            200,
            {
                "outcome": report.outcome.value,
                "released": report.released,
                "why": report.why,
                "held_by": list(before.latch) if before is not None else None,
                "before": status_json(before, 0.0) if before is not None else None,
                "armed": report.armed,
            },
        )

    def _release_if_cancelled(self, done: Future[Any]) -> None:
        if done.cancelled():
            self._clear_busy.release()

    # -- echo ---------------------------------------------------------------------------------
    def _echo_of(self, topic: str) -> _Echo:
        with self._echo_lock:
            echo = self._echoes.get(topic)
            if echo is None:
                loop = asyncio.get_running_loop()
                echo = self._echoes[topic] = _Echo(self.console.port, topic, loop)
            return echo

    async def _echo(self, request: Request, timeout_s: float, send: _Send) -> None:
        topic = request.query_params.get("topic", "")
        if topic not in ECHO_KINDS:
            raise _AnswerError(400, f"topic must be one of {', '.join(ECHO_KINDS)}")
        count_text = request.query_params.get("count", "0")
        if not (count_text.isascii() and count_text.isdigit()):
            raise _AnswerError(400, f"count must be an integer >= 0, got {count_text!r}")
        if self._streams >= _MAX_ECHOES:
            raise _AnswerError(503, f"already {_MAX_ECHOES} echo streams")
        # The slot is given back in the finally, however the stream ends.
        self._streams += 1
        try:
            echo = self._echo_of(topic)
            reader = echo.join()
            try:
                first = self._last_known(echo)
                response = StreamingResponse(
                    self._stream(echo, reader, first, int(count_text), timeout_s),
                    media_type="application/x-ndjson",
                    headers={"Cache-Control": "no-store"},
                )
                await response(request.scope, request.receive, send)
            finally:
                echo.leave(reader)
        finally:
            self._streams -= 1

    def _last_known(self, echo: _Echo) -> dict[str, Any] | None:
        """The topic's last value before this reader joined: the last message the
        console's subscription took, or for ``command_status`` the last status the
        console heard (it listens from the stack's start)."""
        if echo.topic == "command_status":
            heard = self.console.heard
            if heard:
                return {"t": time.time(), "text": heard[-1], "data": {"data": heard[-1]}}
        if echo.last is not None:
            return _line(echo.topic, *echo.last)
        return None

    async def _stream(
        self,
        echo: _Echo,
        reader: _Reader,
        first: dict[str, Any] | None,
        count: int,
        timeout_s: float,
    ) -> AsyncIterator[bytes]:
        shown = 0
        yield b'{"listening":true}\n'  # the client's header: the topic is subscribed
        if first is not None:
            first["last_known"] = True
            yield json.dumps(first).encode() + b"\n"
            shown += 1
        while not self._closing and (count == 0 or shown < count):
            if not reader.items:
                reader.ready.clear()
                try:
                    await asyncio.wait_for(reader.ready.wait(), min(timeout_s, _ECHO_KEEPALIVE_S))
                except TimeoutError:
                    yield b"\n"  # keep-alive: a blank line, which the client skips
                continue
            stamp, msg = reader.items.popleft()
            yield json.dumps(_line(echo.topic, stamp, msg), default=str).encode() + b"\n"
            shown += 1


def _line(topic: str, stamp: float, msg: Any) -> dict[str, Any]:
    return {"t": stamp, "text": describe(topic, msg), "data": plain_message(msg)}


def _timeout(request: Request) -> float:
    text = request.query_params.get("timeout", "10")
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0 < value <= _MAX_TIMEOUT_S:
        raise _AnswerError(400, f"timeout must be a number in (0, {_MAX_TIMEOUT_S:g}] s")
    return value


def _json(status: int, obj: dict[str, Any]) -> Response:
    return Response(
        json.dumps(obj, default=str).encode(),
        status,
        {"Cache-Control": "no-store"},
        "application/json",
    )
