"""The host side of the controller protocol: handshake, two send lanes, acknowledgements,
heartbeats, link supervision and reconnects (docs/protocol.md).

:class:`ControllerLink` is what the bridge node drives; it knows nothing of ROS. It
reports every step's fate as a ``/command_status`` string through ``on_status``, hands
telemetry to ``on_telemetry`` and tells ``on_state`` of every change of
:class:`LinkState` (the node publishes ``/diagnostics`` at once on it).

**STOP lane.** :meth:`ControllerLink.emergency_stop` writes STOP on the calling thread at
once, ahead of anything queued, then repeats it every ``stop_repeat_s`` until STOP_ACK
with its id. The operator's intent is remembered: if the controller reboots or the link
comes back, STOP is sent again right after the handshake. Only :meth:`clear_stop`
(CLEAR_STOP, repeated until CLEAR_ACK) releases it.

**Latch** (docs/protocol.md, "Latch and faults"). The controller's HEARTBEAT says what
holds its latch (``latch_stop``, ``latch_watchdog``, ``latch_fault``) and which fault
conditions are active (``fault_bits``). With ``auto_clear_watchdog`` the link sends
CLEAR_STOP itself when the watchdog alone holds the latch, its condition is gone, the
session is ours and no emergency stop is requested: a link outage does not leave the
rover stuck. An automatic clear never outlives a change of the latch's causes: answered
FAULT_PERSISTS, or a HEARTBEAT showing ``latch_stop`` or ``latch_fault``, ends it, and
only the operator can then clear. An operator's clear answered FAULT_PERSISTS is kept
and sent again (a new request id, at most once per controller heartbeat) once a
HEARTBEAT shows no stopping fault condition, until it is answered, or an emergency stop
or a reboot ends it.

**MOTION lane.** Steps go out in order, one frame at a time: a MOTION is retransmitted
after ``ack_timeout_s`` without ACK, at most ``motion_retries`` times, and the next is
sent only after its ACK, so the controller can never receive them out of order. The
controller deduplicates retransmissions, so no step runs twice. At most
``controller_queue`` steps are outstanding in the controller. Retries exhausted:
``fault:no_ack`` and the link is declared lost.

**Supervision.** HELLO is repeated until IDENT; a protocol or schema-hash mismatch
refuses every step (``rejected:schema_mismatch``). HOST_HEARTBEAT every
``heartbeat_s``; ``link_lost_beats`` controller heartbeats missed -> ``fault:link_lost``,
by the timer or, when this process itself was held up, by the first heartbeat that
arrives after a longer gap (the controller's watchdog has stopped the rover meanwhile).
Sensor samples (ENCODERS, WHEEL_SPEEDS, IMU, POSE) reach ``on_telemetry`` only while
the link is ready, that is in a session whose IDENT told the boot nonce: a conforming
controller sends none before a HELLO, so the first count of a new boot can never be
taken for motion of the old one (counted in ``samples_outside_session``).
A changed boot nonce -> ``fault:controller_reboot``. A transport error -> reconnect with
exponential backoff, which only a completed handshake resets. In every one of these
cases every step not yet settled (in the controller, in flight, waiting in the lane) is
dropped and gets its own fate, oldest first, each counted in ``steps_aborted``:
``aborted:link_lost``, ``aborted:controller_reboot`` or ``aborted:schema_mismatch``;
then one ``fault:<reason>`` reports the link event itself. No stale motion is ever replayed.

Threads: the transport's dispatcher thread calls in with messages (its reader thread
only reads and decodes, :mod:`bridge.transport`); one timer thread runs the periodic
work; one writer thread writes every frame but STOP, in the order they were queued; any
thread may call the API. State is guarded by one lock, and no write to the transport
ever happens with it held: a write stuck in the OS (a full buffer, a stalled USB-serial
adapter) holds up neither the API, nor the dispatcher, nor a STOP. STOP is written by
the thread that decided it (the caller of :meth:`ControllerLink.emergency_stop`, the
timer for repeats) through the transport's STOP path, which waits for no other write;
a MOTION not yet written when its step is dropped (a STOP, a lost link, a reboot) is
dropped with it, and its ACK timeout runs from when it was written.
Callbacks run outside the lock, one at a time, in the order their events happened.
"""

from __future__ import annotations

import enum
import logging
import math
import statistics
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from types import TracebackType

from bridge.errors import TransportError
from bridge.rosport.contract import (
    ACCEPTED,
    CLEARED,
    COMPLETED,
    READY,
    STOPPED,
    aborted,
    fault,
    rejected,
)
from bridge.transport import SAMPLE_MESSAGES, Transport, open_transport
from firmware_proto.faults import STOPPING_FAULTS, fault_bit
from firmware_proto.gapstats import GapStats
from firmware_proto.message import Message
from firmware_proto.messages import (
    ACK_TIMEOUT_MS,
    CONTROLLER_HEARTBEAT_PERIOD_MS,
    HOST_HEARTBEAT_PERIOD_MS,
    LINK_LOST_HEARTBEATS,
    MOTION_QUEUE_DEPTH,
    MOTION_RETRIES,
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    STOP_REPEAT_MS,
    AbortReason,
    Ack,
    AckField,
    AckResult,
    ClearAck,
    ClearResult,
    ClearStop,
    Command,
    ControllerState,
    Fault,
    FaultCode,
    Heartbeat,
    Hello,
    HostHeartbeat,
    Ident,
    Motion,
    Progress,
    Status,
    StepState,
    Stop,
    StopAck,
    Stopped,
    StopSource,
)
from firmware_proto.runtime import stall

__all__ = ["ControllerLink", "LinkConfig", "LinkDiagnostics", "LinkState", "StepRequest"]

logger = logging.getLogger(__name__)

OnStatus = Callable[[str], None]
OnTelemetry = Callable[[Message, float], None]
OnState = Callable[["LinkState"], None]

_ACK_REASONS = {
    AckResult.OUT_OF_RANGE: "out_of_range",
    AckResult.QUEUE_FULL: "queue_full",
    AckResult.STOP_LATCHED: "stop_latched",
    AckResult.NOT_READY: "not_ready",
    AckResult.FAULT_ACTIVE: "fault_active",
}


class LinkState(enum.Enum):
    """Where the link to the controller stands."""

    DISCONNECTED = "disconnected"
    HANDSHAKE = "handshake"
    READY = "ready"
    MISMATCH = "mismatch"
    LOST = "lost"


