"""A client of a device's control port: how the suite makes a controller do what a host
cannot cause over the protocol (a reboot, a fault).

The emulator serves one (``rover emulate --control-port``; docs/emulator.md): one
command per line over TCP, one JSON answer per line. A lab can offer the same port in
front of its firmware's test hooks; the suite needs ``inject reboot``,
``inject encoder-dropout:left`` / ``inject clear:encoder-dropout`` and
``inject stall:right`` / ``inject clear:stall``.
"""

from __future__ import annotations

import json
import socket
from types import TracebackType
from typing import Any

from bridge.errors import ConformanceError

__all__ = ["ControlClient", "parse_host_port"]


def parse_host_port(text: str) -> tuple[str, int]:
    """``HOST:PORT`` -> ``(host, port)``.

    Raises:
        ConformanceError: not of that form.
    """
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConformanceError(f"control address must be HOST:PORT, got {text!r}")
    return host, int(port)


class ControlClient:
    """One connection to a control port; commands answered in order."""

    def __init__(self, address: str, *, timeout_s: float = 10.0) -> None:
        """Args:
        address: ``HOST:PORT``.
        timeout_s: for connecting and for each answer.

        Raises:
            ConformanceError: a malformed address.
        """
        self.address = address
        self._host, self._port = parse_host_port(address)
        self._timeout_s = timeout_s
        self._sock: socket.socket | None = None
        self._buf = b""

    def _connect(self) -> socket.socket:
        if self._sock is None:
            try:
                self._sock = socket.create_connection(
                    (self._host, self._port), timeout=self._timeout_s
                )
            except OSError as exc:
                raise ConformanceError(f"control port {self.address}: {exc}") from exc
        return self._sock

    def command(self, line: str) -> dict[str, Any]:
        """Send one command; its JSON answer.

        Raises:
            ConformanceError: no connection, no answer in time, or an answer that is not
                ``{"ok": true, ...}``.
        """
        sock = self._connect()
        try:
            sock.sendall(line.encode() + b"\n")
            while b"\n" not in self._buf:
                chunk = sock.recv(4096)
                if not chunk:
                    raise ConformanceError(f"control port {self.address} closed")
                self._buf += chunk
        except OSError as exc:
            raise ConformanceError(f"control port {self.address}: {exc}") from exc
        raw, _, self._buf = self._buf.partition(b"\n")
        try:
            answer = json.loads(raw)
        except ValueError as exc:
            raise ConformanceError(f"control port {self.address}: not JSON: {raw!r}") from exc
        if not isinstance(answer, dict) or answer.get("ok") is not True:
            raise ConformanceError(f"control port refused {line!r}: {answer}")
        return answer

    def inject(self, fault: str) -> dict[str, Any]:
        """``inject FAULT``: make the device do it now."""
        return self.command(f"inject {fault}")

    def close(self) -> None:
        """Close the connection (idempotent)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> ControlClient:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
