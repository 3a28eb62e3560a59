"""What ``rover bridge`` says about its link at the default verbosity
(``bridge/link/linklines.py``): the narrator fed snapshots, then the real process against a
missing device, a silent pty, an emulator at the wrong baud and a good one."""

from __future__ import annotations

import dataclasses
import os
import pty
import subprocess
import sys
from pathlib import Path

import pytest

from bridge.link.controllerlink import LinkDiagnostics
from bridge.link.linklines import SILENT_AFTER_S, LinkNarrator
from tests.child import Child

BASE = LinkDiagnostics(
    state="disconnected", url="/dev/x", connected=False, missed_beats=0, lost_after_beats=None,
    heartbeat_losses=0, reconnects=0, reboots=0, rtt_ms=None, rtt_median_ms=None,
    heartbeat_age_s=None, rx_frames=0, tx_frames=0, crc_errors=0, resyncs=0, rx_dropped=0,
    rx_overflow=0, lost_frames=0, retries=0, no_ack_faults=0, stop_repeats=0, watchdog_trips=0,
    last_stop_latency_ms=None, last_stopping_distance_mm=None, controller_state="UNKNOWN",
    stop_latched=False, estop_requested=False, faults=(), controller_queue=0, boot_nonce=None,
    firmware="", schema_hash="", host_schema_hash="", steps_sent=0, steps_completed=0,
    steps_rejected=0, steps_aborted=0, rejected=(), last_error="",
)  # fmt: skip


def snap(**changes: object) -> LinkDiagnostics:
    return dataclasses.replace(BASE, **changes)  # type: ignore[arg-type]


def test_a_missing_device_is_said_once_in_words() -> None:
    n = LinkNarrator("/dev/ttyUSB7", 115200)
    error = "cannot open /dev/ttyUSB7: [Errno 2] No such file or directory: '/dev/ttyUSB7'"
    assert n.update(snap(last_error=error), 0.0) == [
        "cannot open /dev/ttyUSB7: no such device (plugged in? 'rover devices' lists them); "
        "retrying"
    ]
    assert n.update(snap(last_error=error), 0.5) == []  # not once per retry
    assert not n.reached


def test_an_open_device_that_stays_silent_or_sends_garbage() -> None:
    silent = LinkNarrator("/dev/pts/9", 115200)
    assert silent.update(snap(state="handshake"), 0.0) == []
    [line] = silent.update(snap(state="handshake"), SILENT_AFTER_S)
    assert line.startswith("/dev/pts/9 is open but no controller answers")
    assert "is it at 115200 baud?" in line
    assert silent.update(snap(state="handshake"), 2 * SILENT_AFTER_S) == []  # said once
    garbage = LinkNarrator("/dev/ttyACM0", 9600)
    garbage.update(snap(state="handshake"), 0.0)
    [line] = garbage.update(snap(state="handshake", crc_errors=12, resyncs=30), SILENT_AFTER_S)
    assert "no frame (12 CRC errors, 30 resyncs): wrong baud suspected" in line
    assert line.endswith("(the bridge is at 9600 baud: --baud)")


def test_handshake_loss_and_return_in_the_order_they_happened() -> None:
    n = LinkNarrator("/dev/x")
    ready = snap(state="ready", boot_nonce=0x1234, firmware="1.0.0", rx_frames=10)
    assert n.update(ready, 0.0) == ["handshake done: controller firmware 1.0.0, boot nonce 0x1234"]
    assert n.reached
    lost = dataclasses.replace(
        ready, state="lost", heartbeat_losses=1, last_error="no heartbeat", rx_frames=10
    )
    assert n.update(lost, 1.0) == ["link lost: no heartbeat; handshaking again"]
    back = dataclasses.replace(lost, state="ready")
    assert n.update(back, 2.0) == ["link back: controller firmware 1.0.0, boot nonce 0x1234"]
    # Ready and lost between two snapshots: the handshake is said before the loss.
    late = LinkNarrator("/dev/x")
    assert late.update(lost, 0.0) == [
        "handshake done: controller firmware 1.0.0, boot nonce 0x1234",
        "link lost: no heartbeat; handshaking again",
    ]


