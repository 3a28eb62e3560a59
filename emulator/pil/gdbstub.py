"""A minimal client of the GDB remote serial protocol, for reading and writing an
emulated MCU's RAM while it runs (qemu's ``-gdb``): the nRF51 runner's way into the
image's counters (``pil_stats``, ``pil_view``) and fault hooks (``pil_hooks``).

Only connect (which stops the machine), ``continue``, and :meth:`GdbStub.read` /
:meth:`GdbStub.write`, each of which interrupts the machine, accesses memory and
continues it. Threads: any, one at a time (a lock). Every wait has a timeout.
"""

from __future__ import annotations

import socket
import threading
import time

from emulator.pil.errors import PilError

__all__ = ["GdbStub"]


def _checksum(payload: bytes) -> bytes:
    return b"%02x" % (sum(payload) & 0xFF)


class GdbStub:
    """A connection to a GDB stub on a Unix or TCP socket.

    Args:
        address: a Unix socket path (``str``) or ``(host, port)``.
        timeout_s: how long any one answer may take.

    Raises:
        PilError: the stub did not accept the connection within ``timeout_s``.
    """

    def __init__(self, address: str | tuple[str, int], timeout_s: float = 5.0) -> None:
        self._timeout_s = timeout_s
        self._lock = threading.Lock()
        self._buf = b""
        self._running = False
        deadline = time.monotonic() + timeout_s
        while True:
            family = socket.AF_UNIX if isinstance(address, str) else socket.AF_INET
            sock = socket.socket(family, socket.SOCK_STREAM)
            sock.settimeout(timeout_s)
            try:
                sock.connect(address)
                break
            except OSError as exc:
                sock.close()
                if time.monotonic() > deadline:
                    raise PilError(f"no GDB stub at {address}: {exc}") from exc
                time.sleep(0.02)
        self._sock = sock
        self._command(b"?")  # the stop reason: the machine is halted now

    # -- packets ---------------------------------------------------------------------------
    def _send(self, payload: bytes) -> None:
        self._sock.sendall(b"$" + payload + b"#" + _checksum(payload))

    def _recv_packet(self) -> bytes:
        deadline = time.monotonic() + self._timeout_s
        while True:
            start = self._buf.find(b"$")
            if start >= 0:
                end = self._buf.find(b"#", start)
                if end >= 0 and len(self._buf) >= end + 3:
                    payload = self._buf[start + 1 : end]
                    self._buf = self._buf[end + 3 :]
                    self._sock.sendall(b"+")
                    return payload
            if time.monotonic() > deadline:
                raise PilError("the GDB stub did not answer in time")
            try:
                chunk = self._sock.recv(4096)
            except TimeoutError as exc:
                raise PilError("the GDB stub did not answer in time") from exc
            if not chunk:
                raise PilError("the GDB stub closed the connection")
            self._buf += chunk

    def _command(self, payload: bytes) -> bytes:
        self._send(payload)
        return self._recv_packet()

    def _halt(self) -> None:
        if self._running:
            self._sock.sendall(b"\x03")
            self._recv_packet()  # the stop reply
            self._running = False

    def _resume(self) -> None:
        self._send(b"c")  # no answer until the next stop
        self._running = True

    # -- API -------------------------------------------------------------------------------
    def cont(self) -> None:
        """Let the machine run."""
        with self._lock:
            if not self._running:
                self._resume()

    def read(self, address: int, length: int) -> bytes:
        """``length`` bytes of the target's memory at ``address`` (halts it briefly)."""
        with self._lock:
            was_running = self._running
            self._halt()
            try:
                answer = self._command(b"m%x,%x" % (address, length))
            finally:
                if was_running:
                    self._resume()
        if answer.startswith(b"E") or len(answer) != 2 * length:
            raise PilError(f"reading {length} bytes at 0x{address:x}: {answer!r}")
        return bytes.fromhex(answer.decode())

    def write(self, address: int, data: bytes) -> None:
        """Write ``data`` into the target's memory at ``address`` (halts it briefly)."""
        with self._lock:
            was_running = self._running
            self._halt()
            try:
                answer = self._command(b"M%x,%x:" % (address, len(data)) + data.hex().encode())
            finally:
                if was_running:
                    self._resume()
        if answer != b"OK":
            raise PilError(f"writing {len(data)} bytes at 0x{address:x}: {answer!r}")

    def close(self) -> None:
        """Detach (the machine runs on) and close (idempotent)."""
        with self._lock:
            if self._sock.fileno() < 0:
                return
            try:
                self._halt()
                self._send(b"D")
            except (OSError, PilError):
                pass
            self._sock.close()
