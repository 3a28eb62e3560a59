"""CAN front end: the controller as one node on any python-can bus, through the link-I/O
layer's CAN endpoint on the controller's side
(:class:`~firmware_proto.linkio.can_endpoint.CanEndpoint`).

Any python-can interface (``socketcan``, ``virtual``, ...). The node id (1..15) lets
controllers share a bus: other nodes' frames are ignored, broadcast (node 0) is taken.
Identifiers and payloads are docs/protocol.md's; arbitration lets the STOP lane win.
"""

from __future__ import annotations

import logging
from typing import Any

import can

from emulator.frontend import FrontEnd
from firmware_proto.linkio.can_endpoint import CanEndpoint
from firmware_proto.linkio.endpoint import CONTROLLER
from firmware_proto.linkio.trafficlog import TrafficRecorder
from firmware_proto.wire.canmap import CanDecoder
from firmware_proto.wire.messages import DEFAULT_NODE

__all__ = ["CanFrontEnd"]

logger = logging.getLogger(__name__)


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
        interface, channel: python-can interface and channel (``socketcan``,
            ``vcan0``); ignored when ``bus`` is given.
        node: this controller's node id, 1..15.
        bus: an already open bus to use (the caller keeps ownership).
        seed: seeds the link-fault generators.
        recorder: traffic log (see FrontEnd); it sees other nodes' frames too.
        bus_options: passed to ``can.Bus`` (e.g. ``bitrate``).

        Raises:
            ValueError: node out of range, or an interface python-can does not know
                (:class:`~firmware_proto.linkio.errors.LinkUrlError`).
        """
        self.can = CanEndpoint(
            CONTROLLER,
            interface,
            channel,
            node=node,
            bus=bus,
            send_timeout_s=0.05,  # the control loop never waits long for a full bus
            **bus_options,
        )
        super().__init__(self.can, seed=seed, recorder=recorder)
        self.interface, self.channel, self.node = interface, channel, node

    @property
    def decoder(self) -> CanDecoder:
        """The endpoint's decoder (its counters say what was rejected)."""
        return self.can.decoder

    @property
    def foreign(self) -> int:
        """Frames of other nodes, and our own kind echoed back: counted, ignored."""
        return self.can.foreign

    @property
    def error_frames(self) -> int:
        """Error frames received (counted, otherwise ignored)."""
        return self.can.error_frames

    def _open(self) -> None:
        super()._open()
        logger.info("serving node %d on CAN %s", self.node, self.device)
