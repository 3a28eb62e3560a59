"""The host side of the controller protocol as a state machine with no threads, no clock
and no I/O (docs/protocol.md): handshake, the two send lanes, acknowledgements and
retries, STOP and its repeats, the latch and its automatic clear, heartbeats, link
supervision, reconnect decisions and counters.

:class:`LinkCore` is driven by events, each with the time it happened (any monotonic
clock, seconds): a frame received (:meth:`~LinkCore.on_frame`), a request
(:meth:`~LinkCore.submit_step`, :meth:`~LinkCore.emergency_stop`,
:meth:`~LinkCore.clear_stop`), the transport opened, refused or failed
(:meth:`~LinkCore.on_connected`, :meth:`~LinkCore.connect_failed`,
:meth:`~LinkCore.failed`), a frame written (:meth:`~LinkCore.written`,
:meth:`~LinkCore.stop_written`), and the passing of time (:meth:`~LinkCore.tick`, due
at :meth:`~LinkCore.next_deadline` at the latest). What it decides comes out through:

- :meth:`~LinkCore.take_stops`: STOP frames to write now, on the STOP lane (ahead of
  anything queued; a STOP waits for no other write);
- :meth:`~LinkCore.take_write`: the next ordinary frame (HELLO, HOST_HEARTBEAT,
  CLEAR_STOP, MOTION) for the writer, in order, one at a time; the writer reports it
  with :meth:`~LinkCore.written` (the ACK timeout runs from then);
- :meth:`~LinkCore.take_events`: the ``/command_status`` strings (each a
  :class:`~bridge.link.linktypes.StatusEvent` naming its step) and the
  :class:`~bridge.link.linktypes.LinkState` changes, in the order they happened;
- :meth:`~LinkCore.on_frame`'s result: whether the frame is telemetry to forward.

The same core runs in real time inside :class:`~bridge.link.controllerlink.ControllerLink`
and in virtual time inside the wire simulator (``rover sim``, docs/sim.md).

The rules (docs/protocol.md, "Latch and faults", "STOP semantics", "MOTION,
acknowledgement and deduplication", "Watchdog and heartbeats"; with the bridge's
defaults, docs/bridge.md, "The link to the controller"), as the core keeps them:

**STOP lane.** :meth:`LinkCore.emergency_stop` claims the first STOP copy at once, then
repeats it every ``stop_repeat_s`` until STOP_ACK with its id; the request survives a
reboot or a lost link (sent again right after the handshake) until
:meth:`~LinkCore.clear_stop`. No CLEAR_STOP reaches the wire after a later STOP.

**Latch.** Every CLEAR_STOP names the latch generation it releases. An operator's clear
names the last generation this core learned, after every stopping cause it learned was
reported (``fault:<name>``); it waits for the STOP_ACK of this host's own STOP still
out; refused, it is over. Steps submitted while it is out wait for its answer. With
``auto_clear_watchdog`` the core clears a latch the watchdog alone holds. A CLEAR_STOP
copy is repeated every ``stop_repeat_s`` after the previous copy was written, never queued
behind an unwritten one.

**MOTION lane.** One MOTION at a time, in order, the next only after its ACK: a MOTION is
retransmitted ``ack_timeout_s`` after it was written, at most ``motion_retries`` times
(then ``fault:no_ack`` and the link is lost); at most ``controller_queue`` steps are
outstanding in the controller.

**Supervision.** HELLO is repeated until IDENT; a mismatch refuses every step
(``rejected:schema_mismatch``). ``link_lost_beats`` controller heartbeats missed ->
``fault:link_lost`` (by :meth:`~LinkCore.tick`, or by the first heartbeat after a longer
gap when the host was held up). Sensor samples are forwarded only in a session whose
IDENT told the boot nonce. A changed boot nonce -> ``fault:controller_reboot``; a
transport error -> reconnect with exponential backoff, reset only by a completed
handshake. In each case every step not yet settled is dropped with its own fate, oldest
first (``aborted:<reason>``, counted in ``steps_aborted``), then one ``fault:<reason>``;
no stale motion is ever replayed.

**Seams.** A few rules sit in methods of their own so that the wire simulator can
undo exactly one fix in a subclass (``sim/linkmutants.py``, docs/sim.md "Mutants"):
:meth:`LinkCore._forwards`, :meth:`LinkCore._ended_by_progress`,
:meth:`LinkCore._settle_latched`, :meth:`LinkCore._new_watchdog_trip`,
:meth:`LinkCore._stopping_fault_frame`, :meth:`LinkCore._auto_clear_refused`,
:meth:`LinkCore._auto_clear_outlived`. The core itself holds no test switch.

Not thread-safe: one caller at a time (the shell holds its lock around every call).
"""

from __future__ import annotations

import logging
import math
import statistics
from collections import Counter, deque
from dataclasses import dataclass, field

from bridge.link.linktypes import (
    SAMPLE_MESSAGES,
    LinkConfig,
    LinkDiagnostics,
    LinkState,
    MediumStats,
    StatusEvent,
    StepRequest,
)
from bridge.ros.rosport.contract import (
    ACCEPTED,
    CLEARED,
    COMPLETED,
    READY,
    STOPPED,
    aborted,
    fault,
    rejected,
)
from firmware_proto.wire.faults import STOPPING_FAULTS, fault_bit
from firmware_proto.wire.gapstats import GapStats
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
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

__all__ = ["LinkCore", "Outgoing", "latch_causes"]

logger = logging.getLogger(__name__)

_ACK_REASONS = {
    AckResult.OUT_OF_RANGE: "out_of_range",
    AckResult.QUEUE_FULL: "queue_full",
    AckResult.STOP_LATCHED: "stop_latched",
    AckResult.NOT_READY: "not_ready",
    AckResult.FAULT_ACTIVE: "fault_active",
}

_TIME_EPS_S = 1e-9
"""Float slack for deadlines, s: each is compared as ``now >= last + period``, the very sum
:meth:`LinkCore.next_deadline` returns, so that a tick at the deadline finds it due."""


@dataclass(eq=False)
class _Step:
    request: StepRequest
    number: int
    """The number :meth:`LinkCore.submit_step` gave it (its events carry it)."""
    seq: int = -1
    sends: int = 0
    first_sent: float = 0.0
    last_sent: float = 0.0
    unwritten: int = 0
    """Copies queued for the writer, not yet written: the ACK timeout runs from the write."""
    written: bool = False
    """A copy of it reached the wire (``steps_sent`` counts it then)."""


