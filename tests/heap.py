"""The test process's garbage collector, kept from holding up the real-time parts a test
runs in it (docs/testing.md, "Garbage collection").

A test that runs an emulator's control loop, a link or a bridge in the pytest process
shares that process's heap with the collected suite: about 150,000 objects, which one
full (generation 2) collection scans in about 110 ms here, holding the interpreter lock
all the while (a product process's whole heap takes 5-7 ms). On a busy host that is
enough for a controller's 250 ms watchdog to see a gap in the heartbeats (idle CI runs
failed on stalls of 171 and 190 ms of a whole test process, which such a collection
fits; a stall of the whole machine fits them too).

So once the suite is collected, its garbage is collected and what is left frozen
(:func:`gc.freeze`: moved where no collection looks again; the collected suite lives as
long as the session does), and before each test that keeps wall time
(:func:`tests.lanes.keeps_wall_time`: marked ``slow``, not ``virtual``) the objects made
since are collected: a full collection during the test then scans only what the test
and its fixtures made. Frozen objects are never freed, so only what lives for the whole
session is frozen. Tests that keep no wall clock get no collection: before each of them
it cost the fast lane about 6 ms a test, and the test command's background part (one
process over 1,589 tests) about a minute.
"""

from __future__ import annotations

import gc

import pytest

from tests.lanes import keeps_wall_time


def pytest_collection_finish(session: pytest.Session) -> None:
    """Collect once, then freeze the collected suite (see the module docstring)."""
    gc.collect()
    gc.freeze()


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    """Before a test that keeps wall time, collect what earlier tests left, so that no
    full collection falls due in it for want of one."""
    if keeps_wall_time(item):
        gc.collect()
