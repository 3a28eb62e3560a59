"""CAN endpoint: frames of docs/protocol.md on any python-can bus, for either side.

``socketcan`` on Linux, ``virtual`` in-process, any other python-can interface by name.
Identifiers and payloads are :mod:`firmware_proto.wire.canmap`'s; the bus arbitrates by
identifier, so the STOP lane wins by itself. A host takes its controller node's frames;
a controller its own node's and broadcasts (node 0); other frames decoded count as
:attr:`~firmware_proto.linkio.endpoint.Endpoint.foreign`.

**Bus health.** The fault-confinement state (error-active, error-warning, error-passive,
bus-off) is read from SocketCAN error frames (:func:`decode_error_frame`, pure) and from
``bus.state`` where an interface reports it. Every error frame is counted
(:attr:`CanEndpoint.error_frames`), a change of state is logged once and counted
(:attr:`CanEndpoint.state_changes`) and shows in :attr:`CanEndpoint.medium_state`. On
the host side bus-off is a failure of the medium (``read`` raises OSError: the link
reconnects); the emulated controller counts it and carries on.
"""

from __future__ import annotations

import logging
import random
import time
from dataclasses import dataclass
from typing import Any

import can

from firmware_proto.linkio.endpoint import HOST, Endpoint, Side
from firmware_proto.linkio.errors import LinkUrlError
from firmware_proto.linkio.trafficio import can_record
from firmware_proto.linkio.trafficlog import CanRecord, TrafficRecord, TrafficRecorder
from firmware_proto.linkio.urls import parse_can_url
from firmware_proto.wire.canmap import CanDecoder, can_id, encode_can
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import BROADCAST_NODE, DEFAULT_NODE

__all__ = [
    "BUS_OFF",
    "CAN_ERR_BUSOFF",
    "CAN_ERR_CRTL",
    "CAN_ERR_CRTL_ACTIVE",
    "CAN_ERR_CRTL_RX_PASSIVE",
    "CAN_ERR_CRTL_RX_WARNING",
    "CAN_ERR_CRTL_TX_PASSIVE",
    "CAN_ERR_CRTL_TX_WARNING",
    "CAN_ERR_FLAG",
    "CAN_ERR_RESTARTED",
    "CAN_STATES",
    "ERROR_ACTIVE",
    "ERROR_PASSIVE",
    "ERROR_WARNING",
    "CanEndpoint",
    "CanErrorFrame",
    "decode_error_frame",
    "open_bus",
]

logger = logging.getLogger(__name__)

# linux/can/error.h (and linux/can.h for the flag).
CAN_ERR_FLAG = 0x20000000
"""Set in a SocketCAN ``can_id`` for an error frame (python-can: ``is_error_frame``)."""
CAN_ERR_MASK = 0x1FFFFFFF
CAN_ERR_CRTL = 0x004
"""Class bit: controller problems, detail in ``data[1]``."""
CAN_ERR_BUSOFF = 0x040
"""Class bit: the controller went bus-off."""
CAN_ERR_RESTARTED = 0x100
"""Class bit: the controller restarted (after bus-off); error-active again."""
CAN_ERR_CRTL_RX_OVERFLOW = 0x01
CAN_ERR_CRTL_TX_OVERFLOW = 0x02
CAN_ERR_CRTL_RX_WARNING = 0x04
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40

ERROR_ACTIVE, ERROR_WARNING, ERROR_PASSIVE, BUS_OFF = (
    "error_active",
    "error_warning",
    "error_passive",
    "bus_off",
)
CAN_STATES = (ERROR_ACTIVE, ERROR_WARNING, ERROR_PASSIVE, BUS_OFF)
"""Fault-confinement states of :attr:`CanTransport.medium_state`, in order of severity."""


@dataclass(frozen=True)
class CanErrorFrame:
    """What one SocketCAN error frame says.

    Attributes:
        classes: the error class bits (``CAN_ERR_*``), flag removed.
        controller: ``data[1]``, the controller detail bits (``CAN_ERR_CRTL_*``); 0 without
            a ``CAN_ERR_CRTL`` class or such a byte.
        state: the fault-confinement state it reports (:data:`CAN_STATES`), or ``None``
            (lost arbitration, a protocol error, an overflow).
    """

    classes: int
    controller: int
    state: str | None


