"""The time limit of every test (tests/timeouts.py): a test past it fails with its
stacks, pytest goes on, and a hang no signal ends still names the test (issue #38: a
limit that fell due inside pytest's own report crashed the session with INTERNALERROR)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

_TESTS = """
import signal, subprocess, threading, time
import pytest

@pytest.mark.timeout(0.5)
def test_asleep():
    time.sleep(30)

@pytest.mark.timeout(0.5)
def test_joining():
    done = threading.Event()
    t = threading.Thread(target=done.wait, args=(3,), name="held-thread")
    t.start()
    t.join()

@pytest.fixture
def slow_clean_up():
    yield
    time.sleep(30)

@pytest.mark.timeout(0.5)
def test_clean_up_hangs(slow_clean_up):
    pass

@pytest.mark.timeout(0.5)
def test_in_a_child():
    subprocess.run(["sleep", "30"])

def test_quick():
    pass
"""

# The hook that made pytest-timeout's signal crash pytest: its report itself is slow, so
# a limit armed around the whole test falls due inside it.
_SLOW_REPORT = """
import time

def pytest_runtest_logreport(report):
    if report.when == "call" and "slow_report" in report.nodeid:
        time.sleep(1.0)
"""

_SLOW_REPORT_TEST = """
import pytest

@pytest.mark.timeout(0.5)
def test_slow_report():
    pass

def test_after_it():
    pass
"""

_UNINTERRUPTIBLE = """
import signal, time
import pytest

@pytest.mark.timeout(0.5)
def test_signal_blocked():
    signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGALRM])
    time.sleep(30)
"""


def _pytest(where: Path, *args: str, grace_s: float = 30.0) -> subprocess.CompletedProcess[str]:
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT),
        "ROVER_TEST_WATCHDOG_GRACE_S": str(grace_s),
        "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1",
    }
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "tests.timeouts", "-p", "no:cacheprovider",
         "-q", "-rA", *args],
        cwd=where, capture_output=True, text=True, timeout=90, env=env, check=False,
    )  # fmt: skip


def test_a_test_past_its_limit_fails_with_its_stacks_and_the_run_goes_on(tmp_path: Path) -> None:
    (tmp_path / "test_hangs.py").write_text(_TESTS)
    done = _pytest(tmp_path)
    out = done.stdout + done.stderr
    assert done.returncode == 1, out
    assert "INTERNALERROR" not in out
    for name in ("test_asleep", "test_joining", "test_in_a_child"):
        assert f"FAILED test_hangs.py::{name} - tests.timeouts.TimeLimitExceeded" in out, out
    assert "ERROR test_hangs.py::test_clean_up_hangs" in out  # teardown has a limit too
    assert "PASSED test_hangs.py::test_quick" in out
    assert "ran past its time limit of 0.5 s (in call)" in out
    assert "(in teardown)" in out
    assert "--- thread held-thread" in out  # the other threads' stacks
    assert "time.sleep(30)" in out  # where the test itself was


def test_a_limit_due_inside_pytests_own_report_crashes_nothing(tmp_path: Path) -> None:
    (tmp_path / "conftest.py").write_text(_SLOW_REPORT)
    (tmp_path / "test_report.py").write_text(_SLOW_REPORT_TEST)
    done = _pytest(tmp_path)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    assert "INTERNALERROR" not in out
    assert "2 passed" in out


@pytest.mark.parametrize("workers", [(), ("-n", "1")], ids=["alone", "xdist"])
def test_a_hang_no_signal_ends_names_the_test(tmp_path: Path, workers: tuple[str, ...]) -> None:
    (tmp_path / "test_stuck.py").write_text(_UNINTERRUPTIBLE)
    args = ("-p", "xdist", *workers) if workers else ()
    done = _pytest(tmp_path, *args, grace_s=1.0)
    out = done.stdout + done.stderr
    assert done.returncode != 0, out
    assert "INTERNALERROR" not in out
    if workers:
        assert "crashed while running 'test_stuck.py::test_signal_blocked'" in out, out
    else:
        assert "TIMEOUT: test_stuck.py::test_signal_blocked\n" in out, out
