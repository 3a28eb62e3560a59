"""An in-memory serial line: two byte ports, each reading what the other wrote.

:func:`memory_line` gives the two ends as :class:`MemoryPort` objects, byte ports for a
:class:`~firmware_proto.linkio.serial_endpoint.SerialEndpoint`: the bytes go through the
real codec with nothing between but a buffer. A lockstep run reads with timeout 0, which
never blocks; a thread may also wait in :meth:`MemoryPort.read` for another's writes.
"""

from __future__ import annotations

import threading

__all__ = ["MemoryPort", "memory_line"]


class _Direction:
    """Bytes written one way, not yet read."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.cond = threading.Condition()
        self.reader_gone = False
        """The reading end closed: what is written this way is dropped."""


class MemoryPort:
    """One end of a :func:`memory_line`; a :class:`BytePort`."""

    def __init__(self, name: str, rx: _Direction, tx: _Direction) -> None:
        self._name = name
        self._rx = rx
        self._tx = tx
        self._closed = False

    @property
    def name(self) -> str:
        """What the line was called (``memory:NAME/host`` or ``.../controller``)."""
        return self._name

    def read(self, timeout_s: float) -> bytes:
        """What the other end wrote since the last read, waiting up to ``timeout_s`` for
        some (0: never waits). Raises OSError once closed."""
        rx = self._rx
        if not rx.buf and not timeout_s > 0:
            # Nothing written and no wait (a lockstep tick's poll): the answer the locked
            # path would give, without taking the lock.
            if self._closed:
                raise OSError(f"{self._name} is closed")
            return b""
        with rx.cond:
            if self._closed:
                raise OSError(f"{self._name} is closed")
            if not rx.buf and timeout_s > 0:
                rx.cond.wait_for(lambda: bool(rx.buf) or self._closed, timeout_s)
            data = bytes(rx.buf)
            rx.buf.clear()
        return data

    def write(self, data: bytes) -> bool:
        """Hand ``data`` to the other end; False (dropped) once either end is closed, as
        on a line nobody listens to."""
        tx = self._tx
        with tx.cond:
            if self._closed or tx.reader_gone:
                return False
            tx.buf += data
            tx.cond.notify_all()
        return True

    def close(self) -> None:
        """Close this end (idempotent): its reads raise, writes to it are dropped."""
        with self._rx.cond:
            self._closed = True
            self._rx.reader_gone = True
            self._rx.buf.clear()
            self._rx.cond.notify_all()


def memory_line(name: str = "line") -> tuple[MemoryPort, MemoryPort]:
    """The two ends of a new line: ``(host end, controller end)``."""
    to_controller, to_host = _Direction(), _Direction()
    return (
        MemoryPort(f"memory:{name}/host", to_host, to_controller),
        MemoryPort(f"memory:{name}/controller", to_controller, to_host),
    )