def decode_error_frame(arbitration_id: int, data: bytes) -> CanErrorFrame:
    """Decode an error frame's id and payload (linux/can/error.h); pure, never raises.

    Bus-off wins over a restart, a restart over the controller bits, and among those the
    most severe state set (passive over warning over active).
    """
    classes = arbitration_id & CAN_ERR_MASK
    controller = data[1] if classes & CAN_ERR_CRTL and len(data) > 1 else 0
    state: str | None = None
    if classes & CAN_ERR_BUSOFF:
        state = BUS_OFF
    elif classes & CAN_ERR_RESTARTED:
        state = ERROR_ACTIVE
    elif controller & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
        state = ERROR_PASSIVE
    elif controller & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING):
        state = ERROR_WARNING
    elif controller & CAN_ERR_CRTL_ACTIVE:
        state = ERROR_ACTIVE
    return CanErrorFrame(classes, controller, state)


_BUS_STATES = {can.BusState.ACTIVE: ERROR_ACTIVE, can.BusState.PASSIVE: ERROR_PASSIVE}


def open_bus(interface: str, channel: str, **options: Any) -> can.BusABC:
    """Open a python-can bus; OSError naming the interface when it is unknown or the channel
    cannot be opened (``socketcan`` on a kernel without SocketCAN)."""
    try:
        return can.Bus(interface=interface, channel=channel, **options)
    except (can.CanError, OSError, ImportError, ValueError, NotImplementedError) as exc:
        raise OSError(f"cannot open CAN bus {interface}:{channel}: {exc}") from exc


