"""Which faults stop the rover (docs/protocol.md, "Latch and faults").

WATCHDOG, STALL_LEFT, STALL_RIGHT, ENCODER, DRIVER and INTERNAL stop the rover and
latch; CLEAR_STOP answers FAULT_PERSISTS while the condition of any of them is active.
IMU and POSE only report. One set for the controller (the emulator), the host (the
bridge) and the conformance suite.
"""

from __future__ import annotations

from firmware_proto.wire.messages import FaultCode

__all__ = ["STOPPING_FAULTS", "fault_bit"]

STOPPING_FAULTS: frozenset[int] = frozenset(
    {
        FaultCode.WATCHDOG,
        FaultCode.STALL_LEFT,
        FaultCode.STALL_RIGHT,
        FaultCode.ENCODER,
        FaultCode.DRIVER,
        FaultCode.INTERNAL,
    }
)
"""Fault codes that stop the rover and latch (the rest only report)."""


def fault_bit(code: int) -> int:
    """The bit of HEARTBEAT ``fault_bits`` for a fault code: ``1 << (code - 1)``."""
    return 1 << (code - 1)