@dataclass
class _Pending:
    stop_id: int
    first_sent: float = 0.0
    last_sent: float = 0.0
    sends: int = 0
    latch_gen: int | None = None
    """CLEAR_STOP: the latch generation it names (``None``: not known yet)."""
    auto: bool = False
    """CLEAR_STOP: the core's own automatic clear, not the operator's."""
    unwritten: int = 0
    """CLEAR_STOP: copies queued for the writer and not yet written."""
    after_stop: bool = False
    """CLEAR_STOP: waits for the STOP_ACK of this host's own STOP before it goes."""


@dataclass(eq=False)
class Outgoing:
    """One ordinary frame for the writer (see :meth:`LinkCore.take_write`).

    Attributes:
        conn: the connection it was queued for (a write for an older one is moot).
        auto_clear: a CLEAR_STOP the core decided by itself (``auto_clear_watchdog``),
            not the operator's.
    """

    msg: Message
    conn: int
    step: _Step | None = None
    auto_clear: bool = False

    @property
    def step_number(self) -> int | None:
        """The number of the step a MOTION carries (``None`` for any other frame)."""
        return self.step.number if self.step is not None else None


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


def latch_causes(hb: Heartbeat) -> tuple[str, ...]:
    """The latch causes a HEARTBEAT reports, sorted (``fault``, ``stop``, ``watchdog``)."""
    return tuple(
        name
        for name, bit in (
            ("fault", hb.latch_fault),
            ("stop", hb.latch_stop),
            ("watchdog", hb.latch_watchdog),
        )
        if bit
    )


