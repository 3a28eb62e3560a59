"""Whole lines on standard output from any thread: what ``rover stack up`` and ``rover
demo`` print while their parts' readers print too.

``print(line)`` is two writes, and another thread's line can come between them;
:func:`say` writes the line and its newline at once, under one lock, and flushes.
"""

from __future__ import annotations

import sys
import threading
from typing import TextIO

__all__ = ["say"]

_LOCK = threading.Lock()


def say(line: str, *, stream: TextIO | None = None) -> None:
    """Write ``line`` and a newline in one write, whole, and flush (any thread)."""
    out = sys.stdout if stream is None else stream
    with _LOCK:
        out.write(line + "\n")
        out.flush()
