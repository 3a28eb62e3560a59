"""A stack's parts end when the stack's process is killed outright (SIGKILL runs no
cleanup): its pipe to each part closes and the part ends itself
(firmware_proto/runtime/parentwatch.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from firmware_proto.runtime.parentwatch import pipe_for_child
from planner.stack.processes import ChildProcess

PARENT = """
import os, sys
from planner.stack.processes import ChildProcess
part = ChildProcess("gate", ["gate", "--port", "0", "--map", "lab", "--workers", "1",
                     "--pool", "thread"], "GATE ", 60, dict(os.environ))
print(part.proc.pid, flush=True)
sys.stdin.read()  # until the test kills this process
"""


def _gone(pid: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        try:  # a zombie of ours would never go: this is no child of ours, but be sure
            with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
                if stat.read().split(") ", 1)[1].startswith("Z"):
                    return True
        except FileNotFoundError:
            return True
        time.sleep(0.05)
    return False


@pytest.mark.timeout(120)
def test_a_part_ends_when_its_stack_is_killed() -> None:
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    part_pid = 0
    try:
        assert parent.stdout is not None
        part_pid = int(parent.stdout.readline())
        os.kill(part_pid, 0)  # the part is up
        parent.send_signal(signal.SIGKILL)
        parent.wait(30)
        assert _gone(part_pid, 60), f"the part {part_pid} outlived its killed parent"
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait(10)
        if part_pid and not _gone(part_pid, 0):
            os.kill(part_pid, signal.SIGKILL)


@pytest.mark.timeout(120)
def test_a_part_whose_parent_is_gone_before_it_starts_ends_too() -> None:
    # The parent dies before the part has started watching: the pipe, not the parent's
    # pid, tells (firmware_proto/runtime/parentwatch.py).
    read_fd, write_fd, watch_env = pipe_for_child()
    part = subprocess.Popen(
        [sys.executable, "-m", "firmware_proto.cli", "gate", "--port", "0", "--map", "lab"],
        stdin=read_fd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, **watch_env},
    )
    os.close(read_fd)
    os.close(write_fd)  # "the parent" is gone at once
    try:
        assert part.wait(60) is not None
    finally:
        if part.poll() is None:
            part.kill()
            part.wait(10)


@pytest.mark.timeout(120)
def test_a_part_stopped_by_its_parent_ends_cleanly() -> None:
    # The watch must not hold standard input's lock: the interpreter aborted at exit
    # ("could not acquire lock for <stdin> at interpreter shutdown") when it did.
    part = ChildProcess(
        "gate",
        ["gate", "--port", "0", "--map", "lab", "--workers", "1", "--pool", "thread"],
        "GATE ",
        60,
        dict(os.environ),
    )
    part.stop()
    assert part.proc.returncode == 0, part.stderr_tail()
    assert "Fatal Python error" not in part.stderr_tail()
