"""The interpreter setting of the processes that keep time, for STOP latency.

CPython lets a thread hold the interpreter lock for up to ``sys.getswitchinterval()``
(5 ms by default) before another thread that wants it gets it. A STOP arriving on one
thread of the bridge (or a frame on the emulator's reader) would wait that long behind
the others, so those processes ask for slices of :data:`SWITCH_INTERVAL_S`
(:class:`~firmware_proto.runtime.process.ProcessRuntime`); they are not CPU-bound, so the
extra switching costs little.

Process-wide: only the entry points that keep time (and the benchmark that stands for
the bridge) call :func:`use_short_switch_interval`; importing this module changes nothing.
"""

from __future__ import annotations

import logging
import sys

__all__ = ["SWITCH_INTERVAL_S", "use_short_switch_interval"]

logger = logging.getLogger(__name__)

SWITCH_INTERVAL_S = 0.0005
"""The interpreter's thread switch interval in the bridge process, s."""


def use_short_switch_interval(interval_s: float = SWITCH_INTERVAL_S) -> float:
    """Set this process's thread switch interval (s); returns the previous one."""
    previous = sys.getswitchinterval()
    sys.setswitchinterval(interval_s)
    logger.info("thread switch interval %.4f s (was %.4f s)", interval_s, previous)
    return previous
