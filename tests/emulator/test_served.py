"""The emulator served on a real pty and a real python-can bus, driven by a plain host
(pyserial / python-can + firmware_proto), as a real host would drive the firmware."""

from __future__ import annotations

import math
import os
import random
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import pytest

from emulator.can_frontend import CanFrontEnd
from emulator.control import ControlServer
from emulator.controller import ControllerConfig, ControllerModel
from emulator.engine import Emulator
from emulator.errors import InjectionError
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin
from firmware_proto.messages import (
    SCHEMA_HASH,
    AckResult,
    ClearAck,
    ClearResult,
    ClearStop,
    Command,
    Encoders,
    Heartbeat,
    Ident,
    Motion,
    Status,
    StepState,
    Stop,
    StopAck,
    Stopped,
    WheelSpeeds,
)
from firmware_proto.messages import Ack as AckMsg
from firmware_proto.rover import RoverDescription

from .conftest import SPEED
from .host import CanHost, SerialHost

Factory = Callable[..., Emulator]


def drive_one_metre(host: SerialHost | CanHost, seq: int = 1) -> Status:
    since = host.mark()
    host.send(Motion(seq, Command.FWD, 60, 23000))
    ack = host.wait_for(AckMsg, lambda a: a.seq == seq, since=since)
    assert ack.result == AckResult.ACCEPTED
    return host.wait_for(
        Status, lambda s: s.seq == seq and s.state != StepState.STARTED, since=since, timeout=15
    )