@dataclass(frozen=True)
class LinkConfig:
    """Link parameters; defaults are the protocol's (docs/protocol.md, Timing).

    Attributes:
        url: transport URL (see :mod:`bridge.transport`).
        ack_timeout_s: wait for ACK before retransmitting a MOTION, s.
        motion_retries: retransmissions of one MOTION before ``fault:no_ack``.
        stop_repeat_s: STOP and CLEAR_STOP are repeated this often until acknowledged, s.
        heartbeat_s: HOST_HEARTBEAT period, s (also the HELLO repeat period).
        controller_heartbeat_s: the controller's heartbeat period, s.
        link_lost_beats: controller heartbeats missed before the link is lost.
        reconnect_min_s, reconnect_max_s: reconnect backoff bounds, s (doubling with
            every failed open or failure before a completed handshake).
        controller_queue: steps allowed outstanding in the controller.
        lane_limit: steps the bridge holds waiting to be sent; more are rejected.
        auto_clear_watchdog: clear a latch that the controller's watchdog alone holds
            (HEARTBEAT ``latch_watchdog`` only) once the watchdog's condition is gone;
            never one with an emergency stop or a fault in it.
    """

    url: str
    ack_timeout_s: float = ACK_TIMEOUT_MS / 1000.0
    motion_retries: int = MOTION_RETRIES
    stop_repeat_s: float = STOP_REPEAT_MS / 1000.0
    heartbeat_s: float = HOST_HEARTBEAT_PERIOD_MS / 1000.0
    controller_heartbeat_s: float = CONTROLLER_HEARTBEAT_PERIOD_MS / 1000.0
    link_lost_beats: int = LINK_LOST_HEARTBEATS
    reconnect_min_s: float = 0.1
    reconnect_max_s: float = 2.0
    controller_queue: int = MOTION_QUEUE_DEPTH
    lane_limit: int = 64
    auto_clear_watchdog: bool = True


@dataclass(frozen=True)
class StepRequest:
    """A validated motion step: command code, speed units, distance units."""

    command: int
    speed: int
    distance: int


@dataclass
class _Step:
    request: StepRequest
    seq: int = -1
    sends: int = 0
    first_sent: float = 0.0
    last_sent: float = 0.0
    unwritten: int = 0
    """Copies queued for the writer and not yet written: the ACK timeout runs from
    when a copy is on the wire, not from when it was queued."""


@dataclass
class _Pending:
    stop_id: int
    first_sent: float = 0.0
    last_sent: float = 0.0
    sends: int = 0


@dataclass(frozen=True)
class LinkDiagnostics:
    """Everything ``/diagnostics`` reports about the link and the controller."""

    state: str
    url: str
    connected: bool
    missed_beats: int
    """Whole controller heartbeat periods since the last heartbeat (0 while fresh)."""
    lost_after_beats: int | None
    """Missed heartbeat periods when the link was last declared lost for silence."""
    heartbeat_losses: int
    """Times the link was declared lost because the controller's heartbeats stopped."""
    reconnects: int
    reboots: int
    rtt_ms: float | None
    rtt_median_ms: float | None
    heartbeat_age_s: float | None
    rx_frames: int
    tx_frames: int
    crc_errors: int
    resyncs: int
    rx_dropped: int
    rx_overflow: int
    """Sensor samples dropped because the receive queue was full (bridge.transport)."""
    lost_frames: int
    retries: int
    no_ack_faults: int
    stop_repeats: int
    watchdog_trips: int
    last_stop_latency_ms: float | None
    last_stopping_distance_mm: int | None
    controller_state: str
    stop_latched: bool
    estop_requested: bool
    faults: tuple[str, ...]
    controller_queue: int
    boot_nonce: int | None
    firmware: str
    schema_hash: str
    host_schema_hash: str
    steps_sent: int
    steps_completed: int
    steps_rejected: int
    steps_aborted: int
    rejected: tuple[tuple[str, int], ...]
    """Steps refused by the link or the controller, by reason (sorted by reason)."""
    last_error: str
    medium_state: str = "ok"
    medium_errors: int = 0
    latch: tuple[str, ...] = ()
    """What holds the controller's latch (``stop``, ``watchdog``, ``fault``), from its
    last HEARTBEAT; empty when it is not latched."""
    latch_fault: str = ""
    """The last stopping fault other than WATCHDOG the controller raised (what
    ``latch_fault`` most likely stands for), ``""`` if none since the link started."""
    heartbeat_rx_gap_max_ms: float | None = None
    """Longest gap between two controller HEARTBEATs received on one connection, ms
    (their period is 100 ms; a gap longer than the link-lost limit loses the link)."""
    heartbeat_rx_gap_p99_ms: float | None = None
    """99th percentile of the last 1,000 such gaps, ms."""
    heartbeat_tx_gap_max_ms: float | None = None
    """Longest gap between two HOST_HEARTBEATs written, ms (their period is
    ``heartbeat_s``; the controller's watchdog stops the rover after 250 ms without a
    frame)."""
    heartbeat_tx_gap_p99_ms: float | None = None
    """99th percentile of the last 1,000 such gaps, ms."""
    samples_outside_session: int = 0
    """Sensor samples received while the link was not ready, ignored (a conforming
    controller sends none before a HELLO)."""
    stalls: int = 0
    """Stalls of this process or its loops over the stall threshold (docs/realtime.md)."""
    stall_max_ms: float = 0.0
    """The longest of them, ms."""


@dataclass
class _Counters:
    reconnects: int = 0
    reboots: int = 0
    retries: int = 0
    no_ack_faults: int = 0
    stop_repeats: int = 0
    watchdog_trips: int = 0
    steps_sent: int = 0
    steps_completed: int = 0
    steps_rejected: int = 0
    steps_aborted: int = 0
    heartbeat_losses: int = 0
    lost_after_beats: int | None = None
    samples_outside_session: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    rtts: deque[float] = field(default_factory=lambda: deque(maxlen=100))


