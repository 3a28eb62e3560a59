"""Every test's time limit: a test past it fails, with the stacks of every thread, and
pytest goes on (docs/testing.md, "Time limits").

The limit is the test's ``@pytest.mark.timeout(SECONDS)``, else ``--timeout SECONDS``,
else the ``timeout`` ini value (pyproject.toml); 0 turns it off. Setup and call share
it; teardown has one of its own, so that the clean-up of a test that ran out of time
still runs.

How, and why not pytest-timeout: its ``signal`` method arms one timer around the whole
run of a test, pytest's own reporting included, so a limit that fell due there raised
inside pytest and crashed the session (INTERNALERROR, exit 3: issue #38); its ``thread``
method ends the whole process. Here the timer (``SIGALRM``, ``setitimer``) is armed only
while a phase's own code runs, inside the hook that pytest wraps in ``CallInfo.from_call``,
and the handler raises only while it is armed, so the exception always lands where
pytest turns it into that test's failure. Python retries an interrupted system call
only after the handler returned (PEP 475), and lock waits are interruptible, so a test
blocked in a read, a join or a wait is interrupted too.

A test that even the signal cannot interrupt (native code that never returns to the
interpreter) is the watchdog's: :data:`WATCHDOG_GRACE_S` after its limit, a thread
writes the test's id and every thread's stack to the process's standard error, kills
the test's child processes and ends the process (exit status 70). Under pytest-xdist the
controller then reports "worker crashed while running <test id>" and goes on with a new
worker; alone, the output ends with the test's name. Either way the hang names the test.

pytest-timeout is blocked (``-p no:timeout`` in pyproject.toml) so that the two never
both act; this plugin takes over its option, ini value and mark.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Generator, Iterator

import pytest

__all__ = ["WATCHDOG_GRACE_S", "TimeLimitExceeded", "limit_s", "stacks"]

WATCHDOG_GRACE_S = float(os.environ.get("ROVER_TEST_WATCHDOG_GRACE_S", "30"))
"""After a phase's limit, how long the signal has to end it before the watchdog ends the
process, s (``ROVER_TEST_WATCHDOG_GRACE_S``: tests/test_timeouts.py makes it short)."""

_EXIT_STATUS = 70  # EX_SOFTWARE


class TimeLimitExceeded(pytest.fail.Exception):  # type: ignore[name-defined,misc]
    """A test ran past its time limit (a pytest failure, not an error of pytest's)."""


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--timeout",
        type=float,
        default=None,
        metavar="SECONDS",
        help="each test's time limit unless it is marked with its own (0: none); "
        "default: the timeout ini value",
    )
    parser.addini("timeout", "each test's time limit, s, unless marked (0: none)", default="0")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "timeout(seconds): this test's time limit, s (setup and call; teardown gets as much "
        "again): tests/timeouts.py",
    )
    if hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGALRM, _on_alarm)
    _WATCHDOG.start(_original_stderr(config))


def _original_stderr(config: pytest.Config) -> int:
    """A descriptor of the standard error pytest's capture replaced (fd 2 when none)."""
    capman = config.pluginmanager.getplugin("capturemanager")
    err = getattr(getattr(capman, "_global_capturing", None), "err", None)
    saved = getattr(err, "targetfd_save", None)
    try:
        return os.dup(saved if isinstance(saved, int) else 2)
    except OSError:
        return 2


def limit_s(item: pytest.Item) -> float:
    """The test's time limit, s (0: none)."""
    mark = item.get_closest_marker("timeout")
    if mark is not None and mark.args:
        return float(mark.args[0])
    if mark is not None and "seconds" in mark.kwargs:
        return float(mark.kwargs["seconds"])
    given = item.config.getoption("timeout")
    if given is not None:
        return float(given)
    return float(item.config.getini("timeout") or 0)


def stacks(*, others_only: bool = False) -> str:
    """Every thread's stack, named, the calling thread's last (or not at all: pytest
    shows the interrupted test's own)."""
    names = {t.ident: t.name for t in threading.enumerate()}
    me = threading.get_ident()
    frames = sorted(sys._current_frames().items(), key=lambda kv: kv[0] == me)
    out = []
    for ident, frame in frames:
        if others_only and ident == me:
            continue
        if ident == _WATCHDOG.ident:
            continue
        out.append(f"--- thread {names.get(ident, '?')} ({ident}):\n")
        out.extend(traceback.format_stack(frame))
    return "".join(out) or "(no other thread)\n"


