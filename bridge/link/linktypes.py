"""The values the host side of the link exchanges: its configuration, its state, a step
request, the events it reports and its diagnostics snapshot.

Shared by the pure core (:mod:`bridge.link.linkcore`), its threaded shell
(:mod:`bridge.link.controllerlink`) and the simulator that drives the core in virtual time. Pure: no
I/O, no clock.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    ACK_TIMEOUT_MS,
    CONTROLLER_HEARTBEAT_PERIOD_MS,
    HOST_HEARTBEAT_PERIOD_MS,
    LINK_LOST_HEARTBEATS,
    MOTION_QUEUE_DEPTH,
    MOTION_RETRIES,
    STOP_REPEAT_MS,
    Encoders,
    Imu,
    PoseMsg,
    WheelSpeeds,
)

__all__ = [
    "SAMPLE_MESSAGES",
    "LinkConfig",
    "LinkDiagnostics",
    "LinkState",
    "MediumStats",
    "StatusEvent",
    "StepRequest",
]


SAMPLE_MESSAGES: tuple[type[Message], ...] = (Encoders, WheelSpeeds, Imu, PoseMsg)
"""Periodic sensor samples: forwarded only in a session; a full receive queue drops only them."""


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
        url: transport URL (see :mod:`bridge.link.transport`).
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


@dataclass(frozen=True)
class StatusEvent:
    """One ``/command_status`` string the link reports, in order.

    Attributes:
        text: the status (``accepted``, ``completed``, ``rejected:<reason>``, ...).
        step: the number :meth:`LinkCore.submit_step <bridge.link.linkcore.LinkCore.submit_step>`
            gave the step this status is about (its fate or its acceptance), ``None`` for
            a link or latch event (``ready``, ``stopped``, ``cleared``, ``fault:link_lost``,
            a controller fault).
    """

    text: str
    step: int | None = None


@dataclass(frozen=True)
class MediumStats:
    """What the transport knows of the medium, for :class:`LinkDiagnostics` (zeros and
    ``medium_state`` ``n/a`` while there is no transport).

    Attributes:
        connected: a transport is open.
        rx_frames: frames received and decoded.
        tx_frames: frames written (STOPs included).
        crc_errors, resyncs, rx_dropped: receive errors (resyncs: framing and oversize;
            rx_dropped: every rejected frame).
        rx_lost: gaps in the controller's frame counter, as the decoder counts them
            (before the link forgives a reboot's restart).
        rx_overflow: sensor samples dropped because the receive queue was full.
        medium_state, medium_errors: the medium's own condition (CAN: fault
            confinement) and error count.
    """

    connected: bool = False
    rx_frames: int = 0
    tx_frames: int = 0
    crc_errors: int = 0
    resyncs: int = 0
    rx_dropped: int = 0
    rx_lost: int = 0
    rx_overflow: int = 0
    medium_state: str = "n/a"
    medium_errors: int = 0


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
    """Sensor samples dropped because the receive queue was full (bridge.link.transport)."""
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
    """What holds the controller's latch (``stop``, ``watchdog``, ``fault``), per its HEARTBEAT."""
    latch_fault: str = ""
    """Last stopping fault but WATCHDOG raised since the link began (``""``: none)."""
    heartbeat_rx_gap_max_ms: float | None = None
    """Longest gap between two controller HEARTBEATs on one connection, ms (their period: 100)."""
    heartbeat_rx_gap_p99_ms: float | None = None
    """99th percentile of the last 1,000 such gaps, ms."""
    heartbeat_tx_gap_max_ms: float | None = None
    """Longest gap between two HOST_HEARTBEATs written, ms (their period is ``heartbeat_s``; the
    controller's watchdog stops the rover after 250 ms without a frame)."""
    heartbeat_tx_gap_p99_ms: float | None = None
    """99th percentile of the last 1,000 such gaps, ms."""
    samples_outside_session: int = 0
    """Sensor samples received outside a session, ignored (a conforming controller sends none)."""
    stalls: int = 0
    """Stalls of this process or its loops over the stall threshold (docs/realtime.md)."""
    stall_max_ms: float = 0.0
    """The longest of them, ms."""