class CanEndpoint(Endpoint):
    """One node's end of the link on a CAN bus (see the module docstring); its counters are
    per connection and only grow."""

    medium = "can"

    def __init__(
        self,
        side: Side,
        interface: str,
        channel: str,
        *,
        node: int = DEFAULT_NODE,
        bus: can.BusABC | None = None,
        send_timeout_s: float = 0.1,
        recorder: TrafficRecorder | None = None,
        **bus_options: Any,
    ) -> None:
        """Args:
        side: which end of the link this is.
        interface, channel: the python-can interface and channel (``socketcan``, ``vcan0``);
            ``interface`` is checked against python-can's list unless ``bus`` is given.
        node: the controller's node id, 1..15 (a host's peer, or the controller itself).
        bus: an already open bus to use (the caller keeps ownership).
        send_timeout_s: longest wait for room in the transmit queue, s.
        recorder: a first listener; as a bus monitor it sees other nodes' frames too.
        bus_options: passed to ``can.Bus`` (e.g. ``bitrate``).

        Raises:
            LinkUrlError: node id outside 1..15, or an interface python-can does not know.
        """
        super().__init__(side, recorder=recorder)
        if not isinstance(node, int) or not 1 <= node <= 15:
            raise LinkUrlError(f"CAN node id must be 1..15, got {node!r}")
        if bus is None and interface not in can.interfaces.VALID_INTERFACES:
            known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
            raise LinkUrlError(f"unknown python-can interface {interface!r}; known: {known}")
        self.interface, self.channel, self.node = interface, channel, node
        self._ours = (node,) if side == HOST else (node, BROADCAST_NODE)
        """The nodes whose frames this side takes."""
        self._given_bus = bus
        self._bus: can.BusABC | None = None
        self._bus_options = bus_options
        self._send_timeout_s = send_timeout_s
        self.decoder = CanDecoder()
        self.counters = self.decoder.counters
        self.error_frames = 0
        self.state_changes: dict[str, int] = dict.fromkeys(CAN_STATES, 0)
        self._can_state = ERROR_ACTIVE
        self._polled_state: can.BusState | None = None

    @classmethod
    def for_url(
        cls,
        side: Side,
        url: str,
        *,
        node: int | None = None,
        recorder: TrafficRecorder | None = None,
        **bus_options: Any,
    ) -> CanEndpoint:
        """An endpoint on ``can://INTERFACE/CHANNEL[?node=N&OPTION=VALUE...]``; ``node``
        and ``bus_options`` override the URL's.

        Raises:
            LinkUrlError: malformed URL, node id out of range, unknown interface.
        """
        interface, channel, options = parse_can_url(url)
        url_node = options.pop("node", DEFAULT_NODE)
        try:
            return cls(
                side,
                interface,
                channel,
                node=node if node is not None else url_node,
                recorder=recorder,
                **{**options, **bus_options},
            )
        except LinkUrlError as exc:
            raise LinkUrlError(f"{url!r}: {exc}") from exc

    @property
    def name(self) -> str:
        return f"{self.interface}:{self.channel}"

    @property
    def medium_state(self) -> str:
        """The bus's fault-confinement state as last reported: ``error_active``,
        ``error_warning``, ``error_passive`` or ``bus_off`` (:data:`CAN_STATES`)."""
        return self._can_state

    @property
    def medium_errors(self) -> int:
        """Error frames received."""
        return self.error_frames

    @property
    def can_corrupt(self) -> bool:
        return False

    def _open(self) -> None:
        bus = self._given_bus
        self._bus = (
            bus if bus is not None else open_bus(self.interface, self.channel, **self._bus_options)
        )
        logger.info("%s: CAN %s, node %d", self.side, self.name, self.node)

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None and bus is not self._given_bus:
            bus.shutdown()

    def _enter(self, state: str, why: str) -> None:
        """Reader thread: the bus reported ``state``; log and count a transition once."""
        if state == self._can_state:
            return
        previous, self._can_state = self._can_state, state
        self.state_changes[state] += 1
        level = logging.INFO if state == ERROR_ACTIVE else logging.WARNING
        if state == BUS_OFF:
            level = logging.ERROR
        logger.log(level, "CAN %s: %s -> %s (%s)", self.name, previous, state, why)

    def read(self, timeout_s: float) -> list[Message]:
        bus = self._bus
        if bus is None:
            raise OSError(f"CAN {self.name} is closed")
        try:
            frame = bus.recv(timeout=timeout_s)
        except can.CanError as exc:
            raise OSError(f"CAN receive failed: {exc}") from exc
        self._poll_state(bus)
        if frame is None:
            return []
        if self.recording:
            received_at = frame.timestamp or time.time()
            self._emit(can_record(frame, self.channel, is_rx=True, time_s=received_at))
        if frame.is_error_frame:
            self._on_error_frame(frame)
            return []
        decoded = self.decoder.decode(
            frame.arbitration_id,
            bytes(frame.data),
            is_extended=frame.is_extended_id,
            is_remote=frame.is_remote_frame,
        )
        if decoded is None:
            return []
        if decoded.node not in self._ours or not self.takes(decoded.message):
            self.foreign += 1
            return []
        return [decoded.message]

    def _send(self, message: can.Message) -> None:
        bus = self._bus
        if bus is None:
            raise OSError(f"CAN {self.name} is closed")
        try:
            bus.send(message, timeout=self._send_timeout_s)
        except can.CanError as exc:
            raise OSError(f"CAN send failed: {exc}") from exc

    def write(self, message: Message, *, corrupt: random.Random | None = None) -> bool:
        if corrupt is not None:
            raise ValueError("a CAN frame's CRC is the bus's: it cannot be sent damaged")
        arbitration_id, data = encode_can(message, self.node)
        if self.recording:
            # Logged before the send, so the log keeps the wire's order.
            self._emit(CanRecord(time.time(), self.channel, arbitration_id, data, is_rx=False))
        self._send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))
        return True

    def write_raw(self, msg_id: int, payload: bytes, *, bad_crc: bool = False) -> None:
        if bad_crc:
            raise ValueError("a CAN frame's CRC is the bus's: it cannot be sent damaged")
        if len(payload) > 8:
            raise ValueError(f"a classic CAN frame carries at most 8 bytes, not {len(payload)}")
        self._send(
            can.Message(
                arbitration_id=can_id(msg_id, self.node), data=payload, is_extended_id=False
            )
        )

    def write_record(self, record: TrafficRecord) -> None:
        if not isinstance(record, CanRecord):
            raise TypeError("a CAN endpoint replays CAN records")
        self._send(
            can.Message(
                arbitration_id=record.arbitration_id,
                data=record.data,
                is_extended_id=record.is_extended_id,
                is_remote_frame=record.is_remote_frame,
            )
        )

    def _poll_state(self, bus: can.BusABC) -> None:
        """Follow ``bus.state`` where the interface reports it; only a change counts, since
        interfaces that do not report always say ACTIVE.

        Raises:
            OSError: host side, the interface says bus-off (BusState.ERROR).
        """
        try:
            state = bus.state
        except (can.CanError, NotImplementedError, OSError) as exc:
            logger.debug("CAN %s: bus state unavailable: %s", self.channel, exc)
            return
        if state == self._polled_state:
            return
        first, self._polled_state = self._polled_state is None, state
        if state == can.BusState.ERROR:
            self._enter(BUS_OFF, "interface bus state ERROR")
            if self.side == HOST:
                raise OSError(f"CAN {self.name}: bus off (interface state)")
        elif state in _BUS_STATES and not (first and state == can.BusState.ACTIVE):
            self._enter(_BUS_STATES[state], f"interface bus state {state.name}")

    def _on_error_frame(self, frame: can.Message) -> None:
        """Reader thread: count and act on one error frame; OSError on the host at bus-off."""
        self.error_frames += 1
        report = decode_error_frame(frame.arbitration_id, bytes(frame.data))
        logger.debug(
            "CAN %s: error frame class 0x%03X controller 0x%02X",
            self.channel,
            report.classes,
            report.controller,
        )
        if report.state is None:
            return
        self._enter(report.state, f"error frame class 0x{report.classes:03X}")
        if report.state == BUS_OFF and self.side == HOST:
            raise OSError(f"CAN {self.name}: bus off (error frame)")
