"""The emulator served on a real pty and a real python-can bus, driven by a plain host
(pyserial / python-can + firmware_proto), as a real host would drive the firmware.

The lockstep versions in test_controller.py check the exact claims tick by tick; these
check that a host on the wire sees the same: every answer here crossed a pty or a CAN
bus as frames."""

from __future__ import annotations

import json
import math
import os
import random
import signal
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import can
import pytest

from emulator.can_frontend import CanFrontEnd
from emulator.control import ControlServer
from emulator.controller import ControllerConfig, ControllerModel
from emulator.drive import turn_units_for_yaw
from emulator.engine import Emulator
from emulator.errors import InjectionError
from emulator.injection import Injector, parse_fault
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin
from firmware_proto.cli import main as rover_main
from firmware_proto.linkio.host import ProtocolHost
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap
from firmware_proto.runtime.realtime import EMULATOR_PRIORITY
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    SCHEMA_HASH,
    AckField,
    AckResult,
    ClearAck,
    ClearResult,
    Command,
    Encoders,
    Heartbeat,
    Ident,
    Motion,
    PoseMsg,
    Status,
    StepState,
    Stop,
    StopAck,
    Stopped,
    WheelSpeeds,
)
from firmware_proto.wire.messages import Ack as AckMsg
from tests.scheduling import threads_at

from .conftest import SPEED
from .host import can_host, serial_host
from .test_controller import ready
from .test_controller import run as run_lockstep

Factory = Callable[..., Emulator]


def drive_one_metre(host: ProtocolHost, seq: int = 1) -> Status:
    since = host.mark()
    host.send(Motion(seq, Command.FWD, 60, 23000))
    ack = host.expect(AckMsg, lambda a: a.seq == seq, since=since, timeout_s=10.0)
    assert ack.result == AckResult.ACCEPTED
    return host.expect(
        Status, lambda s: s.seq == seq and s.state != StepState.STARTED, since=since, timeout_s=15
    )


