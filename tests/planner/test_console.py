"""``rover status``, ``rover stop``, ``rover clear-stop`` and ``rover echo`` against a
real ``rover bridge`` and ``rover emulate`` (real ROS 2, private network namespace); the
readable status from the bridge's own diagnostics; the stacks' domains."""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import shlex
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from bridge.link.controllerlink import LinkDiagnostics
from bridge.ros.diagnostics import diagnostic_array
from bridge.ros.rosport.msgs import stamp
from planner.ground.roverstatus import from_diagnostics
from planner.stack import domains
from tests.child import Child, run_rover

BASE = LinkDiagnostics(
    state="ready", url="/dev/x", connected=True, missed_beats=0, lost_after_beats=None,
    heartbeat_losses=0, reconnects=0, reboots=0, rtt_ms=0.2, rtt_median_ms=0.2,
    heartbeat_age_s=0.01, rx_frames=10, tx_frames=10, crc_errors=0, resyncs=0, rx_dropped=0,
    rx_overflow=0, lost_frames=0, retries=0, no_ack_faults=0, stop_repeats=0, watchdog_trips=0,
    last_stop_latency_ms=None, last_stopping_distance_mm=None, controller_state="IDLE",
    stop_latched=False, estop_requested=False, faults=(), controller_queue=0, boot_nonce=1,
    firmware="1.0.0", schema_hash="", host_schema_hash="", steps_sent=3, steps_completed=2,
    steps_rejected=1, steps_aborted=0, rejected=(("stop_latched", 1),), last_error="",
)  # fmt: skip


def _status(**changes: object) -> object:
    diag = dataclasses.replace(BASE, **changes)  # type: ignore[arg-type]
    msg = diagnostic_array(diag, stamp(), statuses=["ready", "accepted", "fault:stall_left"])
    return from_diagnostics(msg)


def test_the_status_reads_the_bridges_diagnostics_and_says_why_it_is_held() -> None:
    ready = _status()
    assert ready.ready and ready.why_held() == []  # type: ignore[attr-defined]
    text = ready.text("test")  # type: ignore[attr-defined]
    assert text.splitlines()[0] == "rover status (test): READY: steps are accepted"
    assert "statuses    ready, accepted, fault:stall_left  (oldest first)" in text
    assert "rejected 1 (stop_latched 1)" in text
    held = _status(
        controller_state="FAULT",
        stop_latched=True,
        latch=("stop", "fault"),
        latch_fault="STALL_LEFT",
        faults=("STALL_LEFT", "IMU"),
    )
    assert not held.ready  # type: ignore[attr-defined]
    why = held.why_held()  # type: ignore[attr-defined]
    assert why[0].startswith("fault condition STALL_LEFT is active")  # IMU only reports
    assert any("latched by a fault (STALL_LEFT)" in w for w in why)
    assert any("latched by an emergency stop: release it with 'rover clear-stop'" in w for w in why)
    lost = _status(state="lost", last_error="no controller heartbeat for 0.35 s")
    assert lost.why_held()[0].startswith(  # type: ignore[attr-defined]
        "the bridge has no link to the controller (link lost: no controller heartbeat"
    )
    doc = held.as_dict()  # type: ignore[attr-defined]
    assert doc["latch"] == ["stop", "fault"] and doc["levels"]["controller"] == "ERROR"


def test_each_stack_holds_a_domain_of_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(domains.DIR_ENV, str(tmp_path))
    with domains.claim() as one, domains.claim() as two:
        assert one.domain != two.domain
        assert {one.domain, two.domain} <= set(domains.STACK_DOMAINS)
        one.publish({"env": {"ROS_DOMAIN_ID": str(one.domain)}})
        assert [s["domain"] for s in domains.running()] == [one.domain]
        with (
            pytest.raises(domains.DomainBusyError, match=f"ROS domain {one.domain} is held"),
            domains.claim(one.domain),
        ):
            pass
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "firmware_proto.cli",
                "stack",
                "up",
                "--domain",
                str(two.domain),
            ],
            capture_output=True,
            text=True,
            timeout=60,
            env={**os.environ, domains.DIR_ENV: str(tmp_path)},
            check=False,
        )
        assert out.returncode == 1, out.stderr
        assert out.stderr.splitlines()[-1].startswith(
            f"rover stack: error: ROS domain {two.domain} is held by another rover stack"
        )
    assert domains.running() == []  # released with the stacks


_rover = functools.partial(run_rover, timeout_s=60.0)


@pytest.mark.rclpy
def test_nobody_answering_is_one_line_and_exit_1() -> None:
    out = _rover("status", "--timeout", "2")
    assert out.returncode == 1 and out.stdout == ""
    [line] = out.stderr.splitlines()
    assert line.startswith("rover status: error: no /diagnostics from a bridge on /ground/")
    assert line.endswith("add --namespace /")  # a bridge started alone is at the root
    out = _rover("clear-stop", "--timeout", "2")
    assert out.returncode == 1
    assert "NOT released: no answer" in out.stderr and "is a bridge running" in out.stderr
    assert "add --namespace /" in out.stderr
    out = _rover("status", "--namespace", "/", "--timeout", "2")
    assert out.returncode == 1 and "--namespace /" not in out.stderr


