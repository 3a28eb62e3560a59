"""A minimal protocol host for tests: a plain pyserial or python-can client using
firmware_proto, as any host would be. Not the bridge: tests of the emulator must not
depend on it.

The client's reader thread collects every message received; :meth:`Host.wait_for`
blocks (with a timeout) until one matches. A heartbeat thread keeps the controller's
watchdog fed unless paused.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import TypeVar

import can
import serial

from firmware_proto.canmap import CanDecoder, encode_can
from firmware_proto.framing import FrameDecoder, FrameEncoder
from firmware_proto.message import Message
from firmware_proto.messages import PROTOCOL_VERSION, SCHEMA_HASH, Hello, HostHeartbeat, Ident

M = TypeVar("M", bound=Message)


class Host:
    """Base: message log, waiting, heartbeats. Subclasses do the I/O."""

    def __init__(self, heartbeat_s: float | None = 0.05) -> None:
        self.received: list[tuple[float, Message]] = []
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self.heartbeats = threading.Event()
        if heartbeat_s is not None:
            self.heartbeats.set()
        self._heartbeat_s = heartbeat_s or 0.05
        self._threads: list[threading.Thread] = []

    def _start(self) -> None:
        for target, name in ((self._read_loop, "host-rx"), (self._heartbeat_loop, "host-hb")):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)

    def _record(self, msg: Message) -> None:
        with self._cond:
            self.received.append((time.monotonic(), msg))
            self._cond.notify_all()

    def _heartbeat_loop(self) -> None:
        n = 0
        while not self._stop.wait(self._heartbeat_s):
            if self.heartbeats.is_set():
                n += 1
                self.send(HostHeartbeat(n & 0xFFFF))

    def send(self, msg: Message, *, strict: bool = True) -> None:
        raise NotImplementedError

    def _read_loop(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5.0)

    def __enter__(self: H) -> H:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- queries ------------------------------------------------------------------------
    def mark(self) -> int:
        """Index to wait from: messages received after this call."""
        with self._cond:
            return len(self.received)

    def messages(self, kind: type[M], since: int = 0) -> list[M]:
        with self._cond:
            return [m for _, m in self.received[since:] if isinstance(m, kind)]

    def wait_for(
        self,
        kind: type[M],
        pred: Callable[[M], bool] = lambda m: True,
        *,
        since: int = 0,
        timeout: float = 10.0,
    ) -> M:
        """The first message of ``kind`` after index ``since`` satisfying ``pred``.

        Raises:
            TimeoutError: none within ``timeout`` seconds (names what was awaited).
        """
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for _, m in self.received[since:]:
                    if isinstance(m, kind) and pred(m):
                        return m
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no {kind.__name__} matching within {timeout} s")
                self._cond.wait(left)

    def handshake(self, timeout: float = 5.0) -> Ident:
        since = self.mark()
        self.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
        return self.wait_for(Ident, since=since, timeout=timeout)


H = TypeVar("H", bound=Host)


class SerialHost(Host):
    """A host on a serial device (a pty here), through pyserial."""

    def __init__(self, device: str, heartbeat_s: float | None = 0.05) -> None:
        super().__init__(heartbeat_s)
        self.port = serial.Serial(device, baudrate=115200, timeout=0.05)
        self.decoder = FrameDecoder()
        self.encoder = FrameEncoder()
        self._write_lock = threading.Lock()
        self._start()

    def send(self, msg: Message, *, strict: bool = True) -> None:
        self.write_raw(self.encoder.encode(msg, strict))

    def write_raw(self, data: bytes) -> None:
        with self._write_lock:
            self.port.write(data)

    def _read_loop(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.port.read(self.port.in_waiting or 1)
            except (serial.SerialException, OSError, TypeError):
                if self._stop.is_set():
                    return
                time.sleep(0.01)
                continue
            for frame in self.decoder.feed(data):
                self._record(frame.message)

    def close(self) -> None:
        super().close()
        self.port.close()


class CanHost(Host):
    """A host on a python-can bus."""

    def __init__(self, bus: can.BusABC, node: int = 1, heartbeat_s: float | None = 0.05) -> None:
        super().__init__(heartbeat_s)
        self.bus = bus
        self.node = node
        self.decoder = CanDecoder()
        self._start()

    def send(self, msg: Message, *, strict: bool = True) -> None:
        arb, data = encode_can(msg, self.node, strict)
        self.bus.send(can.Message(arbitration_id=arb, data=data, is_extended_id=False))

    def _read_loop(self) -> None:
        while not self._stop.is_set():
            frame = self.bus.recv(timeout=0.05)
            if frame is None:
                continue
            decoded = self.decoder.decode(
                frame.arbitration_id,
                bytes(frame.data),
                is_extended=frame.is_extended_id,
                is_remote=frame.is_remote_frame,
            )
            if (
                decoded is not None
                and decoded.node == self.node
                and decoded.message.DIRECTION == "controller_to_host"
            ):
                self._record(decoded.message)
