"""The port's RAM structures as the runner reads them (``port_pil/pil_port.h``): one
layout on every target (little-endian, no padding), decoded with precompiled structs."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from firmware_proto.wire.messages import ControllerState, FaultCode

__all__ = ["HOOKS", "STATS", "VIEW", "WORLD", "WORLD_MAGIC", "PilStats", "PortView", "hooks_bytes"]

STATS = struct.Struct("<10I")
"""``pil_stats_t``: ticks, tick_last, tick_max, late_ticks, rx_overflows, tx_drops,
tick_unit_hz, stop_ack_last, stop_ack_max, ident_last."""
VIEW = struct.Struct("<2i2i2ihHHBBBB2xI")
"""``pil_view_t``."""
HOOKS = struct.Struct("<2B2B2H")
"""``pil_hooks_t``: stall[2], encoder_dropout[2], slip_permille[2]."""
WORLD = struct.Struct("<I2ih2xI")
"""``pil_world_t``: magic, x_mm, y_mm, yaw_ddeg, travel_mm."""
WORLD_MAGIC = 0x57524C44
"""``PIL_WORLD_MAGIC``."""
_LATCH = ((1, "stop"), (2, "watchdog"), (4, "fault"))


@dataclass(frozen=True)
class PilStats:
    """``pil_stats``: the port's counters since boot."""

    ticks: int
    tick_last: int
    tick_max: int
    late_ticks: int
    rx_overflows: int
    tx_drops: int
    tick_unit_hz: int
    stop_ack_last: int
    stop_ack_max: int
    ident_last: int

    @classmethod
    def decode(cls, raw: bytes) -> PilStats:
        """From the bytes of ``pil_stats``."""
        return cls(*STATS.unpack(raw))


@dataclass(frozen=True)
class PortView:
    """``pil_view``: the controller after its last tick."""

    commanded_um_s: tuple[int, int]
    speed_um_s: tuple[int, int]
    x_mm: int
    y_mm: int
    yaw_ddeg: int
    boot_nonce: int
    rx_errors: int
    state: int
    latch: int
    faults: int
    queue_depth: int
    travel_mm: int = 0

    @classmethod
    def decode(cls, raw: bytes) -> PortView:
        """From the bytes of ``pil_view``."""
        v = VIEW.unpack(raw)
        return cls((v[0], v[1]), (v[2], v[3]), *v[4:])

    @property
    def state_name(self) -> str:
        """``IDLE``, ``EXECUTING``, ... (``STATE_n`` for an unknown value)."""
        try:
            return ControllerState(self.state).name
        except ValueError:
            return f"STATE_{self.state}"

    @property
    def latch_names(self) -> tuple[str, ...]:
        """What holds the latch, sorted."""
        return tuple(sorted(name for bit, name in _LATCH if self.latch & bit))

    @property
    def fault_names(self) -> tuple[str, ...]:
        """The fault conditions active (``ENCODER``, ``STALL_RIGHT``, ...)."""
        names = []
        for code in FaultCode:
            if code.value and self.faults & (1 << (code.value - 1)):
                names.append(code.name)
        return tuple(names)


def hooks_bytes(
    stall: tuple[bool, bool], dropout: tuple[bool, bool], slip: tuple[float, float]
) -> bytes:
    """The bytes of ``pil_hooks`` for these faults (slip as a traction scale, 0..1]."""
    return HOOKS.pack(
        int(stall[0]),
        int(stall[1]),
        int(dropout[0]),
        int(dropout[1]),
        max(1, min(1000, round(slip[0] * 1000))),
        max(1, min(1000, round(slip[1] * 1000))),
    )
