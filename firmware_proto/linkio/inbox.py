"""A waitable log: items appended by one thread and waited for by another.

:class:`Inbox` is the one collector of the stack's scripted hosts and tests: items are
appended under a condition variable, :meth:`Inbox.mark` names a position ("what arrives
after now"), and waits take the items from a position on, with a timeout. Waiting goes
through a :class:`~firmware_proto.linkio.clock.Clock`, so the same code waits in real
time or advances a lockstep world. A reader thread that fails hands its error to
:meth:`Inbox.fail`: every wait from then on raises :class:`LinkError` from it.

Marks are absolute: when the log is bounded (``keep``), the oldest half is dropped once
it holds twice ``keep`` items, and a mark taken before still means the same position.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Generic, TypeVar

from firmware_proto.linkio.clock import WALL, Clock
from firmware_proto.linkio.errors import LinkError

__all__ = ["Inbox"]

T = TypeVar("T")


class Inbox(Generic[T]):
    """Items in arrival order, waitable (see the module docstring). Thread-safe."""

    def __init__(self, *, clock: Clock = WALL, keep: int | None = None) -> None:
        """Args:
        clock: what waits go through.
        keep: bound the log to about this many items (``None``: unbounded).
        """
        self.clock = clock
        self.keep = keep
        self.cond = threading.Condition()
        """Held while appending and while waiting (re-entrant)."""
        self._items: list[T] = []
        self._base = 0
        self._failure: BaseException | None = None

    def append(self, item: T) -> None:
        """Add one item and wake the waiters."""
        with self.cond:
            self._items.append(item)
            if self.keep is not None and len(self._items) > 2 * self.keep:
                del self._items[: self.keep]
                self._base += self.keep
            self.cond.notify_all()

    def fail(self, exc: BaseException) -> None:
        """The source failed: every wait from now on raises :class:`LinkError` from it."""
        with self.cond:
            self._failure = exc
            self.cond.notify_all()

    @property
    def failure(self) -> BaseException | None:
        """What the source failed with, if it did."""
        return self._failure

    def mark(self) -> int:
        """A position: the items appended after this call are from it on."""
        with self.cond:
            return self._base + len(self._items)

    def items(self, since: int = 0) -> list[T]:
        """Every item still kept from position ``since`` on."""
        with self.cond:
            return self._items[max(0, since - self._base) :]

    def indexed(self, since: int = 0) -> list[tuple[int, T]]:
        """Like :meth:`items`, each with its position."""
        with self.cond:
            start = max(since, self._base)
            return list(enumerate(self._items[start - self._base :], start=start))

    def wait(
        self, accept: Callable[[T], bool], *, since: int, timeout_s: float
    ) -> tuple[int, T] | None:
        """The first item from ``since`` on that ``accept`` takes, with its position, waiting up
        to ``timeout_s`` (clock seconds); ``None`` when none came."""
        found: list[tuple[int, T]] = []
        start = since

        def ready() -> bool:
            nonlocal start
            start = max(start, self._base)
            items = self._items
            for i in range(start - self._base, len(items)):
                if accept(items[i]):
                    found.append((self._base + i, items[i]))
                    return True
            start = self._base + len(items)
            return self._failure is not None

        with self.cond:
            self.clock.wait_for(self.cond, ready, timeout_s)
            if found:
                return found[0]
            self._raise_if_failed()
        return None

    def until(self, condition: Callable[[list[T]], bool], *, since: int, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` until ``condition`` holds of the items from ``since`` on (a
        count, a sequence); whether it did."""
        held: list[bool] = []

        def ready() -> bool:
            if condition(self._items[max(0, since - self._base) :]):
                held.append(True)
                return True
            return self._failure is not None

        with self.cond:
            self.clock.wait_for(self.cond, ready, timeout_s)
            if held:
                return True
            self._raise_if_failed()
        return False

    def settle(self, seconds: float) -> None:
        """Let ``seconds`` of clock time pass (items arrive meanwhile)."""
        with self.cond:
            self.clock.wait_for(self.cond, lambda: self._failure is not None, seconds)
            self._raise_if_failed()

    def _raise_if_failed(self) -> None:
        if self._failure is not None:
            raise LinkError(f"the link failed: {self._failure}") from self._failure
