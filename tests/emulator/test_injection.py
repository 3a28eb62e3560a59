"""Fault injection in lockstep: checking up front, the three triggers, the record of each
injection, the faults in force, and the effect of the sensor faults on the telemetry a
host would receive. The link-drop pattern is checked on a real python-can bus."""

from __future__ import annotations

import logging
import math
import statistics
from collections.abc import Callable

import can
import pytest

from emulator.can_frontend import CanFrontEnd
from emulator.controller import ControllerModel
from emulator.drive import turn_units_for_yaw
from emulator.errors import InjectionError
from emulator.injection import FaultSchedule, InjectionRecord, Injector, parse_fault
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap
from firmware_proto.wire.canmap import CanDecoder
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    Command,
    ControllerState,
    Encoders,
    Fault,
    FaultCode,
    Heartbeat,
    HostHeartbeat,
    Imu,
    Motion,
    Status,
    StepState,
)

from .test_controller import ready

Make = Callable[..., ControllerModel]


def run(
    schedule: FaultSchedule,
    seconds: float,
    until: Callable[[Message], bool] | None = None,
) -> list[Message]:
    """Tick like the engine does (tick, then poll the schedule) for ``seconds`` of twin
    time or until a message matches, feeding the watchdog every 50 ms."""
    model = schedule.injector.model
    out: list[Message] = []
    for i in range(round(seconds / model.twin.dt_s)):
        if i % 50 == 0:
            out += model.handle(HostHeartbeat(i & 0xFFFF))
        new = model.tick()
        new += schedule.poll()
        out += new
        if until is not None and any(until(m) for m in new):
            break
    return out


def completed(seq: int) -> Callable[[Message], bool]:
    return lambda m: isinstance(m, Status) and m.seq == seq and m.state != StepState.STARTED


def poses_at_injection(injector: Injector) -> list[tuple[float, float]]:
    """The twin's (x, y) at each injection, captured by a listener as it fires."""
    seen: list[tuple[float, float]] = []
    twin = injector.model.twin
    injector.listeners.append(lambda _record: seen.append((twin.pose.x_m, twin.pose.y_m)))
    return seen


# -- refused up front ---------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("slip:left=5", r"slip scale must be in \(0, 1\]"),
        ("slip:both=0@t=0.2", r"slip scale must be in \(0, 1\]"),
        ("encoder-noise:left=-1", "encoder-noise must be in"),
        ("imu-bias=40@d=1", "imu-bias must be within"),
        ("link-drop=0.1", "needs a link"),
        ("clear:link-delay@t=1", "needs a link"),
        ("slip:left=0.5@region=nowhere", "unknown region 'nowhere'"),
    ],
)
def test_a_fault_that_cannot_apply_is_refused_when_given(
    make_model: Make, text: str, reason: str
) -> None:
    model = ready(make_model)
    injector = Injector(model)
    spec = parse_fault(text)
    with pytest.raises(InjectionError, match=reason):
        injector.check(spec)
    with pytest.raises(InjectionError, match=reason):
        FaultSchedule(injector, [spec])
    schedule = FaultSchedule(injector)
    with pytest.raises(InjectionError, match=reason):
        schedule.add(spec)
    with pytest.raises(InjectionError, match=reason):
        injector.apply(spec)
    assert schedule.pending == [] and injector.log == [] and injector.in_force() == ()
    assert model.twin.traction_scale == (1.0, 1.0)


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("link-corrupt=0.1", "CRC"),
        ("link-corrupt=0.1@t=0.2", "CRC"),
        ("link-drop=2", "ratio must be in 0..1"),
        ("link-delay=11@t=1", "link-delay must be in 0..10"),
    ],
)
def test_link_faults_are_checked_against_the_front_end(
    make_model: Make, can_channel: str, text: str, reason: str
) -> None:
    # Never started: checking reads what the medium can carry, nothing is opened.
    front = CanFrontEnd(interface="virtual", channel=can_channel)
    injector = Injector(ready(make_model), front)
    with pytest.raises(InjectionError, match=reason):
        FaultSchedule(injector).add(parse_fault(text))
    injector.check(parse_fault("link-drop=0.1@t=0.2"))  # what CAN can carry passes


# -- triggers and records -----------------------------------------------------------------


