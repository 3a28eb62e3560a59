"""``ROVER_REQUIRE_SOCKETCAN=1`` turns the skips of SocketCAN tests into errors (the vcan
CI job must fail loudly when vcan0 is missing), and leaves every other skip alone.

Runs a small test file in a child pytest with this suite's hook, as CI would."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SAMPLE = """
import pytest

@pytest.mark.socketcan
@pytest.mark.skipif(True, reason="no vcan0 here")
def test_marked_and_skipped_by_a_mark():
    pass

@pytest.mark.socketcan
def test_marked_and_skipped_inside():
    pytest.skip("vcan0 is down")

@pytest.mark.socketcan
def test_marked_and_running():
    pass

def test_not_socketcan_and_skipped():
    pytest.skip("no clang")
"""

CONFTEST = """
from tests.conftest import pytest_runtest_makereport  # noqa: F401  the hook under test

def pytest_configure(config):
    config.addinivalue_line("markers", "socketcan: needs vcan0")
"""


def _run(tmp_path: Path, require: str | None) -> subprocess.CompletedProcess[str]:
    (tmp_path / "test_sample.py").write_text(SAMPLE, encoding="utf-8")
    (tmp_path / "conftest.py").write_text(CONFTEST, encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if k != "ROVER_REQUIRE_SOCKETCAN"}
    env["PYTHONPATH"] = str(ROOT)
    if require is not None:
        env["ROVER_REQUIRE_SOCKETCAN"] = require
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-rA", "-p", "no:cacheprovider", str(tmp_path)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_without_the_switch_socketcan_tests_skip_with_their_reason(tmp_path: Path) -> None:
    result = _run(tmp_path, None)
    assert result.returncode == 0, result.stdout
    assert "1 passed, 3 skipped" in result.stdout
    assert "no vcan0 here" in result.stdout


@pytest.mark.parametrize("value", ["0", ""])
def test_only_1_switches_it_on(tmp_path: Path, value: str) -> None:
    assert _run(tmp_path, value).returncode == 0


def test_with_the_switch_a_skipped_socketcan_test_is_an_error(tmp_path: Path) -> None:
    result = _run(tmp_path, "1")
    assert result.returncode == 1, result.stdout
    out = result.stdout
    assert "ERROR test_sample.py::test_marked_and_skipped_by_a_mark" in out
    assert "FAILED test_sample.py::test_marked_and_skipped_inside" in out
    assert "ROVER_REQUIRE_SOCKETCAN=1: this SocketCAN test must run here" in out
    assert "would have been skipped: no vcan0 here" in out
    assert "would have been skipped: vcan0 is down" in out
    assert "PASSED test_sample.py::test_marked_and_running" in out
    assert "SKIPPED [1] test_sample.py" in out  # the other skip stays a skip


RCLPY_SAMPLE = """
import pytest

@pytest.mark.rclpy
def test_needs_ros():
    pytest.skip("no rclpy here")

def test_other():
    pytest.skip("no clang")
"""


def test_require_rclpy_turns_the_skip_of_a_ros_test_into_an_error(tmp_path: Path) -> None:
    (tmp_path / "test_sample.py").write_text(RCLPY_SAMPLE, encoding="utf-8")
    (tmp_path / "conftest.py").write_text(
        CONFTEST.replace("socketcan: needs vcan0", "rclpy: needs ROS 2"), encoding="utf-8"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROVER_REQUIRE_")}
    env["PYTHONPATH"] = str(ROOT)
    command = [sys.executable, "-m", "pytest", "-q", "-rA", "-p", "no:cacheprovider", "."]
    relaxed = subprocess.run(
        command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60, check=False
    )
    assert relaxed.returncode == 0, relaxed.stdout
    strict = subprocess.run(
        command,
        cwd=tmp_path,
        env={**env, "ROVER_REQUIRE_RCLPY": "1"},
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert strict.returncode == 1, strict.stdout
    assert "ROVER_REQUIRE_RCLPY=1: this ROS 2 test must run here" in strict.stdout
    assert "would have been skipped: no rclpy here" in strict.stdout
    assert "SKIPPED [1] test_sample.py" in strict.stdout  # the other skip stays a skip
