"""Real-time scheduling for the processes that must keep time (docs/realtime.md).

A Python process at the default priority can be starved past the controller's watchdog
on a busy computer, so ``rover bridge`` and ``rover emulate`` ask the kernel for a
real-time policy, as ros2_control's controller manager does:

- :func:`apply_realtime`: the **calling thread** (and the threads it starts later) under
  ``SCHED_RR`` or ``SCHED_FIFO``; a program calls it first thing in ``main()``. With
  ``lock_memory``, ``mlockall`` (no page fault waits for the disk), only where the
  memory-lock limit allows it (root, or an unlimited ``RLIMIT_MEMLOCK``: with a small
  limit later allocations would fail), and smaller stacks for later threads
  (:data:`LOCKED_THREAD_STACK_BYTES`). Where the policy is not permitted (no root,
  ``CAP_SYS_NICE`` or ``rtprio`` limit), a lower nice value if that is, else nothing;
  :class:`RealtimeStatus` says which. Nothing fails for want of permission.
- :func:`apply_realtime_to_process` / :func:`leave_realtime_for_process`: every thread of
  the process, after a heavy start or before a heavy end.
- :func:`realtime_threads`: only the threads started inside a stretch of code.
- :func:`module_command_at_normal_priority`: a child started out of the parent's policy.

The kernel's real-time throttling (``sched_rt_runtime_us``) keeps a runaway real-time
thread from locking up the machine.
"""

from __future__ import annotations

import ctypes
import errno
import logging
import os
import resource
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

__all__ = [
    "BRIDGE_PRIORITY",
    "EMULATOR_PRIORITY",
    "FALLBACK_NICE",
    "LOCKED_THREAD_STACK_BYTES",
    "STOP_CHILD_PRIORITY",
    "RealtimeConfig",
    "RealtimeStatus",
    "apply_realtime",
    "apply_realtime_to_process",
    "in_realtime",
    "leave_realtime_for_process",
    "module_command_at_normal_priority",
    "realtime_threads",
    "restore_scheduling",
    "saved_scheduling",
]

logger = logging.getLogger(__name__)

EMULATOR_PRIORITY = 30
"""The emulator's priority, above the host link's: it plays a microcontroller, never descheduled."""
BRIDGE_PRIORITY = 20
"""The bridge's (controller link's) priority: below kernel IRQ threads (50) and the emulator."""
STOP_CHILD_PRIORITY = 15
"""The bridge's STOP-lane ROS 2 child: real time, below the link it feeds."""
FALLBACK_NICE = -10
"""The nice value asked for where the real-time policy is refused."""
LOCKED_THREAD_STACK_BYTES = 1 << 20
"""Stack size of threads started once memory is locked (each is resident in full)."""

_MCL_CURRENT, _MCL_FUTURE = 1, 2  # linux/mman.h on x86 and arm

# ``python -c _NORMAL_PRIORITY_LAUNCH MODULE ARGS...``: out of a real-time policy (a batch
# or idle policy and the nice are kept), then ``python -m MODULE ARGS...`` as if so started.
_NORMAL_PRIORITY_LAUNCH = (
    "import os, runpy, sys\n"
    "if hasattr(os, 'sched_setscheduler') and os.sched_getscheduler(0) in (\n"
    "        os.SCHED_RR, os.SCHED_FIFO):\n"
    "    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))\n"
    "del sys.argv[0]\n"
    "runpy.run_module(sys.argv[0], run_name='__main__', alter_sys=True)\n"
)

_POLICIES = {"rr": getattr(os, "SCHED_RR", 2), "fifo": getattr(os, "SCHED_FIFO", 1)}


@dataclass(frozen=True)
class RealtimeConfig:
    """What a process asks for.

    Attributes:
        priority: real-time priority 1..99; 0 asks for none (normal scheduling, and a
            thread that had a real-time policy is put back to normal).
        policy: ``rr`` (``SCHED_RR``: equal priorities take turns) or ``fifo``.
        lock_memory: lock the process's memory where the limit allows it.
        fallback_nice: the nice value to ask for where real time is refused (0: none).
    """

    priority: int
    policy: str = "rr"
    lock_memory: bool = True
    fallback_nice: int = FALLBACK_NICE

    def __post_init__(self) -> None:
        if not 0 <= self.priority <= 99:
            raise ValueError(f"real-time priority must be 0..99, got {self.priority}")
        if self.policy not in _POLICIES:
            raise ValueError(
                f"unknown scheduling policy {self.policy!r}; known: {', '.join(_POLICIES)}"
            )
        if not -20 <= self.fallback_nice <= 19:
            raise ValueError(f"nice must be -20..19, got {self.fallback_nice}")


