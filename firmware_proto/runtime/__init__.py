"""How the stack's programs run: real-time scheduling where they must keep time, and
stall detection everywhere (docs/realtime.md). It makes system calls and starts a
thread, so the pure folders never import it; every part above may.
"""

from firmware_proto.runtime.process import ProcessRuntime, RuntimeOptions
from firmware_proto.runtime.realtime import RealtimeConfig, RealtimeStatus, apply_realtime
from firmware_proto.runtime.signals import ShutdownSignals
from firmware_proto.runtime.stall import (
    Beat,
    StallMonitor,
    StallRecord,
    describe_stalls,
    read_stalls,
    stall_log_path,
)

__all__ = [
    "Beat",
    "ProcessRuntime",
    "RealtimeConfig",
    "RealtimeStatus",
    "RuntimeOptions",
    "ShutdownSignals",
    "StallMonitor",
    "StallRecord",
    "apply_realtime",
    "describe_stalls",
    "read_stalls",
    "stall_log_path",
]