def test_fwd_one_metre_over_a_pty(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    with serial_host(emu.frontend.device) as host:
        host.handshake()
        done = drive_one_metre(host)
        assert (done.state, done.travel) == (StepState.COMPLETED, 23000)
        enc = host.expect(Encoders, since=host.mark(), timeout_s=10.0)
        assert enc.left == pytest.approx(23000, abs=2)
    status = emu.status()
    assert math.hypot(status.x_m, status.y_m) == pytest.approx(1.0, abs=0.01)


def test_stop_over_a_pty_zeroes_targets_latches_and_clear_resumes(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    with serial_host(emu.frontend.device) as host:
        host.handshake()
        host.send(Motion(1, Command.FWD, 60, 30000))
        host.send(Motion(2, Command.FWD, 60, 30000))
        host.expect(WheelSpeeds, lambda w: w.left_mm_s > 250, timeout_s=10)
        since = host.mark()
        host.send(Stop(77, 0))
        ack = host.expect(StopAck, since=since, timeout_s=10.0)
        assert ack.stop_id == 77
        # Every wheel-speed report after the acknowledgement shows zero targets.
        after_ack = host.mark()
        first = host.expect(WheelSpeeds, since=after_ack, timeout_s=10.0)
        assert (first.left_target_mm_s, first.right_target_mm_s) == (0, 0)
        aborted = {s.seq for s in host.messages(Status, since) if s.state == StepState.ABORTED}
        assert aborted == {1, 2}
        stopped = host.expect(Stopped, since=since, timeout_s=10.0)
        assert stopped.stop_id == 77 and 30 < stopped.distance_mm < 80
        host.expect(
            WheelSpeeds,
            lambda w: w.left_mm_s == 0 and w.right_mm_s == 0,
            since=since,
            timeout_s=10.0,
        )
        mark = host.mark()
        host.send(Motion(3, Command.FWD, 30, 100))
        assert (
            host.expect(AckMsg, lambda a: a.seq == 3, since=mark, timeout_s=10.0).result
            == AckResult.STOP_LATCHED
        )
        host.send(host.clear_stop_for(78))
        answer = host.expect(ClearAck, since=mark, timeout_s=10.0)
        assert (answer.stop_id, answer.result) == (78, ClearResult.CLEARED)
        assert drive_one_metre(host, seq=4).state == StepState.COMPLETED
    assert len(emu.stop_reactions) == 1


def test_garbage_bytes_are_ignored_and_counted(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    rng = random.Random(5)
    with serial_host(emu.frontend.device) as host:
        host.handshake()
        host.write_bytes(
            b"\x00"
            + bytes(rng.randrange(1, 256) for _ in range(200))
            + b"\x00garbage\x00\x01\x02\x00"
        )
        assert drive_one_metre(host).state == StepState.COMPLETED
        beat = host.expect(Heartbeat, lambda h: h.rx_errors > 0, since=host.mark(), timeout_s=10.0)
        assert beat.rx_errors >= 2
    assert emu.status().rx_errors == beat.rx_errors


def test_host_closing_and_reopening_the_port(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    device = emu.frontend.device
    with serial_host(device) as host:
        host.handshake()
    with serial_host(device) as host:  # reopened: stale bytes are skipped, service goes on
        host.handshake()
        assert drive_one_metre(host).state == StepState.COMPLETED


def test_corrupted_link_is_survived(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    with serial_host(emu.frontend.device) as host:
        host.handshake()
        emu.inject("link-corrupt=0.2")
        host.expect(Encoders, since=host.mark(), timeout_s=10.0)

        def damaged() -> int:
            counters = host.endpoint.counters
            return counters.crc + counters.framing + counters.oversize

        # The host's decoder drops the damaged frames; the rest come through. A fifth of
        # the frames is corrupted, so a damaged one arrives within a few heartbeats
        # (bounded: 200 heartbeats undamaged would be 0.8**200).
        for _ in range(200):
            if damaged():
                break
            host.expect(Heartbeat, since=host.mark(), timeout_s=10.0)
        assert damaged() > 0
        emu.inject("clear:link-corrupt")
        assert drive_one_metre(host).state == StepState.COMPLETED


def test_reboot_injection_gives_a_new_ident(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    with serial_host(emu.frontend.device) as host:
        first = host.handshake()
        # handshake() may have returned on the boot IDENT; once a heartbeat says the
        # handshake is done, the IDENT answering our HELLO is in too.
        host.expect(Heartbeat, lambda h: h.handshake_ok == 1, since=host.mark(), timeout_s=10.0)
        since = host.mark()
        control = ControlServer(emu).start()
        try:
            answer = control.execute("inject reboot")
            assert (answer["ok"], answer["fault"]) == (True, "reboot")
            assert answer["applied_s"] >= 0
            assert control.execute("inject warp")["ok"] is False
            assert "injections" in control.execute("injections")
        finally:
            control.close()
        ident = host.expect(Ident, since=since, timeout_s=10.0)
        assert ident.boot_nonce != first.boot_nonce
        beat = host.expect(Heartbeat, since=host.mark(), timeout_s=10.0)
        assert (beat.boot_nonce, beat.handshake_ok) == (ident.boot_nonce, 0)


def test_watchdog_trips_when_the_host_goes_quiet(serial_emulator: Factory) -> None:
    emu = serial_emulator()
    with serial_host(emu.frontend.device) as host:
        host.handshake()
        host.send(Motion(1, Command.FWD, 60, 30000))
        host.expect(WheelSpeeds, lambda w: w.left_mm_s > 100, timeout_s=10.0)
        with host.silent():
            since = host.mark()
            beat = host.expect(Heartbeat, lambda h: h.state == 4, since=since, timeout_s=10.0)
        assert beat.fault_bits & 1  # WATCHDOG; state 4 is FAULT
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
        with serial_host(str(link)) as host:
            host.handshake()
            assert drive_one_metre(host).state == StepState.COMPLETED
    assert not link.exists()


def test_paced_line_still_carries_everything(serial_emulator: Factory) -> None:
    emu = serial_emulator(baud=115200)
    with serial_host(emu.frontend.device) as host:
        host.handshake()
        assert drive_one_metre(host).state == StepState.COMPLETED


def test_retransmitted_motion_is_acknowledged_again_but_executed_once(
    serial_emulator: Factory,
) -> None:
    emu = serial_emulator()
    with serial_host(emu.frontend.device) as host:
        host.handshake()
        since = host.mark()
        host.send(Motion(5, Command.FWD, 60, 2300))
        host.send(Motion(5, Command.FWD, 60, 2300))  # a retransmission: same seq
        host.expect(AckMsg, lambda a: a.result == AckResult.DUPLICATE, since=since, timeout_s=10.0)
        host.expect(
            Status,
            lambda s: s.seq == 5 and s.state != StepState.STARTED,
            since=since,
            timeout_s=10.0,
        )
        host.send(Motion(5, Command.FWD, 60, 2300))  # a late one, after completion
        # Steps run in order: once seq 6 is done, a second run of 5 would have shown.
        host.send(Motion(6, Command.FWD, 60, 2300))
        host.expect(
            Status,
            lambda s: s.seq == 6 and s.state != StepState.STARTED,
            since=since,
            timeout_s=10.0,
        )
        acks = [a.result for a in host.messages(AckMsg, since) if a.seq == 5]
        ended = [s for s in host.messages(Status, since) if s.seq == 5]
    assert acks == [AckResult.ACCEPTED, AckResult.DUPLICATE, AckResult.DUPLICATE]
    assert [s.state for s in ended] == [StepState.STARTED, StepState.COMPLETED]
    assert emu.status().x_m == pytest.approx(0.2, abs=0.005)  # 5 and 6, 0.1 m each


def test_out_of_range_values_get_nack_naming_the_field(serial_emulator: Factory) -> None:
    # The codec refuses to encode a value beyond the plan's limits unless told not to:
    # strict=False checks only the wire range (u8, u16), which is what a faulty host
    # could put on the wire.
    emu = serial_emulator()
    with serial_host(emu.frontend.device) as host:
        host.handshake()
        since = host.mark()
        for motion in (
            Motion(1, Command.FWD, 61, 100),
            Motion(2, Command.FWD, 30, 30001),
            Motion(3, 5, 30, 100),
        ):
            host.send(motion, strict=False)
        host.expect(AckMsg, lambda a: a.seq == 3, since=since, timeout_s=10.0)
        nacks = [(a.seq, a.result, a.field) for a in host.messages(AckMsg, since)]
    assert nacks == [
        (1, AckResult.OUT_OF_RANGE, AckField.SPEED),
        (2, AckResult.OUT_OF_RANGE, AckField.DISTANCE),
        (3, AckResult.OUT_OF_RANGE, AckField.COMMAND),
    ]
    assert emu.status().queue_depth == 0


def test_slip_ground_travel_falls_short_while_the_encoders_count_it_all(
    serial_emulator: Factory, make_model: Callable[..., ControllerModel]
) -> None:
    # What the twin gives for the same step in lockstep, once the body came to rest.
    replica = ready(make_model)
    Injector(replica).apply(parse_fault("slip:both=0.1"))
    replica.handle(Motion(1, Command.FWD, 60, 23000))
    run_lockstep(replica, 15.0)
    expected_m = replica.twin.pose.x_m

    emu = serial_emulator()
    emu.inject("slip:both=0.1")
    with serial_host(emu.frontend.device) as host:
        host.handshake()
        done = drive_one_metre(host)
        enc = host.expect(Encoders, since=host.mark(), timeout_s=10.0)
    status = emu.status()
    assert (done.state, done.travel) == (StepState.COMPLETED, 23000)
    assert enc.left == pytest.approx(23000, abs=2) and enc.right == pytest.approx(23000, abs=2)
    ground_m = math.hypot(status.x_m, status.y_m)
    assert ground_m < 0.2  # the encoders say 1 m
    assert ground_m == pytest.approx(expected_m, abs=0.01)
    assert status.injected == ("slip:both=0.1",)
    assert "faults=none injected=slip:both=0.1 " in status.line()


def test_driving_into_the_lab_table_over_a_pty(serial_emulator: Factory, lab: WorldMap) -> None:
    # The controller has no bumper: against the table the wheels slip, the encoders count
    # the full step and it completes; the ground travel ends at the contact, which the
    # ground-seeing POSE shows, and the emulator reports the collision in its status.
    doc = lab.to_dict()
    doc["start"] = {"x": 2.4, "y": 3.0, "yaw_deg": 0.0}  # 0.85 m short of the table
    emu = serial_emulator(WorldMap.from_dict(doc))
    with serial_host(emu.frontend.device) as host:
        host.handshake()
        since = host.mark()
        host.send(Motion(1, Command.FWD, 60, 30000))
        done = host.expect(
            Status, lambda s: s.seq == 1 and s.state != StepState.STARTED, since=since, timeout_s=15
        )
        pose = host.expect(PoseMsg, since=host.mark(), timeout_s=10.0)
    status = emu.status()
    assert (done.state, done.travel) == (StepState.COMPLETED, 30000)
    assert status.collision == "table" and "HIT table" in status.line()
    assert status.faults == () and status.state == "IDLE"
    assert status.x_m == pytest.approx(3.25, abs=0.01)  # chassis front at the table, x 3.6
    assert pose.x_mm / 1000.0 == pytest.approx(status.x_m, abs=0.05)


def _seeded_run(emu: Emulator) -> dict[str, Any]:
    """A fixed session over the wire: what the host saw that the commands and the seed
    fix. Frames reach the twin at wall-clock-dependent ticks, so timestamps and the phase
    of sampled noise (IMU, POSE) differ between runs; the trajectory does not (the twin
    is at rest until the first step starts)."""
    with serial_host(emu.frontend.device) as host:
        ident = host.handshake()
        since = host.mark()
        for seq, (cmd, dist) in enumerate(
            [(Command.FWD, 9000), (Command.LEFT, 5000), (Command.FWD, 5000)], 1
        ):
            host.send(Motion(seq, cmd, 45, dist))
        host.expect(
            Status,
            lambda s: s.seq == 3 and s.state != StepState.STARTED,
            since=since,
            timeout_s=10.0,
        )
        rest = host.expect(
            WheelSpeeds,
            lambda w: (w.left_mm_s, w.right_mm_s) == (0, 0),
            since=host.mark(),
            timeout_s=10.0,
        )
        enc = host.expect(Encoders, lambda e: e.t_ms > rest.t_ms, since=host.mark(), timeout_s=10.0)
        session = {
            "nonce": ident.boot_nonce,
            "acks": [(a.seq, a.result) for a in host.messages(AckMsg, since)],
            "statuses": host.messages(Status, since),
            "encoders": (enc.left, enc.right),
        }
    status = emu.status()
    session["pose"] = (status.x_m, status.y_m, status.yaw_deg)
    return session


def test_the_same_seeded_run_twice_over_the_wire(serial_emulator: Factory, lab: WorldMap) -> None:
    first = _seeded_run(serial_emulator(lab, seed=3))
    again = _seeded_run(serial_emulator(lab, seed=3))
    # The body still slides some micrometres after the wheels report rest; the pose is
    # read at a wall-clock-dependent moment of that.
    assert again.pop("pose") == pytest.approx(first.pop("pose"), abs=1e-4)
    assert first == again
    assert first["encoders"] == (9000, 19000)
    other = serial_emulator(lab, seed=4)
    with serial_host(other.frontend.device) as host:
        assert host.handshake().boot_nonce != first["nonce"]


# -- CAN ---------------------------------------------------------------------------------


@pytest.fixture
def can_emulator(rover: RoverDescription, can_channel: str) -> Iterator[Callable[..., Emulator]]:
    started: list[Emulator] = []

    def make(node: int = 1, world: WorldMap | None = None, seed: int = 1) -> Emulator:
        model = ControllerModel(
            rover, Twin(rover, world), ControllerConfig(timeout_scale=SPEED), seed=seed
        )
        emu = Emulator(
            model,
            CanFrontEnd(interface="virtual", channel=can_channel, node=node),
            speed_factor=SPEED,
        )
        with threads_at(EMULATOR_PRIORITY):  # as `rover emulate` runs it
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
    with can.Bus(interface="virtual", channel=can_channel) as bus, can_host(bus, node=3) as host:
        host.handshake()
        assert drive_one_metre(host).state == StepState.COMPLETED
        host.send(Motion(2, Command.FWD, 60, 30000))
        host.expect(WheelSpeeds, lambda w: w.left_mm_s > 200, timeout_s=10.0)
        since = host.mark()
        host.send(Stop(5, 0))
        assert host.expect(StopAck, since=since, timeout_s=10.0).stop_id == 5
        assert host.expect(Stopped, since=since, timeout_s=10.0).stop_id == 5
    assert emu.status().stop_latched


def test_a_left_turn_over_a_virtual_can_bus_matches_the_calibrated_model(
    can_emulator: Callable[..., Emulator], can_channel: str, rover: RoverDescription
) -> None:
    emu = can_emulator()
    with can.Bus(interface="virtual", channel=can_channel) as bus, can_host(bus) as host:
        host.handshake()
        since = host.mark()
        units = turn_units_for_yaw(rover, math.pi / 2)
        host.send(Motion(1, Command.LEFT, 30, units))
        done = host.expect(
            Status, lambda s: s.seq == 1 and s.state != StepState.STARTED, since=since, timeout_s=15
        )
        enc = host.expect(Encoders, since=host.mark(), timeout_s=10.0)
    status = emu.status()
    assert done.state == StepState.COMPLETED
    assert status.yaw_deg == pytest.approx(90.0, abs=3.0)
    assert math.hypot(status.x_m, status.y_m) < 0.05  # on the spot
    assert (enc.left, enc.right) == (-units, units)  # the sides ran opposite ways


def test_can_node_ignores_other_nodes_and_refuses_corruption(
    can_emulator: Callable[..., Emulator], can_channel: str
) -> None:
    emu = can_emulator(node=2)
    with (
        can.Bus(interface="virtual", channel=can_channel) as bus_a,
        can.Bus(interface="virtual", channel=can_channel) as bus_b,
        can_host(bus_a, node=5, heartbeat_s=None) as other,
        can_host(bus_b, node=2) as host,
    ):
        other.send(Motion(1, Command.FWD, 10, 10))  # addressed to node 5: not ours
        host.handshake()
        host.send(Motion(1, Command.FWD, 10, 10))
        host.expect(AckMsg, lambda a: a.seq == 1, timeout_s=10.0)
        assert other.messages(AckMsg) == []  # nobody answered node 5
    assert emu.status().rx_frames >= 2
    for fault in ("link-corrupt=0.1", "link-corrupt=0.1@t=0.2"):
        with pytest.raises(InjectionError, match="CRC"):
            emu.inject(fault)
    assert emu.schedule.pending == [] and emu.injections == []
    assert emu.refused_injections == 2


class ControlClient:
    """A plain TCP client of the control interface: one line out, one JSON line back."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
        self.lines = self.sock.makefile("r", encoding="utf-8")

    def ask(self, line: str) -> dict[str, Any]:
        self.sock.sendall(line.encode() + b"\n")
        answer: dict[str, Any] = json.loads(self.lines.readline())
        return answer

    def close(self) -> None:
        self.lines.close()
        self.sock.close()


@pytest.fixture
def control_client() -> Iterator[Callable[[Emulator], ControlClient]]:
    opened: list[tuple[ControlServer, ControlClient]] = []

    def connect(emu: Emulator) -> ControlClient:
        server = ControlServer(emu).start()
        client = ControlClient(server.port)
        opened.append((server, client))
        return client

    yield connect
    for server, client in opened:
        client.close()
        server.close()


def test_the_control_port_refuses_what_cannot_apply_at_once(
    can_emulator: Callable[..., Emulator],
    control_client: Callable[[Emulator], ControlClient],
) -> None:
    emu = can_emulator()
    ctl = control_client(emu)
    for fault, reason in (
        ("link-corrupt=0.1", "CRC"),
        ("link-corrupt=0.1@t=0.2", "CRC"),
        ("slip:left=5", "slip scale"),
        ("slip:left=5@t=0.2", "slip scale"),
        ("imu-bias=99@d=0.5", "imu-bias"),
        ("stall:left@region=sandbox", "unknown region"),
    ):
        answer = ctl.ask(f"inject {fault}")
        assert answer["ok"] is False and reason in answer["error"], (fault, answer)
    assert ctl.ask("injections") == {"ok": True, "injections": []}
    assert emu.schedule.pending == []
    assert emu.refused_injections == 6


def test_the_control_port_says_when_a_fault_applies(
    serial_emulator: Factory, control_client: Callable[[Emulator], ControlClient]
) -> None:
    emu = serial_emulator()
    ctl = control_client(emu)
    now = ctl.ask("inject slip:left=0.5")
    assert (now["ok"], now["fault"]) == (True, "slip:left=0.5") and now["applied_s"] >= 0
    later = ctl.ask("inject stall:right@t=1000")
    assert later["ok"] is True and later["fires"] == "at twin time t=1000 s"
    assert 0 <= later["scheduled_s"] < 1000
    far = ctl.ask("inject imu-dropout@d=2.5")
    assert far["fires"] == "when the ground travel reaches 2.5 m (now 0.000 m)"
    status = ctl.ask("status")["status"]
    assert status["injected"] == ["slip:left=0.5"]
    assert [i["fault"] for i in ctl.ask("injections")["injections"]] == ["slip:left=0.5"]
    passed = ctl.ask("inject imu-bias=0.01@t=0")
    assert "passed" in passed["fires"]


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
            "--inject",
            "imu-bias=0.01",
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
        with serial_host(device_line[1]) as host:
            host.handshake()
            assert drive_one_metre(host).state == StepState.COMPLETED
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        # The immediate fault applied at the first tick, before the step could run (the
        # default step at 4x: 4 ms of twin time, 1 ms of wall time); the one at t=100 s
        # never fired.
        assert "fault injected: imu-bias=0.01 at t=0.004 s (cli)" in err  # the WARNING log
        injects = [line for line in err.splitlines() if line.startswith("INJECT")]
        assert injects == ["INJECT t=0.004 imu-bias=0.01 (cli)"]
        final = [line for line in err.splitlines() if line.startswith("emulator stopped")]
        assert len(final) == 1 and " injected=imu-bias=0.01 " in final[0]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=5)


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (["--serial", "--inject", "warp:left"], "unknown fault 'warp'"),
        (["--can", "virtual:refused", "--inject", "link-corrupt=0.1@t=0.2"], "CRC"),
    ],
)
def test_rover_emulate_cli_rejects_bad_faults_clearly(args: list[str], reason: str) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", "emulate", *args],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert out.returncode == 1
    assert out.stdout == ""  # refused before serving: no DEVICE or CAN line
    (line,) = out.stderr.splitlines()
    assert line.startswith("rover emulate: error: --inject ") and reason in line


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (["--can", "virtual:refused", "--inject", "link-corrupt=0.1"], "CRC"),
        (["--can", "virtual:refused", "--inject", "link-corrupt=0.1@t=0.2"], "CRC"),
        (["--serial", "--inject", "slip:left=5"], "slip scale must be in (0, 1], got 5"),
        (["--serial", "--inject", "slip:left=5@t=0.2"], "slip scale must be in (0, 1], got 5"),
        (["--serial", "--inject", "link-delay=60@d=1"], "link-delay must be in 0..10"),
        (["--serial", "--inject", "stall:left@region=moon"], "unknown region 'moon'"),
        (["--serial", "--telemetry-hz", "500"], "--telemetry-hz must be in 1..200"),
        (["--serial", "--watchdog-ms", "10"], "--watchdog-ms must be in 50..10000"),
    ],
)
def test_rover_emulate_refuses_what_cannot_apply_before_serving(
    args: list[str], reason: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "never.rlog"
    assert rover_main(["emulate", *args, "--duration", "5", "--record", str(log)]) == 1
    out, err = capsys.readouterr()
    assert out == ""
    (line,) = err.splitlines()
    assert line.startswith("rover emulate: error: ") and reason in line
    assert not log.exists()  # nothing was written either


def test_a_saturated_line_never_starves_the_handshake(serial_emulator: Factory) -> None:
    # 1200 baud carries ~8 frames/s against ~180/s of telemetry: without dropping stale
    # telemetry, IDENT (the lowest class) would wait behind it forever.
    emu = serial_emulator(baud=1200)
    front = emu.frontend
    assert isinstance(front, SerialFrontEnd)
    with serial_host(front.device) as host:
        assert host.handshake(timeout_s=10).schema_hash == SCHEMA_HASH
        # handshake() may return on the boot IDENT, the first frame out, before anything
        # could go stale. Each frame holds the line ~0.1 s while ~18 telemetry frames
        # queue behind it: by the sixth frame the writer has met stale ones and dropped
        # them.
        host.expect(Message, since=5, timeout_s=10)
    assert front.stale_dropped > 0
