"""``rover conformance`` listens before it plays: nobody answering is one line and exit
status 2, garbage is 'wrong baud suspected', a controller whose heartbeats crawl is
named before the table (a real pty, a real ``rover emulate`` at 9600 baud)."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
import threading
from pathlib import Path

from tests.child import Child


def _conformance(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", "conformance", *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def test_nothing_answering_is_one_line_and_exit_2() -> None:
    master, slave = pty.openpty()
    try:
        out = _conformance("--device", os.ttyname(slave))
    finally:
        os.close(master)
        os.close(slave)
    assert out.returncode == 2, out.stdout + out.stderr
    assert out.stdout == ""
    [line] = out.stderr.splitlines()
    assert line.startswith("rover conformance: error: no controller answers at /dev/")
    assert "nothing arrived in 2 s" in line


def test_bytes_that_are_no_frames_suspect_the_baud() -> None:
    master, slave = pty.openpty()
    stop = threading.Event()

    def babble() -> None:  # what a line at the wrong baud looks like: framing errors
        while not stop.wait(0.05):
            os.write(master, bytes([0x55, 0x13, 0xFE, 0x00, 0x21, 0x99, 0x00]))

    talker = threading.Thread(target=babble, daemon=True)
    talker.start()
    try:
        out = _conformance("--device", os.ttyname(slave))
    finally:
        stop.set()
        talker.join(5)
        os.close(master)
        os.close(slave)
    assert out.returncode == 2, out.stdout + out.stderr
    [line] = out.stderr.splitlines()
    assert "but no frame" in line and line.endswith("wrong baud suspected")


def test_a_controller_paced_at_9600_baud_is_named_before_the_table(tmp_path: Path) -> None:
    device = tmp_path / "rover-motor"
    emulator = Child(
        ["emulate", "--serial", "--link", str(device), "--baud", "9600", "--duration", "60"],
        dict(os.environ),
    )
    try:
        emulator.wait_for("DEVICE ")
        out = _conformance("--device", str(device), "--rule", "handshake")
    finally:
        emulator.stop()
    assert out.returncode == 1, out.stdout + out.stderr
    warning = out.stderr.splitlines()[0]
    assert warning.startswith("rover conformance: warning: the controller's heartbeats arrive")
    assert "wrong baud suspected" in warning
    assert "handshake  FAIL" in out.stdout
