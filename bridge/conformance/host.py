"""The wire-level host that plays the host side of docs/protocol.md against a controller.

:class:`WireHost` owns one opened :class:`~bridge.transport.Transport` (any URL that
:func:`~bridge.transport.open_transport` knows: a serial device, a pty, a socket, a CAN
bus). It keeps every message received with its arrival time, sends messages (checked,
or unchecked frames through :meth:`~bridge.transport.Transport.send_raw`), and answers
the rules' questions with timeouts: :meth:`WireHost.expect` (the first matching message
after a mark, or :class:`~bridge.errors.RuleFailedError` saying what was awaited) and
:meth:`WireHost.absent` (no matching message during a window). A heartbeat thread sends
HOST_HEARTBEAT every ``HOST_HEARTBEAT_PERIOD_MS`` unless a rule keeps the host silent
(:meth:`WireHost.silent`, for the watchdog rules).

Every frame sent and received while a rule runs is logged (:class:`FrameRecord`) for the
report; periodic sensor samples (ENCODERS, WHEEL_SPEEDS, IMU, POSE) are counted there
rather than listed. Nothing here knows a rule: see :mod:`bridge.conformance.rules`.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from types import TracebackType
from typing import TypeVar

from bridge.errors import RuleFailedError, TransportError
from bridge.transport import SAMPLE_MESSAGES, Transport
from firmware_proto.message import Message
from firmware_proto.messages import HOST_HEARTBEAT_PERIOD_MS, Heartbeat, HostHeartbeat

__all__ = ["FrameRecord", "WireHost"]

logger = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)

_KEEP = 100_000
"""Received messages kept for the rules' questions: about 9 minutes of everything a
controller sends at the protocol's rates (trimmed by halves beyond twice that)."""


@dataclass(frozen=True)
class FrameRecord:
    """One frame of a rule's exchange.

    Attributes:
        t_s: seconds since the rule started (host clock).
        direction: ``"H>C"`` (sent by the host) or ``"C>H"``.
        text: the message, fields by name (``MOTION seq=3 command=FWD ...``), or the
            raw frame (``RAW id=8 payload=0a0b0c``) for unchecked frames.
    """

    t_s: float
    direction: str
    text: str

    def line(self) -> str:
        """``  0.0123 H>C MOTION seq=3 ...``."""
        return f"{self.t_s:8.4f} {self.direction} {self.text}"


