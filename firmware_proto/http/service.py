"""An ASGI application served by uvicorn on a thread of its own: :class:`HttpService`.

The server runs an asyncio event loop in one thread (named by the caller) and every
connection is a protocol object on that loop, so slow clients cost memory, never
threads. The socket is bound in :meth:`HttpService.start`, so a bad address raises there
and port 0 is known at once.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import threading
from typing import Any

import uvicorn

from firmware_proto.http.limits import ErrorRenderer, ServeLimits
from firmware_proto.http.protocol import ServeConfig

__all__ = ["START_TIMEOUT_S", "HttpService"]

logger = logging.getLogger(__name__)

START_TIMEOUT_S = 30.0
"""Longest wait for the server's loop to start serving."""
_STOP_GRACE_S = 10.0
"""After the drain timeout, how long the loop may take to wind down."""
_BACKLOG = 128


class _Server(uvicorn.Server):
    """uvicorn's server that says when it serves."""

    def __init__(self, config: uvicorn.Config) -> None:
        super().__init__(config)
        self.ready = threading.Event()

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets)
        self.ready.set()


class HttpService:
    """Serve ``app`` (ASGI 3) on ``host:port`` (port 0 picks a free one) in a background
    thread named ``thread_name`` (a context manager); ``limits``, ``render_error`` and
    ``server_name`` (the ``Server`` header) as :class:`~.protocol.ServeConfig` takes them."""

    def __init__(
        self,
        app: Any,
        *,
        host: str,
        port: int,
        limits: ServeLimits,
        render_error: ErrorRenderer,
        server_name: str,
        thread_name: str,
    ) -> None:
        self._config = ServeConfig(
            app, host=host, limits=limits, render_error=render_error, server_name=server_name
        )
        self._host, self._port = host, port
        self._limits = limits
        self._thread_name = thread_name
        self._sock: socket.socket | None = None
        self._server: _Server | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._failure: BaseException | None = None
        self._closed = False
        self._lock = threading.Lock()
        self.stopped_accepting = threading.Event()
        """Set once the listener is closed (new connections are refused)."""

    def start(self) -> HttpService:
        """Bind and serve.

        Raises:
            OSError: the address cannot be bound.
            RuntimeError: already started, or the server did not come up.
        """
        if self._thread is not None:
            raise RuntimeError("already started")
        family = socket.AF_INET6 if ":" in self._host else socket.AF_INET
        # proto named: asyncio sets TCP_NODELAY only on sockets that say they are TCP
        # (else Nagle and the client's delayed ACK hold every keep-alive response).
        sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((self._host, self._port))
            sock.listen(_BACKLOG)
            sock.setblocking(False)
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        self._server = _Server(self._config)
        self._thread = threading.Thread(target=self._run, name=self._thread_name, daemon=True)
        self._thread.start()
        if not self._server.ready.wait(START_TIMEOUT_S) or self._failure is not None:
            self.close()
            raise RuntimeError(f"the HTTP server did not start: {self._failure!r}")
        return self

    def _run(self) -> None:
        assert self._server is not None
        assert self._sock is not None
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._server.serve(sockets=[self._sock]))
        except BaseException as exc:  # reported to start() or logged; the thread ends
            self._failure = exc
            logger.exception("the HTTP server on %s stopped", self.address)
        finally:
            loop.close()
            self._server.ready.set()  # a start() still waiting learns of the failure
            self.stopped_accepting.set()

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` actually bound."""
        if self._sock is None:
            raise RuntimeError("not started")
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    @property
    def url(self) -> str:
        """``http://host:port`` of the listener."""
        host, port = self.address
        return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"

    def stop_accepting(self) -> None:
        """Close the listener now (new connections are refused); requests under way
        and open connections go on until :meth:`close`."""
        loop, server = self._loop, self._server
        if loop is None or server is None or self.stopped_accepting.is_set():
            return

        def close_listeners() -> None:
            for listener in getattr(server, "servers", []):
                listener.close()
            self.stopped_accepting.set()

        try:
            loop.call_soon_threadsafe(close_listeners)
        except RuntimeError:  # the loop has already ended
            self.stopped_accepting.set()
        self.stopped_accepting.wait(START_TIMEOUT_S)

    def close(self) -> None:
        """Stop: close the listener and idle connections, let requests under way finish
        (at most ``drain_timeout_s``), end the thread. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        thread, server = self._thread, self._server
        if thread is None or server is None:
            if self._sock is not None:
                self._sock.close()
            return
        self.stop_accepting()
        server.should_exit = True
        thread.join(self._limits.drain_timeout_s + _STOP_GRACE_S)
        if thread.is_alive():
            logger.warning("the HTTP server did not stop in time; forcing it")
            server.force_exit = True
            thread.join(_STOP_GRACE_S)
        if self._sock is not None:
            self._sock.close()

    def __enter__(self) -> HttpService:
        if self._thread is None:
            self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