def test_fwd_one_metre_over_a_pty(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    with SerialHost(emu.frontend.device) as host:  # type: ignore[attr-defined]
        host.handshake()
        done = drive_one_metre(host)
        assert (done.state, done.travel) == (StepState.COMPLETED, 23000)
        enc = host.wait_for(Encoders, since=host.mark())
        assert enc.left == pytest.approx(23000, abs=2)
    status = emu.status()
    assert math.hypot(status.x_m, status.y_m) == pytest.approx(1.0, abs=0.01)


def test_stop_over_a_pty_zeroes_targets_latches_and_clear_resumes(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    with SerialHost(emu.frontend.device) as host:  # type: ignore[attr-defined]
        host.handshake()
        host.send(Motion(1, Command.FWD, 60, 30000))
        host.send(Motion(2, Command.FWD, 60, 30000))
        host.wait_for(WheelSpeeds, lambda w: w.left_mm_s > 250, timeout=10)
        since = host.mark()
        host.send(Stop(77, 0))
        ack = host.wait_for(StopAck, since=since)
        assert ack.stop_id == 77
        # Every wheel-speed report after the acknowledgement shows zero targets.
        after_ack = host.mark()
        first = host.wait_for(WheelSpeeds, since=after_ack)
        assert (first.left_target_mm_s, first.right_target_mm_s) == (0, 0)
        aborted = {s.seq for s in host.messages(Status, since) if s.state == StepState.ABORTED}
        assert aborted == {1, 2}
        stopped = host.wait_for(Stopped, since=since)
        assert stopped.stop_id == 77 and 30 < stopped.distance_mm < 80
        host.wait_for(WheelSpeeds, lambda w: w.left_mm_s == 0 and w.right_mm_s == 0, since=since)
        mark = host.mark()
        host.send(Motion(3, Command.FWD, 30, 100))
        assert (
            host.wait_for(AckMsg, lambda a: a.seq == 3, since=mark).result == AckResult.STOP_LATCHED
        )
        host.send(ClearStop(78))
        assert host.wait_for(ClearAck, since=mark) == ClearAck(78, ClearResult.CLEARED)
        assert drive_one_metre(host, seq=4).state == StepState.COMPLETED
    assert len(emu.stop_reactions) == 1


def test_garbage_bytes_are_ignored_and_counted(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    rng = random.Random(5)
    with SerialHost(emu.frontend.device) as host:  # type: ignore[attr-defined]
        host.handshake()
        host.write_raw(
            b"\x00"
            + bytes(rng.randrange(1, 256) for _ in range(200))
            + b"\x00garbage\x00\x01\x02\x00"
        )
        assert drive_one_metre(host).state == StepState.COMPLETED
        beat = host.wait_for(Heartbeat, lambda h: h.rx_errors > 0, since=host.mark())
        assert beat.rx_errors >= 2
    assert emu.status().rx_errors == beat.rx_errors


def test_host_closing_and_reopening_the_port(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    device = emu.frontend.device  # type: ignore[attr-defined]
    with SerialHost(device) as host:
        host.handshake()
    with SerialHost(device) as host:  # reopened: stale bytes are skipped, service goes on
        host.handshake()
        assert drive_one_metre(host).state == StepState.COMPLETED


def test_corrupted_link_is_survived(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    with SerialHost(emu.frontend.device) as host:  # type: ignore[attr-defined]
        host.handshake()
        emu.inject("link-corrupt=0.2")
        host.wait_for(Encoders, since=host.mark())
        # The host's decoder drops the damaged frames; the rest come through.
        host.wait_for(Heartbeat, since=host.mark())
        assert (
            host.decoder.counters.crc
            + host.decoder.counters.framing
            + host.decoder.counters.oversize
            > 0
        )
        emu.inject("clear:link-corrupt")
        assert drive_one_metre(host).state == StepState.COMPLETED


def test_reboot_injection_gives_a_new_ident(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    with SerialHost(emu.frontend.device) as host:  # type: ignore[attr-defined]
        first = host.handshake()
        # handshake() may have returned on the boot IDENT; once a heartbeat says the
        # handshake is done, the IDENT answering our HELLO is in too.
        host.wait_for(Heartbeat, lambda h: h.handshake_ok == 1, since=host.mark())
        since = host.mark()
        control = ControlServer(emu).start()
        try:
            assert control.execute("inject reboot") == {"ok": True}
            assert control.execute("inject warp")["ok"] is False
            assert "injections" in control.execute("injections")
        finally:
            control.close()
        ident = host.wait_for(Ident, since=since)
        assert ident.boot_nonce != first.boot_nonce
        beat = host.wait_for(Heartbeat, since=host.mark())
        assert (beat.boot_nonce, beat.handshake_ok) == (ident.boot_nonce, 0)


def test_watchdog_trips_when_the_host_goes_quiet(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    with SerialHost(emu.frontend.device) as host:  # type: ignore[attr-defined]
        host.handshake()
        host.send(Motion(1, Command.FWD, 60, 30000))
        host.wait_for(WheelSpeeds, lambda w: w.left_mm_s > 100)
        host.heartbeats.clear()
        since = host.mark()
        beat = host.wait_for(Heartbeat, lambda h: h.state == 4, since=since)  # FAULT
        assert beat.fault_bits & 1  # WATCHDOG
        assert any(s.state == StepState.ABORTED for s in host.messages(Status, since))


def test_unplug_and_replug_keeps_the_link_name(
    serial_emulator: Factory, tmp_path: Path, rover: RoverDescription
) -> None:
    from emulator.serial_frontend import SerialFrontEnd

    link = tmp_path / "rover-motor"
    model = ControllerModel(rover, Twin(rover), ControllerConfig(timeout_scale=SPEED), seed=2)
    with Emulator(model, SerialFrontEnd(link=link), speed_factor=SPEED) as emu:
        front = emu.frontend
        assert isinstance(front, SerialFrontEnd)
        old = front.device
        assert os.path.realpath(link) == old
        front.unplug()
        assert not link.exists() and not front.plugged
        front.replug()
        assert os.path.realpath(link) == front.device
        with SerialHost(str(link)) as host:
            host.handshake()
            assert drive_one_metre(host).state == StepState.COMPLETED
    assert not link.exists()


def test_paced_line_still_carries_everything(serial_emulator: Factory) -> None:
    emu = serial_emulator(baud=115200)
    with SerialHost(emu.frontend.device) as host:  # type: ignore[attr-defined]
        host.handshake()
        assert drive_one_metre(host).state == StepState.COMPLETED


# -- CAN ---------------------------------------------------------------------------------


@pytest.fixture
def can_emulator(rover: RoverDescription, can_channel: str) -> Iterator[Callable[..., Emulator]]:
    started: list[Emulator] = []

    def make(node: int = 1) -> Emulator:
        model = ControllerModel(rover, Twin(rover), ControllerConfig(timeout_scale=SPEED), seed=1)
        emu = Emulator(
            model,
            CanFrontEnd(interface="virtual", channel=can_channel, node=node),
            speed_factor=SPEED,
        )
        emu.start()
        started.append(emu)
        return emu

    yield make
    for emu in started:
        emu.close()


def test_fwd_and_stop_over_a_virtual_can_bus(
    can_emulator: Callable[..., Emulator], can_channel: str
) -> None:
    emu = can_emulator(node=3)
    with can.Bus(interface="virtual", channel=can_channel) as bus, CanHost(bus, node=3) as host:
        host.handshake()
        assert drive_one_metre(host).state == StepState.COMPLETED
        host.send(Motion(2, Command.FWD, 60, 30000))
        host.wait_for(WheelSpeeds, lambda w: w.left_mm_s > 200)
        since = host.mark()
        host.send(Stop(5, 0))
        assert host.wait_for(StopAck, since=since).stop_id == 5
        assert host.wait_for(Stopped, since=since).stop_id == 5
    assert emu.status().stop_latched


def test_can_node_ignores_other_nodes_and_refuses_corruption(
    can_emulator: Callable[..., Emulator], can_channel: str
) -> None:
    emu = can_emulator(node=2)
    with (
        can.Bus(interface="virtual", channel=can_channel) as bus_a,
        can.Bus(interface="virtual", channel=can_channel) as bus_b,
        CanHost(bus_a, node=5, heartbeat_s=None) as other,
        CanHost(bus_b, node=2) as host,
    ):
        other.send(Motion(1, Command.FWD, 10, 10))  # addressed to node 5: not ours
        host.handshake()
        host.send(Motion(1, Command.FWD, 10, 10))
        host.wait_for(AckMsg, lambda a: a.seq == 1)
        assert other.messages(AckMsg) == []  # nobody answered node 5
    assert emu.status().rx_frames >= 2
    with pytest.raises(InjectionError, match="CRC"):
        emu.inject("link-corrupt=0.1")


# -- the command line --------------------------------------------------------------------


def test_rover_emulate_cli_serves_and_stops_on_sigterm(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "emulate",
            "--serial",
            "--speed-factor",
            "4",
            "--control-port",
            "0",
            "--seed",
            "7",
            "--inject",
            "slip:left=0.5@t=100",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        device_line = proc.stdout.readline().split()
        control_line = proc.stdout.readline().split()
        assert device_line[0] == "DEVICE" and control_line[0] == "CONTROL"
        with SerialHost(device_line[1]) as host:
            host.handshake()
            assert drive_one_metre(host).state == StepState.COMPLETED
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        assert "emulator stopped" in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=5)


def test_rover_emulate_cli_rejects_bad_faults_clearly() -> None:
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "emulate",
            "--serial",
            "--inject",
            "warp:left",
        ],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert out.returncode == 1
    assert "unknown fault 'warp'" in out.stderr and "Traceback" not in out.stderr


def test_a_saturated_line_never_starves_the_handshake(serial_emulator: Factory) -> None:
    # 1200 baud carries ~8 frames/s against ~180/s of telemetry: without dropping stale
    # telemetry, IDENT (the lowest class) would wait behind it forever.
    emu = serial_emulator(baud=1200)
    front = emu.frontend
    assert isinstance(front, SerialFrontEnd)
    with SerialHost(front.device) as host:
        assert host.handshake(timeout=10).schema_hash == SCHEMA_HASH
    assert front.stale_dropped > 0
