"""Ending a mission from the keyboard or the system: SIGINT and SIGTERM as a cancel.

A mission must not die mid-step with the rover still driving: the first signal cancels
it (STOP, outcome ``cancelled``), a second raises ``KeyboardInterrupt``, on which the
executor sends STOP too.

``on_signal`` runs on its own thread (``signal-dispatch``), not in the handler: a handler
that set an event while the main thread was inside that event's ``wait`` would deadlock
on a lock its own thread holds (firmware_proto/runtime/signals.py). The handler only
stores the signal and writes its number to a pipe. Outside the main thread the context
manager does nothing (and logs so).
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from collections.abc import Callable
from types import FrameType, TracebackType
from typing import Any

from firmware_proto.runtime.signals import install_handler, restore_handlers

__all__ = ["CancelOnSignal"]

logger = logging.getLogger(__name__)

_END = 0
"""Written to the dispatch pipe to end its thread (no signal has number 0)."""


class CancelOnSignal:
    """Within ``with``: the first SIGINT/SIGTERM calls ``on_signal(signum)``, the next
    raises ``KeyboardInterrupt``; the previous handlers come back on exit.

    Args:
        on_signal: called on the ``signal-dispatch`` thread, soon after the signal: keep
            it short (set an event, print a line). If it raises ``KeyboardInterrupt``,
            the main thread gets one.

    Attributes:
        signum: the first signal received, or ``None``.
    """

    def __init__(self, on_signal: Callable[[int], None]) -> None:
        self.on_signal = on_signal
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}
        self._read_fd = self._write_fd = -1
        self._dispatcher: threading.Thread | None = None
        self._interrupt = ""  # why the main thread is to raise KeyboardInterrupt, if set

    @property
    def exit_status(self) -> int:
        """The conventional exit status for the signal received (128 + its number);
        1 when none was."""
        return 128 + self.signum if self.signum is not None else 1

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        # In the main thread, between two bytecodes: no lock taken here.
        if self._interrupt:
            reason, self._interrupt = self._interrupt, ""
            raise KeyboardInterrupt(reason)
        if self.signum is not None:
            raise KeyboardInterrupt(f"signal {signal.Signals(signum).name} received twice")
        self.signum = signum
        os.write(self._write_fd, bytes([signum]))

    def _dispatch(self) -> None:
        """The ``signal-dispatch`` thread: ``on_signal`` for each signal written."""
        while (data := os.read(self._read_fd, 1)) and data[0] != _END:
            try:
                self.on_signal(data[0])
            except KeyboardInterrupt as exc:
                # The main thread's handler raises it: the signal again, to the main
                # thread (a wait there ends at once, as it would have for the first).
                self._interrupt = str(exc) or "interrupted"
                main = threading.main_thread().ident
                if main is not None:
                    signal.pthread_kill(main, data[0])
            except Exception:
                logger.exception("the handler of %s failed", signal.Signals(data[0]).name)

    def __enter__(self) -> CancelOnSignal:
        if threading.current_thread() is not threading.main_thread():
            logger.info("not the main thread: SIGINT/SIGTERM keep their handlers")
            return self
        self._read_fd, self._write_fd = os.pipe()
        self._dispatcher = threading.Thread(
            target=self._dispatch, name="signal-dispatch", daemon=True
        )
        self._dispatcher.start()
        self._previous = install_handler(self._handle)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._dispatcher is None:
            return
        # The dispatch thread ends first, while the handler is still ours: a
        # KeyboardInterrupt of on_signal is raised here, not by the handler put back.
        os.write(self._write_fd, bytes([_END]))
        self._dispatcher.join(timeout=10.0)
        restore_handlers(self._previous)
        if self._dispatcher.is_alive():
            logger.warning("signal-dispatch still runs a handler after 10 s; left to end")
        else:
            os.close(self._read_fd)
        os.close(self._write_fd)
        self._dispatcher = None