_LOGS: list[list[str]] = []


@pytest.fixture
def rover_side(tmp_path: Path) -> Iterator[None]:
    """A ``rover emulate`` on a pty and a ``rover bridge`` on it (the bridge's topics at
    the root namespace), up and handshaken."""
    device = tmp_path / "rover-motor"
    env = dict(os.environ)
    children = [Child(["emulate", "--serial", "--link", str(device), "--speed-factor", "4"], env)]
    try:
        children[0].wait_for("DEVICE ")
        children.append(Child(["bridge", "--device", str(device)], env))
        children[-1].wait_for("bridge: handshake done")
        _LOGS.clear()
        _LOGS.extend(c.errors for c in children)  # their stderr, for a failure to show
        yield
    finally:
        for child in reversed(children):
            child.stop()


# Alone, after the rest (marker serial): in 3 of 5 runs of the whole test command the
# link between this bridge and its emulator stalled for more than 250 ms while the other
# worker ran (a watchdog trip or a lost link joined the STOP), never in 7 runs of this
# test alone or beside the simulator's soak. The stall is not diagnosed (docs/realtime.md).
@pytest.mark.serial
@pytest.mark.rclpy
@pytest.mark.usefixtures("rover_side")
def test_stop_status_echo_and_clear_stop_against_a_real_bridge() -> None:
    where = ("--namespace", "/")
    echo = Child(
        ["echo", "command_status", *where, "--count", "3", "--timeout", "30"], dict(os.environ)
    )
    try:
        echo.wait_for("# /command_status [std_msgs/String]")
        # An idle rover says nothing on command_status: its last status comes first, from
        # the bridge's /diagnostics (issue #41: echo failed on an idle rover).
        echo.wait_for("(the last before this echo, from /diagnostics)")
        stopped = _rover("stop", *where)
        assert stopped.returncode == 0, stopped.stdout + stopped.stderr
        assert stopped.stdout.startswith("stopped: the controller acknowledged the STOP")
        held = _rover("status", *where, "--json")
        assert held.returncode == 3, held.stdout + held.stderr
        doc = json.loads(held.stdout)
        assert doc["latch"] == ["stop"] and doc["controller_state"] == "STOP_LATCHED", (
            doc,
            _LOGS,
        )
        assert "stopped" in doc["statuses"]
        released = _rover("clear-stop", *where)
        assert released.returncode == 0, released.stdout + released.stderr
        assert released.stdout.startswith("released: the latch is off (it was held by stop)")
        assert echo.wait(30) == 0
    finally:
        echo.stop()
    heard = [line.split(" ", 1)[1] for line in echo.lines[1:]]
    assert heard == [
        "ready (the last before this echo, from /diagnostics)",
        "stopped",
        "cleared",
    ], (echo.lines, _LOGS)
    again = _rover("clear-stop", *where)
    assert again.returncode == 0 and again.stdout.startswith("not latched: there was nothing")
    watched = _rover("status", *where, "--watch", "--count", "2", "--json")
    assert watched.returncode == 0, watched.stderr
    reports = [json.loads(line) for line in watched.stdout.splitlines()]
    assert len(reports) == 2 and all(r["ready"] for r in reports)
    pose = _rover("echo", "odom_ground", *where, "--count", "1", "--timeout", "20")
    assert pose.returncode == 0, pose.stderr
    line = pose.stdout.splitlines()[1]
    x = float(line.split(" x=", 1)[1].split()[0])
    # The lab's start, x = 1.2 m, as the ground-seeing POSE measures it (1 cm noise: a
    # reading of 1.195 is the start too).
    assert abs(x - 1.2) < 0.05 and "frame=map" in pose.stdout, line


@pytest.mark.rclpy
def test_a_stack_on_a_real_device_starts_no_emulator(tmp_path: Path, one_stack: None) -> None:
    """``rover stack up --device``: the bridge opens the device given (here a
    ``rover emulate`` the lab started itself); no emulator is started, no control port
    is offered, and the health comes back through the link, a lossy one
    (``--loss 0.3 --jitter 0.05``: the relay's options, printed); on the way down it
    names only the parts it started."""
    device = tmp_path / "rover-motor"
    env = dict(os.environ)  # the run's stack directory (tests/conftest.py)
    emulator = Child(["emulate", "--serial", "--link", str(device)], env)
    stack: Child | None = None
    try:
        emulator.wait_for("DEVICE ")
        stack = Child(
            [
                *("stack", "up", "--device", str(device), "--baud", "115200"),
                *("--rtt", "0.2", "--jitter", "0.05", "--loss", "0.3"),
            ],
            env,
        )
        stack.wait_for("STACK UP domain ", timeout_s=120)
        assert (
            "rover stack: link: round trip 0.2 s, jitter up to 0.05 s each way, 30 % of "
            "messages lost each way (seed 1)" in stack.lines
        )
        assert any("rover link --rtt 0.2 --jitter 0.05 --loss 0.3" in x for x in stack.lines)
        assert not any(line.startswith("starting emulator") for line in stack.lines)
        assert any(f"rover bridge --device {device} --baud 115200" in x for x in stack.lines)
        assert f"DEVICE {device}" in stack.lines and not any(
            x.startswith("CONTROL ") for x in stack.lines
        )
        assert any("health: rover status" in x and "READY" in x for x in stack.lines)
        _the_stacks_console_answers(stack, env)
        inject = subprocess.run(
            [sys.executable, "-m", "firmware_proto.cli", "stack", "inject", "reboot"],
            capture_output=True,
            text=True,
            timeout=60,
            env=env,
            check=False,
        )
        assert inject.returncode == 1 and "drives a real device: no emulator" in inject.stderr
        stack.proc.send_signal(2)
        assert stack.wait(60) == 0
        assert (
            "rover stack: stopping the link, the onboard program, the bridge and the gate"
            in stack.lines
        )
    finally:
        if stack is not None:
            stack.stop()
        emulator.stop()


