"""tests/_wait_go.py, the plugin with which ``.ci/test``'s VM collects early and tests on
its turn: after collection, no test runs until the go file exists; without it, within
the time limit, none runs at all and the run says so."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from tests._wait_go import WAIT_GO_ENV, WAIT_GO_TIMEOUT_ENV, wait_for_go

ROOT = Path(__file__).resolve().parents[1]

CHILD_TEST = """
from pathlib import Path

def test_the_go_file_was_there_first():
    assert Path({go!r}).exists()
"""


def test_an_existing_file_is_go_at_once(tmp_path: Path) -> None:
    (tmp_path / "go").touch()
    assert wait_for_go(str(tmp_path / "go"), 0.0)


def test_a_file_that_never_comes_is_no_go_after_the_limit(tmp_path: Path) -> None:
    assert not wait_for_go(str(tmp_path / "go"), 0.2)


def test_a_file_made_while_waiting_is_go(tmp_path: Path) -> None:
    go = tmp_path / "go"
    timer = threading.Timer(0.2, go.touch)
    timer.start()
    try:
        assert wait_for_go(str(go), 60.0)
    finally:
        timer.cancel()


def _child(tmp_path: Path, timeout_s: float) -> subprocess.Popen[str]:
    go = tmp_path / "go"
    (tmp_path / "test_child.py").write_text(CHILD_TEST.format(go=str(go)))
    env = {**os.environ, WAIT_GO_ENV: str(go), WAIT_GO_TIMEOUT_ENV: str(timeout_s)}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return subprocess.Popen(
        [sys.executable, "-m", "pytest", "-p", "tests._wait_go", "-p", "no:cacheprovider",
         "-q", "--rootdir", str(tmp_path), str(tmp_path / "test_child.py")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path, env=env,
    )  # fmt: skip


@pytest.mark.slow  # a pytest process
def test_the_tests_wait_after_collection_until_the_file_exists(tmp_path: Path) -> None:
    child = _child(tmp_path, 600.0)
    try:
        assert child.stdout is not None
        lines = []
        for line in child.stdout:  # the child says it waits once it has collected
            lines.append(line)
            if line.startswith("collected; the tests start once"):
                break
        assert lines and lines[-1].startswith("collected; the tests start"), lines
        (tmp_path / "go").touch()
        rest = child.stdout.read()
        assert child.wait(timeout=120) == 0, "".join(lines) + rest
    finally:
        child.kill()
        child.wait(timeout=30)
    assert "came after" in rest and "1 passed" in rest, rest


@pytest.mark.slow  # a pytest process
def test_no_go_within_the_limit_runs_no_test_and_says_so(tmp_path: Path) -> None:
    child = _child(tmp_path, 0.3)
    try:
        out, _ = child.communicate(timeout=120)
    finally:
        child.kill()
        child.wait(timeout=30)
    assert child.returncode == 4, out
    assert "did not come within 0.3 s: no test ran" in out and "passed" not in out, out
