"""The live view's HTTP server: one static page, a Server-Sent Events stream, STOP.

Standard library only (``http.server.ThreadingHTTPServer``): the page is one file
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

Anything else gets a JSON error (404, 405, 411, 413) and the server goes on.

Binding and auth, as the gate does it: loopback by default; a non-loopback address is
refused without a token; with a token every request needs ``Authorization: Bearer
<token>`` or ``?token=<token>`` (the page passes its own on; ``EventSource`` cannot set
headers), compared in constant time, else 401.

Never in the mission's way: each browser has a bounded queue (drop-oldest) filled by the
hub; its connection thread writes with a timeout (``client_timeout_s``), so a browser
that stops reading is dropped, and a closed one only ends its own thread. Accepted
sockets have ``TCP_NODELAY`` and every response goes out in one write (the 40 ms
Nagle/delayed-ACK stall the gate found).
"""

from __future__ import annotations

import contextlib
import hmac
import ipaddress
import json
import logging
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, quote, urlsplit

from planner.view.hub import ClientQueue, ViewHub

__all__ = ["CLEAR_HEADER", "ViewConfig", "ViewServer", "is_loopback"]

logger = logging.getLogger(__name__)

CLEAR_HEADER = "X-Rover-View"
"""Header a clear-STOP request must carry (value ``1``)."""
_MAX_BODY = 4096
_KEEPALIVE_S = 1.0


