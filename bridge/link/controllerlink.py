"""The host side of the controller protocol in real time: :class:`ControllerLink`, a thin
threaded shell around the pure :class:`~bridge.link.linkcore.LinkCore` (docs/protocol.md).

Every rule of the protocol's host side is the core's and documented there. This module
adds what only real time has: the transport, the threads, the clock
(``self._clock.now()``) and the callbacks.

Given a lockstep clock (:class:`~firmware_proto.linkio.clock.LockstepClock`: a whole
mission in virtual time, docs/sim.md) the same shell starts no thread: once per tick of
the clock it reads the transport (:meth:`~bridge.link.transport.Transport.pump`), runs
the timer's work and writes what the core queued, in that order, on the clock's thread.

:class:`ControllerLink` is what the bridge node drives, through the callbacks its
constructor takes; it knows nothing of ROS.

Threads: the transport's dispatcher thread calls in with messages (its reader thread
only reads and decodes, :mod:`bridge.link.transport`); one timer thread runs the core's
periodic work every 5 ms and (re)connects; one writer thread (``link-tx``) writes every
frame but STOP, in the order the core queued them; any thread may call the API. The
core is guarded by one lock, and no write to the transport ever happens with it held: a
write stuck in the OS holds up neither the API, nor the dispatcher, nor a STOP. STOP is
written by the thread that decided it (the caller of
:meth:`ControllerLink.emergency_stop`, the timer for repeats, the writer for the STOP
that follows a CLEAR_STOP it was writing) through the transport's STOP path, which waits
for no other write. Callbacks run outside the lock, one at a time, in the order their
events happened.
"""

from __future__ import annotations

import logging
import random
import threading
from collections.abc import Callable
from types import TracebackType

from bridge.errors import TransportError
from bridge.link.linkcore import LinkCore, Outgoing
from bridge.link.linktypes import (
    LinkConfig,
    LinkDiagnostics,
    LinkState,
    MediumStats,
    StatusEvent,
    StepRequest,
)
from bridge.link.transport import Transport, open_transport
from firmware_proto.linkio.clock import WALL, Clock, is_lockstep
from firmware_proto.runtime import stall
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Command,
    Stop,
    StopSource,
)

__all__ = ["ControllerLink", "LinkConfig", "LinkDiagnostics", "LinkState", "StepRequest"]

logger = logging.getLogger(__name__)

OnStatus = Callable[[str], None]
OnTelemetry = Callable[[Message, float], None]
OnState = Callable[["LinkState"], None]

TIMER_PERIOD_S = 0.005
"""Period of the timer thread's periodic work, s (at most: a request or failure wakes it early)."""


