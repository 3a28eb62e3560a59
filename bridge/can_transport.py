"""CAN transport: protocol frames on any python-can bus.

``can://INTERFACE/CHANNEL?node=N``: ``socketcan`` on Linux (``vcan0`` in CI, a real
adapter such as ``rovercan0`` on the rover), ``virtual`` in-process, any other python-can
interface by name. Other query options go to ``can.Bus`` (e.g. ``bitrate=500000``).
Frames of other nodes and our own frames echoed back are ignored. A bus that goes
bus-off, or whose send fails, is reported as a transport error so the link reconnects.
"""

from __future__ import annotations

import logging
from typing import Any

import can

from bridge.transport import Transport, parse_can_url
from firmware_proto.canmap import CanDecoder, encode_can
from firmware_proto.message import Message
from firmware_proto.messages import DEFAULT_NODE

__all__ = ["CanTransport"]

logger = logging.getLogger(__name__)


class CanTransport(Transport):
    """Frames of docs/protocol.md on a CAN bus, for one controller node."""

    kind = "can"

    def __init__(self, url: str, node: int | None = None, **bus_options: Any) -> None:
        super().__init__(url)
        self.interface, self.channel, options = parse_can_url(url)
        self.node = int(node if node is not None else options.pop("node", DEFAULT_NODE))
        options.pop("node", None)
        if not 1 <= self.node <= 15:
            raise ValueError(f"CAN node id must be 1..15, got {self.node}")
        self._bus_options = {**options, **bus_options}
        self._bus: can.BusABC | None = None
        self._decoder = CanDecoder()
        self.counters = self._decoder.counters
        self.foreign = 0

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
        try:
            bus.send(
                can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False),
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
        if getattr(bus, "state", None) == can.BusState.ERROR:
            raise OSError("CAN bus off")
        if frame is None or frame.is_error_frame:
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
