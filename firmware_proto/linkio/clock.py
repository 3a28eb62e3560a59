"""Time for a scripted host: the wall clock, or virtual time that runs in lockstep.

A :class:`Clock` tells the time and waits for a condition. Everything that waits on the
link (:class:`~firmware_proto.linkio.inbox.Inbox`,
:class:`~firmware_proto.linkio.host.ProtocolHost`) waits through one, so the same script
runs against a controller in real time (:class:`WallClock`: threads deliver, a waiter
sleeps on a condition variable) and in lockstep with an in-process controller
(:class:`LockstepClock`: no threads; a wait *advances the world* one tick at a time
until the condition holds or its virtual timeout passes).

The lockstep clock knows nothing of controllers: it calls, once per tick and in the
order added, the steps it was given (:meth:`LockstepClock.add`): a controller's tick,
a host's pump of its endpoint, a host's heartbeat timer.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol

__all__ = ["WALL", "Clock", "LockstepClock", "WallClock"]

Ready = Callable[[], bool]


class Clock(Protocol):
    """What a waiter needs of time."""

    def now(self) -> float:
        """Seconds, monotonic (an arbitrary origin)."""

    def wait_for(self, cond: threading.Condition, ready: Ready, timeout_s: float) -> bool:
        """Wait, with ``cond`` held by the caller, until ``ready()`` is true or
        ``timeout_s`` passed; whether it became true."""

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass."""


class WallClock:
    """Real time: ``time.monotonic()``, waits on the condition variable."""

    def now(self) -> float:
        """``time.monotonic()``, s."""
        return time.monotonic()

    def wait_for(self, cond: threading.Condition, ready: Ready, timeout_s: float) -> bool:
        """``cond.wait_for(ready, timeout_s)``: another thread notifies ``cond``."""
        return cond.wait_for(ready, max(0.0, timeout_s))

    def sleep(self, seconds: float) -> None:
        """``time.sleep``."""
        if seconds > 0:
            time.sleep(seconds)


WALL = WallClock()
"""The one wall clock."""


class LockstepClock:
    """Virtual time in ticks of ``dt_s``, advanced only by waits and sleeps.

    Not thread-safe: one thread runs the script and, through its waits, the world.
    """

    def __init__(self, dt_s: float = 0.001) -> None:
        """Args:
        dt_s: one tick, s (> 0): the controller's control period.

        Raises:
            ValueError: ``dt_s`` is not positive.
        """
        if not dt_s > 0:
            raise ValueError(f"a tick must be > 0 s, got {dt_s}")
        self.dt_s = dt_s
        self.ticks = 0
        self._steps: list[Callable[[], None]] = []

    def add(self, step: Callable[[], None]) -> None:
        """Call ``step()`` once per tick from now on, after the steps added before."""
        self._steps.append(step)

    def now(self) -> float:
        """Virtual seconds since the clock was made."""
        return self.ticks * self.dt_s

    def advance(self, ticks: int = 1) -> None:
        """Run ``ticks`` ticks: each step in turn, then the time moves on by ``dt_s``."""
        for _ in range(ticks):
            for step in self._steps:
                step()
            self.ticks += 1

    def wait_for(self, cond: threading.Condition, ready: Ready, timeout_s: float) -> bool:
        """Advance tick by tick until ``ready()`` or ``timeout_s`` of virtual time passed.
        The steps run with ``cond`` held (it must be re-entrant, as
        ``threading.Condition()``'s default lock is)."""
        deadline = self.ticks + max(0, round(timeout_s / self.dt_s))
        while not ready():
            if self.ticks >= deadline:
                return False
            self.advance()
        return True

    def sleep(self, seconds: float) -> None:
        """Advance ``seconds`` of virtual time (rounded to whole ticks)."""
        self.advance(max(0, round(seconds / self.dt_s)))
