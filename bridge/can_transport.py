"""CAN transport: protocol frames on any python-can bus.

``can://INTERFACE/CHANNEL?node=N``: ``socketcan`` on Linux (``vcan0`` in CI, a real
adapter such as ``rovercan0`` on the rover), ``virtual`` in-process, any other python-can
interface by name. Other query options go to ``can.Bus`` (e.g. ``bitrate=500000``).
Frames of other nodes and our own frames echoed back are ignored.

**Bus health.** A CAN controller counts transmit and receive errors and moves between
the fault-confinement states *error-active*, *error-warning* (96 errors or more),
*error-passive* (128 or more) and *bus-off* (256 transmit errors: it leaves the bus).
SocketCAN reports these as error frames (``linux/can/error.h``: the ``CAN_ERR_FLAG`` id
flag, class bits in the id, details in the payload), which python-can delivers with
``is_error_frame`` set; a few other interfaces report ``bus.state`` instead. Both are read
(:func:`decode_error_frame` is pure):

- warning, passive, and the return to active: :attr:`CanTransport.medium_state` changes,
  the transition is logged once and counted, and the link stays up (``/diagnostics``
  shows WARN while the bus is not error-active);
- bus-off (an error frame with ``CAN_ERR_BUSOFF``, or ``bus.state`` ERROR), and a send
  that fails: a transport error, so the link reports ``fault:link_lost``, reconnects with
  backoff and shakes hands again;
- other error frames (lost arbitration, protocol violations, no ACK, transceiver,
  controller overflows): counted in :attr:`CanTransport.error_frames`, logged at DEBUG.

Errors, and which are retried: a malformed URL, a node id outside 1..15 and an
interface python-can does not know are :class:`~bridge.errors.TransportUrlError` from
the constructor (permanent); a bus that cannot be opened (adapter absent, interface down,
no SocketCAN in the kernel), bus-off and failed sends are retried by the link.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any

import can

from bridge.errors import TransportUrlError
from bridge.transport import Transport, parse_can_url
from firmware_proto.canmap import CanDecoder, can_id, encode_can
from firmware_proto.message import Message
from firmware_proto.messages import DEFAULT_NODE
from firmware_proto.trafficio import can_record
from firmware_proto.trafficlog import CanRecord, TrafficRecorder

__all__ = [
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
    "CanErrorFrame",
    "CanTransport",
    "decode_error_frame",
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
"""The fault-confinement states :attr:`CanTransport.medium_state` takes, in order of
severity."""


@dataclass(frozen=True)
class CanErrorFrame:
    """What one SocketCAN error frame says.

    Attributes:
        classes: the error class bits (``CAN_ERR_*`` of linux/can/error.h), flag removed.
        controller: ``data[1]``, the controller detail bits (``CAN_ERR_CRTL_*``); 0 when
            the frame has no ``CAN_ERR_CRTL`` class or no such byte.
        state: the fault-confinement state it reports (one of :data:`CAN_STATES`), or
            ``None`` when it reports no state (lost arbitration, a protocol error, an
            overflow).
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


