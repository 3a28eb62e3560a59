"""CAN front end: the controller as one node on any python-can bus.

Works with every python-can interface: ``socketcan`` on ``vcan0`` or a real adapter on
Linux, ``virtual`` in-process here and in CI, others by name. The node id (1..15) is
configurable so several controllers can share a bus; frames for other nodes are ignored,
broadcast frames (node 0) are taken. Identifiers and payloads are those of
docs/protocol.md; the bus arbitrates by identifier, so the STOP lane wins by itself.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import can

from emulator.frontend import FrontEnd
from firmware_proto.canmap import CanDecoder, encode_can
from firmware_proto.message import Message
from firmware_proto.messages import BROADCAST_NODE, DEFAULT_NODE
from firmware_proto.trafficio import can_record
from firmware_proto.trafficlog import CanRecord, TrafficRecorder

__all__ = ["CanFrontEnd", "open_bus"]

logger = logging.getLogger(__name__)


def open_bus(interface: str, channel: str, **options: Any) -> can.BusABC:
    """Open a python-can bus, with an error that says which interface failed and why.

    Raises:
        OSError: the interface is unknown or the channel cannot be opened (for example
            ``socketcan`` on a kernel without SocketCAN).
    """
    try:
        return can.Bus(interface=interface, channel=channel, **options)
    except (can.CanError, OSError, ImportError, ValueError, NotImplementedError) as exc:
        raise OSError(f"cannot open CAN bus {interface}:{channel}: {exc}") from exc


class CanFrontEnd(FrontEnd):
    """The controller's node on a CAN bus. See the module docstring."""

    name = "can"

    def __init__(
        self,
        *,
        interface: str = "virtual",
        channel: str = "rover",
        node: int = DEFAULT_NODE,
        bus: can.BusABC | None = None,
        seed: int = 0,
        recorder: TrafficRecorder | None = None,
        **bus_options: Any,
    ) -> None:
        """Args:
        interface, channel: python-can interface name and channel (e.g. ``socketcan``,
            ``vcan0``); ignored when ``bus`` is given.
        node: this controller's node id, 1..15.
        bus: an already open bus to use (the caller keeps ownership).
        seed: seeds the link-fault generators.
        recorder: traffic log for every frame sent and received (see FrontEnd); as a
            bus monitor it sees other nodes' frames too.
        bus_options: passed to ``can.Bus`` (e.g. ``bitrate``).

        Raises:
            ValueError: node out of range.
        """
        super().__init__(seed=seed, recorder=recorder)
        if not 1 <= node <= 15:
            raise ValueError(f"CAN node id must be 1..15, got {node}")
        self.interface, self.channel, self.node = interface, channel, node
        self._bus = bus
        self._own_bus = bus is None
        self._bus_options = bus_options
        self.decoder = CanDecoder()
        self.foreign = 0
        self.error_frames = 0
        """Error frames received (counted, logged at DEBUG, otherwise ignored)."""

    @property
    def device(self) -> str:
        """``interface:channel`` of the bus."""
        return f"{self.interface}:{self.channel}"

    def _open(self) -> None:
        if self._bus is None:
            self._bus = open_bus(self.interface, self.channel, **self._bus_options)
        logger.info("serving node %d on CAN %s", self.node, self.device)

    def _close(self) -> None:
        if self._bus is not None and self._own_bus:
            self._bus.shutdown()
        self._bus = None

    def _can_corrupt(self) -> bool:
        return False

    def _decoder_rejects(self) -> int:
        return self.decoder.counters.rejected

    def _read(self, timeout_s: float) -> list[Message]:
        bus = self._bus
        if bus is None:
            return []
        frame = bus.recv(timeout=timeout_s)
        if frame is None:
            return []
        if self.recorder is not None:
            received_at = frame.timestamp or time.time()
            self._record(can_record(frame, self.channel, is_rx=True, time_s=received_at))
        if frame.is_error_frame:
            self.error_frames += 1
            logger.debug("CAN %s: error frame 0x%03X ignored", self.channel, frame.arbitration_id)
            return []
        decoded = self.decoder.decode(
            frame.arbitration_id,
            bytes(frame.data),
            is_extended=frame.is_extended_id,
            is_remote=frame.is_remote_frame,
        )
        if decoded is None:
            return []
        if (
            decoded.node not in (self.node, BROADCAST_NODE)
            or decoded.message.DIRECTION != "host_to_controller"
        ):
            self.foreign += 1  # another node's traffic, or our own kind echoed back
            return []
        return [decoded.message]

    def _write(self, message: Message, corrupt: bool) -> bool:
        bus = self._bus
        if bus is None:
            return False
        arbitration_id, data = encode_can(message, self.node)
        sent_at = time.time()  # before the send: an answer cannot be logged earlier
        try:
            bus.send(
                can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False),
                timeout=0.05,
            )
        except can.CanError as exc:
            logger.debug("CAN send failed: %s", exc)
            return False
        if self.recorder is not None:
            self._record(CanRecord(sent_at, self.channel, arbitration_id, data, is_rx=False))
        return True
