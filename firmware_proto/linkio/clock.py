"""Time for a scripted host: the wall clock, or virtual time that runs in lockstep.

A :class:`Clock` tells the time and waits for a condition. Everything that waits on the
link waits through one, so the same script runs in real time (:class:`WallClock`:
threads deliver, a waiter sleeps on a condition variable) and in lockstep with an
in-process controller (:class:`LockstepClock`: no threads; a wait *advances the world*
one tick at a time until the condition holds or its virtual timeout passes).

The lockstep clock calls, once per tick and in the order added, the steps it was given
(:meth:`LockstepClock.add`): a controller's tick, a host's pump and heartbeat, and in a
whole mission the bridge, the ROS port and the relay (docs/sim.md, "Whole missions in
virtual time"). Its time of day (:meth:`Clock.time`, what stamps ROS messages) starts at a fixed
:data:`EPOCH_S`, so a run stamps the same on every machine.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol

__all__ = ["EPOCH_S", "WALL", "Clock", "LockstepClock", "WallClock", "is_lockstep"]

Ready = Callable[[], bool]

EPOCH_S = 1_767_225_600.0
"""The time of day at a lockstep clock's start, s since the epoch (2026-01-01 00:00 UTC)."""


class Clock(Protocol):
    """What a waiter needs of time."""

    def now(self) -> float:
        """Seconds, monotonic (an arbitrary origin)."""

    def time(self) -> float:
        """The time of day, seconds since the epoch (what stamps a message)."""

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

    def time(self) -> float:
        """``time.time()``, s since the epoch."""
        return time.time()

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

    Not thread-safe: one thread runs the script and, through its waits, the world. A
    step that raises ends the tick and the wait that ran it, with its exception.
    """

    def __init__(self, dt_s: float = 0.001, *, epoch_s: float = EPOCH_S) -> None:
        """Args:
        dt_s: one tick, s (> 0, else ValueError): the controller's control period.
        epoch_s: the time of day at tick 0, s since the epoch.
        """
        if not dt_s > 0:
            raise ValueError(f"a tick must be > 0 s, got {dt_s}")
        self.dt_s = dt_s
        self.epoch_s = epoch_s
        self.ticks = 0
        self._steps: list[Callable[[], None]] = []

    def add(self, step: Callable[[], None]) -> None:
        """Call ``step()`` once per tick from the next one on, after the steps added
        before (a step may add or remove steps)."""
        self._steps = [*self._steps, step]

    def remove(self, step: Callable[[], None]) -> None:
        """Call ``step`` no more (idempotent): what a part that closes does."""
        self._steps = [s for s in self._steps if s != step]

    def now(self) -> float:
        """Virtual seconds since the clock was made."""
        return self.ticks * self.dt_s

    def time(self) -> float:
        """``epoch_s`` plus :meth:`now`."""
        return self.epoch_s + self.ticks * self.dt_s

    def advance(self, ticks: int = 1) -> None:
        """Run ``ticks`` ticks: each step in turn, then the time moves on by ``dt_s``."""
        for _ in range(ticks):
            for step in self._steps:
                step()
            self.ticks += 1

    def wait_for(self, cond: threading.Condition, ready: Ready, timeout_s: float) -> bool:
        """Advance tick by tick until ``ready()`` or ``timeout_s`` of virtual time passed
        (rounded to whole ticks, at least one when positive). The steps run with ``cond`` held
        (it must be re-entrant, as ``threading.Condition()``'s default lock is)."""
        deadline = self.ticks + self._ticks_in(timeout_s)
        while not ready():
            if self.ticks >= deadline:
                return False
            self.advance()
        return True

    def sleep(self, seconds: float) -> None:
        """Advance ``seconds`` of virtual time (rounded to whole ticks)."""
        self.advance(self._ticks_in(seconds))

    def _ticks_in(self, seconds: float) -> int:
        """Whole ticks in ``seconds``, rounded; at least one for any positive time, so
        that a waiter that polls with a wait shorter than a tick still moves time on."""
        if not seconds > 0:
            return 0
        return max(1, round(seconds / self.dt_s))


def is_lockstep(clock: Clock) -> bool:
    """Whether ``clock`` runs in lockstep: a part given it starts no thread and adds its
    periodic work to the clock instead (:meth:`LockstepClock.add`)."""
    return isinstance(clock, LockstepClock)
