"""The leak check every test gets (tests/conftest.py ``_no_leaks``): what it names as
file descriptors left open."""

from __future__ import annotations

import os
import resource

from tests.conftest import still_open


def test_an_open_descriptor_is_named_with_what_it_is_open_on() -> None:
    read_end, write_end = os.pipe()
    try:
        named = still_open({write_end, read_end})
        assert list(named) == sorted((read_end, write_end))
        assert all(target.startswith("pipe:[") for target in named.values())
    finally:
        os.close(read_end)
        os.close(write_end)


def test_a_descriptor_closed_since_it_was_listed_is_not_named() -> None:
    # Closed: a number past the process's limit, which no thread can open meanwhile (a
    # pipe's end closed here could be taken again by another thread's open).
    closed = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    read_end, write_end = os.pipe()
    try:
        assert list(still_open({closed, write_end})) == [write_end]
        assert still_open({closed}) == {}
    finally:
        os.close(read_end)
        os.close(write_end)