@dataclass(frozen=True)
class RealtimeStatus:
    """What the kernel granted.

    Attributes:
        policy: ``SCHED_RR``, ``SCHED_FIFO`` or ``SCHED_OTHER``.
        priority: the real-time priority granted (0 under ``SCHED_OTHER``).
        nice: the nice value of the calling thread.
        memory_locked: ``mlockall`` succeeded.
        requested: real time was asked for (priority > 0).
        note: why something asked for was not granted (empty when all was).
    """

    policy: str
    priority: int
    nice: int
    memory_locked: bool
    requested: bool
    note: str = ""

    @property
    def granted(self) -> bool:
        """Real time was asked for and granted."""
        return self.requested and self.policy != "SCHED_OTHER"

    def line(self) -> str:
        """One line for the operator: what runs how, and why not if it does not."""
        if not self.requested:
            return f"realtime: off (SCHED_OTHER, nice {self.nice})"
        if self.granted:
            memory = "memory locked" if self.memory_locked else "memory not locked"
            extra = f" ({self.note})" if self.note else ""
            return f"realtime: {self.policy} priority {self.priority}, {memory}{extra}"
        return (
            f"realtime: NOT granted ({self.note}); running SCHED_OTHER at nice {self.nice}: "
            "a busy computer can delay this process past the controller's watchdog; "
            "docs/realtime.md says how to grant it"
        )


def _policy_name(policy: int) -> str:
    names = {_POLICIES["rr"]: "SCHED_RR", _POLICIES["fifo"]: "SCHED_FIFO"}
    return names.get(policy & 0xFF, "SCHED_OTHER")


def _lock_memory() -> str:
    """Lock all current and future memory; returns why not, or ``""``."""
    if not sys.platform.startswith("linux"):
        return "memory locking needs Linux"
    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    if soft != resource.RLIM_INFINITY and os.geteuid() != 0:
        return f"memory not locked: RLIMIT_MEMLOCK is {soft} bytes (docs/realtime.md)"
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
        return f"mlockall failed: {os.strerror(ctypes.get_errno())}"
    # Every stack started from now on is resident in full: keep them small.
    threading.stack_size(LOCKED_THREAD_STACK_BYTES)
    return ""


def apply_realtime(config: RealtimeConfig) -> RealtimeStatus:
    """Ask for ``config`` for the calling thread (and the threads it starts later).

    Never raises for want of permission: the status says what was granted and why not,
    and the program prints its :meth:`~RealtimeStatus.line` once.
    """
    if not hasattr(os, "sched_setscheduler"):
        return RealtimeStatus("SCHED_OTHER", 0, 0, False, config.priority > 0, "not on Linux")
    note = ""
    if config.priority == 0:
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        return RealtimeStatus("SCHED_OTHER", 0, os.getpriority(os.PRIO_PROCESS, 0), False, False)
    # Memory first, at the old priority: locking populates every page, which at real-time
    # priority would take the CPU from everyone else meanwhile.
    lock_note = _lock_memory() if config.lock_memory else ""
    locked = config.lock_memory and not lock_note
    try:
        os.sched_setscheduler(0, _POLICIES[config.policy], os.sched_param(config.priority))
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.EACCES, errno.EINVAL):
            raise
        rtprio = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
        note = f"sched_setscheduler: {exc.strerror}; RLIMIT_RTPRIO is {rtprio}"
        if config.fallback_nice:
            try:
                os.setpriority(os.PRIO_PROCESS, 0, config.fallback_nice)
            except OSError as nice_exc:
                note += f"; nice {config.fallback_nice}: {nice_exc.strerror}"
    else:
        note = lock_note
    policy = os.sched_getscheduler(0)
    status = RealtimeStatus(
        policy=_policy_name(policy),
        priority=os.sched_getparam(0).sched_priority,
        nice=os.getpriority(os.PRIO_PROCESS, 0),
        memory_locked=locked,
        requested=True,
        note=note,
    )
    return status


