"""The HTTP gate: ``POST /validate_plan`` and friends over the stdlib HTTP server.

:class:`GateServer` puts a :class:`http.server.ThreadingHTTPServer` (one thread per
connection, HTTP/1.1 keep-alive) in front of a bounded :mod:`worker pool <gate.pool>`:

- *Admission*: at most ``workers + queue_depth`` validations are admitted at once; the
  next one gets 503 with ``Retry-After`` at once instead of waiting in a queue that
  grows without bound. At most ``max_connections`` connections are served; the next is
  answered 503 and closed.
- *Bodies*: a declared length over ``max_body_bytes`` is refused (413) before a byte of
  it is read, then the connection is closed after a short lingering drain so the client
  still sees the answer; chunked bodies are read up to the limit; a body without
  framing gets 411; every error body is JSON.
- *Auth and binding*: with a token, every request needs ``Authorization: Bearer <token>``
  (constant-time comparison; 401 otherwise). The configuration refuses a non-loopback
  address without a token.
- *Latency*: each response is one ``send`` and accepted sockets have ``TCP_NODELAY``,
  which avoids the ~40 ms keep-alive stall of the stdlib server (Nagle + delayed ACK).
- *Shutdown* (:meth:`GateServer.close`, idempotent): stop accepting, close idle
  keep-alive connections, let in-flight requests finish (up to ``drain_timeout_s``),
  then stop the workers. Requests that arrive meanwhile get 503.

The handler threads do I/O and parsing only; playback runs in the pool.
"""

from __future__ import annotations

import contextlib
import hmac
import logging
import socket
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import CancelledError
from concurrent.futures import TimeoutError as FutureTimeoutError
from concurrent.futures.process import BrokenProcessPool
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from firmware_proto.errors import PlanError
from firmware_proto.plan import Plan
from gate import routes
from gate.config import GateConfig
from gate.errors import (
    BadRequestError,
    HttpError,
    MethodNotAllowedError,
    NotFoundError,
    OptionError,
    OverloadedError,
    PayloadTooLargeError,
    PlanSchemaError,
    UnauthorizedError,
)
from gate.openapi import build_openapi
from gate.options import ValidateOptions
from gate.pool import WorkerPool, make_pool
from gate.request import BodyFraming, body_framing, check_json_media_type, parse_json, read_body
from gate.response import SERVER_NAME, encode_response, error_body, json_bytes
from gate.validator import Job, Validator, gate_version

__all__ = ["GateServer"]

logger = logging.getLogger(__name__)

LINGER_S = 1.0
"""After refusing a body unread, how long to drain what the client still sends before
closing (closing with unread data would reset the connection and lose the answer)."""
LINGER_BYTES = 1 << 20
"""Most bytes drained while lingering."""
RETRY_AFTER_S = 1
"""``Retry-After`` of a 503: one typical validation is well under a second."""

_Reply = tuple[int, bytes, dict[str, str]]


class _HTTPServer(ThreadingHTTPServer):
    """The listener: sets TCP_NODELAY, bounds connections, counts them."""

    daemon_threads = True
    block_on_close = True
    allow_reuse_address = True
    request_queue_size = 128

    def __init__(self, gate: GateServer, address: tuple[str, int]) -> None:
        self.gate = gate
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self._count_lock = threading.Lock()
        self.open_connections = 0
        super().__init__(address, _Handler)

    def get_request(self) -> tuple[socket.socket, Any]:
        sock, address = super().get_request()
        if self.gate.config.tcp_nodelay:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return sock, address

    def process_request(self, request: Any, client_address: Any) -> None:
        with self._count_lock:
            full = self.open_connections >= self.gate.config.max_connections
            if not full:
                self.open_connections += 1
        if full:
            self._refuse(request, "too many open connections")
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            with self._count_lock:
                self.open_connections -= 1
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            with self._count_lock:
                self.open_connections -= 1

    def _refuse(self, sock: socket.socket, why: str) -> None:
        """Answer 503 on a connection we will not serve, and close it."""
        logger.warning("refusing a connection: %s", why)
        error = OverloadedError(why, code="too_many_connections", retry_after_s=RETRY_AFTER_S)
        try:
            sock.settimeout(1.0)
            sock.sendall(
                encode_response(503, error_body(error), headers=error.headers, keep_alive=False)
            )
        except OSError:
            pass
        self.shutdown_request(sock)

    def handle_error(self, request: Any, client_address: Any) -> None:
        # A client that resets or times out is routine; nothing for stderr.
        logger.debug("connection from %s ended: %r", client_address, sys.exc_info()[1])


