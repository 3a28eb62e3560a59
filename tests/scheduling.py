"""Real-time scheduling for the programs' threads that tests start in-process."""

from __future__ import annotations

from contextlib import AbstractContextManager

from firmware_proto.runtime.realtime import RealtimeConfig, RealtimeStatus, realtime_threads

__all__ = ["threads_at"]


def threads_at(priority: int) -> AbstractContextManager[RealtimeStatus]:
    """Threads started inside run at real-time ``priority`` where permitted, as the
    programs' own do (docs/realtime.md): an in-process emulator or bridge keeps the
    controller's watchdog beside other work as ``rover emulate`` and ``rover bridge``
    do. The calling thread is put back as it was after; memory is not locked."""
    return realtime_threads(RealtimeConfig(priority, lock_memory=False, fallback_nice=0))