def apply_realtime_to_process(config: RealtimeConfig) -> RealtimeStatus:
    """:func:`apply_realtime` for the calling thread, then, where that granted a real-time
    policy, for every thread the process already has; call it once they exist (threads that
    end meanwhile, or cannot be given the policy, are skipped). Normal scheduling changes
    the calling thread only.

    For a process whose start is heavy CPU-bound work that creates threads (a DDS
    participant): done at normal priority and promoted after, it never holds the cores above
    the kernel's workers (a pty's receive path runs in one; docs/realtime.md).
    """
    status = apply_realtime(config)
    if not hasattr(os, "sched_setscheduler") or status.policy == "SCHED_OTHER":
        return status
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    me = threading.get_native_id()
    for tid in _own_threads():
        if tid == me:
            continue
        try:
            os.sched_setscheduler(tid, policy, param)
        except OSError:  # ended meanwhile, or not permitted
            continue
    return status


def leave_realtime_for_process() -> int:
    """Every thread of the calling process under ``SCHED_RR`` or ``SCHED_FIFO`` goes back
    to ``SCHED_OTHER`` (nice kept); returns how many did. Memory stays locked.

    For a program that has begun to end: its teardown is CPU-bound work of no urgency that
    at real-time priority holds a core above the kernel's workers and can starve another
    link on the machine (docs/realtime.md). Threads that end meanwhile are skipped.
    """
    if not hasattr(os, "sched_setscheduler"):
        return 0
    realtime = (_POLICIES["rr"], _POLICIES["fifo"])
    left = 0
    for tid in _own_threads():
        try:
            if os.sched_getscheduler(tid) in realtime:
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
                left += 1
        except OSError:  # ended meanwhile
            continue
    return left


def _own_threads() -> list[int]:
    """The calling process's thread ids (none where ``/proc`` cannot tell)."""
    try:
        return [int(tid) for tid in os.listdir("/proc/self/task")]
    except OSError:
        return []


def in_realtime() -> bool:
    """The calling thread runs under ``SCHED_RR`` or ``SCHED_FIFO``."""
    if not hasattr(os, "sched_getscheduler"):
        return False
    return os.sched_getscheduler(0) in (_POLICIES["rr"], _POLICIES["fifo"])


def module_command_at_normal_priority(module: str) -> list[str]:
    """The command that runs ``python -m module`` (append its arguments) under normal
    scheduling from its first line, whatever its parent's.

    A child inherits its parent's policy, and a Python program's imports are CPU-bound: at
    real-time priority they can hold every core, the pty's kernel worker starved with them
    (docs/realtime.md). A child that must keep time asks for it after its imports.
    """
    return [sys.executable, "-c", _NORMAL_PRIORITY_LAUNCH, module]


@dataclass(frozen=True)
class _Scheduling:
    policy: int
    priority: int
    nice: int


def saved_scheduling() -> _Scheduling | None:
    """The calling thread's policy, priority and nice (``None`` off Linux)."""
    if not hasattr(os, "sched_getscheduler"):
        return None
    return _Scheduling(
        os.sched_getscheduler(0),
        os.sched_getparam(0).sched_priority,
        os.getpriority(os.PRIO_PROCESS, 0),
    )


def restore_scheduling(saved: _Scheduling | None) -> None:
    """Put the calling thread back to ``saved`` (from :func:`saved_scheduling`); a
    lower nice than now that is not permitted is left as it is."""
    if saved is None:
        return
    os.sched_setscheduler(0, saved.policy, os.sched_param(saved.priority))
    if os.getpriority(os.PRIO_PROCESS, 0) != saved.nice:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, saved.nice)
        except OSError:
            logger.debug("nice %d not restored: not permitted", saved.nice)


@contextmanager
def realtime_threads(config: RealtimeConfig) -> Iterator[RealtimeStatus]:
    """Threads started inside run under ``config`` (where permitted, as
    :func:`apply_realtime` says); the calling thread runs under it inside too and is put
    back as it was after. Memory locking, if asked for, stays (it is process-wide)."""
    saved = saved_scheduling()
    try:
        yield apply_realtime(config)
    finally:
        restore_scheduling(saved)
