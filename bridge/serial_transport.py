"""Serial transport: protocol frames over pyserial's ``serial_for_url``.

Opens a real device (``/dev/ttyACM0``, ``/dev/serial/by-id/...``, ``/dev/rover-motor``),
a pty path, or any pyserial URL (``socket://``, ``rfc2217://``, ``loop://``); ``?baud=N``
in the URL sets the rate (default 115200; a pty ignores it). The port is opened
exclusively where the platform allows, so two bridges cannot share a controller.
"""

from __future__ import annotations

import logging
from urllib.parse import parse_qs, urlsplit, urlunsplit

import serial

from bridge.transport import Transport
from firmware_proto.framing import FrameDecoder, FrameEncoder
from firmware_proto.message import Message

__all__ = ["DEFAULT_BAUD", "SerialTransport"]

logger = logging.getLogger(__name__)

DEFAULT_BAUD = 115200


class SerialTransport(Transport):
    """Frames of docs/protocol.md over a serial port."""

    kind = "serial"

    def __init__(self, url: str, baud: int | None = None) -> None:
        super().__init__(url)
        parts = urlsplit(url)
        query = parse_qs(parts.query)
        self.baud = baud or int(query.pop("baud", [str(DEFAULT_BAUD)])[-1])
        if "://" in url:
            rest = "&".join(f"{k}={v[-1]}" for k, v in query.items())
            self._device = urlunsplit(
                (parts.scheme, parts.netloc, parts.path, rest, parts.fragment)
            )
        else:
            self._device = parts.path
        self._port: serial.SerialBase | None = None
        self._decoder = FrameDecoder()
        self.counters = self._decoder.counters
        self._encoder = FrameEncoder()

    def _open(self) -> None:
        try:
            port = serial.serial_for_url(
                self._device,
                baudrate=self.baud,
                timeout=0.05,
                write_timeout=1.0,
                exclusive=not self._device.startswith(("socket://", "loop://", "rfc2217://"))
                or None,
            )
        except serial.SerialException as exc:
            raise OSError(str(exc)) from exc
        self._decoder.reset()
        self._port = port
        logger.info("opened %s at %d baud", self._device, self.baud)

    def _close(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except (OSError, serial.SerialException) as exc:
                logger.debug("closing %s: %s", self._device, exc)
            self._port = None

    def _write(self, message: Message) -> None:
        port = self._port
        if port is None:
            raise OSError("port closed")
        try:
            port.write(self._encoder.encode(message))
        except serial.SerialException as exc:
            raise OSError(str(exc)) from exc

    def _read(self, timeout_s: float) -> list[Message]:
        port = self._port
        if port is None:
            raise OSError("port closed")
        try:
            # read(n) waits for n bytes or the timeout: ask for what is there, or one byte.
            data = port.read(port.in_waiting or 1)
        except (serial.SerialException, TypeError) as exc:
            # TypeError: pyserial's read on a port closed under it by another thread.
            raise OSError(str(exc)) from exc
        if not data:
            return []
        return [frame.message for frame in self._decoder.feed(data)]