def is_loopback(host: str) -> bool:
    """``127.0.0.0/8``, ``::1`` or ``localhost``; any other name counts as not loopback."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True)
class ViewConfig:
    """Where and how the view listens.

    Attributes:
        host: address to bind (default loopback).
        port: TCP port; 0 picks a free one.
        token: bearer token; required when ``host`` is not loopback.
        client_timeout_s: a write to a browser that takes longer drops that browser.
        max_clients: connections to the push channel at once (503 beyond).
        hold_s: how long ``rover demo``/``rover go`` keep the view up after the mission.
        wait_s: how long they wait for a browser to connect before the mission starts
            (0: they do not wait).

    Raises:
        ValueError: a bad port, token or timeout; a non-loopback host without a token.
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
        if self.token is not None and (not self.token or not self.token.isprintable()):
            raise ValueError("view token must be a non-empty printable string")
        if self.token is None and not is_loopback(self.host):
            raise ValueError(
                f"refusing to serve the view on {self.host!r} without a token: give "
                "--view-token (or ROVER_VIEW_TOKEN), or bind a loopback address"
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


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    view: ViewServer

    def __init__(self, address: tuple[str, int], handler: type[BaseHTTPRequestHandler]) -> None:
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        super().__init__(address, handler)
        self.connections: set[socket.socket] = set()
        self.connections_lock = threading.Lock()

    def get_request(self) -> tuple[socket.socket, Any]:
        sock, addr = super().get_request()
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with self.connections_lock:
            self.connections.add(sock)
        return sock, addr

    def shutdown_request(self, request: Any) -> None:
        with self.connections_lock:
            self.connections.discard(request)
        super().shutdown_request(request)

    def end_connections(self) -> None:
        """Cut every open connection (an idle keep-alive one would hold its thread)."""
        with self.connections_lock:
            socks = list(self.connections)
        for sock in socks:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.1"
    server_version = "rover-view"

    def setup(self) -> None:
        threading.current_thread().name = "view-connection"  # what a CPU account sums
        super().setup()

    def log_message(self, format: str, *args: Any) -> None:
        logger.debug("view %s: %s", self.address_string(), format % args)

    # -- responses --------------------------------------------------------------------------
    def _send(
        self,
        code: int,
        body: bytes,
        content_type: str = "application/json",
        headers: dict[str, str] | None = None,
    ) -> None:
        head = [f"{self.protocol_version} {code} {self.responses.get(code, ('',))[0]}"]
        head += [
            f"Content-Type: {content_type}",
            f"Content-Length: {len(body)}",
            "Cache-Control: no-store",
        ]
        head += [f"{k}: {v}" for k, v in (headers or {}).items()]
        self.wfile.write(("\r\n".join(head) + "\r\n\r\n").encode("latin-1") + body)
        self.log_request(code, len(body))

    def _json(self, code: int, obj: dict[str, Any], headers: dict[str, str] | None = None) -> None:
        self._send(code, json.dumps(obj).encode(), headers=headers)

    def _error(self, code: int, message: str, headers: dict[str, str] | None = None) -> None:
        self._json(code, {"error": message}, headers)

    # -- checks -----------------------------------------------------------------------------
    def _authorised(self) -> bool:
        token = self.server.view.config.token
        if token is None:
            return True
        given = ""
        auth = self.headers.get("Authorization", "")
        if auth.startswith("Bearer "):
            given = auth[len("Bearer ") :].strip()
        else:
            given = parse_qs(urlsplit(self.path).query).get("token", [""])[0]
        if given and hmac.compare_digest(given.encode(), token.encode()):
            return True
        challenge = 'Bearer realm="rover-view"'
        self._error(
            401,
            "this view needs 'Authorization: Bearer <token>' or ?token=<token>"
            if not given
            else "wrong token",
            {"WWW-Authenticate": challenge},
        )
        return False

    def _read_body(self) -> bool:
        length = self.headers.get("Content-Length")
        if length is None:
            if self.headers.get("Transfer-Encoding"):
                self._error(411, "send a Content-Length")
                self.close_connection = True
                return False
            return True
        try:
            n = int(length)
        except ValueError:
            self._error(400, "bad Content-Length")
            self.close_connection = True
            return False
        if n < 0 or n > _MAX_BODY:
            self._error(413, f"body over {_MAX_BODY} bytes")
            self.close_connection = True
            return False
        self.rfile.read(n)
        return True

    # -- methods ----------------------------------------------------------------------------
    def do_GET(self) -> None:
        path = urlsplit(self.path).path
        if not self._authorised():
            return
        view = self.server.view
        if path in ("/", "/index.html"):
            self._send(200, view.page, "text/html; charset=utf-8")
        elif path == "/events":
            self._events()
        elif path == "/state":
            self._json(200, view.hub.state())
        else:
            self._error(404, f"no such page: {path}; try / or /events")

    def do_POST(self) -> None:
        path = urlsplit(self.path).path
        if not self._read_body() or not self._authorised():
            return
        view = self.server.view
        if path == "/stop":
            try:
                done = view.stop()
            except Exception as exc:
                logger.exception("view: STOP failed")
                self._error(500, f"STOP failed on the ground station: {exc}; use Ctrl-C")
                return
            self._json(202, {"stop": done})
        elif path == "/clear_stop":
            if self.headers.get(CLEAR_HEADER) != "1":
                self._error(403, f"clear-STOP needs the header {CLEAR_HEADER}: 1")
                return
            allowed, why = view.hub.clear_allowed()
            if not allowed:
                self._error(409, f"STOP stays latched: {why}")
                return
            try:
                cleared = view.clear()
            except Exception as exc:  # the mission has ended: its ROS port is closed
                logger.warning("view: clear-STOP failed: %s", exc)
                self._error(503, f"the ground station cannot release the latch now: {exc}")
                return
            if cleared:
                self._json(200, {"cleared": True})
            else:
                self._error(504, "the rover did not confirm CLEAR_STOP")
        else:
            self._error(404, f"no such action: {path}; try /stop or /clear_stop")

    def _method_not_allowed(self) -> None:
        self._error(405, f"{self.command} is not served here", {"Allow": "GET, POST"})

    def do_PUT(self) -> None:
        self._method_not_allowed()

    def do_DELETE(self) -> None:
        self._method_not_allowed()

    def do_PATCH(self) -> None:
        self._method_not_allowed()

    def _events(self) -> None:
        view = self.server.view
        client = view.join()
        if client is None:
            self._error(503, f"already {view.config.max_clients} viewers")
            return
        self.close_connection = True
        try:
            self.connection.settimeout(view.config.client_timeout_s)
            self.wfile.write(
                (
                    f"{self.protocol_version} 200 OK\r\n"
                    "Content-Type: text/event-stream\r\n"
                    "Cache-Control: no-store\r\n"
                    "Connection: close\r\n\r\n"
                    "retry: 1000\n\n"
                ).encode()
            )
            while not view.closing:
                records = client.take(_KEEPALIVE_S)
                if client.closed:
                    break
                self.wfile.write(b"".join(records) if records else b": keepalive\n\n")
        except OSError as exc:  # the browser went away or stopped reading (timeout)
            logger.info("view: a viewer left (%s)", exc)
        finally:
            view.leave(client)


class ViewServer:
    """Serves a :class:`~planner.view.hub.ViewHub` (see the module docstring).

    Args:
        hub: the state and its events (started and closed by the caller).
        config: where and how to listen.
        on_stop: sends the emergency stop (what Ctrl-C does) and says what it did;
            called on the request's thread, so it must not block for long (set the
            cancel event).
        on_clear: releases the STOP latch; returns whether the rover confirmed it.

    Raises:
        OSError: the address cannot be bound.
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
        self._httpd = _Server((config.host, config.port), _Handler)
        self._httpd.view = self
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        """The page's address (with ``?token=`` when there is a token)."""
        host, port = self._httpd.socket.getsockname()[:2]
        shown = f"[{host}]" if ":" in host else host
        url = f"http://{shown}:{port}/"
        return url + (f"?token={quote(self.config.token)}" if self.config.token else "")

    def start(self) -> ViewServer:
        """Serve on a thread of its own."""
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, kwargs={"poll_interval": 0.2}, name="view-http"
        )
        self._thread.start()
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
        if self._thread is not None:
            self._httpd.shutdown()
            self._thread.join(5.0)
        self._httpd.end_connections()
        self._httpd.server_close()

    def __enter__(self) -> ViewServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
