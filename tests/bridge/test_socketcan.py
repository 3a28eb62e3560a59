"""The CAN link where a lab runs it: malformed frames, two controllers on one bus, the
interface taken down and up, and the STOP bench as a command, on python-can's
``virtual`` bus and on real SocketCAN (``vcan0``; ``.ci/test`` runs those in
``.ci/vcan-vm`` where this kernel has none)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import can
import pytest

from bridge.link.controllerlink import LinkState, StepRequest
from bridge.tools.stopbench import UNUSED_MSG_ID, malformed_frames
from emulator.can_frontend import CanFrontEnd
from emulator.engine import Emulator
from firmware_proto.wire.canmap import can_id
from firmware_proto.wire.messages import Ack, Command, Heartbeat, Status
from tests.child import Child
from tests.conftest import IN_VCAN_VM

from .conftest import (
    CAN_MEDIA,
    HAVE_VCAN0,
    NO_VCAN0,
    WIDE_WATCHDOG_MS,
    Links,
    can_channel_for,
    link_url,
    serve,
)

Emus = Callable[..., Emulator]

FWD = Command.FWD


def _to_host_malformed(node: int) -> list[can.Message]:
    """Malformed frames in the controller-to-host direction of ``node``: a HEARTBEAT of
    the wrong length, an unused id, an extended-id ACK, a remote STATUS."""
    return [
        can.Message(arbitration_id=can_id(Heartbeat.MSG_ID, node), data=b"1", is_extended_id=False),
        can.Message(arbitration_id=can_id(UNUSED_MSG_ID + 1, node), data=b"", is_extended_id=False),
        can.Message(arbitration_id=can_id(Ack.MSG_ID, node), data=bytes(6), is_extended_id=True),
        can.Message(
            arbitration_id=can_id(Status.MSG_ID, node), is_remote_frame=True, dlc=2,
            is_extended_id=False,
        ),
    ]  # fmt: skip


@pytest.mark.parametrize("kind", CAN_MEDIA)
def test_malformed_frames_are_counted_and_ignored_by_bridge_and_emulator(
    emulators: Emus, links: Links, kind: str, can_channel: str
) -> None:
    emu = serve(emulators, kind, can_channel, node=3)
    frontend = emu.frontend
    assert isinstance(frontend, CanFrontEnd)
    link, rec = links(link_url(emu))
    rec.wait_count("ready", 1)
    emu_before = frontend.decoder.counters.rejected
    diag = link.diagnostics()
    bridge_before, errors_before = diag.rx_dropped, diag.medium_errors
    bad = malformed_frames(3) + _to_host_malformed(3)
    data_frames = [f for f in bad if not f.is_error_frame]
    with can.Bus(interface=kind, channel=can_channel_for(kind, can_channel)) as peer:
        for frame in bad:
            peer.send(frame)
    # Sent before the step: each end has read them all once the step's frames are in.
    mark = rec.mark()
    link.submit_step(StepRequest(FWD, 30, 2300))
    assert rec.wait_count("completed", 1, since=mark) == ["accepted", "completed"]
    assert emu.status().x_m == pytest.approx(0.1, abs=0.01)  # executed once
    diag = link.diagnostics()
    assert diag.rx_dropped - bridge_before == len(data_frames)
    assert diag.medium_errors - errors_before == 1  # the bit-error frame: counted...
    assert diag.medium_state == "error_active" and link.state is LinkState.READY  # ...only
    assert frontend.decoder.counters.rejected - emu_before == len(data_frames)
    assert frontend.error_frames == 1
    counters = frontend.decoder.counters
    assert (counters.bad_length, counters.unknown_id, counters.not_classic) == (2, 2, 4)


@pytest.mark.parametrize("kind", CAN_MEDIA)
def test_two_controllers_on_one_bus_each_run_only_their_own_steps(
    emulators: Emus, links: Links, kind: str, can_channel: str
) -> None:
    # Two controllers and two links in this one process: under the VM's software CPU its
    # threads fall behind, and the link's 3-beat loss check fired over and over there
    # (ready, link_lost, ready, ...), and beside other work the controllers' 250 ms
    # watchdog tripped (their loops 100-160 ms behind); there a MOTION's four sends (50 ms
    # apart) also went unacknowledged once (fault:no_ack). Losing the link or a step is not
    # what this test is about: the watchdog, the loss check and the ACK's retries are the
    # link tests' (and the wire simulator's), so each is given a second here. Nor is
    # telemetry: in the VM it comes at 10 Hz, not 50 (on a host whose Python loop ran the
    # VM's 20 times slower, not 6, the MOTION went unacknowledged for a second there).
    telemetry = {"telemetry_hz": 10} if IN_VCAN_VM else {}
    first = serve(emulators, kind, can_channel, node=1, watchdog_ms=WIDE_WATCHDOG_MS, **telemetry)
    second = serve(
        emulators, kind, can_channel, node=2, seed=2, watchdog_ms=WIDE_WATCHDOG_MS, **telemetry
    )
    link1, rec1 = links(link_url(first), link_lost_beats=10, ack_timeout_s=0.25)
    link2, rec2 = links(link_url(second), link_lost_beats=10, ack_timeout_s=0.25)
    rec1.wait_count("ready", 1)
    rec2.wait_count("ready", 1)
    link1.submit_step(StepRequest(FWD, 30, 2300))
    link2.submit_step(StepRequest(FWD, 30, 4600))
    assert rec1.wait_count("completed", 1) == ["ready", "accepted", "completed"]
    assert rec2.wait_count("completed", 1) == ["ready", "accepted", "completed"]
    assert first.status().x_m == pytest.approx(0.1, abs=0.01)
    assert second.status().x_m == pytest.approx(0.2, abs=0.01)
    # A STOP is for one node only.
    mark = rec1.mark()
    link1.emergency_stop()
    rec1.wait(lambda xs: "stopped" in xs, since=mark)
    assert first.status().stop_latched and not second.status().stop_latched
    mark = rec2.mark()
    link2.submit_step(StepRequest(FWD, 30, 2300))
    assert rec2.wait_count("completed", 1, since=mark) == ["accepted", "completed"]
    assert second.status().x_m == pytest.approx(0.3, abs=0.01)
    assert first.status().x_m == pytest.approx(0.1, abs=0.01)


def _ip(*args: str) -> None:
    subprocess.run(["ip", "link", "set", *args], check=True, timeout=10)


@pytest.mark.socketcan
@pytest.mark.skipif(not HAVE_VCAN0, reason=NO_VCAN0)
def test_interface_down_is_a_lost_link_and_up_a_new_handshake(
    emulators: Emus, links: Links
) -> None:
    """``ip link set vcan0 down`` under a running link (a USB-CAN adapter unplugged, an
    interface restarted): the bridge reports the link lost, drops the step in flight,
    and once the interface is up again shakes hands anew and drives."""
    emu = serve(emulators, "socketcan", "vcan0")
    link, rec = links(link_url(emu), reconnect_min_s=0.05)
    rec.wait_count("ready", 1)
    link.submit_step(StepRequest(FWD, 60, 30000))
    rec.wait_count("accepted", 1)
    mark = rec.mark()
    try:
        _ip("vcan0", "down")
        rec.wait(lambda xs: "fault:link_lost" in xs, since=mark)
    finally:
        _ip("vcan0", "up")
    got = rec.wait(lambda xs: "ready" in xs, since=mark, timeout=30)
    assert "completed" not in got
    # If the emulator's watchdog stopped the rover meanwhile (it does unless the outage
    # was shorter than its timeout), the bridge clears that latch itself; a step sent
    # before then would be refused (fault_active). The watchdog cannot trip after the
    # handshake: our frames arrive again.
    if emu.status().stop_latched:
        rec.wait(lambda xs: "cleared" in xs, since=mark)
    # Under the VM's software CPU the emulator may play the outage into twin time after
    # the handshake: until its watchdog has stopped the rover (or the first step ended),
    # the rover still moves. Measure from a rover at rest and released.
    x_before = _at_rest(emu)
    mark = rec.mark()
    link.submit_step(StepRequest(FWD, 30, 2300))
    assert rec.wait_count("completed", 1, since=mark)[-1] == "completed"
    assert emu.status().x_m == pytest.approx(x_before + 0.1, abs=0.01)


def _at_rest(emu: Emulator, timeout_s: float = 30.0) -> float:
    """The emulated rover's x (m) once its wheels stand still and no STOP is latched,
    the same over two reads 50 ms apart; polled (the emulator's status has no event)."""
    deadline = time.monotonic() + timeout_s
    last: float | None = None
    while time.monotonic() < deadline:
        status = emu.status()
        still = not status.stop_latched and not any(abs(v) > 1e-6 for v in status.wheel_mps)
        if still and last is not None and status.x_m == last:
            return status.x_m
        last = status.x_m if still else None
        time.sleep(0.05)
    raise AssertionError(f"the rover did not come to rest in {timeout_s:g} s: {emu.status()}")


def _bench(out: Path, *extra: str) -> dict[str, object]:
    """``rover bench stop`` over vcan0 against ``rover emulate`` (both processes); the
    parsed stop_trials.json."""
    done = subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", "bench", "stop",
         "--can", "socketcan:vcan0", "--node", "4", "--trials", "3", "--seed", "3",
         "--max-delay", "0.1", "--telemetry-hz", "20", "--flood-hz", "300",
         "--out", str(out), *extra],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "STOP -> STOP_ACK" in done.stdout, done.stdout
    report: dict[str, object] = json.loads((out / "stop_trials.json").read_text())
    return report


