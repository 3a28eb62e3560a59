"""The tests' way to open the scripted protocol host (``firmware_proto.linkio.host``) on
the emulator's pty or CAN bus: a plain host on the link layer, as any host would be. Not
the bridge: tests of the emulator must not depend on it."""

from __future__ import annotations

import can

from firmware_proto.linkio.can_endpoint import CanEndpoint
from firmware_proto.linkio.endpoint import HOST
from firmware_proto.linkio.host import ProtocolHost
from firmware_proto.linkio.serial_endpoint import SerialEndpoint

HEARTBEAT_S = 0.05
"""The tests' host heartbeat period, s: twice the protocol's rate, so that an emulator at
4x real time (its watchdog scaled to match) never starves."""


def serial_host(device: str, *, heartbeat_s: float | None = HEARTBEAT_S) -> ProtocolHost:
    """An open host on a serial device (a pty path), through pyserial."""
    return ProtocolHost(SerialEndpoint.for_url(HOST, device), heartbeat_s=heartbeat_s).open()


def can_host(
    bus: can.BusABC, *, node: int = 1, heartbeat_s: float | None = HEARTBEAT_S
) -> ProtocolHost:
    """An open host for controller ``node`` on an open python-can bus (the caller keeps
    the bus)."""
    channel = str(getattr(bus, "channel_id", "bus"))  # a name for messages and logs
    endpoint = CanEndpoint(HOST, "virtual", channel, node=node, bus=bus)
    return ProtocolHost(endpoint, heartbeat_s=heartbeat_s).open()