class _Handler(BaseHTTPRequestHandler):
    """One connection. Parses, authorises, dispatches by :data:`gate.routes.ROUTES`."""

    protocol_version = "HTTP/1.1"
    server_version = SERVER_NAME
    sys_version = ""
    server: _HTTPServer

    # -- connection life --------------------------------------------------------------
    def setup(self) -> None:
        self.gate = self.server.gate
        self.busy = False
        self._framing = BodyFraming()
        self._stream_broken = False
        super().setup()
        # Idle keep-alive connections, and clients silent mid-request, time out.
        self.connection.settimeout(self.gate.config.idle_timeout_s)
        self.gate._register(self)

    def finish(self) -> None:
        try:
            super().finish()
        finally:
            self.gate._unregister(self)

    def parse_request(self) -> bool:
        self.busy = True  # a request line has arrived: not idle any more
        self._framing = BodyFraming()
        self._stream_broken = False
        return super().parse_request()

    def handle_expect_100(self) -> bool:
        try:
            framing = body_framing(self.headers)
        except HttpError as exc:
            self._stream_broken = True
            self._reply_error(exc)
            return False
        if framing.length is not None and framing.length > self.gate.config.max_body_bytes:
            self._framing = framing
            self._reply_error(
                PayloadTooLargeError(
                    f"body of {framing.length} bytes is over the limit of "
                    f"{self.gate.config.max_body_bytes} bytes"
                )
            )
            return False
        return super().handle_expect_100()

    def log_message(self, format: str, *args: Any) -> None:
        if logger.isEnabledFor(logging.DEBUG):
            logger.debug("%s %s", self.address_string(), format % args)

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """Errors the base class detects (bad request line, 414, 431, 501, 505): JSON too."""
        error = HttpError(message or explain or "request rejected", code=_status_code_name(code))
        error.status = code
        self.close_connection = True
        self._reply_error(error)

    # -- dispatch ---------------------------------------------------------------------------
    def do_GET(self) -> None:
        self._dispatch()

    def do_HEAD(self) -> None:
        self._dispatch()

    def do_POST(self) -> None:
        self._dispatch()

    def do_PUT(self) -> None:
        self._dispatch()

    def do_PATCH(self) -> None:
        self._dispatch()

    def do_DELETE(self) -> None:
        self._dispatch()

    def do_OPTIONS(self) -> None:
        self._dispatch()

    def _dispatch(self) -> None:
        try:
            try:
                self._framing = body_framing(self.headers)
            except HttpError:
                self._stream_broken = True  # where this request ends is unknown
                raise
            self.gate._authorise(self.headers.get("Authorization"))
            if self.gate.draining:
                raise OverloadedError(
                    "the gate is shutting down", code="shutting_down", retry_after_s=RETRY_AFTER_S
                )
            path, _, query = self.path.partition("?")
            try:
                found = routes.match(path)
            except UnicodeDecodeError:
                found = None
            if found is None:
                raise NotFoundError(f"no such path {path!r}")
            route, params = found
            if self.command not in route.allowed:
                raise MethodNotAllowedError(
                    f"{self.command} is not allowed on {route.template}", list(route.allowed)
                )
            operation: Callable[[dict[str, str], str], _Reply] = getattr(
                self, "_op_" + route.operation
            )
            status, body, headers = operation(params, query)
            self._reply(status, body, headers)
        except HttpError as exc:
            self._reply_error(exc)
        except Exception:
            logger.exception("internal error serving %s %s", self.command, self.path)
            self._reply_error(HttpError("internal error; see the gate's log"))

    # -- operations ------------------------------------------------------------------------
    def _op_health(self, params: dict[str, str], query: str) -> _Reply:
        return 200, json_bytes(self.gate.health()), {}

    def _op_list_maps(self, params: dict[str, str], query: str) -> _Reply:
        return 200, self.gate._maps_body, {}

    def _op_get_map(self, params: dict[str, str], query: str) -> _Reply:
        body = self.gate._map_bodies.get(params["name"])
        if body is None:
            known = ", ".join(sorted(self.gate._map_bodies))
            raise NotFoundError(f"no map {params['name']!r}; known: {known}", code="unknown_map")
        return 200, body, {}

    def _op_openapi(self, params: dict[str, str], query: str) -> _Reply:
        return 200, self.gate._openapi_body, {}

    def _op_validate_plan(self, params: dict[str, str], query: str) -> _Reply:
        check_json_media_type(self.headers.get("Content-Type"))
        framing, self._framing = self._framing, BodyFraming()
        try:
            body = read_body(framing, self.rfile, self.gate.config.max_body_bytes)
        except HttpError:
            if framing.chunked or framing.length is None:
                self._stream_broken = True
            else:
                self._framing = framing  # declared length refused unread
            raise
        try:
            plan = Plan.from_dict(parse_json(body))
        except PlanError as exc:
            raise PlanSchemaError(exc.violations) from exc
        try:
            options = ValidateOptions.from_query(query)
            job = self.gate.validator.prepare(
                plan, options.resolve(self.gate.validator.settings, self.gate.validator.default_map)
            )
        except OptionError as exc:
            raise BadRequestError(str(exc), code="invalid_option", parameter=exc.parameter) from exc
        return 200, self.gate._run(job), {}

    # -- writing ---------------------------------------------------------------------------
    def _reply_error(self, error: HttpError) -> None:
        if error.status >= 500 and error.status != 503:
            self.close_connection = True
        self._reply(error.status, error_body(error), error.headers)

    def _reply(self, status: int, body: bytes, headers: dict[str, str]) -> None:
        config = self.gate.config
        linger = False
        framing, self._framing = self._framing, BodyFraming()
        if self._stream_broken:
            self.close_connection = True
        elif framing.has_body:  # a body we did not use: drop it, or give up the connection
            if framing.length is not None and framing.length <= config.max_body_bytes:
                try:
                    self.rfile.read(framing.length)
                except OSError:
                    self.close_connection = True
            else:
                self.close_connection = True
                linger = True
        if self.gate.draining:
            self.close_connection = True
        head = self.command == "HEAD"
        try:
            if config.single_write:
                self.wfile.write(
                    encode_response(
                        status,
                        body,
                        headers=headers,
                        keep_alive=not self.close_connection,
                        head=head,
                    )
                )
            else:
                self._reply_in_pieces(status, body, headers, head)
        except OSError:
            self.close_connection = True
            logger.debug("client %s went away before the answer", self.address_string())
        self.log_request(status, len(body))
        if linger:
            self._linger()
        self.busy = False

    def _reply_in_pieces(
        self, status: int, body: bytes, headers: dict[str, str], head: bool
    ) -> None:
        """The stdlib way (headers, then body: two writes). Kept for the benchmark."""
        self.send_response_only(status)
        self.send_header("Server", SERVER_NAME)
        self.send_header("Date", self.date_time_string())
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        for key, value in headers.items():
            self.send_header(key, value)
        if self.close_connection:
            self.send_header("Connection", "close")
        self.end_headers()
        if not head:
            self.wfile.write(body)

    def _linger(self) -> None:
        """Half-close, then drain what the client still sends, briefly."""
        sock = self.connection
        try:
            sock.shutdown(socket.SHUT_WR)
            deadline = time.monotonic() + LINGER_S
            drained = 0
            while drained < LINGER_BYTES:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                sock.settimeout(left)
                chunk = sock.recv(65536)
                if not chunk:
                    break
                drained += len(chunk)
        except OSError:
            pass


