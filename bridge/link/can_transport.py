"""CAN transport: protocol frames on any python-can bus, through the link-I/O layer's CAN
endpoint on the host's side (:class:`~firmware_proto.linkio.can_endpoint.CanEndpoint`).

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
(:func:`~firmware_proto.linkio.can_endpoint.decode_error_frame` is pure):

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
                python-can does not know (permanent; see the module docstring).
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
