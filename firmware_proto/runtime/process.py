"""One long-running program of the stack: its scheduling and its stall monitor.

Every program that runs for the length of a mission enters a :class:`ProcessRuntime`
first thing in its ``main``: those that must keep time ask for real-time scheduling
(:mod:`~firmware_proto.runtime.realtime`), and every one watches itself for stalls
(:mod:`~firmware_proto.runtime.stall`). Options: :mod:`firmware_proto.cli.runtimeargs`.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
from dataclasses import dataclass
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

from firmware_proto.runtime.interpreter import use_short_switch_interval
from firmware_proto.runtime.realtime import (
    RealtimeConfig,
    RealtimeStatus,
    apply_realtime,
    leave_realtime_for_process,
    restore_scheduling,
    saved_scheduling,
)
from firmware_proto.runtime.stall import (
    DEFAULT_STALL_THRESHOLD_S,
    StallMonitor,
    all_stacks,
    install,
)

__all__ = ["ProcessRuntime", "RuntimeOptions"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RuntimeOptions:
    """How a program runs.

    Attributes:
        name: the program's name in stall records (``bridge``, ``emulator``, ...).
        priority: real-time priority 1..99, or 0 for normal scheduling.
        stall_threshold_s: stalls longer than this are logged, s.
        stall_log: the stall log shared by the stack's processes (``None``: none).
        short_switch: a short interpreter switch interval
            (:mod:`firmware_proto.runtime.interpreter`): for the programs that keep time.
        nice: a nice value to run at (>= 0 needs no permission), for programs that yield
            to those that keep time.
        lock_memory: lock the process's memory when real time is granted.
        stall_stacks_on_console: log each stall's stacks on the console too (``-v``).
    """

    name: str
    priority: int = 0
    stall_threshold_s: float = DEFAULT_STALL_THRESHOLD_S
    stall_log: Path | None = None
    short_switch: bool = False
    nice: int = 0
    lock_memory: bool = True
    stall_stacks_on_console: bool = False


def _dump_stacks(signum: int, frame: FrameType | None) -> None:
    logger.warning("stacks on request (SIGUSR1):\n%s", all_stacks())


class ProcessRuntime:
    """Scheduling and stall monitoring for the calling program (a context manager).

    Enter it from the main thread before any other thread starts, so that every thread
    inherits the scheduling. On exit the calling thread's scheduling and the switch interval
    are put back, so a program run in-process leaves its caller as it found it.
    """

    def __init__(self, options: RuntimeOptions) -> None:
        self.options = options
        self.realtime: RealtimeStatus | None = None
        """What the kernel granted (set on entry)."""
        self.monitor = StallMonitor(
            options.name,
            threshold_s=options.stall_threshold_s,
            log_path=options.stall_log,
            stacks_on_console=options.stall_stacks_on_console,
        )
        self._previous_usr1: Any = signal.SIG_DFL
        self._previous_switch = sys.getswitchinterval()
        self._previous_scheduling = saved_scheduling()

    def __enter__(self) -> ProcessRuntime:
        self._previous_scheduling = saved_scheduling()
        self._previous_switch = sys.getswitchinterval()
        if self.options.short_switch:
            use_short_switch_interval()
        if self.options.nice:
            os.setpriority(os.PRIO_PROCESS, 0, self.options.nice)
        self.realtime = apply_realtime(
            RealtimeConfig(priority=self.options.priority, lock_memory=self.options.lock_memory)
        )
        self.monitor.start()
        install(self.monitor)
        # `kill -USR1 <pid>` logs every thread's stack (docs/realtime.md, Stalls), from a
        # Python handler under the interpreter lock (faulthandler's C one is not).
        self._previous_usr1 = signal.signal(signal.SIGUSR1, _dump_stacks)
        return self

    def wind_down(self) -> None:
        """The program has begun to end: every thread leaves real time
        (:func:`~firmware_proto.runtime.realtime.leave_realtime_for_process`). Call it once the
        work that must keep time is over; leaving the runtime does it too."""
        if self.realtime is not None and self.realtime.granted:
            leave_realtime_for_process()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        signal.signal(signal.SIGUSR1, self._previous_usr1)
        self.wind_down()
        install(None)
        self.monitor.close()
        restore_scheduling(self._previous_scheduling)
        sys.setswitchinterval(self._previous_switch)

    def line(self) -> str:
        """The one line a program prints at start: what scheduling it got."""
        return self.realtime.line() if self.realtime is not None else "realtime: not applied"
