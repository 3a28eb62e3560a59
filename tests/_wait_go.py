"""A pytest plugin for ``.ci/test``'s VM part: once collection is done, wait until the
file that ``ROVER_WAIT_GO`` names exists, then run the tests. The VM boots and collects
(half a minute of its software CPU) while the host's serial part runs, at the lowest
priority, and its tests start only once the host is done with every other part
(docs/testing.md, "The parts of the test command").

``ROVER_WAIT_GO_TIMEOUT`` bounds the wait, s (default 1800): past it, the run ends with
pytest's usage-error status (4), saying so. Without ``ROVER_WAIT_GO`` the plugin does
nothing."""

from __future__ import annotations

import os
import time

import pytest

WAIT_GO_ENV = "ROVER_WAIT_GO"
WAIT_GO_TIMEOUT_ENV = "ROVER_WAIT_GO_TIMEOUT"
POLL_S = 0.5
"""How often the file is looked for, s. In the VM each look (a wake-up and a lookup over
the uncached 9p share) costs qemu's software CPU about 6 ms of the host's: every 0.1 s
that was 3.7 CPU-seconds a minute, 9 or so in a run's wait beside the serial part, where
the idle guest costs nothing measurable (docs/vcan-vm.md); every 0.5 s, a fifth of it
for at most 0.5 s later a start."""


def wait_for_go(path: str, timeout_s: float) -> bool:
    """Whether ``path`` came to exist within ``timeout_s`` (looked for every
    :data:`POLL_S`)."""
    deadline = time.monotonic() + timeout_s
    while not os.path.exists(path):
        if time.monotonic() >= deadline:
            return False
        time.sleep(POLL_S)
    return True


def pytest_collection_finish(session: pytest.Session) -> None:
    """Wait for the go file after collection (every ``modifyitems`` hook done)."""
    path = os.environ.get(WAIT_GO_ENV)
    if not path:
        return
    timeout_s = float(os.environ.get(WAIT_GO_TIMEOUT_ENV, "1800"))
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.write_line(f"collected; the tests start once {path} exists")
    started = time.monotonic()
    if not wait_for_go(path, timeout_s):
        pytest.exit(f"{path} did not come within {timeout_s:g} s: no test ran", returncode=4)
    if reporter is not None:
        reporter.write_line(f"{path} came after {time.monotonic() - started:.1f} s: testing")