def _status_code_name(status: int) -> str:
    try:
        return HTTPStatus(status).name.lower()
    except ValueError:
        return "error"


class GateServer:
    """The simulation gate's HTTP server. See the module docstring.

    Use as a context manager, or call :meth:`start` and :meth:`close`::

        with GateServer(GateConfig(port=0)) as gate:
            print(gate.url)

    Args:
        config: the settings.
        validator: the validator (default: loaded from ``config``).
        pool: the worker pool (default: made from ``config``); the server closes it.
    """

    def __init__(
        self,
        config: GateConfig,
        *,
        validator: Validator | None = None,
        pool: WorkerPool | None = None,
    ) -> None:
        self.config = config
        self.validator = validator if validator is not None else Validator.from_config(config)
        self._pool = pool
        self._httpd: _HTTPServer | None = None
        self._thread: threading.Thread | None = None
        self._draining = threading.Event()
        self.stopped_accepting = threading.Event()
        """Set once :meth:`close` has closed the listener (new connections refused)."""
        self._closed = False
        self._close_lock = threading.Lock()
        self._slots = threading.BoundedSemaphore(config.capacity)
        self._in_flight = 0
        self._conns: set[_Handler] = set()
        self._conn_cond = threading.Condition()
        self._started = time.monotonic()
        names = sorted(self.validator.maps)
        self._map_bodies = {n: json_bytes(self.validator.maps[n].to_dict()) for n in names}
        self._maps_body = json_bytes(self._map_list())
        self._openapi_body = json_bytes(build_openapi(config, names, self.validator.default_map))

    # -- life cycle ---------------------------------------------------------------------
    def start(self) -> GateServer:
        """Start the workers, bind, and serve in a background thread.

        Raises:
            OSError: the address cannot be bound.
            RuntimeError: the worker processes did not start.
        """
        if self._httpd is not None:
            raise RuntimeError("gate server already started")
        if self._pool is None:
            self._pool = make_pool(self.config, self.validator)
        try:
            self._httpd = _HTTPServer(self, (self.config.host, self.config.port))
        except BaseException:
            self._pool.close()
            raise
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, kwargs={"poll_interval": 0.1}, name="gate-serve"
        )
        self._thread.start()
        logger.info(
            "gate listening on %s (%s pool, %d workers, queue %d)",
            self.url,
            self._pool.kind,
            self._pool.workers,
            self.config.queue_depth,
        )
        return self

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` actually bound (the port is real even when 0 was asked)."""
        if self._httpd is None:
            raise RuntimeError("gate server not started")
        host, port = self._httpd.server_address[:2]
        return str(host), int(port)

    @property
    def url(self) -> str:
        """``http://host:port`` of the listener."""
        host, port = self.address
        return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"

    @property
    def draining(self) -> bool:
        """Whether shutdown has begun (new requests get 503)."""
        return self._draining.is_set()

    @property
    def pool(self) -> WorkerPool:
        """The worker pool (after :meth:`start`)."""
        if self._pool is None:
            raise RuntimeError("gate server not started")
        return self._pool

    def begin_drain(self) -> None:
        """Answer every new request with 503 from now on (the first half of
        :meth:`close`, exposed so that tests and supervisors can drain first)."""
        if not self._draining.is_set():
            logger.info("gate draining")
        self._draining.set()

    def close(self) -> None:
        """Graceful shutdown; idempotent. Stop accepting, close idle connections, wait
        for in-flight requests (at most ``drain_timeout_s``), stop the workers."""
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        self.begin_drain()
        httpd = self._httpd
        if httpd is not None:
            if self._thread is not None:
                httpd.shutdown()
                self._thread.join()
            httpd.socket.close()
            self.stopped_accepting.set()
            self._close_idle()
            deadline = time.monotonic() + self.config.drain_timeout_s
            with self._conn_cond:
                while self._conns and time.monotonic() < deadline:
                    self._conn_cond.wait(min(0.1, max(0.0, deadline - time.monotonic())))
                    self._close_idle_locked()
                stuck = list(self._conns)
            for handler in stuck:
                logger.warning("closing a connection still busy after the drain timeout")
                _shutdown_socket(handler.connection)
            httpd.server_close()
        if self._pool is not None:
            self._pool.close(wait=True)
        logger.info("gate closed")

    def __enter__(self) -> GateServer:
        if self._httpd is None:
            self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- used by the handler ------------------------------------------------------------
    def _register(self, handler: _Handler) -> None:
        with self._conn_cond:
            self._conns.add(handler)

    def _unregister(self, handler: _Handler) -> None:
        with self._conn_cond:
            self._conns.discard(handler)
            self._conn_cond.notify_all()

    def _close_idle(self) -> None:
        with self._conn_cond:
            self._close_idle_locked()

    def _close_idle_locked(self) -> None:
        for handler in self._conns:
            if not handler.busy:
                _shutdown_socket(handler.connection)

    def _authorise(self, header: str | None) -> None:
        token = self.config.token
        if token is None:
            return
        challenge = 'Bearer realm="rover-gate"'
        if not header:
            raise UnauthorizedError(
                "this gate needs 'Authorization: Bearer <token>'",
                headers={"WWW-Authenticate": challenge},
            )
        scheme, _, given = header.partition(" ")
        ok = hmac.compare_digest(given.strip().encode(), token.encode())
        if scheme.lower() != "bearer" or not ok:
            raise UnauthorizedError(
                "wrong bearer token",
                code="invalid_token",
                headers={"WWW-Authenticate": challenge + ', error="invalid_token"'},
            )

    def _run(self, job: Job) -> bytes:
        """Admit ``job`` (or 503), run it in the pool, wait for its verdict bytes.

        The admission slot is held until the job has finished in its worker, even when
        the wait times out, so no more than ``capacity`` validations ever run or wait. A
        job whose worker process died is retried once on a fresh worker (playback is
        pure, so a retry is safe); a second death is a 500.
        """
        if not self._slots.acquire(blocking=False):
            raise OverloadedError(
                f"all {self.pool.workers} workers busy and {self.config.queue_depth} "
                "validations queued",
                retry_after_s=RETRY_AFTER_S,
            )
        with self._conn_cond:
            self._in_flight += 1
        release_now = True
        try:
            for attempt in (1, 2):
                try:
                    future = self.pool.submit(job)
                    return future.result(timeout=self.config.request_timeout_s)
                except FutureTimeoutError as exc:
                    release_now = False
                    future.add_done_callback(lambda _f: self._release())
                    raise OverloadedError(
                        f"no verdict within {self.config.request_timeout_s:g} s",
                        code="timeout",
                        retry_after_s=RETRY_AFTER_S,
                    ) from exc
                except BrokenProcessPool as exc:
                    if attempt == 2:
                        raise HttpError(
                            "a worker process died twice on this plan", code="worker_lost"
                        ) from exc
                    logger.warning("a worker process died during a validation; retrying once")
                except (CancelledError, RuntimeError) as exc:
                    if not self.draining:
                        raise
                    raise OverloadedError(
                        "the gate is shutting down",
                        code="shutting_down",
                        retry_after_s=RETRY_AFTER_S,
                    ) from exc
            raise AssertionError("unreachable")  # pragma: no cover
        finally:
            if release_now:
                self._release()

    def _release(self) -> None:
        with self._conn_cond:
            self._in_flight -= 1
        self._slots.release()

    def health(self) -> dict[str, Any]:
        """The body of ``GET /health``."""
        with self._conn_cond:
            in_flight = self._in_flight
        return {
            "status": "draining" if self.draining else "ok",
            "version": gate_version(),
            "default_map": self.validator.default_map,
            "maps": sorted(self.validator.maps),
            "pool": self.pool.kind,
            "workers": self.pool.workers,
            "queue_depth": self.config.queue_depth,
            "in_flight": in_flight,
            "dt_s": self.validator.settings.dt_s,
            "max_body_bytes": self.config.max_body_bytes,
            "uptime_s": round(time.monotonic() - self._started, 3),
        }

    def _map_list(self) -> dict[str, Any]:
        out = []
        for name in sorted(self.validator.maps):
            world = self.validator.maps[name]
            b = world.bounds
            out.append(
                {
                    "name": name,
                    "description": world.description,
                    "sha256": self.validator.map_digest(name),
                    "bounds": {
                        "min_x": b.min_x,
                        "min_y": b.min_y,
                        "max_x": b.max_x,
                        "max_y": b.max_y,
                    },
                    "start": {
                        "x": world.start.x,
                        "y": world.start.y,
                        "yaw_deg": world.start.yaw_deg,
                    },
                    "obstacles": len(world.obstacles),
                    "goals": [
                        {"name": g.name, "x": g.x, "y": g.y, "yaw_deg": g.yaw_deg, "note": g.note}
                        for g in world.goals
                    ],
                }
            )
        return {"default": self.validator.default_map, "maps": out}


def _shutdown_socket(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