class LinkCore:
    """Host end of the controller protocol, pure; see the module docstring."""

    def __init__(
        self,
        config: LinkConfig,
        *,
        protocol_version: int = PROTOCOL_VERSION,
        schema_hash: int = SCHEMA_HASH,
        first_request_id: int = 1,
    ) -> None:
        """Args:
        config: link parameters (:attr:`config` may be replaced while running: each
            value is read when next needed).
        protocol_version, schema_hash: what this host speaks (tests change them).
        first_request_id: the id of the first STOP or CLEAR_STOP request, 1..65535 (a
            real host picks it at random, docs/protocol.md, "Latch and faults").
        """
        self.config = config
        self.protocol_version = protocol_version
        self.schema_hash = schema_hash
        self._conn = 0
        """The connection number: grows at every open and every failure."""
        self._connected = False
        self._state = LinkState.DISCONNECTED
        self._reconnect_at = -math.inf
        self._backoff = config.reconnect_min_s
        self._seq = 0
        self._stop_counter = (first_request_id - 1) % 0xFFFF
        self._numbers = 0
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
        self._last_hello = -math.inf
        self._last_hb_tx = -math.inf
        self._heartbeat: Heartbeat | None = None
        self._faults: set[int] = set()
        """Fault conditions active in the controller (FAULT active 1..0, ``fault_bits``)."""
        self._last_stopping_fault: int | None = None
        self._latch_gen: int | None = None
        """The controller's latch generation, as the last frame of this boot said."""
        self._released_gen: int | None = None
        """Generation our last CLEARED released: a HEARTBEAT still showing it latched is stale."""
        self._last_stop_id: int | None = None
        """The id of this host's last emergency stop."""
        self._stopped_said: int | None = None
        """The stop id ``stopped`` was last said for."""
        self._reported: set[str] = set()
        """Stopping latch causes reported (``watchdog``, ``fault``) since the latch was last
        released (docs/protocol.md: a fault is reported before a clear may release it)."""
        self._hb_counter = 0
        self._last_stop_latency: float | None = None
        self._last_stopping_mm: int | None = None
        self._last_error = ""
        self._counters = _Counters()
        self._outbox: list[StatusEvent | LinkState] = []
        self._stops: list[Stop] = []
        """STOP copies decided and not yet taken by a writer."""
        self._tx: deque[Outgoing] = deque()
        """Ordinary frames for the writer, in order."""
        self._ctrl_latched = False
        self._stop_acked_gen: int | None = None
        """The latch generation of a STOP_ACK no HEARTBEAT of that generation or later has
        followed yet (a HEARTBEAT sent before the STOP does not show it)."""
        self._ctrl_state: int | None = None
        self._ended_seen = 0
        self._last_auto_clear = -math.inf
        self._hello_sent = False  # a HELLO went out in the current handshake
        self._hb_rx_gaps = GapStats(config.controller_heartbeat_s)
        self._hb_tx_gaps = GapStats(config.heartbeat_s)
        self._watchdog_counted = False
        """The watchdog latch episode now in force was counted in ``watchdog_trips``."""
        self._clear_in_write = False
        """The writer is writing a CLEAR_STOP now."""
        self._stop_after_clear: Stop | None = None
        """An emergency stop came while it was: this STOP goes out again after it."""
        self._rx_lost = 0
        """Frames lost before the last frame received, from the gaps in the counter."""
        self._last_rx_seq: int | None = None
        self._session_confirmed = False
        """A HEARTBEAT of this session showed ``handshake_ok``: the controller has it."""
        self._lost_mark = 0
        """The lost-frame count at the last frame of the current boot."""
        self._lost_forgiven = 0
        """Lost frames not counted: the frame counter restarting at a reboot."""

    # -- what the driver reads ------------------------------------------------------------
    @property
    def state(self) -> LinkState:
        """The link state."""
        return self._state

    @property
    def ready(self) -> bool:
        """Handshake done with a matching controller, link alive."""
        return self._state is LinkState.READY

    @property
    def connected(self) -> bool:
        """A transport is open (between :meth:`on_connected` and :meth:`failed`)."""
        return self._connected

    @property
    def stop_latched(self) -> bool:
        """An emergency stop is requested, or the controller's motion is latched (STOP or
        fault) as its last STOP_ACK, CLEAR_ACK or HEARTBEAT said."""
        return self._estop_requested or self._ctrl_latched

    @property
    def estop_requested(self) -> bool:
        """An emergency stop is requested and no clear has been asked for since."""
        return self._estop_requested

    @property
    def latch(self) -> tuple[str, ...]:
        """What holds the controller's latch (``fault``, ``stop``, ``watchdog``) as its
        last HEARTBEAT said, with ``stop`` from a STOP_ACK of a later latch generation than
        that HEARTBEAT's (the next one shows it); empty when it is not latched."""
        if not self._ctrl_latched:
            return ()
        hb = self._heartbeat
        causes = latch_causes(hb) if hb is not None else ()
        if self._stop_acked_gen is not None and "stop" not in causes:
            causes = tuple(sorted((*causes, "stop")))
        return causes

    @property
    def clear_open(self) -> bool:
        """An operator's clear is out and not yet answered: steps submitted now wait for
        its answer (docs/protocol.md, "Latch and faults": Host: a clear, then a step)."""
        return self._operator_clear_out()

    @property
    def boot_nonce(self) -> int | None:
        """The controller's boot nonce as last seen (``None`` before any)."""
        return self._boot_nonce

    @property
    def reboots(self) -> int:
        """Reboots of the controller seen so far (a changed boot nonce, a boot IDENT):
        odometry re-bases whenever it grows."""
        return self._counters.reboots

    @property
    def pending_writes(self) -> bool:
        """Ordinary frames wait for the writer (:meth:`take_write`)."""
        return bool(self._tx)

    def take_events(self) -> list[StatusEvent | LinkState]:
        """The statuses and state changes decided since the last call, in order."""
        out, self._outbox = self._outbox, []
        return out

    def take_stops(self) -> list[Stop]:
        """The STOP copies to write now, on the STOP lane; each is counted as sent."""
        out, self._stops = self._stops, []
        return out

    def take_write(self) -> Outgoing | None:
        """The next ordinary frame to write, for the current connection, or ``None``.
        The writer must report it with :meth:`written` once it is out (or failed)."""
        while self._tx:
            entry = self._tx.popleft()
            if entry.conn != self._conn:
                self._forget_clear_copy(entry)
                continue
            self._clear_in_write = isinstance(entry.msg, ClearStop)
            return entry
        return None

    def written(self, entry: Outgoing, now: float, ok: bool) -> None:
        """``entry`` (from :meth:`take_write`) went out at ``now`` (``ok``) or its write
        failed (report the failure with :meth:`failed`)."""
        if isinstance(entry.msg, ClearStop):
            # A STOP asked for during this write may have reached the wire first: it
            # goes out once more, so the last word the controller hears is STOP.
            self._clear_in_write = False
            again, self._stop_after_clear = self._stop_after_clear, None
            if again is not None and entry.conn == self._conn:
                self._stops.append(again)
            clear = self._pending_clear
            if clear is not None and clear.stop_id == entry.msg.stop_id and clear.unwritten:
                clear.unwritten -= 1
                if ok:
                    clear.last_sent = now  # the repeat interval runs from the write
        if ok and isinstance(entry.msg, HostHeartbeat) and entry.conn == self._conn:
            self._hb_tx_gaps.event(now)
        step = entry.step
        if step is not None:
            step.unwritten -= 1
            if ok:
                # Counted as they reach the wire: a copy dropped unwritten was never sent.
                if step.written:
                    self._counters.retries += 1
                else:
                    self._counters.steps_sent += 1
                    step.written = True
                # The ACK timeout and the round trip run from here.
                step.last_sent = now
                if step.sends == 1:
                    step.first_sent = step.last_sent

    def _forget_clear_copy(self, entry: Outgoing) -> None:
        """A CLEAR_STOP copy will never be written (its connection is gone)."""
        clear = self._pending_clear
        if (
            isinstance(entry.msg, ClearStop)
            and clear is not None
            and clear.stop_id == entry.msg.stop_id
            and clear.unwritten
        ):
            clear.unwritten -= 1

    def stop_written(self, stop_id: int, now: float, ok: bool) -> None:
        """The first copy of emergency stop ``stop_id`` (claimed by :meth:`emergency_stop`)
        was handed to the medium whole at ``now`` (``ok``), or its write failed."""
        stop = self._pending_stop
        if stop is None or stop.stop_id != stop_id:
            return
        if ok:
            stop.last_sent = now  # the repeat interval runs from when the copy left
        else:
            stop.sends = 0  # not on the wire: the next copy is the first

    def next_deadline(self, now: float) -> float:
        """The latest time :meth:`tick` must run next (``now`` if something is due)."""
        cfg = self.config
        if not self._connected:
            return max(now, self._reconnect_at)
        due = self._last_hb_tx + cfg.heartbeat_s
        if self._state in (LinkState.HANDSHAKE, LinkState.LOST):
            due = min(due, self._last_hello + cfg.heartbeat_s)
        stop = self._pending_stop
        if stop is not None and self._state is not LinkState.DISCONNECTED:
            due = min(due, now if stop.sends == 0 else stop.last_sent + cfg.stop_repeat_s)
        clear = self._pending_clear
        if self._clear_sendable(clear) and self._state in (LinkState.READY, LinkState.LOST):
            assert clear is not None
            if not clear.unwritten:
                due = min(due, now if clear.sends == 0 else clear.last_sent + cfg.stop_repeat_s)
        if self._state is LinkState.READY:
            if self._last_hb_rx is not None:
                due = min(due, self._last_hb_rx + self._lost_after_s() + _TIME_EPS_S)
            step = self._inflight
            if step is not None:
                if not step.unwritten:
                    due = min(due, step.last_sent + cfg.ack_timeout_s)
            elif (
                self._lane
                and len(self._in_controller) < cfg.controller_queue
                and not self._operator_clear_out()
            ):
                due = now
        return max(now, due)

    # -- connection ------------------------------------------------------------------------
    def connect_due(self, now: float) -> bool:
        """No transport, and the backoff has passed: open one now."""
        return not self._connected and now >= self._reconnect_at

    def on_connected(self, now: float) -> None:
        """A transport was opened at ``now``: handshake."""
        self._connected = True
        self._conn += 1
        self._set_state(LinkState.HANDSHAKE)
        self._hello_sent = False
        self._last_hello = -math.inf
        self._last_hb_rx = None
        self._hb_rx_gaps.restart()
        self._hb_tx_gaps.restart()
        self._rx_lost = 0
        self._last_rx_seq = None
        self._lost_mark = self._lost_forgiven = 0  # a new transport counts anew
        logger.info("connected to %s; handshaking", self.config.url)

    def connect_failed(self, now: float, error: str) -> None:
        """Opening a transport failed at ``now``: retry after the backoff, which doubles."""
        self._last_error = error
        self._reconnect_at = now + self._backoff
        logger.info("connect failed (%s); retry in %.1f s", error, self._backoff)
        self._backoff = min(self.config.reconnect_max_s, self._backoff * 2)

    def failed(self, now: float, error: str) -> None:
        """The open transport failed at ``now`` (read or write error, device gone, bus
        off): drop every step, report ``fault:link_lost``, reconnect after the backoff."""
        if not self._connected:
            return
        self._connected = False
        self._conn += 1
        for entry in self._tx:
            self._forget_clear_copy(entry)
        self._tx.clear()
        self._last_error = error
        self._counters.reconnects += 1
        self._set_state(LinkState.DISCONNECTED)
        self._heartbeat = None
        # Only a completed handshake resets the backoff: a medium that opens and fails
        # at once (bus-off, a flapping socket) backs off like one that cannot open.
        self._reconnect_at = now + self._backoff
        self._drop_all(aborted("link_lost"))
        self._emit(fault("link_lost"))
        logger.warning(
            "link to %s failed: %s; reconnecting in %.1f s", self.config.url, error, self._backoff
        )
        self._backoff = min(self.config.reconnect_max_s, self._backoff * 2)

    # -- requests -----------------------------------------------------------------------------
    def submit_step(self, step: StepRequest, now: float) -> int:
        """Queue a validated motion step; returns its number (every
        :class:`~bridge.link.linktypes.StatusEvent` about it carries it). Its fate comes as
        ``accepted`` then ``completed``, or ``rejected:``, ``aborted:``, ``fault:``. A STOP
        command is an emergency stop (source PLAN_STEP; no step events)."""
        self._numbers += 1
        number = self._numbers
        if step.command == Command.STOP:
            self.emergency_stop(StopSource.PLAN_STEP, now)
            return number
        reason = self._refusal()
        if reason is None and len(self._lane) >= self.config.lane_limit:
            reason = "queue_full"
        if reason is not None:
            self._counters.steps_rejected += 1
            self._counters.rejected[reason] += 1
            self._emit(rejected(reason), number)
            logger.info("step %s rejected: %s", step, reason)
        else:
            self._lane.append(_Step(step, number))
            self._pump(now)
        return number

    def _refusal(self) -> str | None:
        if self._state is LinkState.MISMATCH:
            return "schema_mismatch"
        if self._state is not LinkState.READY:
            return "link_down"
        if self._operator_clear_out():
            return None  # it waits for the clear's answer (docs/protocol.md)
        if self._ctrl_state == ControllerState.FAULT:
            return "fault_active"
        if self.stop_latched:
            return "stop_latched"
        return None

    def emergency_stop(self, source: int, now: float) -> int:
        """STOP now (module docstring, "STOP lane") and purge every step not yet in the
        controller; works in any link state. Returns the stop id."""
        self._stop_counter = self._stop_counter % 0xFFFF + 1
        stop_id = self._stop_counter
        self._last_stop_id = stop_id
        self._estop_requested = True
        self._estop_source = source
        self._end_clear(None)
        # No CLEAR_STOP may follow this STOP onto the wire (see written()).
        self._unqueue(ClearStop)
        if self._clear_in_write:
            self._stop_after_clear = Stop(stop_id, source)
        write_now = self._connected and self._state is not LinkState.DISCONNECTED
        # The first copy is claimed here, before it is written: a tick must see it as
        # sent (and repeat it only after stop_repeat_s), not as never sent.
        self._pending_stop = _Pending(stop_id, now, now, 1 if write_now else 0)
        if write_now:
            self._stops.append(Stop(stop_id, source))
        self._purge(aborted("stop"))
        logger.info("emergency stop %d (source %s)", stop_id, StopSource(source).name)
        return stop_id

    def clear_stop(self, now: float) -> int:
        """Ask the controller to release its latch (CLEAR_STOP, repeated until CLEAR_ACK);
        returns the request id. The answer comes as ``cleared`` or ``fault:<reason>``."""
        self._stop_counter = self._stop_counter % 0xFFFF + 1
        clear_id = self._stop_counter
        self._estop_requested = False
        stop = self._pending_stop
        after_stop = stop is not None and stop.sends > 0
        if not after_stop:
            self._pending_stop = None  # never on the wire: nothing to wait for
        self._end_clear(None)
        # The generation the operator was told of; the own STOP it waits for adds one
        # when its STOP_ACK says so (_on_stop_ack).
        self._pending_clear = _Pending(
            clear_id, now, 0.0, 0, latch_gen=self._latch_gen, after_stop=after_stop
        )
        return clear_id

    @staticmethod
    def _clear_sendable(clear: _Pending | None) -> bool:
        """``clear`` may go on the wire: it names a generation and waits for no STOP_ACK."""
        return clear is not None and clear.latch_gen is not None and not clear.after_stop

    def _operator_clear_out(self) -> bool:
        """An operator's clear is out, not yet answered (steps wait for it)."""
        clear = self._pending_clear
        return clear is not None and not clear.auto

    def _end_clear(self, refusal: str | None) -> None:
        """The clear request now out (if any) is over; steps that waited for an operator's
        clear are refused with ``refusal`` (``None``: they stay, for what comes next)."""
        clear, self._pending_clear = self._pending_clear, None
        if clear is not None and not clear.auto and refusal is not None:
            self._reject_lane(refusal)

    def _reject_lane(self, reason: str) -> None:
        """Refuse every step waiting in the lane with ``rejected:<reason>``."""
        waiting = list(self._lane)
        self._lane.clear()
        for step in waiting:
            self._counters.steps_rejected += 1
            self._counters.rejected[reason] += 1
            self._emit(rejected(reason), step.number)

    # -- time ---------------------------------------------------------------------------------
    def tick(self, now: float) -> None:
        """The periodic work due at ``now``: HELLO, HOST_HEARTBEAT, STOP and CLEAR_STOP
        repeats, MOTION and its retransmission, the silence that loses the link."""
        cfg = self.config
        if not self._connected:
            return
        out: list[tuple[Message, bool]] = []
        if (
            self._state in (LinkState.HANDSHAKE, LinkState.LOST)
            and now >= self._last_hello + cfg.heartbeat_s
        ):
            self._last_hello = now
            self._hello_sent = True
            out.append((Hello(self.protocol_version, self.schema_hash), False))
        if now >= self._last_hb_tx + cfg.heartbeat_s:
            self._last_hb_tx = now
            self._hb_counter = (self._hb_counter + 1) & 0xFFFF
            out.append((HostHeartbeat(self._hb_counter), False))
        stop = self._pending_stop
        if (
            stop is not None
            and self._state is not LinkState.DISCONNECTED
            and (stop.sends == 0 or now >= stop.last_sent + cfg.stop_repeat_s)
        ):
            if stop.sends:
                self._counters.stop_repeats += 1
            else:
                stop.first_sent = now  # requested while down: its latency runs from here
            stop.sends += 1
            stop.last_sent = now
            self._stops.append(Stop(stop.stop_id, self._estop_source))
        clear = self._pending_clear
        if (
            clear is not None
            and clear.latch_gen is not None
            and self._clear_sendable(clear)
            and self._state in (LinkState.READY, LinkState.LOST)
            and not clear.unwritten
            and (clear.sends == 0 or now >= clear.last_sent + cfg.stop_repeat_s)
        ):
            clear.sends += 1
            clear.last_sent = now
            clear.unwritten += 1
            out.insert(0, (ClearStop(clear.stop_id, clear.latch_gen), clear.auto))
        if self._state is LinkState.READY:
            lost_after = self._lost_after_s()
            if self._last_hb_rx is not None and now > self._last_hb_rx + lost_after:
                self._declare_silence(now - self._last_hb_rx)
        for msg, auto in out:
            self._queue(msg, auto_clear=auto)
        if self._state is LinkState.READY:
            self._pump(now)

    # -- frames received ------------------------------------------------------------------------
    def on_frame(self, msg: Message, now: float, *, rx_seq: int | None = None) -> bool:
        """A message from the controller, arrived at ``now``. ``rx_seq``: its serial frame
        counter (``None`` on CAN), counted frame by frame so that the gap a reboot makes
        is forgiven exactly (docs/protocol.md, Serial framing). Returns whether it is
        telemetry to forward (every message but a sensor sample outside a session)."""
        boot_frame = False
        if rx_seq is not None:
            last = self._last_rx_seq
            if last is not None:
                gap = (rx_seq - last - 1) & 0xFF
                self._rx_lost += gap
                # An IDENT numbered 0 that does not follow frame 255: the counter
                # restarted, a boot's first frame (docs/protocol.md, Serial framing).
                boot_frame = isinstance(msg, Ident) and rx_seq == 0 and gap != 0
            self._last_rx_seq = rx_seq
        if boot_frame:
            assert isinstance(msg, Ident)
            self._on_ident(msg, now, sign="its boot IDENT restarted the frame counter")
        else:
            self._dispatch(msg, now, serial=rx_seq is not None)
        forward = self._forwards(msg)
        if not forward:
            self._counters.samples_outside_session += 1
        return forward

    def _forwards(self, msg: Message) -> bool:
        """Whether a received message is telemetry to hand on (module docstring,
        "Supervision"; docs/protocol.md, Handshake 2)."""
        return self._state is LinkState.READY or not isinstance(msg, SAMPLE_MESSAGES)

    def _dispatch(self, msg: Message, t: float, *, serial: bool = False) -> None:
        if isinstance(msg, Heartbeat):
            self._on_heartbeat(msg, t, serial=serial)
        elif isinstance(msg, Ident):
            self._on_ident(msg, t)
        elif isinstance(msg, StopAck):
            self._on_stop_ack(msg, t)
        elif isinstance(msg, ClearAck):
            self._on_clear_ack(msg, t)
        elif isinstance(msg, Ack):
            self._on_ack(msg, t)
        elif isinstance(msg, Status):
            self._on_status_msg(msg, t)
        elif isinstance(msg, Stopped):
            self._last_stopping_mm = msg.distance_mm
        elif isinstance(msg, Fault):
            self._on_fault(msg)
        elif isinstance(msg, Progress):
            self._on_progress(msg, t)

    def _on_stop_ack(self, msg: StopAck, t: float) -> None:
        stop = self._pending_stop
        known = self._latch_gen
        self._latch_gen = msg.latch_gen
        self._ctrl_latched = True
        self._stop_acked_gen = msg.latch_gen
        self._ctrl_state = msg.state
        if stop is None or msg.stop_id != stop.stop_id:
            if msg.stop_id == self._last_stop_id and self._stopped_said != msg.stop_id:
                # Our last STOP, acknowledged after we stopped waiting for it (a clear
                # asked for, then a reboot): the rover did stop, and the operator hears so.
                self._stopped_said = msg.stop_id
                self._emit(STOPPED)
            return
        self._last_stop_latency = t - stop.first_sent
        self._pending_stop = None
        self._stopped_said = msg.stop_id
        self._emit(STOPPED)
        clear = self._pending_clear
        if clear is not None and clear.after_stop:
            # The clear names the STOP's generation if the STOP alone raised it since the
            # operator's view; else the older one (the controller answers LATCH_CHANGED).
            clear.after_stop = False
            base = clear.latch_gen if clear.latch_gen is not None else known
            if base is None and msg.state == ControllerState.FAULT:
                # A latch cause never reported: not the operator's to release with this clear.
                self._refuse_operator_clear("latch_changed")
            elif base is None or (msg.latch_gen - base) & 0xFF <= 1:
                clear.latch_gen = msg.latch_gen
            else:
                clear.latch_gen = (base + 1) & 0xFF

    def _on_heartbeat(self, hb: Heartbeat, t: float, *, serial: bool = False) -> None:
        """``serial``: it came over a serial link, where no other host can end the
        controller's session with a HELLO of its own."""
        previous = self._last_hb_rx
        if (
            self._state is LinkState.READY
            and previous is not None
            and t - previous > self._lost_after_s()
        ):
            # This process was held up: the controller's watchdog has stopped the rover
            # all the same, so the link was lost.
            self._declare_silence(t - previous)
        self._last_hb_rx = t
        self._hb_rx_gaps.event(t)
        self._heartbeat = hb
        # On a serial link only a reboot ends a session the controller had confirmed (its
        # HEARTBEATs showed handshake_ok): no other host shares the line.
        lost = serial and self._state is LinkState.READY and self._session_confirmed
        sign = "it lost the session it had confirmed" if lost and not hb.handshake_ok else ""
        if self._check_reboot(hb.boot_nonce, t, sign=sign):
            self._heartbeat = hb
            return
        if self._state is LinkState.READY and hb.handshake_ok:
            self._session_confirmed = True
        stale = bool(hb.stop_latched) and hb.latch_gen == self._released_gen
        # A HEARTBEAT sent before a STOP that was acknowledged first does not show the
        # STOP's latch: of an older generation, it leaves the latch as the STOP_ACK said.
        acked = self._stop_acked_gen
        before_stop = acked is not None and (hb.latch_gen - acked) & 0xFF >= 0x80
        if not before_stop:
            self._stop_acked_gen = None
            # A HEARTBEAT sent before our CLEAR_STOP arrived still shows the latch it released.
            self._ctrl_latched = bool(hb.stop_latched) and not stale
            self._ctrl_state = hb.state if not stale else ControllerState.IDLE
            self._learn_gen(hb)
        self._lost_mark = self._rx_lost  # a frame of this boot: loss up to here is real
        if hb.latch_watchdog and not stale and not self._watchdog_counted:
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
            self._last_hello = -math.inf
        if self._state is LinkState.LOST:
            logger.info("controller heartbeats again; new session")
            self._set_state(LinkState.HANDSHAKE)
            self._hello_sent = False
            self._last_hello = -math.inf
        # The heartbeat is the authority on the conditions (FAULT frames may be lost).
        self._faults = {code for code in FaultCode if hb.fault_bits & fault_bit(code)}
        self._maybe_clear(hb, t)

    def _learn_gen(self, hb: Heartbeat) -> None:
        """A HEARTBEAT of this boot: learn its latch generation, after reporting every
        stopping cause it shows that no FAULT frame reported."""
        self._latch_gen = hb.latch_gen
        reported_now = False
        if self._ctrl_latched:
            if hb.latch_watchdog and "watchdog" not in self._reported:
                self._reported.add("watchdog")
                self._emit(fault("watchdog"))
                reported_now = True
            if hb.latch_fault and "fault" not in self._reported:
                self._reported.add("fault")
                self._emit(fault(self._latched_fault_name(hb)))
                reported_now = True
        elif not hb.stop_latched:
            self._reported.clear()
        clear = self._pending_clear
        if clear is not None and clear.latch_gen is None and not clear.after_stop:
            if reported_now:
                # Asked for before this cause was reported: it may not release it.
                self._refuse_operator_clear("latch_changed")
            else:
                clear.latch_gen = hb.latch_gen

    def _latched_fault_name(self, hb: Heartbeat) -> str:
        """The stopping fault behind ``latch_fault``: active now, else the last raised."""
        for code in sorted(STOPPING_FAULTS):
            if code != FaultCode.WATCHDOG and hb.fault_bits & fault_bit(code):
                return FaultCode(code).name.lower()
        if self._last_stopping_fault is not None:
            return FaultCode(self._last_stopping_fault).name.lower()
        return "fault"

    def _refuse_operator_clear(self, why: str) -> None:
        """The operator's clear released nothing (``why``: ``fault_persists``,
        ``latch_changed``): said once; the request is over, and the steps that waited for
        it are refused."""
        self._emit(fault(why))
        self._end_clear(
            "fault_active" if self._ctrl_state == ControllerState.FAULT else "stop_latched"
        )

    def _auto_clear_may_start(self, hb: Heartbeat) -> bool:
        """The latch ``hb`` shows is the host's to clear on its own: the watchdog alone
        holds it (docs/protocol.md, "Latch and faults": Host: automatic clear)."""
        return bool(hb.latch_watchdog and not hb.latch_stop and not hb.latch_fault)

    def _maybe_clear(self, hb: Heartbeat, now: float) -> None:
        """Start the automatic clear of a watchdog-only latch, naming this HEARTBEAT's
        generation; end one the latch has outgrown."""
        if self._state is not LinkState.READY or not hb.handshake_ok:
            return
        clear = self._pending_clear
        if (
            clear is not None
            and clear.auto
            and self._ctrl_latched
            and (not self._auto_clear_may_start(hb) or hb.latch_gen != clear.latch_gen)
            and self._auto_clear_outlived(hb)
        ):
            return
        if self._pending_clear is not None or self._estop_requested or not self._ctrl_latched:
            return
        if any(hb.fault_bits & fault_bit(code) for code in STOPPING_FAULTS):
            return
        if not (self.config.auto_clear_watchdog and self._auto_clear_may_start(hb)):
            return
        # At most one new request per controller heartbeat period (a heartbeat sent
        # before our CLEAR_STOP arrived still shows the latch).
        if now - self._last_auto_clear < self.config.controller_heartbeat_s:
            return
        self._last_auto_clear = now
        self._stop_counter = self._stop_counter % 0xFFFF + 1
        self._pending_clear = _Pending(
            self._stop_counter, now, 0.0, 0, latch_gen=hb.latch_gen, auto=True
        )
        logger.info("watchdog latch with its condition gone: clearing it (auto_clear_watchdog)")

    def _auto_clear_outlived(self, hb: Heartbeat) -> bool:
        """A HEARTBEAT shows the latch gained a cause the automatic clear was not for (an
        emergency stop, a stopping fault, a new trip): that clear is over, the operator
        decides now. Returns whether it ended."""
        self._abandon_auto_clear(hb)
        return True

    def _abandon_auto_clear(self, hb: Heartbeat | None) -> None:
        """End the automatic clear request: the latch's causes changed."""
        clear = self._pending_clear
        if clear is None or not clear.auto:
            return
        self._pending_clear = None
        causes = ",".join(latch_causes(hb)) if hb is not None else "a stopping fault"
        logger.warning(
            "automatic clear abandoned: the latch now holds %s; clear_emergency_stop "
            "(the operator) releases it",
            causes,
        )

    def _check_reboot(self, nonce: int, now: float, *, sign: str = "") -> bool:
        """A HEARTBEAT's or IDENT's boot nonce: the first one known (from either), the
        same boot, or a reboot (handled here). ``sign``: another sign of a reboot on a
        serial link (an IDENT that restarted the frame counter; a HEARTBEAT without the
        session it had confirmed): a reboot whatever the nonce."""
        if self._boot_nonce is None:
            self._boot_nonce = nonce
            return False
        if nonce == self._boot_nonce and not sign:
            return False
        if nonce == self._boot_nonce:
            logger.warning(
                "controller rebooted with the boot nonce 0x%04X of the boot before (%s): a "
                "new boot's nonce must differ (docs/protocol.md, Handshake 1)",
                nonce,
                sign,
            )
        self._boot_nonce = nonce
        self._counters.reboots += 1
        # The controller's frame counter restarted with it (docs/protocol.md, Serial
        # framing): the gap it made since the last frame of the old boot is no loss.
        if self._connected:
            self._lost_forgiven += self._rx_lost - self._lost_mark
            self._lost_mark = self._rx_lost
        self._watchdog_counted = False
        logger.warning("controller rebooted (boot nonce 0x%04X); steps in flight dropped", nonce)
        self._drop_all(aborted("controller_reboot"))
        self._emit(fault("controller_reboot"))
        self._set_state(LinkState.HANDSHAKE)
        self._hello_sent = False
        self._last_hello = -math.inf
        self._faults.clear()
        self._ctrl_latched = False
        self._stop_acked_gen = None
        self._ctrl_state = ControllerState.BOOT
        # The latch went with the reboot, and every request about it.
        self._pending_clear = None
        self._latch_gen = self._released_gen = None
        self._reported.clear()
        self._pending_stop = None
        if self._estop_requested:
            self._pending_stop = _Pending(self._stop_counter, now, 0.0, 0)  # re-latch at once
        return True

    def _on_ident(self, ident: Ident, now: float, *, sign: str = "") -> None:
        self._ident = ident
        if not self._check_reboot(ident.boot_nonce, now, sign=sign):
            self._lost_mark = self._rx_lost
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
            self._session_confirmed = False
            self._backoff = self.config.reconnect_min_s
            self._ended_seen = 0  # the controller counts per session
            self._last_hb_rx = now
            logger.info(
                "handshake done: firmware %d.%d.%d, boot nonce 0x%04X",
                ident.firmware_major,
                ident.firmware_minor,
                ident.firmware_patch,
                ident.boot_nonce,
            )
            self._emit(READY)
            if self._estop_requested and self._pending_stop is None and not self._ctrl_latched:
                self._pending_stop = _Pending(self._stop_counter, now, 0.0, 0)

    def _on_clear_ack(self, ack: ClearAck, t: float) -> None:
        self._latch_gen = ack.latch_gen
        clear = self._pending_clear
        if clear is None or ack.stop_id != clear.stop_id:
            return
        self._pending_clear = None
        if ack.result in (ClearResult.FAULT_PERSISTS, ClearResult.LATCH_CHANGED):
            if clear.auto:
                # Not the host's to clear any more.
                self._pending_clear = clear
                self._auto_clear_refused()
                return
            self._pending_clear = clear
            self._refuse_operator_clear(
                "fault_persists" if ack.result == ClearResult.FAULT_PERSISTS else "latch_changed"
            )
            return
        if ack.result == ClearResult.CLEARED:
            self._released_gen = clear.latch_gen
            self._reported.clear()
            self._settle_latched()
        self._ctrl_latched = False
        self._stop_acked_gen = None
        self._ctrl_state = ControllerState.IDLE
        if ack.result == ClearResult.CLEARED or not clear.auto:
            self._emit(CLEARED)
        self._pump(t)

    def _auto_clear_refused(self) -> bool:
        """The automatic clear was answered FAULT_PERSISTS or LATCH_CHANGED: the latch is
        not the host's to clear any more; the request ends. Returns whether it ended."""
        self._abandon_auto_clear(self._heartbeat)
        return True

    def _on_ack(self, ack: Ack, t: float) -> None:
        step = self._inflight
        if step is None or ack.seq != step.seq:
            return  # a late duplicate ACK of a step already settled
        self._inflight = None
        if step.sends == 1:
            self._counters.rtts.append(t - step.first_sent)
        if ack.result in (AckResult.ACCEPTED, AckResult.DUPLICATE):
            self._in_controller[step.seq] = step
            self._emit(ACCEPTED, step.number)
        else:
            self._counters.steps_rejected += 1
            reason = _ACK_REASONS.get(AckResult(ack.result), f"nack_{ack.result}")
            if ack.result == AckResult.OUT_OF_RANGE and ack.field != AckField.NONE:
                reason += f":{AckField(ack.field).name.lower()}"
            self._counters.rejected[reason] += 1
            self._emit(rejected(reason), step.number)
        self._pump(t)

    def _on_status_msg(self, status: Status, t: float) -> None:
        if status.state == StepState.STARTED:
            return
        self._ended_seen = (self._ended_seen + 1) & 0xFFFF
        if status.seq in self._in_controller:
            self._settle_through(status.seq, status.state, status.reason)
            self._pump(t)

    def _settle_through(self, seq: int, state: int, reason: int) -> None:
        """Step ``seq`` ended with this outcome; steps sent before it ended too (steps end
        in order), so any still open lost their STATUS and get the same outcome."""
        for open_seq, step in list(self._in_controller.items()):
            del self._in_controller[open_seq]
            if state == StepState.COMPLETED:
                self._counters.steps_completed += 1
                self._emit(COMPLETED, step.number)
            else:
                self._counters.steps_aborted += 1
                self._emit(aborted(AbortReason(reason).name.lower()), step.number)
            if open_seq == seq:
                return

    def _on_progress(self, progress: Progress, t: float) -> None:
        """Settle steps whose STATUS was lost (docs/protocol.md, MOTION): every open step
        sent up to ``ended_seq`` has ended, also when ``ended_seq`` itself is no longer
        open."""
        missed = (progress.ended_count - self._ended_seen) & 0xFFFF
        if missed == 0 or missed >= 0x8000 or self._state is not LinkState.READY:
            return
        self._ended_seen = progress.ended_count
        ended = self._ended_by_progress(progress)
        if not ended:
            return  # its ending was seen; steps before it were settled with it
        logger.warning(
            "%d STATUS frame(s) lost; settling through seq %d from PROGRESS",
            missed,
            ended[-1],
        )
        self._settle_through(ended[-1], progress.ended_state, progress.ended_reason)
        self._pump(t)

    def _ended_by_progress(self, progress: Progress) -> list[int]:
        """The open steps (by seq, in order) that ``progress`` says have ended: every one
        sent up to its ``ended_seq``."""
        return [seq for seq in self._in_controller if (progress.ended_seq - seq) & 0xFFFF < 0x8000]

    def _settle_latched(self) -> None:
        """The controller's latch was released: every step still open here ended when it
        was set (a latch purges the queue), its STATUS lost. It is reported aborted, with
        the latch's cause, never completed (its outcome is not known)."""
        if not self._in_controller:
            return
        causes = self.latch
        if "stop" in causes or not causes:
            reason = "stop"
        elif "fault" in causes:
            stall = self._last_stopping_fault in (FaultCode.STALL_LEFT, FaultCode.STALL_RIGHT)
            reason = "stall" if stall else "fault"
        else:
            reason = "watchdog"
        logger.warning(
            "latch released with %d step(s) whose end was never reported: aborted:%s",
            len(self._in_controller),
            reason,
        )
        for step in self._in_controller.values():
            self._counters.steps_aborted += 1
            self._emit(aborted(reason), step.number)
        self._in_controller.clear()

    def _on_fault(self, msg: Fault) -> None:
        self._latch_gen = msg.latch_gen
        name = (
            FaultCode(msg.code).name.lower()
            if msg.code in FaultCode._value2member_map_
            else str(msg.code)
        )
        if msg.active:
            if msg.code in STOPPING_FAULTS and msg.code != FaultCode.WATCHDOG:
                self._stopping_fault_frame(msg.code)
                self._reported.add("fault")
            if msg.code == FaultCode.WATCHDOG:
                self._reported.add("watchdog")
                if self._new_watchdog_trip(msg):
                    # A trip (see _new_watchdog_trip).
                    self._counters.watchdog_trips += 1
                self._watchdog_counted = True
            self._faults.add(msg.code)
            self._emit(fault(name))
            if msg.code in STOPPING_FAULTS:
                self._stopping_cause_reported()
        else:
            # The condition went away; a latch it set is the heartbeat's to report.
            self._faults.discard(msg.code)

    def _stopping_cause_reported(self) -> None:
        """A stopping cause was reported now: an operator's clear asked for before this
        host knew any latch generation may not release it; it is refused
        (``fault:latch_changed``), and a new clear releases (docs/protocol.md)."""
        clear = self._pending_clear
        if clear is not None and not clear.auto and clear.latch_gen is None:
            self._refuse_operator_clear("latch_changed")

    def _stopping_fault_frame(self, code: int) -> None:
        """A stopping fault other than WATCHDOG was raised: remember it, and end an
        automatic clear that is out at once (no copy of it may follow)."""
        self._last_stopping_fault = code
        self._abandon_auto_clear(None)

    def _new_watchdog_trip(self, msg: Fault) -> bool:
        """A WATCHDOG FAULT ``active = 1`` is a new trip unless its condition is already
        active: the same frame received twice (a CAN frame whose acknowledgement the
        controller missed is sent again) is not two."""
        return msg.code not in self._faults

    # -- the lanes ----------------------------------------------------------------------------
    def _queue(self, msg: Message, step: _Step | None = None, *, auto_clear: bool = False) -> None:
        """Queue a frame for the writer; dropped if no transport is open."""
        if self._connected:
            self._tx.append(Outgoing(msg, self._conn, step, auto_clear))
            if step is not None:
                step.unwritten += 1

    def _unqueue(self, kind: type[Message]) -> None:
        """Take every frame of ``kind`` not yet taken by the writer out of its queue."""
        if any(isinstance(entry.msg, kind) for entry in self._tx):
            kept = [entry for entry in self._tx if not isinstance(entry.msg, kind)]
            self._tx.clear()
            self._tx.extend(kept)

    def _pump(self, now: float) -> None:
        """Queue the lane's head, or its retransmission on ack timeout."""
        step = self._inflight
        if step is not None:
            if step.unwritten or now < step.last_sent + self.config.ack_timeout_s:
                return
            if step.sends > self.config.motion_retries:
                self._inflight = None
                self._counters.no_ack_faults += 1
                # Steps already in the controller are older: their fates come first.
                older = list(self._in_controller.values())
                self._in_controller.clear()
                for old in older:
                    self._counters.steps_aborted += 1
                    self._emit(aborted("link_lost"), old.number)
                self._counters.steps_aborted += 1
                self._emit(fault("no_ack"), step.number)
                self._lose(f"MOTION seq {step.seq} not acknowledged after {step.sends} tries")
                return
            step.sends += 1
            step.last_sent = now
            self._queue(self._motion(step), step)
        elif (
            self._lane
            and len(self._in_controller) < self.config.controller_queue
            and self.ready
            and not self._operator_clear_out()
        ):
            step = self._lane.popleft()
            self._seq = (self._seq + 1) & 0xFFFF
            step.seq = self._seq
            step.sends = 1
            step.first_sent = step.last_sent = now
            self._inflight = step
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
        """No controller heartbeat for ``silence_s``: the link is lost."""
        self._counters.heartbeat_losses += 1
        self._counters.lost_after_beats = int(silence_s / self.config.controller_heartbeat_s)
        self._lose(
            f"no controller heartbeat for {silence_s:.2f} s "
            f"({self._counters.lost_after_beats} beats missed)"
        )

    def _lose(self, why: str) -> None:
        """The controller stopped answering: report, drop every step, re-handshake."""
        logger.warning("link lost: %s", why)
        self._last_error = why
        self._set_state(LinkState.LOST)
        self._hello_sent = False
        self._drop_all(aborted("link_lost"))
        self._emit(fault("link_lost"))

    def _set_state(self, state: LinkState) -> None:
        """Change the link state; reported in order with the statuses."""
        if state is not self._state:
            self._state = state
            self._outbox.append(state)

    def _emit(self, text: str, step: int | None = None) -> None:
        self._outbox.append(StatusEvent(text, step))

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
        self._unqueue(Motion)  # a dropped step must never reach the controller
        for step in dropped:
            self._counters.steps_aborted += 1
            self._emit(status, step.number)
        if dropped:
            logger.info("%d step(s) dropped (%s); none will be replayed", len(dropped), status)

    def _purge(self, status: str) -> None:
        """Drop steps not yet in the controller (it reports its own ABORTED)."""
        pending = ([self._inflight] if self._inflight else []) + list(self._lane)
        self._inflight = None
        self._lane.clear()
        self._unqueue(Motion)
        for step in pending:
            self._counters.steps_aborted += 1
            self._emit(status, step.number)

    # -- diagnostics ---------------------------------------------------------------------------
    def diagnostics(
        self,
        now: float,
        medium: MediumStats | None = None,
        *,
        stalls: int = 0,
        stall_max_ms: float = 0.0,
    ) -> LinkDiagnostics:
        """A snapshot for ``/diagnostics`` at ``now``, with what the transport knows
        (``medium``) and this process's stalls (docs/realtime.md)."""
        m = medium or MediumStats()
        hb = self._heartbeat
        ident = self._ident
        rtts = list(self._counters.rtts)
        c = self._counters
        age = now - self._last_hb_rx if self._last_hb_rx is not None else None
        rx_gaps, tx_gaps = self._hb_rx_gaps.summary(), self._hb_tx_gaps.summary()
        return LinkDiagnostics(
            state=self._state.value,
            url=self.config.url,
            connected=m.connected,
            missed_beats=int(age / self.config.controller_heartbeat_s) if age else 0,
            lost_after_beats=c.lost_after_beats,
            heartbeat_losses=c.heartbeat_losses,
            reconnects=c.reconnects,
            reboots=c.reboots,
            rtt_ms=rtts[-1] * 1e3 if rtts else None,
            rtt_median_ms=statistics.median(rtts) * 1e3 if rtts else None,
            heartbeat_age_s=age,
            rx_frames=m.rx_frames,
            tx_frames=m.tx_frames,
            crc_errors=m.crc_errors,
            resyncs=m.resyncs,
            rx_dropped=m.rx_dropped,
            rx_overflow=m.rx_overflow,
            lost_frames=max(0, m.rx_lost - self._lost_forgiven) if m.connected else 0,
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
                sorted(FaultCode(f).name for f in self._faults if f in FaultCode._value2member_map_)
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
            medium_state=m.medium_state,
            medium_errors=m.medium_errors,
            latch=self.latch,
            latch_fault=FaultCode(self._last_stopping_fault).name
            if self._last_stopping_fault is not None
            else "",
            heartbeat_rx_gap_max_ms=rx_gaps.max_ms,
            heartbeat_rx_gap_p99_ms=rx_gaps.p99_ms,
            heartbeat_tx_gap_max_ms=tx_gaps.max_ms,
            heartbeat_tx_gap_p99_ms=tx_gaps.p99_ms,
            samples_outside_session=c.samples_outside_session,
            stalls=stalls,
            stall_max_ms=stall_max_ms,
        )