@pytest.mark.socketcan
@pytest.mark.timeout(300)  # two STOP benches in the VM's software CPU: 32 to 46 s seen
@pytest.mark.skipif(not HAVE_VCAN0, reason=NO_VCAN0)
def test_the_stop_bench_command_over_vcan_flooded_with_valid_and_malformed_frames(
    tmp_path: Path,
) -> None:
    """``rover bench stop --can socketcan:vcan0`` against ``rover emulate`` on vcan0: with
    the default lower-priority flood, then with a flood of malformed frames aimed at the
    controller (which ignores every one), recording the run for ``rover decode``."""
    emulator = Child(
        ["emulate", "--can", "socketcan:vcan0", "--node", "4", "--seed", "5", "--dt", "0.004"],
        dict(os.environ),
    )
    try:
        assert emulator.wait_for("CAN ") == "CAN socketcan:vcan0 node 4"
        valid = _bench(tmp_path / "valid", "--record", str(tmp_path / "b.log"))
        malformed = _bench(tmp_path / "bad", "--flood-malformed")
    finally:
        emulator.stop()
    for report in (valid, malformed):
        assert report["passed"] == 3, report  # trials that passed every check
        flood = report["flood"]
        assert isinstance(flood, dict) and flood["sent"] > 0
    assert "CAN flood 0x63F" in str(valid["load"])
    assert "malformed frames" in str(malformed["load"])
    decoded = subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", "decode", "--only", "STOP,STOP_ACK",
         str(tmp_path / "b.log")],
        capture_output=True, text=True, timeout=60, check=True,
    ).stdout.splitlines()  # fmt: skip
    assert sum("STOP_ACK" in line for line in decoded) >= 3