def test_at_time_trigger_fires_on_time_is_recorded_and_logged(
    make_model: Make, caplog: pytest.LogCaptureFixture
) -> None:
    model = ready(make_model)
    schedule = FaultSchedule(Injector(model), [parse_fault("imu-bias=0.05@t=0.5")], source="cli")
    assert schedule.pending == [parse_fault("imu-bias=0.05@t=0.5")]
    with caplog.at_level(logging.WARNING, logger="emulator.injection"):
        out = run(schedule, 1.0)
    assert schedule.pending == []
    (record,) = schedule.injector.log
    assert (record.fault, record.source) == ("imu-bias=0.05@t=0.5", "cli")
    assert 0.5 <= record.time_s < 0.5 + 1.5 * model.twin.dt_s
    assert record.line() == f"INJECT t={record.time_s:.3f} imu-bias=0.05@t=0.5 (cli)"
    (logged,) = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert "imu-bias=0.05" in logged.getMessage() and "t=0.500" in logged.getMessage()
    assert "@t=0.5" in logged.getMessage()
    # The gyro at rest reads noise only before, the bias after (its message in mrad/s).
    rates = [(m.t_ms, m.yaw_rate_mrad_s) for m in out if isinstance(m, Imu)]
    before = [r for t, r in rates if t < 500]
    after = [r for t, r in rates if t > 500]
    assert abs(statistics.mean(before)) < 5
    assert statistics.mean(after) == pytest.approx(50, abs=5)
    assert schedule.injector.in_force() == ("imu-bias=0.05",)


def test_distance_trigger_fires_after_that_much_ground_travel(make_model: Make) -> None:
    model = ready(make_model)
    start = model.twin.pose
    schedule = FaultSchedule(Injector(model), [parse_fault("slip:both=0.5@d=0.3")])
    fired_at = poses_at_injection(schedule.injector)
    model.handle(Motion(1, Command.FWD, 60, 23000))
    run(schedule, 10.0, until=completed(1))
    ((x, y),) = fired_at
    # Within one tick's travel (0.3 mm at full speed) of the distance asked for.
    assert math.hypot(x - start.x_m, y - start.y_m) == pytest.approx(0.3, abs=1e-3)
    assert schedule.ground_m > 0.5
    assert model.twin.traction_scale == (0.5, 0.5)
    assert [r.fault for r in schedule.injector.log] == ["slip:both=0.5@d=0.3"]


def test_region_trigger_fires_at_once_when_starting_inside(
    lab: WorldMap, rover: RoverDescription
) -> None:
    doc = lab.to_dict()
    doc["start"] = {"x": 1.1, "y": 5.1, "yaw_deg": 0.0}  # inside the lab's sandbox
    in_sandbox = WorldMap.from_dict(doc)
    model = ControllerModel(rover, Twin(rover, in_sandbox), seed=1)
    model.boot()
    schedule = FaultSchedule(Injector(model), [parse_fault("stall:left@region=sandbox")])
    run(schedule, 0.01)
    (record,) = schedule.injector.log
    assert record.time_s == pytest.approx(model.twin.dt_s)  # the first poll
    assert model.twin.wheel_locked == (True, False)
    assert schedule.injector.in_force() == ("stall:left",)


def test_region_trigger_fires_on_entering_the_region(
    make_model: Make, lab: WorldMap, rover: RoverDescription
) -> None:
    # From the lab's start (1.2, 3.0) facing east: turn north, drive 1.7 m into the
    # sandbox, whose south edge is y = 4.5.
    model = ready(make_model, lab)
    schedule = FaultSchedule(Injector(model), [parse_fault("slip:both=0.3@region=sandbox")])
    fired_at = poses_at_injection(schedule.injector)
    model.handle(Motion(1, Command.LEFT, 30, turn_units_for_yaw(rover, math.pi / 2)))
    model.handle(Motion(2, Command.FWD, 60, 30000))
    model.handle(Motion(3, Command.FWD, 60, 10000))
    run(schedule, 25.0, until=completed(3))
    ((x, y),) = fired_at
    assert 0.3 < x < 1.9
    assert y == pytest.approx(4.5, abs=1e-3)
    assert model.twin.traction_scale == (0.3, 0.3)


# -- faults in force ----------------------------------------------------------------------