class WireHost:
    """A protocol host on one transport; see the module docstring.

    Args:
        transport: an unopened transport (``open_transport(url)``).
        timeout_scale: multiplies every timeout a rule asks for (a slow controller or a
            loaded machine; never below 1 in meaning).
    """

    def __init__(self, transport: Transport, *, timeout_scale: float = 1.0) -> None:
        self.transport = transport
        self.timeout_scale = max(1.0, timeout_scale)
        self._cond = threading.Condition()
        self._rx: list[tuple[float, Message]] = []
        self._base = 0  # messages dropped from the front of _rx: marks stay absolute
        self._log: list[FrameRecord] = []
        self._samples = 0
        self._t0 = time.monotonic()
        self._silent = 0
        self._failure: Exception | None = None
        self._stop = threading.Event()
        self._beats: threading.Thread | None = None
        self._hb_counter = 0

    @property
    def kind(self) -> str:
        """``"serial"`` or ``"can"``: what the medium is."""
        return self.transport.kind

    # -- lifecycle ------------------------------------------------------------------------
    def open(self) -> WireHost:
        """Open the transport and start the heartbeat thread.

        Raises:
            TransportError: the device or bus cannot be opened.
        """
        self.transport.open(self._on_message, self._on_error)
        self._beats = threading.Thread(target=self._heartbeats, name="conformance-hb", daemon=True)
        self._beats.start()
        return self

    def close(self) -> None:
        """Stop the heartbeat thread and close the transport (idempotent)."""
        self._stop.set()
        if self._beats is not None:
            self._beats.join(timeout=5.0)
            self._beats = None
        self.transport.close()

    def __enter__(self) -> WireHost:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- the log of one rule --------------------------------------------------------------
    def start_log(self) -> None:
        """Start a new rule's frame log (and its clock)."""
        with self._cond:
            self._log = []
            self._samples = 0
            self._t0 = time.monotonic()

    def take_log(self) -> tuple[tuple[FrameRecord, ...], int]:
        """The frames logged since :meth:`start_log`, and the sensor samples counted."""
        with self._cond:
            return tuple(self._log), self._samples

    def _note(self, direction: str, text: str, at: float) -> None:
        self._log.append(FrameRecord(round(at - self._t0, 6), direction, text))

    # -- receive ----------------------------------------------------------------------------
    def _on_message(self, msg: Message, arrived: float) -> None:
        with self._cond:
            self._rx.append((arrived, msg))
            if len(self._rx) > _KEEP * 2:  # bounded: keep the recent half
                del self._rx[:_KEEP]
                self._base += _KEEP
            if isinstance(msg, SAMPLE_MESSAGES):
                self._samples += 1
            else:
                self._note("C>H", msg.describe(), arrived)
            self._cond.notify_all()

    def _on_error(self, exc: Exception) -> None:
        with self._cond:
            self._failure = exc
            self._cond.notify_all()

    def mark(self) -> int:
        """A position in the received messages: what arrives after this call."""
        with self._cond:
            return self._base + len(self._rx)

    def received(self, since: int) -> list[Message]:
        """Every message received from ``since`` on (those still kept)."""
        with self._cond:
            return [m for _, m in self._rx[max(0, since - self._base) :]]

    def _scaled(self, timeout_s: float) -> float:
        return timeout_s * self.timeout_scale

    def expect(
        self,
        kind: type[M],
        what: str,
        *,
        since: int,
        where: Callable[[M], bool] = lambda _: True,
        timeout_s: float = 1.0,
    ) -> M:
        """The first ``kind`` message from ``since`` on for which ``where`` holds,
        waiting up to ``timeout_s`` (scaled).

        Raises:
            RuleFailedError: none came: "expected <what> within <t> s".
            ConformanceError: the transport failed meanwhile.
        """
        found: list[M] = []
        start = since

        def seen() -> bool:
            nonlocal start
            start = max(start, self._base)
            for _, msg in self._rx[start - self._base :]:
                start += 1
                if isinstance(msg, kind) and where(msg):
                    found.append(msg)
                    return True
            return self._failure is not None

        with self._cond:
            self._cond.wait_for(seen, self._scaled(timeout_s))
            if found:
                return found[0]
            self._raise_if_failed()
        raise RuleFailedError(f"expected {what} within {self._scaled(timeout_s):g} s")

    def absent(
        self,
        kind: type[M],
        what: str,
        *,
        since: int,
        where: Callable[[M], bool] = lambda _: True,
        window_s: float = 0.3,
    ) -> None:
        """Wait ``window_s`` (scaled) and check that no such message came from ``since`` on.

        Raises:
            RuleFailedError: one came: "unexpected <what>: <message>".
        """
        deadline = time.monotonic() + self._scaled(window_s)
        with self._cond:
            while True:
                for _, msg in self._rx[max(0, since - self._base) :]:
                    if isinstance(msg, kind) and where(msg):
                        raise RuleFailedError(f"unexpected {what}: {msg.describe()}")
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                self._cond.wait(left)
                self._raise_if_failed()

    def heartbeat(self, *, since: int | None = None, timeout_s: float = 1.0) -> Heartbeat:
        """The next HEARTBEAT after ``since`` (default: after now)."""
        return self.expect(
            Heartbeat,
            "HEARTBEAT",
            since=self.mark() if since is None else since,
            timeout_s=timeout_s,
        )

    def heartbeat_where(
        self, what: str, where: Callable[[Heartbeat], bool], *, timeout_s: float = 1.0
    ) -> Heartbeat:
        """The first HEARTBEAT from now on for which ``where`` holds."""
        return self.expect(
            Heartbeat,
            f"a HEARTBEAT with {what}",
            since=self.mark(),
            where=where,
            timeout_s=timeout_s,
        )

    def _raise_if_failed(self) -> None:
        if self._failure is not None:
            raise RuleFailedError(f"the link failed: {self._failure}") from self._failure

    # -- send -------------------------------------------------------------------------------
    def send(self, msg: Message) -> int:
        """Send one message (its semantic limits checked); returns :meth:`mark` taken
        just before, so the answer can be awaited from there."""
        mark = self.mark()
        self._send(msg)
        return mark

    def send_unchecked(self, msg: Message) -> int:
        """Send a message whose fields break their semantic limits (a MOTION with speed
        61): only the wire range is checked. Returns the mark taken before."""
        mark = self.mark()
        self._send_raw(msg.MSG_ID, msg.pack(strict=False), f"{msg.describe()} (unchecked)")
        return mark

    def send_raw(self, msg_id: int, payload: bytes, *, bad_crc: bool = False) -> int:
        """Send an unchecked frame (an unknown id, a wrong length, a bad CRC). Returns the
        mark taken before."""
        mark = self.mark()
        note = f"RAW id={msg_id} payload={payload.hex() or '-'}" + (" bad-crc" if bad_crc else "")
        self._send_raw(msg_id, payload, note, bad_crc=bad_crc)
        return mark

    def _send(self, msg: Message) -> None:
        try:
            self.transport.send(msg)
        except TransportError as exc:
            raise RuleFailedError(f"cannot send {msg.NAME}: {exc}") from exc
        with self._cond:
            self._note("H>C", msg.describe(), time.monotonic())

    def _send_raw(self, msg_id: int, payload: bytes, note: str, *, bad_crc: bool = False) -> None:
        try:
            self.transport.send_raw(msg_id, payload, bad_crc=bad_crc)
        except TransportError as exc:
            raise RuleFailedError(f"cannot send {note}: {exc}") from exc
        with self._cond:
            self._note("H>C", note, time.monotonic())

    # -- heartbeats -------------------------------------------------------------------------
    @contextlib.contextmanager
    def silent(self) -> Iterator[None]:
        """No HOST_HEARTBEAT while inside (the rule sends nothing either): the host goes
        quiet, as a cut cable or a frozen host would."""
        with self._cond:
            self._silent += 1
        try:
            yield
        finally:
            with self._cond:
                self._silent -= 1

    def _heartbeats(self) -> None:
        period = HOST_HEARTBEAT_PERIOD_MS / 1000.0
        while not self._stop.wait(period):
            with self._cond:
                if self._silent:
                    continue
                self._hb_counter = (self._hb_counter + 1) & 0xFFFF
                beat = HostHeartbeat(self._hb_counter)
            try:
                self.transport.send(beat)
            except TransportError as exc:
                logger.warning("host heartbeat not sent: %s", exc)
