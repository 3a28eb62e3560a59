"""Ending a mission from the keyboard or the system: SIGINT and SIGTERM as a cancel.

A mission must not die mid-step with the rover still driving. :class:`CancelOnSignal`
turns the first SIGINT (Ctrl-C) or SIGTERM into a call of ``on_signal``, which normally
sets the ``cancel`` event the mission runner and the executor watch: the running plan
ends with STOP and the mission reports ``cancelled``. A second signal raises
``KeyboardInterrupt`` in the main thread, for an operator who cannot wait; the executor
sends STOP on that path too before the exception goes on.

Signal handlers can only be installed from the main thread; elsewhere the context
manager does nothing (say so in the log) and signals keep their handlers.
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable
from types import FrameType, TracebackType
from typing import Any

__all__ = ["CancelOnSignal"]

logger = logging.getLogger(__name__)


class CancelOnSignal:
    """Within ``with``: the first SIGINT/SIGTERM calls ``on_signal(signum)``, the next
    raises ``KeyboardInterrupt``; the previous handlers come back on exit.

    Args:
        on_signal: called in the main thread, between two bytecodes of whatever it runs:
            keep it short (set an event, print a line). It may raise (e.g.
            ``KeyboardInterrupt`` while nothing is running yet that needs a STOP).

    Attributes:
        signum: the first signal received, or ``None``.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, on_signal: Callable[[int], None]) -> None:
        self.on_signal = on_signal
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    @property
    def exit_status(self) -> int:
        """The conventional exit status for the signal received (128 + its number);
        1 when none was."""
        return 128 + self.signum if self.signum is not None else 1

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt(f"signal {signal.Signals(signum).name} received twice")
        self.signum = signum
        self.on_signal(signum)

    def __enter__(self) -> CancelOnSignal:
        if threading.current_thread() is not threading.main_thread():
            logger.info("not the main thread: SIGINT/SIGTERM keep their handlers")
            return self
        for sig in self.SIGNALS:
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        while self._previous:
            sig, handler = self._previous.popitem()
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
