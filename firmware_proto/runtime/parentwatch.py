"""A part of a stack ends when the process that started it ends, however that ends.

``rover stack up`` and ``rover demo`` start their parts as child processes; a parent
killed outright (SIGKILL, the out-of-memory killer) runs no way out. So the parent makes
a pipe for each part's standard input, names it in the part's environment
(:data:`EXIT_WITH_PARENT_ENV`, the pipe's inode: :func:`pipe_for_child`) and never writes
to it. The kernel closes it when the parent ends; the part's :func:`watch_parent` thread
reads end-of-file and sends the part SIGTERM (it ends as at Ctrl-C, with its STOP), then
ends it outright if it is still there :data:`GRACE_S` later. The pipe is named, not the
parent: a part whose parent died before it started still reads end-of-file, and a
process that inherited the variable with another standard input watches nothing. Parts
never read their standard input otherwise. All parts get SIGTERM at once, so if the
bridge ends before its STOP went out, the controller's watchdog stops the wheels.
"""

from __future__ import annotations

import logging
import os
import signal
import stat
import threading
import time
from collections.abc import Callable, Mapping
from typing import BinaryIO

__all__ = ["EXIT_WITH_PARENT_ENV", "GRACE_S", "pipe_for_child", "watch_parent"]

logger = logging.getLogger(__name__)

EXIT_WITH_PARENT_ENV = "ROVER_EXIT_WITH_PARENT"
"""Set by a parent to the inode of the pipe it gives the child as standard input."""

GRACE_S = 10.0
"""Seconds a part is given to end after SIGTERM once its parent is gone."""


def watch_parent(
    environ: Mapping[str, str] | None = None,
    stdin: BinaryIO | None = None,
    *,
    on_orphaned: Callable[[], None] | None = None,
    grace_s: float = GRACE_S,
) -> threading.Thread | None:
    """Start the watch if this process is a part whose parent asked for it; returns the
    thread (daemon, ``parent-watch``), or ``None`` when there is nothing to watch.
    ``environ`` defaults to ``os.environ``; ``stdin``, the pipe from the parent, to fd 0
    (read through its descriptor only); ``on_orphaned`` to SIGTERM to this process, then
    ``os._exit(1)`` if it is still running ``grace_s`` later."""
    env = os.environ if environ is None else environ
    wanted = env.get(EXIT_WITH_PARENT_ENV, "")
    try:
        fd = stdin.fileno() if stdin is not None else 0
        info = os.fstat(fd)
    except (OSError, ValueError):  # no standard input at all
        return None
    if not wanted.isdigit() or not stat.S_ISFIFO(info.st_mode) or info.st_ino != int(wanted):
        return None
    act = on_orphaned if on_orphaned is not None else (lambda: _end_self(grace_s))

    def watch() -> None:
        # os.read on the descriptor, not sys.stdin: a thread blocked in the buffered reader
        # holds its lock, and the interpreter aborts at exit when it cannot take it.
        try:
            while os.read(fd, 4096):  # the parent never writes: only end-of-file comes
                pass
        except OSError:  # closed under us while the program ends
            return
        logger.warning("the process that started this one has ended: stopping")
        act()

    thread = threading.Thread(target=watch, name="parent-watch", daemon=True)
    thread.start()
    return thread


def pipe_for_child() -> tuple[int, int, dict[str, str]]:
    """A pipe for a child's standard input: ``(read_fd, write_fd, environment)``. Give
    the child ``read_fd`` as its standard input and ``environment`` on top of its own,
    close ``read_fd`` once it is started, and keep ``write_fd`` open (never written) for
    as long as the child should live."""
    read_fd, write_fd = os.pipe()
    return read_fd, write_fd, {EXIT_WITH_PARENT_ENV: str(os.fstat(read_fd).st_ino)}


def _end_self(grace_s: float) -> None:
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(grace_s)
    logger.error("still running %.0f s after SIGTERM with no parent: exiting", grace_s)
    os._exit(1)
