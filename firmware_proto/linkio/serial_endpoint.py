"""Serial endpoint: frames of docs/protocol.md over a byte stream, for either side.

:class:`SerialEndpoint` does the framing (pure, :mod:`firmware_proto.wire.framing`), the
listeners and the counting; a :class:`BytePort` moves the bytes:

- :class:`PyserialPort`: anything pyserial's ``serial_for_url`` opens, exclusively where
  the platform allows (two hosts cannot share a controller). The host's end.
- :class:`PtyPort`: the controller's end of a new pty pair, whose other end a host opens
  by path. While nobody has the device open, frames written are dropped (``write``
  returns False), as on a UART line nobody listens to.

A damaged frame is counted by the decoder and dropped; the decoder resynchronises at the
next delimiter (docs/protocol.md, Framing).
"""

from __future__ import annotations

import errno
import logging
import os
import random
import select
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import serial

from firmware_proto.linkio.endpoint import Endpoint, Side
from firmware_proto.linkio.ptypair import PtyPair
from firmware_proto.linkio.trafficlog import (
    SerialRecord,
    TrafficRecord,
    TrafficRecorder,
    received_serial_records,
)
from firmware_proto.linkio.urls import split_serial_url
from firmware_proto.wire.framing import Frame, FrameDecoder, FrameEncoder
from firmware_proto.wire.message import Message

__all__ = ["BytePort", "PtyPort", "PyserialPort", "SerialEndpoint"]

logger = logging.getLogger(__name__)


class BytePort(Protocol):
    """A byte stream that a :class:`SerialEndpoint` frames."""

    @property
    def name(self) -> str:
        """The device path (or URL) of the stream."""

    def read(self, timeout_s: float) -> bytes:
        """Wait up to ``timeout_s`` (a port may use its own short timeout instead) and
        return the bytes there (``b""``: none). Raise OSError when the device is gone."""

    def write(self, data: bytes) -> bool:
        """Write all of ``data``; False if the medium dropped it (nobody listening).
        Raise OSError when the write failed."""

    def close(self) -> None:
        """Release the stream (idempotent)."""


def _release(port: serial.SerialBase) -> None:
    """Close ``port`` and whatever it holds, never raising (pyserial's ``socket://`` close
    leaks the socket after a connection reset: close it ourselves)."""
    sock = getattr(port, "_socket", None)
    try:
        port.close()
    except (OSError, serial.SerialException) as exc:
        logger.debug("closing %s: %s", port.portstr, exc)
    if isinstance(sock, socket.socket):
        sock.close()


class PyserialPort:
    """A pyserial port: reads wait at most 50 ms, writes at most ``write_timeout_s``."""

    def __init__(
        self, device: str, baud: int, *, exclusive: bool = False, write_timeout_s: float = 1.0
    ) -> None:
        """Open ``device`` (a path or pyserial URL, without our ``baud`` option).

        Raises:
            OSError: it cannot be opened (absent, busy: ``errno`` EAGAIN, refused).
        """
        port = serial.serial_for_url(
            device,
            do_not_open=True,
            baudrate=baud,
            timeout=0.05,
            write_timeout=write_timeout_s,
            exclusive=exclusive or None,
        )
        try:
            port.open()
        except serial.SerialException as exc:
            # A socket port can fail after connecting (a reset while flushing its input).
            _release(port)
            if exc.errno is None:
                raise OSError(str(exc)) from exc
            # pyserial's text holds "[Errno N] ..." twice over: say the cause once.
            raise OSError(exc.errno, os.strerror(exc.errno), device) from exc
        self._port = port
        self._name = device

    @property
    def name(self) -> str:
        return self._name

    def read(self, timeout_s: float) -> bytes:
        try:
            # read(n) waits for n bytes or the timeout: ask for what is there, or one byte.
            return bytes(self._port.read(self._port.in_waiting or 1))
        except (serial.SerialException, TypeError) as exc:
            # TypeError: pyserial's read on a port closed under it by another thread.
            raise OSError(str(exc)) from exc

    def write(self, data: bytes) -> bool:
        try:
            self._port.write(data)
        except serial.SerialException as exc:
            raise OSError(str(exc)) from exc
        return True

    def close(self) -> None:
        _release(self._port)


