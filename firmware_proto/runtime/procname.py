"""A process's name as the kernel keeps it (``/proc/PID/comm``): what ``top``, ``ps -o
comm``, ``pgrep NAME``, ``pidstat`` and process accounting show.

Every Python program is ``python`` there, so a rover computer running a bridge, its two
ROS 2 children, a link relay and a gate showed five alike. Each ``rover`` command names
its process ``rover-COMMAND`` (``rover-bridge``, ``rover-emulate``, ``rover-stack``),
the bridge's ROS 2 children ``rover-ros-node`` and ``rover-stop-lane``, and the gate's
workers ``rover-gate-work`` (docs/realtime.md, "Which process is which"). The command
line (``ps -o args``, ``pgrep -f``) is unchanged.
"""

from __future__ import annotations

import logging

__all__ = ["COMM_MAX_BYTES", "process_name", "set_process_name"]

logger = logging.getLogger(__name__)

COMM_MAX_BYTES = 15
"""The kernel keeps at most this many bytes of a name (``TASK_COMM_LEN`` less its NUL)."""

_COMM = "/proc/self/comm"  # the main thread's name: the process's


def set_process_name(name: str) -> bool:
    """Name the calling process ``name`` (ASCII; cut to :data:`COMM_MAX_BYTES` bytes).

    Returns:
        Whether the kernel took it: ``False`` where there is no ``/proc`` (not Linux) or
        it refused; the process keeps running under its old name either way.

    Raises:
        ValueError: ``name`` is empty or not printable ASCII.
    """
    if not name or not name.isascii() or not name.isprintable():
        raise ValueError(f"a process name is printable ASCII, got {name!r}")
    try:
        with open(_COMM, "w", encoding="ascii") as comm:
            comm.write(name[:COMM_MAX_BYTES])
    except OSError as exc:
        logger.debug("process name %r not set: %s", name, exc)
        return False
    return True


def process_name(pid: int | str = "self") -> str:
    """The kernel's name of process ``pid`` (default this one); ``""`` if it is gone."""
    try:
        with open(f"/proc/{pid}/comm", encoding="ascii", errors="replace") as comm:
            return comm.read().strip()
    except OSError:
        return ""