class CanTransport(Transport):
    """Frames of docs/protocol.md on a CAN bus, for one controller node.

    Counters (per connection; they only grow): :attr:`error_frames` (every error frame
    received), :attr:`state_changes` (fault-confinement transitions, by the state
    entered).
    """

    kind = "can"

    def __init__(
        self,
        url: str,
        node: int | None = None,
        recorder: TrafficRecorder | None = None,
        **bus_options: Any,
    ) -> None:
        """Args:
        url: ``can://INTERFACE/CHANNEL[?node=N&OPTION=VALUE...]``.
        node: the controller's node id, 1..15; overrides ``?node=``.
        recorder: traffic log (see :class:`~bridge.transport.Transport`).
        bus_options: passed to ``can.Bus``, over the URL's options.

        Raises:
            TransportUrlError: malformed URL, node id outside 1..15, or an interface
                python-can does not know (permanent; see the module docstring).
        """
        super().__init__(url, recorder)
        self.interface, self.channel, options = parse_can_url(url)
        raw_node = node if node is not None else options.pop("node", DEFAULT_NODE)
        options.pop("node", None)
        if not isinstance(raw_node, int) or not 1 <= raw_node <= 15:
            raise TransportUrlError(f"{url!r}: CAN node id must be 1..15, got {raw_node!r}")
        if self.interface not in can.interfaces.VALID_INTERFACES:
            known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
            raise TransportUrlError(
                f"{url!r}: unknown python-can interface {self.interface!r}; known: {known}"
            )
        self.node = raw_node
        self._bus_options = {**options, **bus_options}
        self._bus: can.BusABC | None = None
        self._decoder = CanDecoder()
        self.counters = self._decoder.counters
        self.foreign = 0
        self.error_frames = 0
        self.state_changes: dict[str, int] = dict.fromkeys(CAN_STATES, 0)
        self._can_state = ERROR_ACTIVE
        self._polled_state: can.BusState | None = None

    @property
    def medium_state(self) -> str:
        """The bus's fault-confinement state as last reported: ``error_active``,
        ``error_warning``, ``error_passive`` or ``bus_off`` (:data:`CAN_STATES`).
        Read-only; ``error_active`` until the bus says otherwise."""
        return self._can_state

    @property
    def medium_errors(self) -> int:
        """Error frames received on this connection."""
        return self.error_frames

    def _enter(self, state: str, why: str) -> None:
        """Reader thread: the bus reported ``state``; log and count a transition once."""
        if state == self._can_state:
            return
        previous, self._can_state = self._can_state, state
        self.state_changes[state] += 1
        level = logging.INFO if state == ERROR_ACTIVE else logging.WARNING
        if state == BUS_OFF:
            level = logging.ERROR
        logger.log(
            level, "CAN %s:%s: %s -> %s (%s)", self.interface, self.channel, previous, state, why
        )

    def _open(self) -> None:
        try:
            self._bus = can.Bus(interface=self.interface, channel=self.channel, **self._bus_options)
        except (can.CanError, ImportError, NotImplementedError) as exc:
            raise OSError(f"CAN {self.interface}:{self.channel}: {exc}") from exc
        logger.info("opened CAN %s:%s for node %d", self.interface, self.channel, self.node)

    def _close(self) -> None:
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def _write(self, message: Message) -> None:
        bus = self._bus
        if bus is None:
            raise OSError("bus closed")
        arbitration_id, data = encode_can(message, self.node)
        if self.recorder is not None:
            # Logged before the send: the reader may log the answer as soon as the frame
            # is out, and the log must keep the wire's order.
            self._record(CanRecord(time.time(), self.channel, arbitration_id, data, is_rx=False))
        try:
            bus.send(
                can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False),
                timeout=0.1,
            )
        except can.CanError as exc:
            raise OSError(f"CAN send failed: {exc}") from exc

    def _write_raw(self, msg_id: int, payload: bytes, bad_crc: bool) -> None:
        bus = self._bus
        if bus is None:
            raise OSError("bus closed")
        if bad_crc:
            raise ValueError("a CAN frame's CRC is the bus's: it cannot be sent damaged")
        if len(payload) > 8:
            raise ValueError(f"a classic CAN frame carries at most 8 bytes, not {len(payload)}")
        try:
            bus.send(
                can.Message(
                    arbitration_id=can_id(msg_id, self.node), data=payload, is_extended_id=False
                ),
                timeout=0.1,
            )
        except can.CanError as exc:
            raise OSError(f"CAN send failed: {exc}") from exc

    def _read(self, timeout_s: float) -> list[Message]:
        bus = self._bus
        if bus is None:
            raise OSError("bus closed")
        try:
            frame = bus.recv(timeout=timeout_s)
        except can.CanError as exc:
            raise OSError(f"CAN receive failed: {exc}") from exc
        self._poll_state(bus)
        if frame is None:
            return []
        if self.recorder is not None:
            received_at = frame.timestamp or time.time()
            self._record(can_record(frame, self.channel, is_rx=True, time_s=received_at))
        if frame.is_error_frame:
            self._on_error_frame(frame)
            return []
        decoded = self._decoder.decode(
            frame.arbitration_id,
            bytes(frame.data),
            is_extended=frame.is_extended_id,
            is_remote=frame.is_remote_frame,
        )
        if decoded is None:
            return []
        if decoded.node != self.node or decoded.message.DIRECTION != "controller_to_host":
            self.foreign += 1
            return []
        return [decoded.message]

    def _poll_state(self, bus: can.BusABC) -> None:
        """Follow ``bus.state`` where the interface reports it. Interfaces that do not
        always say ACTIVE, so only a change of what it says counts (an error frame's
        state is not overridden by a constant ACTIVE).

        Raises:
            OSError: the interface says bus-off (BusState.ERROR).
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
            raise OSError(f"CAN {self.interface}:{self.channel}: bus off (interface state)")
        if state in _BUS_STATES and not (first and state == can.BusState.ACTIVE):
            self._enter(_BUS_STATES[state], f"interface bus state {state.name}")

    def _on_error_frame(self, frame: can.Message) -> None:
        """Reader thread: count and act on one error frame (see the module docstring).

        Raises:
            OSError: the frame reports bus-off.
        """
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
        if report.state == BUS_OFF:
            raise OSError(f"CAN {self.interface}:{self.channel}: bus off (error frame)")
