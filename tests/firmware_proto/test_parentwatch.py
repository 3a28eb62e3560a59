"""A part ends when the process that started it ends (firmware_proto/runtime/parentwatch.py)."""

from __future__ import annotations

import os
import threading

from firmware_proto.runtime.parentwatch import EXIT_WITH_PARENT_ENV, pipe_for_child, watch_parent


def test_end_of_file_from_the_parent_means_it_is_gone() -> None:
    read_end, write_end, environ = pipe_for_child()
    orphaned = threading.Event()
    with os.fdopen(read_end, "rb", buffering=0) as stdin:
        thread = watch_parent(environ, stdin, on_orphaned=orphaned.set)
        assert thread is not None and thread.name == "parent-watch" and thread.daemon
        assert not orphaned.wait(0.2)  # the parent is alive: its end of the pipe is open
        os.close(write_end)  # what the kernel does when the parent ends
        assert orphaned.wait(10)
        thread.join(10)
        assert not thread.is_alive()


def test_nothing_is_watched_unless_the_parent_asked_for_it() -> None:
    read_end, write_end, _ = pipe_for_child()
    other_read, other_write, other = pipe_for_child()
    with os.fdopen(read_end, "rb", buffering=0) as stdin:
        for environ in ({}, {EXIT_WITH_PARENT_ENV: "x"}, other):
            # unset, malformed, or naming another pipe (inherited from further up)
            assert watch_parent(environ, stdin, on_orphaned=lambda: None) is None
    for fd in (write_end, other_read, other_write):
        os.close(fd)