def test_faults_in_force_follow_injections_and_clears(make_model: Make) -> None:
    injector = Injector(ready(make_model))
    for text in ("slip:both=0.1", "reboot", "imu-dropout"):
        injector.apply(parse_fault(text))
    assert injector.in_force() == ("imu-dropout", "slip:both=0.1")
    injector.apply(parse_fault("slip:left=0.3"))
    assert injector.in_force() == ("imu-dropout", "slip:left=0.3", "slip:right=0.1")
    injector.apply(parse_fault("clear:slip:right"))
    injector.apply(parse_fault("clear:imu-dropout"))
    assert injector.in_force() == ("slip:left=0.3",)
    injector.apply(parse_fault("slip:left=1"))  # full traction: nothing in force
    assert injector.in_force() == ()
    assert [r.fault for r in injector.log][-1] == "slip:left=1"


# -- sensor faults as a host sees them ------------------------------------------------------


def test_encoder_noise_shows_on_one_side_of_the_counts(make_model: Make) -> None:
    model = ready(make_model, seed=4)
    schedule = FaultSchedule(
        Injector(model),
        [parse_fault("encoder-noise:left=40@t=0.5"), parse_fault("clear:encoder-noise@t=1.5")],
    )
    out = run(schedule, 2.0)
    counts = [(m.t_ms, m.left, m.right) for m in out if isinstance(m, Encoders)]
    noisy = [left for t, left, _ in counts if 500 < t < 1500]
    assert {left for t, left, _ in counts if t < 500} == {0}  # at rest, no noise
    assert 20 < statistics.pstdev(noisy) < 60
    assert {right for _, _, right in counts} == {0}
    assert {left for t, left, _ in counts if t > 1500} == {0}
    assert schedule.injector.in_force() == ()


def test_imu_dropout_silences_the_imu_and_reports_a_fault_without_stopping(
    make_model: Make,
) -> None:
    model = ready(make_model)
    schedule = FaultSchedule(
        Injector(model), [parse_fault("imu-dropout@t=0.3"), parse_fault("clear:imu-dropout@t=0.6")]
    )
    model.handle(Motion(1, Command.FWD, 30, 4600))
    out = run(schedule, 1.0)
    imu_times = [m.t_ms for m in out if isinstance(m, Imu)]
    assert any(t < 300 for t in imu_times) and any(t > 600 for t in imu_times)
    assert not any(300 < t < 600 for t in imu_times)
    assert [m for m in out if isinstance(m, Fault)] == [
        Fault(FaultCode.IMU, 1, 0, model.latch_gen),
        Fault(FaultCode.IMU, 0, 0, model.latch_gen),
    ]
    imu_bit = 1 << (FaultCode.IMU - 1)
    assert any(isinstance(m, Heartbeat) and m.fault_bits & imu_bit for m in out)
    # Reporting only: the step ran on.
    assert model.state == ControllerState.EXECUTING
    assert [r.time_s for r in schedule.injector.log] == pytest.approx([0.3, 0.6], abs=0.002)


# -- link faults: the same seed, the same pattern ---------------------------------------------


def drop_pattern(channel: str, seed: int, frames: int = 200) -> list[int]:
    """Which of ``frames`` ENCODERS frames a host on a virtual CAN bus receives through a
    front end dropping half of them; the generator is seeded with ``seed``."""
    decoder = CanDecoder()
    with can.Bus(interface="virtual", channel=channel) as host:
        front = CanFrontEnd(interface="virtual", channel=channel, seed=seed)
        front.start(lambda _msg, _arrived: None)
        try:
            front.set_link_faults(drop=0.5)
            front.send([Encoders(i, i, 0) for i in range(frames)])
            front.set_link_faults(drop=0.0)
            front.send([Encoders(frames, -1, 0)])  # the end marker, never dropped
            got: list[int] = []
            while True:
                frame = host.recv(timeout=5.0)
                assert frame is not None, "the end marker never came"
                decoded = decoder.decode(frame.arbitration_id, bytes(frame.data))
                assert decoded is not None and isinstance(decoded.message, Encoders)
                if decoded.message.left < 0:
                    break
                got.append(decoded.message.t_ms)
            assert front.stats.fault_dropped == frames - len(got)
        finally:
            front.close()
    return got


def test_the_same_seed_drops_the_same_frames(can_channel: str) -> None:
    first = drop_pattern(can_channel + "-a", seed=7)
    again = drop_pattern(can_channel + "-b", seed=7)
    other = drop_pattern(can_channel + "-c", seed=8)
    assert first == again
    assert other != first
    assert 60 < len(first) < 140  # about half


def test_a_record_names_time_fault_and_source() -> None:
    record = InjectionRecord(1.25, "stall:right@t=1.25", "control")
    assert record.line() == "INJECT t=1.250 stall:right@t=1.25 (control)"