def test_a_flapping_link_with_frames_arriving_is_said_once() -> None:
    """Its bytes frame: a link that drops out or is too slow, not a wrong baud (#40, 9b)."""
    n = LinkNarrator("/dev/x", 115200)
    lines: list[str] = []
    for i in range(8):
        lines += n.update(
            snap(state="ready", boot_nonce=1, heartbeat_losses=i, rx_frames=30 * i), 0.5 * i
        )
    said = [x for x in lines if "heartbeats come late again and again" in x]
    assert len(said) == 1, lines
    assert "its bytes frame (the baud is right)" in said[0]
    assert not [x for x in lines if "wrong baud" in x]
    after = lines[lines.index(said[0]) + 1 :]
    assert not any("lost" in x for x in after)  # no line per flap once it is said


def test_a_flapping_link_among_bytes_that_do_not_frame_suspects_the_baud_once() -> None:
    n = LinkNarrator("/dev/x", 115200)
    lines: list[str] = []
    for i in range(8):
        diag = snap(
            state="ready", boot_nonce=1, heartbeat_losses=i, rx_frames=30 * i, crc_errors=40 * i
        )
        lines += n.update(diag, 0.5 * i)
    [suspected] = [x for x in lines if "wrong baud suspected" in x]
    assert "(120 CRC errors and resyncs beside 90 frames)" in suspected
    assert suspected.endswith("(the bridge is at 115200 baud: --baud)")


def test_losses_while_the_bridge_itself_stalled_say_nothing_of_the_link() -> None:
    n = LinkNarrator("/dev/x", 115200)
    lines: list[str] = []
    for i in range(8):
        diag = snap(state="ready", boot_nonce=1, heartbeat_losses=i, rx_frames=30 * i, stalls=i)
        lines += n.update(diag, 0.5 * i)
    assert not [x for x in lines if "again and again" in x], lines


def _bridge(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", "bridge", "--ros-backend", "inprocess", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@pytest.mark.parametrize(
    ("device", "said"),
    [
        ("/nonexistent/ttyUSB7", "cannot open /nonexistent/ttyUSB7: no such device"),
        ("/dev/null", "cannot open /dev/null: not a serial port"),
        ("/", "cannot open /: it is a directory, not a serial device"),
    ],
)
def test_the_bridge_on_a_device_it_cannot_open_says_why_and_exits_3(device: str, said: str) -> None:
    out = _bridge("--device", device, "--duration", "2")
    assert out.returncode == 3, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("BRIDGE ")
    assert len(lines) == 2, lines  # one line, not one per retry
    assert lines[1].startswith(f"bridge: {said}") and lines[1].endswith("; retrying")
    assert out.stderr.splitlines()[-1] == (
        f"rover bridge: error: stopped without ever reaching a controller at {device}"
    )


def test_the_bridge_on_a_silent_pty_says_nobody_answers() -> None:
    master, slave = pty.openpty()
    try:
        out = _bridge("--device", os.ttyname(slave), "--duration", str(SILENT_AFTER_S + 1.5))
    finally:
        os.close(master)
        os.close(slave)
    assert out.returncode == 3, out.stderr
    assert any("is open but no controller answers" in x for x in out.stdout.splitlines())


def test_the_bridge_says_handshake_done_and_a_slow_emulator_is_said_too_slow(
    tmp_path: Path,
) -> None:
    good, slow = tmp_path / "good", tmp_path / "slow"
    emulators = [
        Child(["emulate", "--serial", "--link", str(good), "--duration", "60"], dict(os.environ)),
        Child(
            ["emulate", "--serial", "--link", str(slow), "--baud", "9600", "--duration", "60"],
            dict(os.environ),
        ),
    ]
    try:
        for emulator in emulators:
            emulator.wait_for("DEVICE ")
        ok = _bridge("--device", str(good), "--duration", "2")
        assert ok.returncode == 0, ok.stderr
        assert ok.stdout.splitlines()[1].startswith("bridge: handshake done: controller firmware")
        bad = _bridge("--device", str(slow), "--duration", "8")
    finally:
        for emulator in emulators:
            emulator.stop()
    # A pty has no baud: the paced emulator's bytes all frame, it is only too slow for
    # its telemetry (a wrong baud on a real line shows as bytes that do not frame).
    said = [x for x in bad.stdout.splitlines() if "again and again" in x]
    assert len(said) == 1, bad.stdout
    assert "slower than the controller's telemetry" in said[0]
    assert "wrong baud" not in bad.stdout
    # The link's own warnings are the narrator's lines (a stall of this process on a
    # loaded machine is reported by the stall monitor, not by the link: not counted).
    link_warnings = [
        x for x in bad.stderr.splitlines() if "WARNING" in x and "runtime.stall" not in x
    ]
    assert link_warnings == [], bad.stderr
