"""The stack's console socket: ``rover status``, ``stop``, ``clear-stop`` and ``echo``
answered by the running stack in well under a second, with no ROS 2 discovery in the
command (docs/commands.md, "The stack's console").

Each of those commands started rclpy and waited for DDS discovery before it could say
anything: 4-5 s idle, 13 s for ``rover stop`` at a load of 15. ``rover stack up`` has
discovered the bridge long before: :class:`ConsoleServer` serves what its
:class:`~planner.ground.console.RoverConsole` (an rclpy port in the bridge's own
namespace, matched at start) already knows and does, over HTTP on the project's one
HTTP stack (:mod:`firmware_proto.http`, the gate's and the view's), with the gate's bind
and token policy (:mod:`firmware_proto.http.bindpolicy`): loopback by default, a token
needed anywhere else. The commands' client is the standard library's
(:mod:`planner.ground.console_client`).

======================================  ===================================================
``GET /status``                         the bridge's latest ``/diagnostics`` (kept as it
                                        comes, 1 Hz) and how old it is; ``plan``: the
                                        plan on board, ``rover onboard``'s latest report
                                        (``null``: none; docs/onboard.md)
``POST /stop?timeout=S``                ``true`` on ``emergency_stop`` until the bridge
                                        says ``stopped`` (repeated every 0.5 s): the
                                        bridge takes it on its STOP lane, as any STOP
``POST /clear_stop?timeout=S``          ``clear_emergency_stop``; the controller's answer
``GET /echo?topic=T&count=N&timeout=S``  one JSON line per message of ``T`` (its last
                                        value first, where one is kept), streamed
======================================  ===================================================

This is the rover side, the bench's console: the stack's console talks to the bridge
directly, not through the emulated Earth-Moon link (``rover status --ros`` goes through
it, as ``rover go`` does). Blocking work (a STOP waiting for its ``stopped``) runs on a
small pool of threads (``console-action``), never on the event loop; every wait is
bounded.
"""

from __future__ import annotations

import asyncio
import json
import logging
import queue
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable, MutableMapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from starlette.requests import Request
from starlette.responses import Response, StreamingResponse

from bridge.ros.rosport import STOP_LANE, RosPort, Subscription, qos
from bridge.ros.rosport.msgs import Bool, DiagnosticArray, Empty, Int16MultiArray, Odometry, String
from firmware_proto.http import ClientGoneError, HttpService, RequestBodyError, ServeLimits
from firmware_proto.http import read_body as _read_body
from firmware_proto.http.bindpolicy import bearer_token, check_bind, token_matches
from planner.ground.cli_console import describe
from planner.ground.console import RoverConsole
from planner.ground.roverstatus import RoverStatus
from planner.record.mcaprec import plain_message

__all__ = ["ECHO_KINDS", "ConsoleConfig", "ConsoleServer", "status_json"]

logger = logging.getLogger(__name__)

_MAX_BODY = 1024
_MAX_TIMEOUT_S = 60.0
_ECHO_QUEUE = 256
_MAX_ECHOES = 8
"""Echo streams open at once (503 beyond): each holds a thread of its own pool while it
waits, never one of the pool that serves STOP."""


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
    """Where the console listens.

    Attributes:
        host: address to bind (default loopback).
        port: TCP port; 0 picks a free one.
        token: bearer token; required when ``host`` is not loopback.

    Raises:
        ValueError: a bad port or token; a non-loopback host without a token.
    """

    host: str = "127.0.0.1"
    port: int = 0
    token: str | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ValueError(f"console port must be 0..65535, got {self.port}")
        check_bind(
            self.host,
            self.token,
            what="console token",
            hint="--console-token (or ROVER_CONSOLE_TOKEN)",
        )


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


