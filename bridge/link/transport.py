"""Transports to the motor controller: the host's end of the link, with its threads.

:func:`open_transport` builds the transport a link URL names (docs/bridge.md,
"Transports"): ``can://...`` a :class:`~bridge.link.can_transport.CanTransport`, anything
else a :class:`~bridge.link.serial_transport.SerialTransport`.

A transport moves protocol messages, not bytes, through an
:class:`~firmware_proto.linkio.endpoint.Endpoint` of the link-I/O layer on the host's
side (the same serial and CAN endpoints the emulator serves with): the endpoint frames,
decodes, filters and hands every frame to the traffic log; the transport adds the
threads, the receive queue and its drop policy, the write locks and the bridge's errors.
Two threads per open transport:

- the **reader** does I/O only: it reads, feeds the pure decoder, stamps each message
  with its arrival time (``time.monotonic()``) and puts it on a bounded queue
  (:attr:`Transport.rx_queue_depth`); it never runs a callback;
- the **dispatcher** takes the messages off that queue in order and hands each to
  ``on_message`` (the link's state machine, odometry, ROS publishing run here). An
  exception in the callback is logged and the next message is dispatched.

When the queue is full (the dispatcher fell behind), a sensor sample (ENCODERS,
WHEEL_SPEEDS, IMU, POSE: the next one supersedes it) is dropped, counted in
:attr:`Transport.rx_overflow` and logged (the first and every 100th at WARNING); any other
message is never dropped: the reader waits for room, and the OS buffers the device's
bytes meanwhile. An I/O error ends the reader; it is reported once through
``on_error``, on the dispatcher thread after every message received before it (the link
reconnects).

**Writes** happen on the caller's thread. Ordinary messages are written one at a time, in
the order their callers got the write lock. STOP has a lock of its own (one STOP at a
time): it never waits for another message's write, even one stuck in the OS for the
serial write timeout. On a serial line a STOP may cut a frame half-way out and still
arrive whole (docs/bridge.md, "The link to the controller"); on CAN it goes to the bus
ahead of any frame of ours still waiting for the write lock.

**In lockstep** (a whole mission in virtual time, docs/sim.md) a transport is opened with
``threads=False`` and read by :meth:`Transport.pump` once per tick.

A new medium is a new :class:`~firmware_proto.linkio.endpoint.Endpoint`; a test that
must see or stall the writes overrides ``_write`` (one message, on the writing thread).
"""

from __future__ import annotations

import errno
import importlib
import logging
import queue
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import TracebackType
from typing import Any

from bridge.errors import DeviceBusyError, TransportError, TransportUrlError
from bridge.link.linktypes import SAMPLE_MESSAGES
from firmware_proto.linkio.endpoint import Endpoint
from firmware_proto.linkio.errors import LinkUrlError
from firmware_proto.linkio.media import medium_of
from firmware_proto.runtime import stall
from firmware_proto.wire.counters import RxCounters
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Stop

__all__ = [
    "RX_QUEUE_DEPTH",
    "SAMPLE_MESSAGES",
    "TRANSPORTS",
    "OnError",
    "OnMessage",
    "Transport",
    "open_transport",
    "url_errors",
]

logger = logging.getLogger(__name__)

OnMessage = Callable[[Message, float], None]
"""Called on the dispatcher thread with each message in order and its arrival (monotonic s)."""
OnError = Callable[[Exception], None]
"""Called once, on the dispatcher thread, when the transport fails (after every earlier message)."""

RX_QUEUE_DEPTH = 2048
"""Messages the reader may hold for the dispatcher by default: about 11 s at the protocol's rates
(docs/protocol.md), so that only a stalled dispatcher fills it."""

_POLL_S = 0.05
"""How often the reader and the dispatcher look at the stop flag while they wait, s."""

TRANSPORTS: dict[str, tuple[str, str]] = {
    "serial": ("bridge.link.serial_transport", "SerialTransport"),
    "can": ("bridge.link.can_transport", "CanTransport"),
}
"""Medium (:func:`firmware_proto.linkio.media.medium_of`) -> (module, transport class), lazily."""


@contextmanager
def url_errors(url: str) -> Iterator[None]:
    """Turn the link layer's malformed-URL error into the bridge's (permanent)
    :class:`~bridge.errors.TransportUrlError`."""
    try:
        yield
    except LinkUrlError as exc:
        text = str(exc)
        raise TransportUrlError(text if repr(url) in text else f"{url!r}: {text}") from exc