class ControllerLink:
    """Host end of the controller protocol; see the module docstring."""

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
    ) -> None:
        """Args:
        config: link parameters.
        on_status: every ``/command_status`` string, in order, one at a time (a status
            may be handed out by a link thread still delivering earlier ones, after the
            call that caused it returned).
        on_telemetry: every message from the controller with its arrival time
            (``time.monotonic()``), on the transport's dispatcher thread.
        on_state: the new :class:`LinkState` at every change, in order, outside the
            lock, on the thread that made the change or on one of the link's threads
            still delivering earlier events; it must not block.
        transport_factory: builds the (unopened) transport for a URL.
        protocol_version, schema_hash: what this host speaks (tests change them).

        Raises:
            TransportUrlError: ``config.url`` is malformed; found here, once, because no
                reconnect could fix it (a transport is built to check it, not opened).
        """
        transport_factory(config.url)
        self.config = config
        self._on_status = on_status
        self._on_telemetry = on_telemetry
        self._on_state = on_state
        self._factory = transport_factory
        self.protocol_version = protocol_version
        self.schema_hash = schema_hash
        self._lock = threading.RLock()
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._writer: threading.Thread | None = None
        self._tx: deque[tuple[Transport, Message, _Step | None]] = deque()
        """Frames for the writer thread, in order (lock held to change it)."""
        self._tx_wake = threading.Event()
        self._transport: Transport | None = None
        self._state = LinkState.DISCONNECTED
        self._reconnect_at = 0.0
        self._backoff = config.reconnect_min_s
        self._seq = 0
        self._stop_counter = 0
        self._lane: deque[_Step] = deque()
        self._inflight: _Step | None = None
        self._in_controller: dict[int, _Step] = {}
        self._pending_stop: _Pending | None = None
        self._pending_clear: _Pending | None = None
        self._estop_requested = False
        self._estop_source: int = StopSource.OPERATOR
        self._boot_nonce: int | None = None
        self._ident: Ident | None = None
        self._last_hb_rx: float | None = None
        self._last_hello = 0.0
        self._last_hb_tx = 0.0
        self._heartbeat: Heartbeat | None = None
        self._faults: set[int] = set()
        """Fault conditions active in the controller (FAULT active 1..0, ``fault_bits``)."""
        self._last_stopping_fault: int | None = None
        self._clear_wanted = False  # a clear (operator's or automatic) not yet answered done
        self._clear_auto = False  # ... and it is the automatic one
        self._clear_persisted = False  # ... and was answered FAULT_PERSISTS (said once)
        self._hb_counter = 0
        self._last_stop_latency: float | None = None
        self._last_stopping_mm: int | None = None
        self._last_error = ""
        self._counters = _Counters()
        self._outbox: list[str | LinkState] = []
        self._delivering = False  # a thread is in _flush handing out the outbox
        self._failure: tuple[Transport, Exception] | None = None
        self._opening: Transport | None = None  # being opened by _connect
        self._ctrl_latched = False
        self._ctrl_state: int | None = None
        self._ended_seen = 0
        self._last_clear_request = -math.inf
        self._hello_sent = False  # a HELLO went out in the current handshake
        self.last_stop_written: float | None = None
        """``time.monotonic()`` when the last STOP frame was handed to the OS, whole."""
        self._hb_rx_gaps = GapStats(config.controller_heartbeat_s)
        self._hb_tx_gaps = GapStats(config.heartbeat_s)
        self._watchdog_counted = False
        """The watchdog latch episode now in force was counted in ``watchdog_trips``."""
        self._clear_in_write = False
        """The writer thread is writing a CLEAR_STOP now."""
        self._stop_after_clear: Stop | None = None
        """An emergency stop came while it was: this STOP goes out again after it."""
        self._lost_mark = 0
        """The transport's lost-frame count at the last frame of the current boot."""
        self._lost_forgiven = 0
        """Lost frames not counted: the frame counter restarting at a reboot."""

    # -- lifecycle ----------------------------------------------------------------------
    def reconfigure(self, config: LinkConfig) -> None:
        """Use ``config`` from now on (timeouts, retries, heartbeat, backoff, automatic
        clear): each is read when next needed. The URL cannot change while running.

        Raises:
            ValueError: ``config.url`` is not this link's.
        """
        if config.url != self.config.url:
            raise ValueError(f"the link's URL cannot change while it runs ({self.config.url})")
        self.config = config

    def start(self) -> None:
        """Start the timer thread, which connects (and reconnects) on its own, and the
        writer thread."""
        if self._thread is not None:
            raise RuntimeError("link already started")
        self._writer = threading.Thread(target=self._write_queued, name="link-tx", daemon=True)
        self._writer.start()
        self._thread = threading.Thread(target=self._timer, name="link-timer", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop every thread and close the transport (idempotent)."""
        self._stopping.set()
        self._wake.set()
        self._tx_wake.set()
        for thread in (self._thread, self._writer):
            if thread is not None and thread is not threading.current_thread():
                # The writer may be in a write stuck in the OS: that ends with the
                # transport's write timeout (serial 1 s, CAN 0.1 s).
                thread.join(timeout=5.0)
                if thread.is_alive():
                    logger.error("link thread %s did not stop within 5 s", thread.name)
        self._thread = self._writer = None
        with self._lock:
            transport, self._transport = self._transport, None
            self._tx.clear()
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
        return self._state

    @property
    def ready(self) -> bool:
        """Handshake done with a matching controller, link alive."""
        return self._state is LinkState.READY

    @property
    def stop_latched(self) -> bool:
        """An emergency stop is requested, or the controller's motion is latched (STOP or
        fault) as its last STOP_ACK, CLEAR_ACK or HEARTBEAT said."""
        return self._estop_requested or self._ctrl_latched

    # -- API: steps ------------------------------------------------------------------------
    def submit_step(self, step: StepRequest) -> None:
        """Queue a validated motion step. Its fate comes through ``on_status``:
        ``accepted`` then ``completed``, or ``rejected:<reason>``, ``aborted:<reason>``,
        ``fault:<reason>``. A STOP command is an emergency stop."""
        if step.command == Command.STOP:
            self.emergency_stop(StopSource.PLAN_STEP)
            return
        with self._lock:
            reason = self._refusal()
            if reason is None and len(self._lane) >= self.config.lane_limit:
                reason = "queue_full"
            if reason is not None:
                self._counters.steps_rejected += 1
                self._counters.rejected[reason] += 1
                self._emit(rejected(reason))
                logger.info("step %s rejected: %s", step, reason)
            else:
                self._lane.append(_Step(step))
                self._pump(time.monotonic())
        self._flush()

    def _refusal(self) -> str | None:
        if self._state is LinkState.MISMATCH:
            return "schema_mismatch"
        if self._state is not LinkState.READY:
            return "link_down"
        if self._ctrl_state == ControllerState.FAULT:
            return "fault_active"
        if self.stop_latched:
            return "stop_latched"
        return None

    # -- API: STOP lane --------------------------------------------------------------------
    def emergency_stop(self, source: int = StopSource.OPERATOR) -> int:
        """Send STOP now (repeated until acknowledged) and purge every pending step.

        Returns the stop id. Works in any link state: if the link is down the STOP goes
        out first thing after the next handshake.
        """
        now = time.monotonic()
        with self._lock:
            self._stop_counter = self._stop_counter % 0xFFFF + 1
            stop_id = self._stop_counter
            self._estop_requested = True
            self._estop_source = source
            self._pending_clear = None
            self._clear_wanted = False
            # A CLEAR_STOP queued before this STOP must never follow it onto the wire;
            # one being written now is answered by this STOP once more, after it.
            self._unqueue(ClearStop)
            if self._clear_in_write:
                self._stop_after_clear = Stop(stop_id, source)
            transport = (
                self._transport
                if self._state
                in (LinkState.READY, LinkState.LOST, LinkState.HANDSHAKE, LinkState.MISMATCH)
                else None
            )
            # The first copy is claimed here, under the lock, before it is written: the
            # timer thread must see it as sent (and repeat it only after stop_repeat_s),
            # not as never sent, or it writes a second copy while this one is on its way.
            self._pending_stop = _Pending(stop_id, now, now, 1 if transport is not None else 0)
        if transport is not None:
            self._send_stop(transport, stop_id, source)
        with self._lock:
            self._purge(aborted("stop"))
        self._flush()
        logger.info("emergency stop %d (source %s)", stop_id, StopSource(source).name)
        return stop_id

    def _send_stop(self, transport: Transport, stop_id: int, source: int) -> None:
        """Write the first copy of a STOP already claimed in ``_pending_stop``."""
        try:
            transport.send(Stop(stop_id, source))
        except TransportError as exc:
            with self._lock:
                if self._pending_stop is not None and self._pending_stop.stop_id == stop_id:
                    self._pending_stop.sends = 0  # not on the wire: the next copy is the first
            self._report_failure(transport, exc)
            return
        written = time.monotonic()
        self.last_stop_written = written
        with self._lock:
            if self._pending_stop is not None and self._pending_stop.stop_id == stop_id:
                # The repeat interval runs from when the copy left, not from the claim.
                self._pending_stop.last_sent = written

    def clear_stop(self) -> int:
        """Ask the controller to release its latch (CLEAR_STOP, repeated until CLEAR_ACK).
        Returns the request id; the answer comes as ``cleared`` or ``fault:<reason>``."""
        now = time.monotonic()
        with self._lock:
            self._stop_counter = self._stop_counter % 0xFFFF + 1
            clear_id = self._stop_counter
            self._estop_requested = False
            self._pending_stop = None
            self._pending_clear = _Pending(clear_id, now, 0.0, 0)
            self._last_clear_request = now
            self._clear_wanted, self._clear_auto = True, False
            self._clear_persisted = False
            self._wake.set()
        return clear_id

    # -- supervision, on the timer thread -----------------------------------------------------
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
            now = time.monotonic()
            if self._transport is None:
                if now >= self._reconnect_at:
                    self._connect()
            else:
                with self._lock:
                    transport, stops = self._transport, self._periodic(now)
                if transport is not None:
                    for stop in stops:
                        self._send(transport, stop)
                self._flush()
            self._wake.wait(0.005)
            self._wake.clear()

    def _write_queued(self) -> None:
        """Writer thread: write the queued frames in order, outside the lock. A frame
        queued for a connection that has since failed or closed is discarded."""
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
                    if not self._tx:
                        break
                    transport, msg, step = self._tx.popleft()
                    if transport is not self._transport:
                        continue
                    clearing = isinstance(msg, ClearStop)
                    self._clear_in_write = clearing
                sent = self._send(transport, msg)
                if clearing:
                    self._after_clear_written(transport)
                if sent and isinstance(msg, HostHeartbeat):
                    with self._lock:
                        self._hb_tx_gaps.event(time.monotonic())
                if step is not None:
                    with self._lock:
                        step.unwritten -= 1
                        if sent:
                            # The ACK timeout and the round trip run from here.
                            step.last_sent = time.monotonic()
                            if step.sends == 1:
                                step.first_sent = step.last_sent

    def _after_clear_written(self, transport: Transport) -> None:
        """A CLEAR_STOP is out. If an emergency stop was asked for while it was being
        written, its STOP may have gone out first (STOP waits for no other write): send
        it again, so the last word the controller hears is STOP (docs/protocol.md, "Latch
        and faults": no CLEAR_STOP may reach the wire after a later STOP)."""
        with self._lock:
            self._clear_in_write = False
            again, self._stop_after_clear = self._stop_after_clear, None
        if again is not None:
            self._send(transport, again)

    def _unqueue(self, kind: type[Message]) -> None:
        """Take every frame of ``kind`` not yet written out of the writer's queue (lock
        held)."""
        if any(isinstance(msg, kind) for _, msg, _ in self._tx):
            kept = [entry for entry in self._tx if not isinstance(entry[1], kind)]
            self._tx.clear()
            self._tx.extend(kept)

    def _unqueue_motions(self) -> None:
        """Take every MOTION not yet written out of the writer's queue (lock held): its
        step is being dropped, and a dropped step must never reach the controller."""
        self._unqueue(Motion)

    def _queue(self, msg: Message, step: _Step | None = None) -> None:
        """Queue a frame for the writer thread (lock held), with the step a MOTION
        carries; dropped if not connected."""
        if self._transport is not None:
            self._tx.append((self._transport, msg, step))
            self._tx_wake.set()
            if step is not None:
                step.unwritten += 1

    def _connect(self) -> None:
        try:
            transport = self._factory(self.config.url)
            opening = transport
            with self._lock:
                # A failure reported while open() is still running (the reader may fail
                # before open() returns) is kept, not ignored: see _report_failure.
                self._opening = opening
            transport.open(self._on_message, lambda exc: self._report_failure(opening, exc))
        except TransportError as exc:
            with self._lock:
                self._opening = None
                self._last_error = str(exc)
                self._reconnect_at = time.monotonic() + self._backoff
                logger.info("connect failed (%s); retry in %.1f s", exc, self._backoff)
                self._backoff = min(self.config.reconnect_max_s, self._backoff * 2)
            return
        with self._lock:
            self._opening = None
            stopping = self._stopping.is_set()
            if not stopping:
                self._transport = transport
                self._set_state(LinkState.HANDSHAKE)
                self._hello_sent = False
                self._last_hello = 0.0
                self._last_hb_rx = None
                self._hb_rx_gaps.restart()
                self._hb_tx_gaps.restart()
                self._lost_mark = self._lost_forgiven = 0  # a new transport counts anew
                logger.info("connected to %s; handshaking", self.config.url)
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
        """Timer thread: close the failed transport, report, schedule the reconnect."""
        with self._lock:
            failure, self._failure = self._failure, None
            if failure is None or self._transport is not failure[0]:
                return
            transport, exc = failure
            self._transport = None
            self._last_error = str(exc)
            self._counters.reconnects += 1
            self._set_state(LinkState.DISCONNECTED)
            self._heartbeat = None
            # The backoff is reset by a completed handshake only: a medium that opens and
            # fails again at once (a CAN bus going bus-off repeatedly, a flapping socket)
            # backs off like one that cannot be opened.
            self._reconnect_at = time.monotonic() + self._backoff
            self._drop_all(aborted("link_lost"))
            self._emit(fault("link_lost"))
            logger.warning(
                "link to %s failed: %s; reconnecting in %.1f s", self.config.url, exc, self._backoff
            )
            self._backoff = min(self.config.reconnect_max_s, self._backoff * 2)
        transport.close()
        self._flush()

    def _periodic(self, now: float) -> list[Message]:
        """The timer's work (lock held): queue HELLO, HOST_HEARTBEAT, CLEAR_STOP and
        MOTION for the writer; return the STOP copies due, for the caller to write once
        it has released the lock."""
        cfg = self.config
        if self._transport is None:
            return []
        out: list[Message] = []
        stops: list[Message] = []
        if (
            self._state in (LinkState.HANDSHAKE, LinkState.LOST)
            and now - self._last_hello >= cfg.heartbeat_s
        ):
            self._last_hello = now
            self._hello_sent = True
            out.append(Hello(self.protocol_version, self.schema_hash))
        if now - self._last_hb_tx >= cfg.heartbeat_s:
            self._last_hb_tx = now
            self._hb_counter = (self._hb_counter + 1) & 0xFFFF
            out.append(HostHeartbeat(self._hb_counter))
        stop = self._pending_stop
        if (
            stop is not None
            and self._state is not LinkState.DISCONNECTED
            and (stop.sends == 0 or now - stop.last_sent >= cfg.stop_repeat_s)
        ):
            if stop.sends:
                self._counters.stop_repeats += 1
            else:
                stop.first_sent = now  # requested while down: its latency runs from here
            stop.sends += 1
            stop.last_sent = now
            stops.append(Stop(stop.stop_id, self._estop_source))
        clear = self._pending_clear
        if (
            clear is not None
            and self._state in (LinkState.READY, LinkState.LOST)
            and (clear.sends == 0 or now - clear.last_sent >= cfg.stop_repeat_s)
        ):
            clear.sends += 1
            clear.last_sent = now
            out.insert(0, ClearStop(clear.stop_id))
        if self._state is LinkState.READY:
            lost_after = self._lost_after_s()
            if self._last_hb_rx is not None and now - self._last_hb_rx > lost_after:
                self._declare_silence(now - self._last_hb_rx)
        for msg in out:
            self._queue(msg)
        if self._state is LinkState.READY:
            self._pump(now)
        return stops

    def _send(self, transport: Transport, msg: Message) -> bool:
        try:
            transport.send(msg)
        except TransportError as exc:
            self._report_failure(transport, exc)
            return False
        return True

    def _pump(self, now: float) -> None:
        """Queue the lane's head, or its retransmission on ack timeout (lock held)."""
        step = self._inflight
        if step is not None:
            if step.unwritten or now - step.last_sent < self.config.ack_timeout_s:
                return
            if step.sends > self.config.motion_retries:
                self._inflight = None
                self._counters.no_ack_faults += 1
                # Steps already in the controller are older: their fates come first.
                older = list(self._in_controller.values())
                self._in_controller.clear()
                for _ in older:
                    self._counters.steps_aborted += 1
                    self._emit(aborted("link_lost"))
                self._counters.steps_aborted += 1
                self._emit(fault("no_ack"))
                self._lose(f"MOTION seq {step.seq} not acknowledged after {step.sends} tries")
                return
            self._counters.retries += 1
            step.sends += 1
            step.last_sent = now
            self._queue(self._motion(step), step)
        elif self._lane and len(self._in_controller) < self.config.controller_queue and self.ready:
            step = self._lane.popleft()
            self._seq = (self._seq + 1) & 0xFFFF
            step.seq = self._seq
            step.sends = 1
            step.first_sent = step.last_sent = now
            self._inflight = step
            self._counters.steps_sent += 1
            self._queue(self._motion(step), step)

    @staticmethod
    def _motion(step: _Step) -> Motion:
        r = step.request
        return Motion(step.seq, r.command, r.speed, r.distance)

    def _lost_after_s(self) -> float:
        """How long without a controller heartbeat the link is lost, s."""
        cfg = self.config
        return cfg.link_lost_beats * cfg.controller_heartbeat_s + cfg.controller_heartbeat_s / 2

    def _declare_silence(self, silence_s: float) -> None:
        """No controller heartbeat for ``silence_s``: the link is lost (lock held)."""
        self._counters.heartbeat_losses += 1
        self._counters.lost_after_beats = int(silence_s / self.config.controller_heartbeat_s)
        self._lose(
            f"no controller heartbeat for {silence_s:.2f} s "
            f"({self._counters.lost_after_beats} beats missed)"
        )

    def _mark_lost_frames(self) -> None:
        """A frame of the current boot: loss counted up to here is real loss."""
        transport = self._transport
        if transport is not None:
            self._lost_mark = transport.counters.lost

    def _lose(self, why: str) -> None:
        """The controller stopped answering: report, drop every step, re-handshake."""
        logger.warning("link lost: %s", why)
        self._last_error = why
        self._set_state(LinkState.LOST)
        self._hello_sent = False
        self._drop_all(aborted("link_lost"))
        self._emit(fault("link_lost"))

    def _set_state(self, state: LinkState) -> None:
        """Change the link state (lock held); ``on_state`` hears of it at the next flush."""
        if state is not self._state:
            self._state = state
            self._outbox.append(state)

    def _drop_all(self, status: str) -> None:
        """Drop every step not yet settled, oldest first (in the controller by sequence,
        then the one in flight, then the lane), each reported ``status`` and counted."""
        dropped = (
            list(self._in_controller.values())
            + ([self._inflight] if self._inflight else [])
            + list(self._lane)
        )
        self._in_controller.clear()
        self._inflight = None
        self._lane.clear()
        self._unqueue_motions()
        for _ in dropped:
            self._counters.steps_aborted += 1
            self._emit(status)
        if dropped:
            logger.info("%d step(s) dropped (%s); none will be replayed", len(dropped), status)

    def _purge(self, status: str) -> None:
        """Drop steps not yet in the controller (it reports its own ABORTED)."""
        pending = ([self._inflight] if self._inflight else []) + list(self._lane)
        self._inflight = None
        self._lane.clear()
        self._unqueue_motions()
        for _ in pending:
            self._counters.steps_aborted += 1
            self._emit(status)

    # -- receive, on the transport's dispatcher thread ---------------------------------------
    def _on_message(self, msg: Message, arrived: float) -> None:
        with self._lock:
            self._dispatch(msg, arrived)
            forward = self._state is LinkState.READY or not isinstance(msg, SAMPLE_MESSAGES)
            if not forward:
                self._counters.samples_outside_session += 1
        self._flush()
        if forward and self._on_telemetry is not None:
            self._on_telemetry(msg, arrived)

    def _dispatch(self, msg: Message, t: float) -> None:
        if isinstance(msg, Heartbeat):
            self._on_heartbeat(msg, t)
        elif isinstance(msg, Ident):
            self._on_ident(msg)
        elif isinstance(msg, StopAck):
            stop = self._pending_stop
            self._ctrl_latched = True
            self._ctrl_state = msg.state
            if stop is not None and msg.stop_id == stop.stop_id:
                self._last_stop_latency = t - stop.first_sent
                self._pending_stop = None
                self._emit(STOPPED)
        elif isinstance(msg, ClearAck):
            self._on_clear_ack(msg)
        elif isinstance(msg, Ack):
            self._on_ack(msg, t)
        elif isinstance(msg, Status):
            self._on_status_msg(msg)
        elif isinstance(msg, Stopped):
            self._last_stopping_mm = msg.distance_mm
        elif isinstance(msg, Fault):
            self._on_fault(msg)
        elif isinstance(msg, Progress):
            self._on_progress(msg)

    def _on_heartbeat(self, hb: Heartbeat, t: float) -> None:
        previous = self._last_hb_rx
        if (
            self._state is LinkState.READY
            and previous is not None
            and t - previous > self._lost_after_s()
        ):
            # The timer did not see the silence first (this process was held up, and
            # the heartbeats queued meanwhile arrive now): the controller's watchdog
            # has stopped the rover all the same, so the link was lost.
            self._declare_silence(t - previous)
        self._last_hb_rx = t
        self._hb_rx_gaps.event(t)
        self._heartbeat = hb
        self._ctrl_latched = bool(hb.stop_latched)
        self._ctrl_state = hb.state
        if self._check_reboot(hb.boot_nonce):
            return
        self._mark_lost_frames()
        if hb.latch_watchdog and not self._watchdog_counted:
            # A trip whose FAULT frame was lost: the latch still tells.
            self._counters.watchdog_trips += 1
            self._watchdog_counted = True
        elif not hb.latch_watchdog:
            self._watchdog_counted = False
        if self._state is LinkState.READY and not hb.handshake_ok:
            logger.warning("controller has no session with us; handshaking again")
            self._drop_all(aborted("link_lost"))
            self._emit(fault("link_lost"))
            self._set_state(LinkState.HANDSHAKE)
            self._hello_sent = False
            self._last_hello = 0.0
        if self._state is LinkState.LOST:
            logger.info("controller heartbeats again; new session")
            self._set_state(LinkState.HANDSHAKE)
            self._hello_sent = False
            self._last_hello = 0.0
        # The heartbeat is the authority on the conditions (FAULT frames may be lost).
        self._faults = {code for code in FaultCode if hb.fault_bits & fault_bit(code)}
        self._maybe_clear(hb, t)

    def _maybe_clear(self, hb: Heartbeat, now: float) -> None:
        """Send CLEAR_STOP when docs/protocol.md ("Latch and faults") allows the host to:
        the automatic clear of a watchdog-only latch, or the retry of a clear that was
        answered FAULT_PERSISTS once no stopping fault condition is active."""
        if self._state is not LinkState.READY or not hb.handshake_ok:
            return
        if self._clear_wanted and not hb.stop_latched and self._pending_clear is None:
            # Released meanwhile (by another host, or a reboot we have not seen yet).
            self._clear_wanted = False
            if not self._clear_auto:
                self._ctrl_latched = False
                self._emit(CLEARED)
            return
        watchdog_only = bool(hb.latch_watchdog and not hb.latch_stop and not hb.latch_fault)
        if self._clear_wanted and self._clear_auto and hb.stop_latched and not watchdog_only:
            # The latch gained a cause the automatic clear was not for (an emergency
            # stop, a stopping fault): that clear is over; the operator decides now.
            self._abandon_auto_clear(hb)
            return
        if self._pending_clear is not None or self._estop_requested or not hb.stop_latched:
            return
        stopping_active = any(hb.fault_bits & fault_bit(code) for code in STOPPING_FAULTS)
        if stopping_active:
            return
        retry = self._clear_wanted
        auto = self.config.auto_clear_watchdog and watchdog_only
        # At most one new request per controller heartbeat period after the last one: a
        # heartbeat sent before our CLEAR_STOP arrived still shows the latch.
        if (
            not (retry or auto)
            or now - self._last_clear_request < self.config.controller_heartbeat_s
        ):
            return
        self._last_clear_request = now
        self._stop_counter = self._stop_counter % 0xFFFF + 1
        self._pending_clear = _Pending(self._stop_counter, now, 0.0, 0)
        if not retry:
            self._clear_wanted, self._clear_auto = True, True
            self._clear_persisted = False
            logger.info("watchdog latch with its condition gone: clearing it (auto_clear_watchdog)")
        else:
            logger.info("no stopping fault condition any more: sending CLEAR_STOP again")
        self._wake.set()

    def _abandon_auto_clear(self, hb: Heartbeat | None) -> None:
        """End the automatic clear request (lock held): the latch's causes changed."""
        self._clear_wanted = self._clear_auto = self._clear_persisted = False
        self._pending_clear = None
        causes = ",".join(_latch_causes(hb)) if hb is not None else "a stopping fault"
        logger.warning(
            "automatic clear abandoned: the latch now holds %s; clear_emergency_stop "
            "(the operator) releases it",
            causes,
        )

    def _check_reboot(self, nonce: int) -> bool:
        if self._boot_nonce is None or nonce == self._boot_nonce:
            return False
        self._boot_nonce = nonce
        self._counters.reboots += 1
        # The controller's frame counter restarted with it (docs/protocol.md, Serial
        # framing): the gap it made since the last frame of the old boot is no loss.
        transport = self._transport
        if transport is not None:
            self._lost_forgiven += transport.counters.lost - self._lost_mark
            self._lost_mark = transport.counters.lost
        self._watchdog_counted = False
        logger.warning("controller rebooted (boot nonce 0x%04X); steps in flight dropped", nonce)
        self._drop_all(aborted("controller_reboot"))
        self._emit(fault("controller_reboot"))
        self._set_state(LinkState.HANDSHAKE)
        self._hello_sent = False
        self._last_hello = 0.0
        self._faults.clear()
        self._ctrl_latched = False
        self._ctrl_state = ControllerState.BOOT
        self._clear_wanted = False  # the latch went with the reboot
        if self._estop_requested:
            now = time.monotonic()
            self._pending_stop = _Pending(self._stop_counter, now, 0.0, 0)  # re-latch at once
        return True

    def _on_ident(self, ident: Ident) -> None:
        self._ident = ident
        if self._boot_nonce is None:
            self._boot_nonce = ident.boot_nonce
        elif not self._check_reboot(ident.boot_nonce):
            self._mark_lost_frames()
        match = (
            ident.protocol_version == self.protocol_version
            and ident.schema_hash == self.schema_hash
        )
        if not match:
            if self._state is not LinkState.MISMATCH:
                logger.error(
                    "controller speaks protocol v%d schema 0x%04X, we speak v%d schema 0x%04X: "
                    "refusing to drive",
                    ident.protocol_version,
                    ident.schema_hash,
                    self.protocol_version,
                    self.schema_hash,
                )
                self._drop_all(aborted("schema_mismatch"))
                self._emit(fault("schema_mismatch"))
            self._set_state(LinkState.MISMATCH)
            theirs = f"v{ident.protocol_version}/0x{ident.schema_hash:04X}"
            ours = f"v{self.protocol_version}/0x{self.schema_hash:04X}"
            self._last_error = f"protocol/schema mismatch: controller {theirs}, host {ours}"
            return
        if not self._hello_sent:
            return  # unsolicited (a boot IDENT): the session starts with our HELLO's answer
        if self._state in (LinkState.HANDSHAKE, LinkState.MISMATCH, LinkState.LOST):
            self._set_state(LinkState.READY)
            self._backoff = self.config.reconnect_min_s
            self._ended_seen = 0  # the controller counts per session
            self._last_hb_rx = time.monotonic()
            logger.info(
                "handshake done: firmware %d.%d.%d, boot nonce 0x%04X",
                ident.firmware_major,
                ident.firmware_minor,
                ident.firmware_patch,
                ident.boot_nonce,
            )
            self._emit(READY)
            if self._estop_requested and self._pending_stop is None and not self._ctrl_latched:
                now = time.monotonic()
                self._pending_stop = _Pending(self._stop_counter, now, 0.0, 0)

    def _on_clear_ack(self, ack: ClearAck) -> None:
        clear = self._pending_clear
        if clear is None or ack.stop_id != clear.stop_id:
            return
        self._pending_clear = None
        if ack.result == ClearResult.FAULT_PERSISTS:
            if self._clear_auto:
                # A stopping fault joined the watchdog in the latch: not for us to clear.
                self._abandon_auto_clear(self._heartbeat)
                return
            # The operator's clear is kept: sent again once no stopping fault condition
            # is active (_maybe_clear). Said once per request, not once per retry.
            if not self._clear_persisted:
                self._emit(fault("fault_persists"))
            self._clear_persisted = True
            return
        was_auto = self._clear_auto
        self._clear_wanted = self._clear_auto = False
        self._clear_persisted = False
        self._ctrl_latched = False
        self._ctrl_state = ControllerState.IDLE
        if ack.result == ClearResult.CLEARED or not was_auto:
            self._emit(CLEARED)

    def _on_ack(self, ack: Ack, t: float) -> None:
        step = self._inflight
        if step is None or ack.seq != step.seq:
            return  # a late duplicate ACK of a step already settled
        self._inflight = None
        if step.sends == 1:
            self._counters.rtts.append(t - step.first_sent)
        if ack.result in (AckResult.ACCEPTED, AckResult.DUPLICATE):
            self._in_controller[step.seq] = step
            self._emit(ACCEPTED)
        else:
            self._counters.steps_rejected += 1
            reason = _ACK_REASONS.get(AckResult(ack.result), f"nack_{ack.result}")
            if ack.result == AckResult.OUT_OF_RANGE and ack.field != AckField.NONE:
                reason += f":{AckField(ack.field).name.lower()}"
            self._counters.rejected[reason] += 1
            self._emit(rejected(reason))
        self._pump(t)

    def _on_status_msg(self, status: Status) -> None:
        if status.state == StepState.STARTED:
            return
        self._ended_seen = (self._ended_seen + 1) & 0xFFFF
        if status.seq in self._in_controller:
            self._settle_through(status.seq, status.state, status.reason)
            self._pump(time.monotonic())

    def _settle_through(self, seq: int, state: int, reason: int) -> None:
        """Step ``seq`` ended with this outcome; steps sent before it ended too (steps end
        in order), so any still open lost their STATUS and get the same outcome."""
        for open_seq in list(self._in_controller):
            del self._in_controller[open_seq]
            if state == StepState.COMPLETED:
                self._counters.steps_completed += 1
                self._emit(COMPLETED)
            else:
                self._counters.steps_aborted += 1
                self._emit(aborted(AbortReason(reason).name.lower()))
            if open_seq == seq:
                return

    def _on_progress(self, progress: Progress) -> None:
        """Settle steps whose STATUS was lost (docs/protocol.md, MOTION)."""
        missed = (progress.ended_count - self._ended_seen) & 0xFFFF
        if missed == 0 or missed >= 0x8000 or self._state is not LinkState.READY:
            return
        self._ended_seen = progress.ended_count
        if progress.ended_seq not in self._in_controller:
            return  # its ending was seen; steps before it were settled with it
        logger.warning(
            "%d STATUS frame(s) lost; settling through seq %d from PROGRESS",
            missed,
            progress.ended_seq,
        )
        self._settle_through(progress.ended_seq, progress.ended_state, progress.ended_reason)
        self._pump(time.monotonic())

    def _on_fault(self, msg: Fault) -> None:
        name = (
            FaultCode(msg.code).name.lower()
            if msg.code in FaultCode._value2member_map_
            else str(msg.code)
        )
        if msg.active:
            self._faults.add(msg.code)
            if msg.code in STOPPING_FAULTS and msg.code != FaultCode.WATCHDOG:
                self._last_stopping_fault = msg.code
            if msg.code == FaultCode.WATCHDOG:
                self._counters.watchdog_trips += 1
                self._watchdog_counted = True
            self._emit(fault(name))
        else:
            # The condition went away; a latch it set is the heartbeat's to report.
            self._faults.discard(msg.code)

    # -- status emission ---------------------------------------------------------------------
    def _emit(self, status: str) -> None:
        self._outbox.append(status)

    def _flush(self) -> None:
        """Deliver the statuses and state changes queued under the lock, in order.

        One thread delivers at a time, outside the lock: a thread that finds another
        delivering leaves its items to it (they are later than the ones being delivered),
        so two threads never hand out their statuses interleaved."""
        with self._lock:
            if self._delivering:
                return
            self._delivering = True
        try:
            while True:
                with self._lock:
                    out, self._outbox = self._outbox, []
                    if not out:
                        self._delivering = False
                        return
                for item in out:
                    try:
                        if isinstance(item, LinkState):
                            if self._on_state is not None:
                                self._on_state(item)
                        else:
                            self._on_status(item)
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
            counters = transport.counters if transport is not None else None
            hb = self._heartbeat
            ident = self._ident
            rtts = list(self._counters.rtts)
            c = self._counters
            now = time.monotonic()
            age = now - self._last_hb_rx if self._last_hb_rx is not None else None
            rx_gaps, tx_gaps = self._hb_rx_gaps.summary(), self._hb_tx_gaps.summary()
            monitor = stall.current_monitor()
            return LinkDiagnostics(
                state=self._state.value,
                url=self.config.url,
                connected=transport is not None,
                missed_beats=int(age / self.config.controller_heartbeat_s) if age else 0,
                lost_after_beats=c.lost_after_beats,
                heartbeat_losses=c.heartbeat_losses,
                reconnects=c.reconnects,
                reboots=c.reboots,
                rtt_ms=rtts[-1] * 1e3 if rtts else None,
                rtt_median_ms=statistics.median(rtts) * 1e3 if rtts else None,
                heartbeat_age_s=age,
                rx_frames=counters.frames if counters else 0,
                tx_frames=transport.tx_frames if transport else 0,
                crc_errors=counters.crc if counters else 0,
                resyncs=(counters.framing + counters.oversize) if counters else 0,
                rx_dropped=counters.rejected if counters else 0,
                rx_overflow=transport.rx_overflow if transport else 0,
                lost_frames=max(0, counters.lost - self._lost_forgiven) if counters else 0,
                retries=c.retries,
                no_ack_faults=c.no_ack_faults,
                stop_repeats=c.stop_repeats,
                watchdog_trips=c.watchdog_trips,
                last_stop_latency_ms=self._last_stop_latency * 1e3
                if self._last_stop_latency is not None
                else None,
                last_stopping_distance_mm=self._last_stopping_mm,
                controller_state=ControllerState(hb.state).name if hb else "UNKNOWN",
                stop_latched=self.stop_latched,
                estop_requested=self._estop_requested,
                faults=tuple(
                    sorted(
                        FaultCode(f).name for f in self._faults if f in FaultCode._value2member_map_
                    )
                ),
                controller_queue=hb.queue_depth if hb else 0,
                boot_nonce=self._boot_nonce,
                firmware=(
                    f"{ident.firmware_major}.{ident.firmware_minor}.{ident.firmware_patch}"
                    if ident
                    else ""
                ),
                schema_hash=f"0x{ident.schema_hash:04X}" if ident else "",
                host_schema_hash=f"0x{self.schema_hash:04X}",
                steps_sent=c.steps_sent,
                steps_completed=c.steps_completed,
                steps_rejected=c.steps_rejected,
                steps_aborted=c.steps_aborted,
                rejected=tuple(sorted(c.rejected.items())),
                last_error=self._last_error,
                medium_state=transport.medium_state if transport else "n/a",
                medium_errors=transport.medium_errors if transport else 0,
                latch=_latch_causes(hb) if hb is not None and self._ctrl_latched else (),
                latch_fault=FaultCode(self._last_stopping_fault).name
                if self._last_stopping_fault is not None
                else "",
                heartbeat_rx_gap_max_ms=rx_gaps.max_ms,
                heartbeat_rx_gap_p99_ms=rx_gaps.p99_ms,
                heartbeat_tx_gap_max_ms=tx_gaps.max_ms,
                heartbeat_tx_gap_p99_ms=tx_gaps.p99_ms,
                samples_outside_session=c.samples_outside_session,
                stalls=len(monitor.records) if monitor is not None else 0,
                stall_max_ms=monitor.longest_ms if monitor is not None else 0.0,
            )


def _latch_causes(hb: Heartbeat) -> tuple[str, ...]:
    """The latch causes a HEARTBEAT reports, sorted."""
    return tuple(
        name
        for name, bit in (
            ("fault", hb.latch_fault),
            ("stop", hb.latch_stop),
            ("watchdog", hb.latch_watchdog),
        )
        if bit
    )
