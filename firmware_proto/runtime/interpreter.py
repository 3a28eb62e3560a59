"""The interpreter setting of the processes that keep time, for STOP latency.

CPython lets a thread hold the interpreter lock for up to ``sys.getswitchinterval()``
(5 ms by default) before another thread that wants it gets it. In the bridge a STOP
arrives on one thread (a ROS callback) while others (the transport's dispatcher with
odometry, the link's timer, the ROS port's own threads) run Python too, so the default
lets a STOP wait up to 5 ms for a turn; in the emulator a frame's reader waits likewise
for the control loop. Those processes therefore ask for slices of
:data:`SWITCH_INTERVAL_S` (:class:`~firmware_proto.runtime.process.ProcessRuntime`).
Measured with ``benchmarks/bench_bridge.py``, one run of each on a 2-core machine (100
trials, a ROS message on the in-process port, the motion queue full and telemetry at
100 Hz): STOP -> wheel targets zero p95 2.0 -> 0.55 ms, p99 3.7 -> 0.69 ms. The bridge
is not CPU-bound, so the extra switching costs it little.

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
    """Set the interpreter's thread switch interval (s) for this process; returns the
    previous one."""
    previous = sys.getswitchinterval()
    sys.setswitchinterval(interval_s)
    logger.info("thread switch interval %.4f s (was %.4f s)", interval_s, previous)
    return previous