class Transport:
    """A connection to the controller that carries protocol messages, through an
    endpoint on the host's side (see the module docstring)."""

    kind = "transport"
    rx_queue_depth = RX_QUEUE_DEPTH
    """Messages the reader may hold for the dispatcher (set before :meth:`open`)."""

    def __init__(self, url: str, endpoint: Endpoint) -> None:
        """Args:
        url: the transport URL (see the module docstring).
        endpoint: the host's end of the link on its medium, not yet open; its listeners
            (a traffic log: the caller keeps ownership and closes it after the
            transport) get every frame sent and received.
        """
        self.url = url
        self.endpoint = endpoint
        self._tx_frames = 0
        self._tx_stops = 0
        self.rx_overflow = 0
        """Sensor samples dropped because the dispatcher fell behind (queue full)."""
        self._write_lock = threading.Lock()
        self._stop_lock = threading.Lock()
        """STOP's own write lock: never held while waiting for ``_write_lock``."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._dispatcher: threading.Thread | None = None
        self._rx: queue.Queue[tuple[Message, float, int | None] | Exception] = queue.Queue(1)
        self.dispatch_seq: int | None = None
        """Serial frame counter of the message handed to ``on_message`` (``None`` on CAN); read it
        there, on the dispatcher thread (the link's lost-frame forgiveness at a reboot)."""
        self._callbacks: tuple[OnMessage, OnError] | None = None
        self._opened = False

    @property
    def counters(self) -> RxCounters:
        """The decoder's receive counters (frames, bytes, rejects by cause)."""
        return self.endpoint.counters

    @property
    def medium_state(self) -> str:
        """The medium's own condition, for ``/diagnostics``: ``ok`` unless the medium
        knows better (CAN: its fault-confinement state, see
        :mod:`firmware_proto.linkio.can_endpoint`). ``ok`` and ``error_active`` are
        healthy; anything else is a warning."""
        return self.endpoint.medium_state

    @property
    def medium_errors(self) -> int:
        """Errors the medium itself reported on this connection (CAN: error frames)."""
        return self.endpoint.medium_errors

    def _write(self, message: Message) -> None:
        """Send one message; raises OSError on failure (a test overrides it to stall writes)."""
        self.endpoint.write(message)

    # -- API ----------------------------------------------------------------------------
    def open(self, on_message: OnMessage, on_error: OnError, *, threads: bool = True) -> None:
        """Open and start reading.

        Args:
            on_message, on_error: see :data:`OnMessage`, :data:`OnError`.
            threads: start the reader and the dispatcher (real time). Without them (a
                link in lockstep, docs/sim.md) nothing is read until :meth:`pump`.

        Raises:
            DeviceBusyError: another process holds the device's exclusive lock.
            TransportError: the device or bus cannot be opened; says which and why.
        """
        try:
            self.endpoint.open()
        except (OSError, ValueError) as exc:
            if isinstance(exc, OSError) and exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                raise DeviceBusyError(
                    f"cannot open {self.url}: another process holds it ({exc}); "
                    "is a bridge already running on it?"
                ) from exc
            raise TransportError(f"cannot open {self.url}: {exc}") from exc
        self._opened = True
        self._stop.clear()
        self._callbacks = (on_message, on_error)
        if not threads:
            return
        self._rx = queue.Queue(self.rx_queue_depth)
        self._dispatcher = threading.Thread(
            target=self._dispatch,
            args=(on_message, on_error),
            name=f"{self.kind}-dispatch",
            daemon=True,
        )
        self._thread = threading.Thread(target=self._reader, name=f"{self.kind}-rx", daemon=True)
        self._dispatcher.start()
        self._thread.start()

    def pump(self, now: float) -> None:
        """Lockstep (opened with ``threads=False``): read what has arrived, without
        waiting, and hand each message to ``on_message`` on this thread, arrived at
        ``now``; a failed read goes to ``on_error`` once, after them. The caller's thread
        is both the reader and the dispatcher, so the receive queue and its drop policy
        do not apply.
        """
        if not self._opened or self._stop.is_set() or self._callbacks is None:
            return
        on_message, on_error = self._callbacks
        try:
            received = self.endpoint.read_ready()
        except (OSError, ValueError) as exc:
            logger.warning("%s: read failed: %s", self.url, exc)
            self._stop.set()
            on_error(exc)
            return
        for message, seq in received:
            self.dispatch_seq = seq
            try:
                on_message(message, now)
            except Exception:
                logger.exception("%s: handling %s failed; carrying on", self.url, message.NAME)

    def send(self, message: Message) -> None:
        """Send one message now, on the calling thread. A :class:`Stop` does not wait
        for any other message's write (see the module docstring, Writes).

        Raises:
            TransportError: not open, or the write failed (device gone, bus off).
        """
        stop = isinstance(message, Stop)
        with self._stop_lock if stop else self._write_lock:
            if not self._opened:
                raise TransportError(f"{self.url} is not open")
            try:
                self._write(message)
            except (OSError, ValueError) as exc:
                raise TransportError(f"write to {self.url} failed: {exc}") from exc
            if stop:
                self._tx_stops += 1  # under _stop_lock
            else:
                self._tx_frames += 1  # under _write_lock

    @property
    def tx_frames(self) -> int:
        """Frames written on this transport (STOPs included)."""
        return self._tx_frames + self._tx_stops

    def send_raw(self, msg_id: int, payload: bytes, *, bad_crc: bool = False) -> None:
        """Send a frame with this message id and these payload bytes, unchecked, now, on
        the calling thread: for a conformance host that must put frames on the wire that
        the codec refuses (an unknown id, a wrong length, a field outside its range).

        Args:
            msg_id: the message id, 0..127 (CAN: identifier ``msg_id << 4 | node``).
            bad_crc: serial only: invert the frame's CRC.

        Raw frames are not written to the traffic log.

        Raises:
            TransportError: not open, the write failed, or this medium cannot send such a
                frame (a bad CRC on CAN: the bus computes its own).
        """
        with self._write_lock:
            if not self._opened:
                raise TransportError(f"{self.url} is not open")
            try:
                self.endpoint.write_raw(msg_id, payload, bad_crc=bad_crc)
            except (OSError, ValueError) as exc:
                raise TransportError(f"write to {self.url} failed: {exc}") from exc
            self._tx_frames += 1

    def close(self) -> None:
        """Stop the reader and the dispatcher and release the device (idempotent; safe
        from any thread, the dispatcher's own included). Messages not yet dispatched are
        discarded."""
        self._stop.set()
        for thread in (self._thread, self._dispatcher):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=5.0)
                if thread.is_alive():
                    logger.error("%s: thread %s did not stop within 5 s", self.url, thread.name)
        self._thread = self._dispatcher = None
        with self._stop_lock, self._write_lock:
            if self._opened:
                self._opened = False
                self.endpoint.close()

    def __enter__(self) -> Transport:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- the two threads ------------------------------------------------------------------
    def _reader(self) -> None:
        """Reader thread: read and decode (``_read``), stamp, queue. No callbacks."""
        beat = stall.watch(f"{self.kind}-rx")
        try:
            self._read_loop(beat)
        finally:
            stall.forget(beat)

    def _read_loop(self, beat: stall.Beat) -> None:
        while not self._stop.is_set():
            beat.tick()
            try:
                received = self.endpoint.read_numbered(_POLL_S)
            except (OSError, ValueError) as exc:
                if not self._stop.is_set():
                    logger.warning("%s: read failed: %s", self.url, exc)
                    self._put(exc)
                return
            if received:
                now = time.monotonic()
                for message, seq in received:
                    if isinstance(message, SAMPLE_MESSAGES):
                        try:
                            self._rx.put_nowait((message, now, seq))
                        except queue.Full:
                            self._overflow(message)
                    else:
                        self._put((message, now, seq))

    def _put(self, item: tuple[Message, float, int | None] | Exception) -> None:
        """Queue ``item``, waiting for room as long as the transport is open."""
        while not self._stop.is_set():
            try:
                self._rx.put(item, timeout=_POLL_S)
                return
            except queue.Full:
                continue

    def _overflow(self, message: Message) -> None:
        self.rx_overflow += 1
        level = (
            logging.WARNING
            if self.rx_overflow == 1 or self.rx_overflow % 100 == 0
            else logging.DEBUG
        )
        logger.log(
            level,
            "%s: receive queue full (%d); %s dropped (%d sample(s) dropped so far)",
            self.url,
            self.rx_queue_depth,
            message.NAME,
            self.rx_overflow,
        )

    def _dispatch(self, on_message: OnMessage, on_error: OnError) -> None:
        """Dispatcher thread: hand queued messages to ``on_message`` in order; report the
        reader's failure through ``on_error`` once, after them."""
        beat = stall.watch(f"{self.kind}-dispatch")
        try:
            self._dispatch_loop(on_message, on_error, beat)
        finally:
            stall.forget(beat)

    def _dispatch_loop(self, on_message: OnMessage, on_error: OnError, beat: stall.Beat) -> None:
        rx = self._rx
        while True:
            beat.tick()
            try:
                item = rx.get(timeout=_POLL_S)
            except queue.Empty:
                if self._stop.is_set():
                    return
                continue
            if self._stop.is_set():
                return
            if isinstance(item, Exception):
                on_error(item)
                return
            message, arrived, self.dispatch_seq = item
            try:
                on_message(message, arrived)
            except Exception:
                logger.exception("%s: handling %s failed; carrying on", self.url, item[0].NAME)


def open_transport(url: str, **options: Any) -> Transport:
    """Build (not open) the transport for ``url`` (see the module docstring).

    Raises:
        TransportUrlError: the URL names no known transport, or is malformed (permanent:
            retrying cannot help; docs/bridge.md, Transports).
    """
    with url_errors(url):
        kind = medium_of(url)
    module_name, class_name = TRANSPORTS[kind]
    cls = getattr(importlib.import_module(module_name), class_name)
    transport: Transport = cls(url, **options)
    return transport