class ControllerLink:
    """Host end of the controller protocol in real time; see the module docstring."""

    def __init__(
        self,
        config: LinkConfig,
        *,
        on_status: OnStatus,
        on_telemetry: OnTelemetry | None = None,
        on_state: OnState | None = None,
        transport_factory: Callable[[str], Transport] = open_transport,
        protocol_version: int = PROTOCOL_VERSION,
        schema_hash: int = SCHEMA_HASH,
        clock: Clock = WALL,
        first_request_id: int | None = None,
    ) -> None:
        """Args:
        on_status: every ``/command_status`` string, in order, one at a time (possibly
            after the call that caused it returned, by a link thread).
        on_telemetry: every message from the controller with its arrival time
            (``self._clock.now()``), on the transport's dispatcher thread; sensor samples
            only in a session (:mod:`bridge.link.linkcore`).
        on_state: the new :class:`LinkState` at every change, in order, outside the
            lock, on the thread that made the change or on one of the link's threads
            still delivering earlier events; it must not block.
        transport_factory: builds the (unopened) transport for a URL.
        protocol_version, schema_hash: what this host speaks (tests change them).
        clock: what tells every time the link uses; a lockstep clock runs the link on
            its ticks, without threads (module docstring).
        first_request_id: the id of the first STOP or CLEAR_STOP, 1..65535; ``None``
            (the default, and what a bridge must use) draws it at random. A replay
            gives the recorded one, to send the recorded bytes again.

        Raises:
            TransportUrlError: ``config.url`` is malformed (checked here, not opened).
        """
        transport_factory(config.url)
        # A bridge started again must not repeat the last request of the one before.
        self._core = LinkCore(
            config,
            protocol_version=protocol_version,
            schema_hash=schema_hash,
            first_request_id=(
                random.SystemRandom().randrange(1, 0x10000)
                if first_request_id is None
                else first_request_id
            ),
        )
        self._on_status = on_status
        self._on_telemetry = on_telemetry
        self._on_state = on_state
        self._factory = transport_factory
        self._clock = clock
        self._lockstep = is_lockstep(clock)
        self._started = False
        self.protocol_version = protocol_version
        self.schema_hash = schema_hash
        self._lock = threading.RLock()
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._writer: threading.Thread | None = None
        self._tx_wake = threading.Event()
        self._transport: Transport | None = None
        self._delivering = False  # a thread is in _flush handing out the core's events
        self._failure: tuple[Transport, Exception] | None = None
        self._opening: Transport | None = None  # being opened by _connect
        self.last_stop_written: float | None = None
        """``self._clock.now()`` when the last STOP frame was handed whole to the OS."""

    # -- lifecycle ----------------------------------------------------------------------
    @property
    def config(self) -> LinkConfig:
        """The link parameters in force."""
        return self._core.config

    def reconfigure(self, config: LinkConfig) -> None:
        """Use ``config`` from now on (timeouts, retries, heartbeat, backoff, automatic
        clear): each is read when next needed. The URL cannot change while running.

        Raises:
            ValueError: ``config.url`` is not this link's.
        """
        if config.url != self._core.config.url:
            raise ValueError(f"the link's URL cannot change while it runs ({self.config.url})")
        with self._lock:
            self._core.config = config

    def start(self) -> None:
        """Start the timer thread, which connects (and reconnects) on its own, and the
        writer thread (in lockstep: run their work on every tick of the clock)."""
        if self._thread is not None or self._started:
            raise RuntimeError("link already started")
        self._started = True
        if self._lockstep:
            self._clock.add(self._lockstep_tick)  # type: ignore[attr-defined]
            return
        self._writer = threading.Thread(target=self._write_queued, name="link-tx", daemon=True)
        self._writer.start()
        self._thread = threading.Thread(target=self._timer, name="link-timer", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop every thread and close the transport (idempotent)."""
        if self._lockstep:
            self._clock.remove(self._lockstep_tick)  # type: ignore[attr-defined]
        self._stopping.set()
        self._wake.set()
        self._tx_wake.set()
        for thread in (self._thread, self._writer):
            if thread is not None and thread is not threading.current_thread():
                # A write stuck in the OS ends with the transport's write timeout.
                thread.join(timeout=5.0)
                if thread.is_alive():
                    logger.error("link thread %s did not stop within 5 s", thread.name)
        self._thread = self._writer = None
        with self._lock:
            transport, self._transport = self._transport, None
            while self._core.take_write() is not None:
                pass
        if transport is not None:
            transport.close()

    def __enter__(self) -> ControllerLink:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- properties -----------------------------------------------------------------------
    @property
    def state(self) -> LinkState:
        """The link state."""
        return self._core.state

    @property
    def ready(self) -> bool:
        """Handshake done with a matching controller, link alive."""
        return self._core.ready

    @property
    def reboots(self) -> int:
        """Reboots of the controller seen so far (:attr:`LinkCore.reboots`), counting the
        frame being delivered to the telemetry callback."""
        return self._core.reboots

    @property
    def stop_latched(self) -> bool:
        """See :attr:`LinkCore.stop_latched`."""
        return self._core.stop_latched

    # -- API ------------------------------------------------------------------------------
    def submit_step(self, step: StepRequest) -> None:
        """Queue a validated step (:meth:`LinkCore.submit_step`); its fate: ``on_status``."""
        if step.command == Command.STOP:
            self.emergency_stop(StopSource.PLAN_STEP)
            return
        with self._lock:
            self._core.submit_step(step, self._clock.now())
            self._wake_writer()
            transport = self._transport
        self._flush()
        if self._lockstep and transport is not None:
            self._write_now(transport)

    def emergency_stop(self, source: int = StopSource.OPERATOR) -> int:
        """Send STOP now, on this thread, ahead of anything queued (repeated until
        acknowledged), and purge every pending step; returns the stop id. Works in any
        link state (:meth:`LinkCore.emergency_stop`)."""
        with self._lock:
            stop_id = self._core.emergency_stop(source, self._clock.now())
            stops, transport = self._core.take_stops(), self._transport
        if transport is not None:
            for stop in stops:
                self._write_first_stop(transport, stop)
        self._flush()
        return stop_id

    def _write_first_stop(self, transport: Transport, stop: Stop) -> None:
        """Write the first copy of an emergency stop the core claimed."""
        try:
            transport.send(stop)
        except TransportError as exc:
            with self._lock:
                self._core.stop_written(stop.stop_id, self._clock.now(), False)
            self._report_failure(transport, exc)
            return
        written = self._clock.now()
        self.last_stop_written = written
        with self._lock:
            self._core.stop_written(stop.stop_id, written, True)

    def clear_stop(self) -> int:
        """Ask the controller to release its latch (:meth:`LinkCore.clear_stop`); the request id."""
        with self._lock:
            clear_id = self._core.clear_stop(self._clock.now())
        self._wake.set()
        return clear_id

    # -- lockstep --------------------------------------------------------------------------
    def _lockstep_tick(self) -> None:
        """One tick of a lockstep clock, in the module docstring's order."""
        if self._stopping.is_set():
            return
        transport = self._transport
        if transport is not None:
            transport.pump(self._clock.now())
        if self._failure is not None:
            self._handle_failure()
        now = self._clock.now()
        with self._lock:
            connect = self._transport is None and self._core.connect_due(now)
        if connect:
            self._connect()
            return
        transport = self._transport
        if transport is None:
            return
        with self._lock:
            self._core.tick(now)
            stops = self._core.take_stops()
        self._send_all(transport, stops)
        self._flush()
        self._write_now(transport)

    def _write_now(self, transport: Transport) -> None:
        """Lockstep: write every frame the core queued, in order, as the writer thread would."""
        while not self._stopping.is_set():
            with self._lock:
                entry = self._core.take_write() if self._transport is transport else None
            if entry is None:
                break
            sent = self._send(transport, entry.msg)
            with self._lock:
                self._core.written(entry, self._clock.now(), sent)
                stops = self._core.take_stops()
            self._send_all(transport, stops)
        self._flush()

    # -- the timer thread --------------------------------------------------------------------
    def _timer(self) -> None:
        beat = stall.watch("link-timer")
        try:
            self._timer_loop(beat)
        finally:
            stall.forget(beat)

    def _timer_loop(self, beat: stall.Beat) -> None:
        while not self._stopping.is_set():
            beat.tick()
            if self._failure is not None:
                self._handle_failure()
            now = self._clock.now()
            with self._lock:
                connect = self._transport is None and self._core.connect_due(now)
            if connect:
                self._connect()
            else:
                with self._lock:
                    transport = self._transport
                    stops: list[Stop] = []
                    if transport is not None:
                        self._core.tick(now)
                        stops = self._core.take_stops()
                        self._wake_writer()
                if transport is not None:
                    self._send_all(transport, stops)
                    self._flush()
            self._wake.wait(TIMER_PERIOD_S)
            self._wake.clear()

    def _connect(self) -> None:
        try:
            transport = self._factory(self.config.url)
            opening = transport
            with self._lock:
                # A failure reported while open() still runs is kept: see _report_failure.
                self._opening = opening

            def on_error(exc: Exception) -> None:
                self._report_failure(opening, exc)

            if self._lockstep:
                transport.open(self._on_message, on_error, threads=False)
            else:
                transport.open(self._on_message, on_error)
        except TransportError as exc:
            with self._lock:
                self._opening = None
                self._core.connect_failed(self._clock.now(), str(exc))
            return
        with self._lock:
            self._opening = None
            stopping = self._stopping.is_set()
            if not stopping:
                self._transport = transport
                self._core.on_connected(self._clock.now())
        if stopping:
            transport.close()  # outside the lock: it joins the dispatcher, which may want it
            return
        self._flush()

    def _report_failure(self, transport: Transport, exc: Exception) -> None:
        """Any thread: the transport failed. The timer thread handles it (it may have to
        join the reader thread, which must never happen with the state lock held)."""
        with self._lock:
            current = self._transport is transport or self._opening is transport
            if current and self._failure is None:
                self._failure = (transport, exc)
        self._wake.set()

    def _handle_failure(self) -> None:
        """Timer thread: close the failed transport; the core schedules the reconnect."""
        with self._lock:
            failure, self._failure = self._failure, None
            if failure is None or self._transport is not failure[0]:
                return
            transport, exc = failure
            self._transport = None
            self._core.failed(self._clock.now(), str(exc))
        transport.close()
        self._flush()

    # -- the writer thread --------------------------------------------------------------------
    def _wake_writer(self) -> None:
        """Wake the writer if the core queued frames (lock held)."""
        if self._core.pending_writes:
            self._tx_wake.set()

    def _write_queued(self) -> None:
        """Writer thread: write the core's queued frames in order, outside the lock."""
        beat = stall.watch("link-tx")
        try:
            self._write_loop(beat)
        finally:
            stall.forget(beat)

    def _write_loop(self, beat: stall.Beat) -> None:
        while not self._stopping.is_set():
            beat.tick()
            self._tx_wake.wait(0.05)
            self._tx_wake.clear()
            while not self._stopping.is_set():
                beat.tick()
                with self._lock:
                    transport = self._transport
                    entry: Outgoing | None = None
                    if transport is not None:
                        entry = self._core.take_write()
                if entry is None or transport is None:
                    break
                sent = self._send(transport, entry.msg)
                with self._lock:
                    self._core.written(entry, self._clock.now(), sent)
                    stops = self._core.take_stops()
                self._send_all(transport, stops)

    def _send_all(self, transport: Transport, stops: list[Stop]) -> None:
        for stop in stops:
            self._send(transport, stop)

    def _send(self, transport: Transport, msg: Message) -> bool:
        try:
            transport.send(msg)
        except TransportError as exc:
            self._report_failure(transport, exc)
            return False
        return True

    # -- receive, on the transport's dispatcher thread ---------------------------------------
    def _on_message(self, msg: Message, arrived: float) -> None:
        with self._lock:
            transport = self._transport
            seq = transport.dispatch_seq if transport is not None else None
            forward = self._core.on_frame(msg, arrived, rx_seq=seq)
            self._wake_writer()
        self._flush()
        if forward and self._on_telemetry is not None:
            self._on_telemetry(msg, arrived)

    # -- callbacks ------------------------------------------------------------------------------
    def _flush(self) -> None:
        """Deliver the statuses and state changes the core decided, in order.

        One thread delivers at a time, outside the lock: a thread that finds another
        delivering leaves its (later) items to it, so statuses are never interleaved."""
        with self._lock:
            if self._delivering:
                return
            self._delivering = True
        try:
            while True:
                with self._lock:
                    out = self._core.take_events()
                    if not out:
                        self._delivering = False
                        return
                for item in out:
                    try:
                        if isinstance(item, StatusEvent):
                            self._on_status(item.text)
                        elif self._on_state is not None:
                            self._on_state(item)
                    except Exception:
                        logger.exception("link callback failed for %r", item)
        except BaseException:
            with self._lock:
                self._delivering = False
            raise

    # -- diagnostics ---------------------------------------------------------------------------
    def diagnostics(self) -> LinkDiagnostics:
        """A consistent snapshot for ``/diagnostics``."""
        with self._lock:
            transport = self._transport
            medium = MediumStats()
            if transport is not None:
                counters = transport.counters
                medium = MediumStats(
                    connected=True,
                    rx_frames=counters.frames,
                    tx_frames=transport.tx_frames,
                    crc_errors=counters.crc,
                    resyncs=counters.framing + counters.oversize,
                    rx_dropped=counters.rejected,
                    rx_lost=counters.lost,
                    rx_overflow=transport.rx_overflow,
                    medium_state=transport.medium_state,
                    medium_errors=transport.medium_errors,
                )
            monitor = stall.current_monitor()
            return self._core.diagnostics(
                self._clock.now(),
                medium,
                stalls=len(monitor.records) if monitor is not None else 0,
                stall_max_ms=monitor.longest_ms if monitor is not None else 0.0,
            )
