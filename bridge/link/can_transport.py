"""CAN transport: protocol frames on any python-can bus, through the link-I/O layer's CAN
endpoint on the host's side (:class:`~firmware_proto.linkio.can_endpoint.CanEndpoint`).

``can://INTERFACE/CHANNEL?node=N``: ``socketcan``, ``virtual`` or any other python-can
interface by name; other query options go to ``can.Bus``. Frames of other nodes and our
own frames echoed back are ignored.

**Bus health** (docs/bridge.md, "Transports"), from SocketCAN error frames or
``bus.state``: error-warning and error-passive change :attr:`CanTransport.medium_state`,
are logged once and counted, and the link stays up; bus-off and a failed send are a
transport error (the link reconnects); other error frames are counted in
:attr:`CanTransport.error_frames` and logged at DEBUG.
"""

from __future__ import annotations

from typing import Any

from bridge.link.transport import Transport, url_errors
from firmware_proto.linkio.can_endpoint import CanEndpoint
from firmware_proto.linkio.endpoint import HOST
from firmware_proto.linkio.trafficlog import TrafficRecorder

__all__ = ["CanTransport"]


class CanTransport(Transport):
    """Frames of docs/protocol.md on a CAN bus, for one controller node.

    Counters (per connection; they only grow): :attr:`error_frames` (every error frame
    received), :attr:`state_changes` (fault-confinement transitions, by the state
    entered), :attr:`foreign` (frames of other nodes, our own echoed back).
    """

    kind = "can"
    endpoint: CanEndpoint

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
        recorder: traffic log (see :class:`~bridge.link.transport.Transport`).
        bus_options: passed to ``can.Bus``, over the URL's options.

        Raises:
            TransportUrlError: malformed URL, node id outside 1..15, or an interface
                python-can does not know (permanent: never retried).
        """
        with url_errors(url):
            endpoint = CanEndpoint.for_url(HOST, url, node=node, recorder=recorder, **bus_options)
        super().__init__(url, endpoint)
        self.interface, self.channel, self.node = (
            endpoint.interface,
            endpoint.channel,
            endpoint.node,
        )

    @property
    def foreign(self) -> int:
        """Frames decoded but not from our controller (another node's, our own echoed)."""
        return self.endpoint.foreign

    @property
    def error_frames(self) -> int:
        """Error frames received on this connection."""
        return self.endpoint.error_frames

    @property
    def state_changes(self) -> dict[str, int]:
        """Fault-confinement transitions on this connection, by the state entered."""
        return self.endpoint.state_changes