class _Echo:
    """One topic's subscription on the console's port, its last message, and the
    streams reading it (each a bounded queue, drop-oldest)."""

    def __init__(self, port: RosPort, topic: str) -> None:
        msg_type, profile = _kinds()[topic]
        self.topic = topic
        self.last: tuple[float, Any] | None = None
        self._lock = threading.Lock()
        self._readers: set[queue.Queue[tuple[float, Any]]] = set()
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
            try:
                reader.put_nowait(item)
            except queue.Full:  # a slow reader loses its oldest, never holds the port
                try:
                    reader.get_nowait()
                    reader.put_nowait(item)
                except (queue.Empty, queue.Full):
                    pass

    def join(self) -> queue.Queue[tuple[float, Any]]:
        reader: queue.Queue[tuple[float, Any]] = queue.Queue(_ECHO_QUEUE)
        with self._lock:
            self._readers.add(reader)
        return reader

    def leave(self, reader: queue.Queue[tuple[float, Any]]) -> None:
        with self._lock:
            self._readers.discard(reader)

    def close(self) -> None:
        self._sub.close()


class ConsoleServer:
    """Serves a :class:`RoverConsole` (see the module docstring); a context manager.

    Args:
        console: the reads and writes of the bridge's topics (its port stays the
            caller's; it is not closed here).
        config: where to listen.
    """

    def __init__(self, console: RoverConsole, config: ConsoleConfig | None = None) -> None:
        self.console = console
        self.config = config or ConsoleConfig()
        self._acted_seen = 0
        """The bridge's /diagnostics seen when a STOP or a clear was last answered: a
        status asked after it waits for a newer one (1 Hz), so that ``rover status`` right
        after ``rover stop`` shows the latch, not the state from before."""
        self._echoes: dict[str, _Echo] = {}
        self._echo_lock = threading.Lock()
        self._closing = False
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
        self._actions = ThreadPoolExecutor(4, thread_name_prefix="console-action")
        self._takers = ThreadPoolExecutor(_MAX_ECHOES, thread_name_prefix="console-echo")
        self._streams = 0
        self.requests = 0
        """Requests served (any answer)."""

    @property
    def url(self) -> str:
        """``http://HOST:PORT`` (after :meth:`start`)."""
        return self._service.url

    def start(self) -> ConsoleServer:
        """Bind and serve on a thread of its own.

        Raises:
            OSError: the address cannot be bound.
        """
        try:
            self._service.start()
        except BaseException:
            self._actions.shutdown(wait=False)
            self._takers.shutdown(wait=False)
            raise
        return self

    def close(self) -> None:
        """Stop serving, end every echo stream, close the echo subscriptions
        (idempotent)."""
        if self._closing:
            return
        self._closing = True
        self._service.close()
        self._actions.shutdown(wait=True, cancel_futures=True)
        self._takers.shutdown(wait=True, cancel_futures=True)
        with self._echo_lock:
            echoes = list(self._echoes.values())
            self._echoes.clear()
        for echo in echoes:
            echo.close()

    def __enter__(self) -> ConsoleServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the ASGI application -------------------------------------------------------------
    async def _asgi(self, scope: _Scope, receive: _Receive, send: _Send) -> None:
        if scope["type"] != "http":
            return
        request = Request(scope, receive)
        self.requests += 1
        try:
            response = await self._dispatch(request)
        except ClientGoneError:
            return
        except _AnswerError as exc:
            logger.info("console: %s %s: %d %s", request.method, scope["path"], exc.status, exc)
            response = _json(exc.status, {"error": exc.message})
        await response(scope, receive, send)

    async def _dispatch(self, request: Request) -> Response:
        path = request.url.path
        if request.method == "POST":
            declared = request.headers.get("content-length")
            if declared is not None and int(declared) > _MAX_BODY:
                raise _AnswerError(413, f"body over {_MAX_BODY} bytes")
            try:
                await _read_body(request.receive, limit_bytes=_MAX_BODY, timeout_s=10.0)
            except RequestBodyError as exc:
                raise _AnswerError(exc.status, exc.message) from exc
        self._authorise(request)
        timeout_s = _timeout(request)
        route = {
            ("GET", "/status"): self._status,
            ("POST", "/stop"): self._stop,
            ("POST", "/clear_stop"): self._clear,
        }.get((request.method, path))
        if route is not None:
            answer: Response = await self._in_thread(lambda: route(timeout_s))
            return answer
        if (request.method, path) == ("GET", "/echo"):
            return self._echo(request, timeout_s)
        if path in ("/status", "/stop", "/clear_stop", "/echo"):
            raise _AnswerError(405, f"{request.method} {path} is not served here")
        raise _AnswerError(404, f"no such thing: {path}; try /status, /stop, /clear_stop, /echo")

    def _authorise(self, request: Request) -> None:
        token = self.config.token
        if token is None:
            return
        given = bearer_token(request.headers.get("authorization"))
        if token_matches(given, token):
            return
        raise _AnswerError(
            401, "wrong token" if given else "this console needs 'Authorization: Bearer <token>'"
        )

    async def _in_thread(self, action: Callable[[], Response]) -> Response:
        return await asyncio.get_running_loop().run_in_executor(self._actions, action)

    # -- the answers (on a console-action thread) -----------------------------------------
    def _status(self, timeout_s: float) -> Response:
        status = self.console.status(timeout_s, newer_than=self._acted_seen)
        if status is None:
            raise _AnswerError(
                504, f"no /diagnostics from the bridge within {timeout_s:g} s: is it running?"
            )
        doc = status_json(status, self.console.diagnostics_age_s)
        plan = self.console.onboard  # the plan on board, when rover onboard reports one
        doc["plan"] = json.loads(plan.to_json()) if plan is not None else None
        return _json(200, doc)

    def _stop(self, timeout_s: float) -> Response:
        if self.console.stop(timeout_s):
            self._acted_seen = self.console.diagnostics_seen
            return _json(200, {"stopped": True})
        raise _AnswerError(504, f"no 'stopped' from the bridge within {timeout_s:g} s")

    def _clear(self, timeout_s: float) -> Response:
        # The state after comes with the bridge's next /diagnostics (1 Hz): not waited
        # for here, so that the answer comes as soon as the controller's does.
        report = self.console.clear_stop(timeout_s, after_wait_s=0.0)
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
            },
        )

    # -- echo ---------------------------------------------------------------------------------
    def _echo_of(self, topic: str) -> _Echo:
        with self._echo_lock:
            echo = self._echoes.get(topic)
            if echo is None:
                echo = self._echoes[topic] = _Echo(self.console.port, topic)
            return echo

    def _echo(self, request: Request, timeout_s: float) -> Response:
        topic = request.query_params.get("topic", "")
        if topic not in ECHO_KINDS:
            raise _AnswerError(400, f"topic must be one of {', '.join(ECHO_KINDS)}")
        count_text = request.query_params.get("count", "0")
        if not count_text.isdigit():
            raise _AnswerError(400, f"count must be an integer >= 0, got {count_text!r}")
        with self._echo_lock:
            if self._streams >= _MAX_ECHOES:
                raise _AnswerError(503, f"already {_MAX_ECHOES} echo streams")
            self._streams += 1
        echo = self._echo_of(topic)
        reader = echo.join()
        first = self._last_known(echo)
        return StreamingResponse(
            self._stream(echo, reader, first, int(count_text), timeout_s),
            media_type="application/x-ndjson",
            headers={"Cache-Control": "no-store"},
        )

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
        reader: queue.Queue[tuple[float, Any]],
        first: dict[str, Any] | None,
        count: int,
        timeout_s: float,
    ) -> AsyncIterator[bytes]:
        loop = asyncio.get_running_loop()
        shown = 0
        try:
            yield b'{"listening":true}\n'  # the client's header: the topic is subscribed
            if first is not None:
                first["last_known"] = True
                yield json.dumps(first).encode() + b"\n"
                shown += 1
            while not self._closing and (count == 0 or shown < count):
                try:
                    stamp, msg = await loop.run_in_executor(
                        self._takers, lambda: reader.get(timeout=min(timeout_s, 1.0))
                    )
                except queue.Empty:
                    yield b"\n"  # keep-alive: a blank line, which the client skips
                    continue
                yield json.dumps(_line(echo.topic, stamp, msg), default=str).encode() + b"\n"
                shown += 1
        finally:
            echo.leave(reader)
            with self._echo_lock:
                self._streams -= 1


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
