"""SIGINT and SIGTERM for a program's main loop, received without a lock.

A handler that calls ``threading.Event.set()`` can hang its own process: Python runs it
in the main thread between two bytecodes, which may fall inside ``Event.wait()`` on the
same event, so ``set()`` waits for a lock its own thread holds. Here the handler only
stores the signal's number, and the interpreter's wake-up file descriptor
(:func:`signal.set_wakeup_fd`) wakes :meth:`ShutdownSignals.wait`.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import threading
import time
from collections.abc import Callable
from types import FrameType, TracebackType
from typing import Any

__all__ = ["SIGNALS", "ShutdownSignals", "install_handler", "restore_handlers"]

SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""The signals that end a program (Ctrl-C, and what a launch system or ``kill`` sends)."""

Handler = Callable[[int, FrameType | None], Any]


def install_handler(handler: Handler) -> dict[int, Any]:
    """``handler`` for each of :data:`SIGNALS` (main thread only); the handlers it
    replaced, for :func:`restore_handlers`."""
    return {sig: signal.signal(sig, handler) for sig in SIGNALS}


def restore_handlers(previous: dict[int, Any]) -> None:
    """Put back what :func:`install_handler` replaced (emptying ``previous``)."""
    while previous:
        sig, handler = previous.popitem()
        signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


class ShutdownSignals:
    """While entered (in the main thread), SIGINT and SIGTERM end :meth:`wait`; the first
    one received is :attr:`signum`. On exit the previous handlers and wake-up descriptor are
    put back. Entered in another thread it changes nothing and :meth:`wait` only times out.

    ``interrupt``: while true (the program may change it, e.g. during start-up), a signal
    raises :class:`KeyboardInterrupt` in the main thread instead.
    """

    def __init__(self, *, interrupt: bool = False) -> None:
        self.interrupt = interrupt
        self.signum: int | None = None
        """The first signal received, or ``None``."""
        self._previous: dict[int, Any] = {}
        self._previous_fd = -1  # the wake-up descriptor before ours (-1: none)
        self._read_fd = self._write_fd = -1

    @property
    def received(self) -> bool:
        """A signal came."""
        return self.signum is not None

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        # No lock taken here, nothing but stores (see the module's docstring).
        if self.signum is None:
            self.signum = signum
        if self.interrupt:
            raise KeyboardInterrupt(signal.Signals(signum).name)

    def __enter__(self) -> ShutdownSignals:
        if threading.current_thread() is not threading.main_thread():
            return self
        self._read_fd, self._write_fd = os.pipe()
        os.set_blocking(self._read_fd, False)
        os.set_blocking(self._write_fd, False)
        self._previous_fd = signal.set_wakeup_fd(self._write_fd, warn_on_full_buffer=False)
        self._previous = install_handler(self._handle)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._read_fd < 0:
            return
        restore_handlers(self._previous)
        signal.set_wakeup_fd(self._previous_fd)
        for fd in (self._read_fd, self._write_fd):
            os.close(fd)
        self._read_fd = self._write_fd = -1

    def wait(self, timeout_s: float | None) -> bool:
        """Wait up to ``timeout_s`` (``None``: for ever) for a signal; whether one has come."""
        deadline = None if timeout_s is None else time.monotonic() + max(0.0, timeout_s)
        while self.signum is None:
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return False
            if self._read_fd < 0:  # not the main thread: nothing can wake this wait
                time.sleep(remaining if remaining is not None else 3600.0)
                continue
            ready, _, _ = select.select([self._read_fd], [], [], remaining)
            if ready:
                self._drain()
        return True

    def _drain(self) -> None:
        """Read the wake-up bytes: each is the number of a signal Python handled. Ours
        count at once (the Python-level handler may not have run yet when the signal
        landed in another thread); others (e.g. SIGUSR1's stack dump) only woke us."""
        with contextlib.suppress(BlockingIOError):
            while data := os.read(self._read_fd, 512):
                for number in data:
                    if number in SIGNALS and self.signum is None:
                        self.signum = number
