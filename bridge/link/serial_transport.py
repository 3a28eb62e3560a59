"""Serial transport: protocol frames over pyserial's ``serial_for_url``, through the
link-I/O layer's serial endpoint on the host's side
(:class:`~firmware_proto.linkio.serial_endpoint.SerialEndpoint`).

Opens a device path, a pty path, or any pyserial URL; ``?baud=N`` (default 115200) is
our own option, stripped before the rest goes to pyserial verbatim (docs/bridge.md,
"Transports"). Devices are opened exclusively where the platform allows, so two bridges
cannot share a controller. Only a malformed URL is permanent (from the constructor);
every other error is a :class:`~bridge.errors.TransportError`, and the link reconnects.
"""

from __future__ import annotations

from bridge.errors import DeviceBusyError, TransportUrlError
from bridge.link.transport import Transport, url_errors
from firmware_proto.linkio.endpoint import HOST
from firmware_proto.linkio.errors import LinkBusyError
from firmware_proto.linkio.serial_endpoint import SerialEndpoint
from firmware_proto.linkio.trafficlog import TrafficRecorder
from firmware_proto.linkio.urls import DEFAULT_BAUD
from firmware_proto.linkio.urls import refuse_if_in_use as _refuse_if_in_use

__all__ = ["DEFAULT_BAUD", "SerialTransport", "refuse_if_in_use"]


def refuse_if_in_use(url: str) -> None:
    """Fail when another process holds the device of ``url`` exclusively, e.g. a bridge
    already running on it (:func:`firmware_proto.linkio.urls.refuse_if_in_use`).

    Raises:
        DeviceBusyError: the device is locked by another process.
        TransportUrlError: the URL is malformed.
    """
    with url_errors(url):
        try:
            _refuse_if_in_use(url)
        except LinkBusyError as exc:
            raise DeviceBusyError(str(exc)) from exc


class SerialTransport(Transport):
    """Frames of docs/protocol.md over a serial port."""

    kind = "serial"
    endpoint: SerialEndpoint

    def __init__(
        self, url: str, baud: int | None = None, recorder: TrafficRecorder | None = None
    ) -> None:
        """Args:
        url: device path or pyserial URL (see the module docstring).
        baud: rate in bit/s; overrides ``?baud=`` in the URL.
        recorder: traffic log (see :class:`~bridge.link.transport.Transport`).

        Raises:
            TransportUrlError: the URL is malformed (permanent; see the module docstring).
        """
        if baud is not None and baud <= 0:
            raise TransportUrlError(f"{url!r}: baud must be a positive integer, got {baud}")
        with url_errors(url):
            endpoint = SerialEndpoint.for_url(HOST, url, baud=baud, recorder=recorder)
        super().__init__(url, endpoint)

    @property
    def baud(self) -> int:
        """The line's rate in bit/s (the URL's ``?baud=``, the argument, or 115200)."""
        baud = self.endpoint.baud
        assert baud is not None  # for_url always sets it
        return baud

    @property
    def device(self) -> str:
        """What pyserial opens: the URL without our ``baud`` option."""
        return self.endpoint.name