@pytest.mark.rclpy
def test_a_stack_whose_device_never_answers_does_not_stay_up(
    tmp_path: Path, one_stack: None
) -> None:
    """``rover stack up --device`` on a device with no controller behind it ends with the
    bridge's reason (exit 1) instead of staying up with the link in ERROR: within
    ``--link-timeout`` (plus the round trip) of the rover's first report, however long
    ``--startup-timeout`` would let the parts take."""
    stack = Child(
        [
            *("stack", "up", "--device", str(tmp_path / "nothing-here"), "--rtt", "0.2"),
            *("--startup-timeout", "45", "--link-timeout", "2"),
        ],
        dict(os.environ),
    )
    try:
        assert stack.wait(120) == 1
    finally:
        stack.stop()
    assert not any(line.startswith("STACK UP") for line in stack.lines), stack.lines
    error = next(line for line in stack.errors if line.startswith("rover stack: error:"))
    assert "no link to the controller" in error and "nothing-here" in error, stack.errors
    assert "within 2.2 s of the rover's first report" in error, error
    assert (
        "rover stack: stopping the link, the onboard program, the bridge and the gate"
        in stack.lines
    )


def _the_stacks_console_answers(stack: Child, env: dict[str, str]) -> None:
    """``rover stop``, ``status``, ``clear-stop`` and ``echo`` through the stack's
    console socket (issue #41: each took 4-13 s of rclpy start and DDS discovery): the
    export line points them at it; the STOP reaches the controller (latched by ``stop``,
    which only the bridge's STOP lane sets); ``stop`` loads no rclpy; a console that does
    not answer is said, and the command goes on over ROS 2."""
    stack.wait_for('  eval "$(rover stack env)"', 30)
    exported = subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", "stack", "env"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        check=False,
    )
    assert exported.returncode == 0, exported.stderr
    names = dict(item.split("=", 1) for item in shlex.split(exported.stdout.strip())[1:])
    url = names["ROVER_STACK_CONSOLE"]
    assert any(x.startswith(f"CONSOLE {url} ") for x in stack.lines)
    env = {**env, **names}

    def rover(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "firmware_proto.cli", *args],
            capture_output=True,
            text=True,
            timeout=60,
            env=env,
            check=False,
        )

    # `rover stop` as typed at a console, in a process that shows what it imported.
    probe = (
        "import sys; from firmware_proto.cli import main; status = main(['stop']); "
        "print('rclpy loaded:', 'rclpy' in sys.modules); sys.exit(status)"
    )
    stopped = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        check=False,
    )
    assert stopped.returncode == 0, stopped.stdout + stopped.stderr
    assert stopped.stdout.startswith(
        f"stopped: the controller acknowledged the STOP (the stack's console {url}, rover side)"
    )
    assert "rclpy loaded: False" in stopped.stdout
    held = rover("status", "--json")
    assert held.returncode == 3, held.stdout + held.stderr
    doc = json.loads(held.stdout)
    assert doc["latch"] == ["stop"] and doc["where"].startswith("the stack's console")
    assert "stopped" in doc["statuses"]
    released = rover("clear-stop")
    assert released.returncode == 0, released.stdout + released.stderr
    assert released.stdout.startswith("released: the latch is off (it was held by stop)")
    echo = rover("echo", "command_status", "--count", "1", "--timeout", "10")
    assert echo.returncode == 0, echo.stderr
    assert echo.stdout.splitlines()[1].endswith(" cleared (the last before this echo)")
    # A console that is gone: said once, then ROS 2 (here: the link's side, as rover go).
    with socket.socket() as probe_socket:
        probe_socket.bind(("127.0.0.1", 0))
        dead = f"http://127.0.0.1:{probe_socket.getsockname()[1]}"
    fallback = rover("status", "--console", dead, "--timeout", "20")
    assert fallback.returncode == 0, fallback.stdout + fallback.stderr
    assert f"rover status: the stack's console at {dead}" in fallback.stderr
    assert "over ROS 2 instead (--ros)" in fallback.stderr
    assert fallback.stdout.startswith("rover status (/ground, ROS domain ")