class _Phase:
    """The phase under way: which test, which phase, when its limit falls due."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.nodeid = ""
        self.when = ""
        self.limit_s = 0.0
        self.due: float | None = None  # time.monotonic() at the limit; None: unarmed
        self.armed = False  # the signal may raise


_PHASE = _Phase()
_SETUP_STARTED = pytest.StashKey[float]()


def _on_alarm(signum: int, frame: object) -> None:
    if not _PHASE.armed:
        return  # the phase ended as the timer fired: nothing to interrupt
    _PHASE.armed = False
    raise TimeLimitExceeded(
        f"Timeout: {_PHASE.nodeid} ran past its time limit of {_PHASE.limit_s:g} s "
        f"(in {_PHASE.when}); the traceback below is where it was; the other threads:\n"
        f"{stacks(others_only=True)}",
        pytrace=True,
    )


def _arm(item: pytest.Item, when: str, left_s: float, limit: float) -> None:
    with _PHASE.lock:
        _PHASE.nodeid, _PHASE.when, _PHASE.limit_s = item.nodeid, when, limit
        _PHASE.due = time.monotonic() + left_s
        _PHASE.armed = True
    if hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread():
        signal.setitimer(signal.ITIMER_REAL, max(left_s, 0.001))


def _disarm() -> None:
    _PHASE.armed = False
    if hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread():
        signal.setitimer(signal.ITIMER_REAL, 0)
    with _PHASE.lock:
        _PHASE.due = None


@contextlib.contextmanager
def _phase(item: pytest.Item, when: str) -> Iterator[None]:
    """Arm the limit around one phase's own code (setup and call share the test's limit;
    teardown has its own)."""
    limit = limit_s(item)
    if limit <= 0:
        yield
        return
    now = time.monotonic()
    left = limit
    if when == "setup":
        item.stash[_SETUP_STARTED] = now
    elif when == "call":
        left = limit - (now - item.stash.get(_SETUP_STARTED, now))
    if left <= 0:
        raise TimeLimitExceeded(
            f"Timeout: {item.nodeid}'s setup used its whole time limit of {limit:g} s",
            pytrace=False,
        )
    _arm(item, when, left, limit)
    try:
        yield
    finally:
        _disarm()


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> Generator[None, None, None]:
    with _phase(item, "setup"):
        return (yield)


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_call(item: pytest.Item) -> Generator[None, None, None]:
    with _phase(item, "call"):
        return (yield)


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_teardown(
    item: pytest.Item, nextitem: pytest.Item | None
) -> Generator[None, None, None]:
    with _phase(item, "teardown"):
        return (yield)


class _Watchdog:
    """Ends the process when a phase outlives its limit by :data:`WATCHDOG_GRACE_S`."""

    def __init__(self) -> None:
        self._thread: threading.Thread | None = None
        self.stderr_fd = 2

    def start(self, stderr_fd: int) -> None:
        """Watch from now on, writing to ``stderr_fd``."""
        self.stderr_fd = stderr_fd
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="test-watchdog", daemon=True)
            self._thread.start()

    def _run(self) -> None:
        while True:
            time.sleep(1.0)
            with _PHASE.lock:
                due, nodeid, when, limit = _PHASE.due, _PHASE.nodeid, _PHASE.when, _PHASE.limit_s
            if due is None or time.monotonic() < due + WATCHDOG_GRACE_S:
                continue
            _end_process(nodeid, when, limit, self.stderr_fd)

    @property
    def ident(self) -> int | None:
        """The watchdog thread's id (its own stack is never shown)."""
        return self._thread.ident if self._thread is not None else None


_WATCHDOG = _Watchdog()


def _end_process(nodeid: str, when: str, limit: float, fd: int) -> None:
    text = (
        f"\n\nTIMEOUT: {nodeid} ran past its time limit of {limit:g} s (in {when}) and "
        f"{WATCHDOG_GRACE_S:g} s more without being interrupted; the stacks of every "
        f"thread, then this process ({os.getpid()}) ends:\n{stacks()}\n"
        f"TIMEOUT: {nodeid}\n"
    )
    with contextlib.suppress(OSError):
        os.write(fd, text.encode(errors="replace"))
    _kill_children()
    os._exit(_EXIT_STATUS)


def _kill_children() -> None:
    """SIGKILL every process this one started (read from /proc), so that none outlives
    the run."""
    me = str(os.getpid())
    try:
        entries = os.listdir("/proc")
    except OSError:
        return
    for entry in entries:
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[-1].split()
        if len(fields) > 1 and fields[1] == me:
            with contextlib.suppress(OSError):
                os.kill(int(entry), signal.SIGKILL)
