"""Serial transport: protocol frames over pyserial's ``serial_for_url``.

Opens a real device (``/dev/ttyACM0``, ``/dev/serial/by-id/...``, ``/dev/rover-motor``),
a pty path, or any pyserial URL (``socket://HOST:PORT``, ``rfc2217://HOST:PORT``,
``loop://``, ``spy://DEVICE``, ``alt://``, ``hwgrep://``, ``cp2110://``). ``?baud=N`` in
the URL sets the rate (default 115200; a pty or a socket ignores it); it is our own
parameter and is stripped before the URL goes to pyserial, which gets the rest verbatim
(``loop://`` stays ``loop://``, ``spy:///dev/x?raw`` stays ``spy:///dev/x?raw``). Devices
are opened exclusively where the platform allows, so two bridges cannot share a
controller.

Errors, and which are retried:

- **permanent**, :class:`~bridge.errors.TransportUrlError` from the constructor (so from
  :func:`~bridge.transport.open_transport`, before anything is opened): a scheme pyserial
  does not know, ``socket://`` or ``rfc2217://`` without ``HOST:PORT``, ``spy://``
  without a device, an option the scheme does not take, a baud rate that is not a
  positive integer. No reconnect can fix these; the link refuses to start with them.
- **retryable**, :class:`~bridge.errors.TransportError` from ``open``, ``send`` or the
  reader: the device is not there (yet), busy or not permitted, the connection is
  refused or drops, the device disappears. The link reconnects with backoff.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import socket
import time
from dataclasses import dataclass

import serial

from bridge.errors import DeviceBusyError, TransportUrlError
from bridge.transport import Transport
from firmware_proto.framing import FrameDecoder, FrameEncoder
from firmware_proto.message import Message
from firmware_proto.trafficlog import (
    SerialRecord,
    TrafficRecorder,
    message_direction,
    received_serial_records,
)

__all__ = ["DEFAULT_BAUD", "SerialTransport", "refuse_if_in_use", "split_serial_url"]

logger = logging.getLogger(__name__)

DEFAULT_BAUD = 115200

_LOGGING = frozenset({"logging"})


@dataclass(frozen=True)
class _Scheme:
    """What a pyserial URL scheme needs.

    Attributes:
        options: the query options it takes (besides our ``baud``); ``None``: not
            checked here, pyserial checks them when the port opens.
        host_port: needs ``HOST:PORT``.
        target: wraps a device path (``spy://DEVICE``).
        exclusive: the port is a local device, opened exclusively.
    """

    options: frozenset[str] | None
    host_port: bool = False
    target: bool = False
    exclusive: bool = False


_SCHEMES: dict[str, _Scheme] = {
    "": _Scheme(frozenset(), exclusive=True),  # a device path
    "socket": _Scheme(_LOGGING, host_port=True),
    "rfc2217": _Scheme(_LOGGING | {"ign_set_control", "poll_modem", "timeout"}, host_port=True),
    "loop": _Scheme(_LOGGING),
    "spy": _Scheme(frozenset({"file", "color", "raw", "all"}), target=True, exclusive=True),
    "alt": _Scheme(None),
    "hwgrep": _Scheme(None, exclusive=True),
    "cp2110": _Scheme(None),
}
"""The schemes pyserial's ``serial_for_url`` knows (``""``: a plain device path)."""


def split_serial_url(url: str, baud: int | None = None) -> tuple[str, int, bool]:
    """Check a serial URL and take our ``baud`` option out of it; pure.

    Args:
        url: a device path or pyserial URL, with optional ``?baud=N`` (see the module
            docstring).
        baud: overrides the URL's ``baud`` when given.

    Returns:
        (what to hand to pyserial, verbatim but for ``baud``; the baud rate in bit/s;
        whether to open it exclusively).

    Raises:
        TransportUrlError: the URL is malformed; says what is wrong and what is expected.
    """
    head, sep, query = url.partition("?")
    scheme = head.split("://", 1)[0].lower() if "://" in head else ""
    spec = _SCHEMES.get(scheme)
    if spec is None:
        known = ", ".join(f"{s}://" for s in _SCHEMES if s)
        raise TransportUrlError(f"{url!r}: unknown serial URL scheme {scheme!r}; known: {known}")
    kept: list[str] = []
    rate = DEFAULT_BAUD
    for item in query.split("&") if sep else []:
        key, _, value = item.partition("=")
        if key == "baud":
            try:
                rate = int(value)
            except ValueError:
                rate = 0
            if rate <= 0:
                raise TransportUrlError(f"{url!r}: baud must be a positive integer, got {value!r}")
        elif spec.options is not None and key not in spec.options:
            takes = ", ".join(sorted(spec.options | {"baud"}))
            where = f"{scheme}://" if scheme else "a device path"
            raise TransportUrlError(f"{url!r}: {where} takes no option {key!r}; it takes: {takes}")
        else:
            kept.append(item)
    rest = head[len(scheme) + 3 :] if scheme else head
    if spec.host_port:
        host, colon, port = rest.rstrip("/").rpartition(":")
        if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise TransportUrlError(f"{url!r}: {scheme}:// needs HOST:PORT (port 1..65535)")
    if (spec.target or not scheme) and not rest:
        raise TransportUrlError(f"{url!r}: no device path")
    device = head + ("?" + "&".join(kept) if kept else "")
    return device, baud if baud is not None else rate, spec.exclusive


def refuse_if_in_use(url: str) -> None:
    """Fail when another process holds the device of ``url`` exclusively (as pyserial's
    ``exclusive=True`` does: ``flock(LOCK_EX | LOCK_NB)``), e.g. a bridge already running
    on it. A device that is absent, or a URL that is not a local device, passes: the link
    waits for those.

    Raises:
        DeviceBusyError: the device is locked by another process.
        TransportUrlError: the URL is malformed.
    """
    device, _, exclusive = split_serial_url(url)
    if not exclusive or "://" in device:
        return
    try:
        fd = os.open(device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return  # not there (yet), or not permitted: the link reports and retries
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
            raise DeviceBusyError(
                f"{device} is held by another process (is a bridge already running on it?)"
            ) from exc
    finally:
        os.close(fd)  # also releases our lock


def _release(port: serial.SerialBase) -> None:
    """Close ``port`` and whatever it holds, never raising.

    pyserial 3.5's ``socket://`` close shuts the socket down and closes it in one
    ``try``: after a connection reset the shutdown fails, the close is skipped and the
    descriptor stays open until garbage collection. Close that socket ourselves.
    """
    sock = getattr(port, "_socket", None)
    try:
        port.close()
    except (OSError, serial.SerialException) as exc:
        logger.debug("closing %s: %s", port.portstr, exc)
    if isinstance(sock, socket.socket):
        sock.close()


class SerialTransport(Transport):
    """Frames of docs/protocol.md over a serial port."""

    kind = "serial"

    def __init__(
        self, url: str, baud: int | None = None, recorder: TrafficRecorder | None = None
    ) -> None:
        """Args:
        url: device path or pyserial URL (see the module docstring).
        baud: rate in bit/s; overrides ``?baud=`` in the URL.
        recorder: traffic log (see :class:`~bridge.transport.Transport`).

        Raises:
            TransportUrlError: the URL is malformed (permanent; see the module docstring).
        """
        super().__init__(url, recorder)
        if baud is not None and baud <= 0:
            raise TransportUrlError(f"{url!r}: baud must be a positive integer, got {baud}")
        self._device, self.baud, self._exclusive = split_serial_url(url, baud)
        self._port: serial.SerialBase | None = None
        self._decoder = FrameDecoder()
        self.counters = self._decoder.counters
        self._encoder = FrameEncoder()

    @property
    def device(self) -> str:
        """What pyserial opens: the URL without our ``baud`` option."""
        return self._device

    def _open(self) -> None:
        port = serial.serial_for_url(
            self._device,
            do_not_open=True,
            baudrate=self.baud,
            timeout=0.05,
            write_timeout=1.0,
            exclusive=self._exclusive or None,
        )
        try:
            port.open()
        except serial.SerialException as exc:
            # A socket port can fail after connecting (a reset while flushing its input).
            _release(port)
            raise OSError(exc.errno, str(exc)) from exc
        self._decoder.reset()
        self._port = port
        logger.info("opened %s at %d baud", self._device, self.baud)

    def _close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            _release(port)

    def _write(self, message: Message) -> None:
        port = self._port
        if port is None:
            raise OSError("port closed")
        wire = self._encoder.encode(message)
        if self.recorder is not None:
            # Logged before the write: the reader may log the answer as soon as the frame
            # is out, and the log must keep the wire's order.
            self._record(SerialRecord(time.time(), message_direction(message), wire))
        try:
            port.write(wire)
        except serial.SerialException as exc:
            raise OSError(str(exc)) from exc

    def _write_raw(self, msg_id: int, payload: bytes, bad_crc: bool) -> None:
        port = self._port
        if port is None:
            raise OSError("port closed")
        wire = self._encoder.encode_raw(msg_id, payload, bad_crc=bad_crc)
        try:
            port.write(wire)
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
        frames = self._decoder.feed(data)
        if self.recorder is not None and frames:
            for record in received_serial_records(frames, time.time()):
                self._record(record)
        return [frame.message for frame in frames]