class PtyPort:
    """The controller's end of a new raw pty pair; :attr:`device` is the host's end."""

    def __init__(self, link: str | Path | None = None) -> None:
        """Make the pair, with an optional stable symlink ``link`` to the device; OSError when no
        pty is available or ``link`` exists and is not a symlink."""
        self._pair = PtyPair(link)
        os.set_blocking(self._pair.master_fd, False)
        self.device = self._pair.device

    @property
    def name(self) -> str:
        return self.device

    def read(self, timeout_s: float) -> bytes:
        fd = self._pair.master_fd
        if fd < 0:
            raise OSError(errno.EBADF, "pty closed")
        ready, _, _ = select.select([fd], [], [], timeout_s)
        if not ready:
            return b""
        try:
            return os.read(fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:  # no host has the device open
                time.sleep(timeout_s)
                return b""
            raise

    def write(self, data: bytes) -> bool:
        try:
            written = os.write(self._pair.master_fd, data)
        except (BlockingIOError, InterruptedError):
            return False  # nobody reads: the bytes go nowhere, as on an open UART line
        except OSError as exc:
            if exc.errno in (errno.EIO, errno.EBADF):
                return False
            raise
        return written == len(data)

    def close(self) -> None:
        self._pair.close()


class SerialEndpoint(Endpoint):
    """Frames of docs/protocol.md over a :class:`BytePort` (see the module docstring); it can
    be closed and opened again (a device unplugged and plugged in, a reconnect)."""

    medium = "serial"

    def __init__(
        self,
        side: Side,
        open_port: Callable[[], BytePort],
        *,
        name: str = "",
        baud: int | None = None,
        recorder: TrafficRecorder | None = None,
    ) -> None:
        """Args:
        side: which end of the link this is.
        open_port: makes and opens the byte port (raises OSError when it cannot); called on
            every :meth:`open`.
        name: what the endpoint is on until open (a URL); then the port's own name.
        baud: the line's rate in bit/s, where the port has one (``None``: a pty).
        recorder: a first listener.
        """
        super().__init__(side, recorder=recorder)
        self._open_port = open_port
        self._name = name
        self.baud = baud
        """The line's rate in bit/s, or ``None`` (a pty has none)."""
        self._port: BytePort | None = None
        self.decoder = FrameDecoder()
        self.counters = self.decoder.counters
        self._encoder = FrameEncoder()

    @classmethod
    def for_url(
        cls,
        side: Side,
        url: str,
        *,
        baud: int | None = None,
        write_timeout_s: float = 1.0,
        recorder: TrafficRecorder | None = None,
    ) -> SerialEndpoint:
        """An endpoint on a device path or pyserial URL (:func:`split_serial_url`).

        Raises:
            LinkUrlError: the URL is malformed.
        """
        device, rate, exclusive = split_serial_url(url, baud)
        return cls(
            side,
            lambda: PyserialPort(
                device, rate, exclusive=exclusive, write_timeout_s=write_timeout_s
            ),
            name=device,
            baud=rate,
            recorder=recorder,
        )

    @property
    def name(self) -> str:
        port = self._port
        return port.name if port is not None else self._name

    @property
    def is_open(self) -> bool:
        """Whether the port is open."""
        return self._port is not None

    def _open(self) -> None:
        self.decoder.reset()
        self._port = self._open_port()

    def _close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            port.close()

    def _frames(self, timeout_s: float) -> list[Frame]:
        port = self._port
        if port is None:
            raise OSError(errno.EBADF, f"{self._name or 'serial port'} is closed")
        data = port.read(timeout_s)
        if not data:
            return []
        frames = self.decoder.feed(data)
        if frames and self.recording:
            for record in received_serial_records(frames, time.time()):
                self._emit(record)
        return frames

    def read(self, timeout_s: float) -> list[Message]:
        return [frame.message for frame in self._frames(timeout_s)]

    def read_numbered(self, timeout_s: float) -> list[tuple[Message, int | None]]:
        return [(frame.message, frame.seq) for frame in self._frames(timeout_s)]

    def read_ready(self) -> list[tuple[Message, int | None]]:
        """One read without waiting: a byte port returns every byte it has."""
        return self.read_numbered(0.0)

    def restart_counter(self) -> None:
        self._encoder = FrameEncoder()

    def encode(self, message: Message, *, corrupt: random.Random | None = None) -> bytes:
        """The frame of ``message``, with one bit flipped by ``corrupt`` if given."""
        wire = self._encoder.encode(message)
        if corrupt is not None:
            damaged = bytearray(wire)
            damaged[corrupt.randrange(len(damaged))] ^= 1 << corrupt.randrange(8)
            wire = bytes(damaged)
        return wire

    def write(self, message: Message, *, corrupt: random.Random | None = None) -> bool:
        return self.write_wire(self.encode(message, corrupt=corrupt))

    def write_wire(self, wire: bytes, *, log: bool = True) -> bool:
        """Write one encoded frame (from :meth:`encode`); see :meth:`Endpoint.write`.
        ``log``: hand it to the listeners first."""
        port = self._port
        if port is None:
            return False
        if log and self.recording:
            # Logged before the write, so the log keeps the wire's order.
            self._emit(SerialRecord(time.time(), self.sends, wire))
        return port.write(wire)

    def write_raw(self, msg_id: int, payload: bytes, *, bad_crc: bool = False) -> None:
        port = self._port
        if port is None:
            raise OSError(errno.EBADF, f"{self.name} is closed")
        port.write(self._encoder.encode_raw(msg_id, payload, bad_crc=bad_crc))

    def write_record(self, record: TrafficRecord) -> None:
        if not isinstance(record, SerialRecord):
            raise TypeError("a serial endpoint replays serial records")
        self.write_wire(record.wire, log=False)
