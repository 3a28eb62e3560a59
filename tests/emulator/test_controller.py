"""The controller model in lockstep: firmware behaviour checked tick by tick.

These drive ControllerModel directly (handle/tick), which is how the exact claims
("zero in the tick the STOP arrives", "executed once") can be checked without timing.
The same behaviour over a real pty and a real CAN bus is in test_served.py.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar

import pytest

from emulator.controller import ControllerModel
from emulator.drive import turn_units_for_yaw
from emulator.injection import Injector, parse_fault
from emulator.twin import Pose2D
from firmware_proto.model.geometry import wrap_rad
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap
from firmware_proto.wire import messages as wm
from firmware_proto.wire.message import Message

Make = Callable[..., ControllerModel]


def run(
    model: ControllerModel,
    seconds: float,
    until: Callable[[Message], bool] | None = None,
    heartbeat_s: float | None = 0.05,
) -> list[Message]:
    """Tick for ``seconds`` of twin time (or until a message matches), feeding the
    watchdog like a host would."""
    out: list[Message] = []
    ticks = round(seconds / model.twin.dt_s)
    every = round(heartbeat_s / model.twin.dt_s) if heartbeat_s else 0
    for i in range(ticks):
        if every and i % every == 0:
            out += model.handle(wm.HostHeartbeat(i & 0xFFFF))
        new = model.tick()
        out += new
        if until is not None and any(until(m) for m in new):
            break
    return out


M = TypeVar("M", bound=Message)


def one(out: list[Message], kind: type[M] | None = None) -> Any:
    """The first message of ``out`` (of ``kind`` if given), typed for attribute access."""
    for msg in out:
        if kind is None or isinstance(msg, kind):
            return msg
    raise AssertionError(f"no {kind.__name__ if kind else 'message'} in {out}")


def ready(make: Make, world: WorldMap | None = None, **kw: object) -> ControllerModel:
    model = make(world, **kw)
    model.boot()
    model.handle(wm.Hello(wm.PROTOCOL_VERSION, wm.SCHEMA_HASH))
    return model


def completed(seq: int) -> Callable[[Message], bool]:
    return lambda m: isinstance(m, wm.Status) and m.seq == seq and m.state != wm.StepState.STARTED


def test_boot_sends_ident_and_motion_needs_a_handshake(make_model: Make) -> None:
    model = make_model()
    (ident,) = model.boot()
    assert isinstance(ident, wm.Ident)
    assert (ident.protocol_version, ident.schema_hash) == (wm.PROTOCOL_VERSION, wm.SCHEMA_HASH)
    assert model.state == wm.ControllerState.BOOT
    (ack,) = model.handle(wm.Motion(1, wm.Command.FWD, 30, 1000))
    assert ack == wm.Ack(1, wm.AckResult.NOT_READY, wm.AckField.NONE, 0)
    assert isinstance(model.handle(wm.Hello(wm.PROTOCOL_VERSION, wm.SCHEMA_HASH))[0], wm.Ident)
    assert model.state == wm.ControllerState.IDLE and model.handshake_ok


def test_schema_mismatch_at_hello_refuses_motion(make_model: Make) -> None:
    model = make_model()
    model.boot()
    ident = one(model.handle(wm.Hello(wm.PROTOCOL_VERSION, wm.SCHEMA_HASH ^ 0x1)), wm.Ident)
    assert ident.schema_hash == wm.SCHEMA_HASH  # the host sees the firmware's own hash
    assert not model.handshake_ok
    assert (
        one(model.handle(wm.Motion(1, wm.Command.FWD, 30, 1000))).result == wm.AckResult.NOT_READY
    )


def test_fwd_one_metre_without_slip(make_model: Make) -> None:
    model = ready(make_model)
    start = model.twin.pose
    model.handle(wm.Motion(1, wm.Command.FWD, 60, 23000))
    out = run(model, 10.0, until=completed(1))
    status = [m for m in out if isinstance(m, wm.Status)]
    assert [s.state for s in status] == [wm.StepState.STARTED, wm.StepState.COMPLETED]
    assert status[-1].travel == 23000
    end = model.twin.pose
    assert math.hypot(end.x_m - start.x_m, end.y_m - start.y_m) == pytest.approx(1.0, abs=0.01)
    assert model.state == wm.ControllerState.IDLE


def test_rev_goes_backwards(make_model: Make) -> None:
    model = ready(make_model)
    model.handle(wm.Motion(1, wm.Command.REV, 30, 11500))
    run(model, 10.0, until=completed(1))
    assert model.twin.pose.x_m == pytest.approx(-0.5, abs=0.01)


@pytest.mark.parametrize(("command", "sign"), [(wm.Command.LEFT, 1), (wm.Command.RIGHT, -1)])
def test_turns_match_the_calibrated_model(
    make_model: Make, rover: RoverDescription, command: int, sign: int
) -> None:
    model = ready(make_model)
    units = turn_units_for_yaw(rover, math.pi / 2)
    model.handle(wm.Motion(1, command, 30, units))
    run(model, 15.0, until=completed(1))
    assert math.degrees(model.twin.pose.yaw_rad) == pytest.approx(sign * 90.0, abs=3.0)
    assert math.hypot(model.twin.pose.x_m, model.twin.pose.y_m) < 0.05  # on the spot


def test_slip_makes_ground_travel_fall_short_while_encoders_count_it_all(make_model: Make) -> None:
    model = ready(make_model)
    Injector(model).apply(parse_fault("slip:both=0.1"))
    model.handle(wm.Motion(1, wm.Command.FWD, 60, 23000))
    out = run(model, 20.0, until=completed(1))
    assert [m for m in out if isinstance(m, wm.Status)][-1] == wm.Status(
        1, wm.StepState.COMPLETED, wm.AbortReason.NONE, 23000
    )
    encoders = [m for m in out if isinstance(m, wm.Encoders)][-1]
    assert encoders.left == pytest.approx(23000, abs=2) and encoders.right == pytest.approx(
        23000, abs=2
    )
    assert model.twin.pose.x_m < 0.95  # the ground saw less than the encoders


def test_slip_on_one_side_makes_the_rover_veer(make_model: Make) -> None:
    model = ready(make_model)
    Injector(model).apply(parse_fault("slip:left=0.1"))
    model.handle(wm.Motion(1, wm.Command.FWD, 60, 30000))
    run(model, 20.0, until=completed(1))
    assert abs(math.degrees(model.twin.pose.yaw_rad)) > 5.0


def test_stop_zeroes_targets_in_the_call_purges_latches_and_clear_resumes(make_model: Make) -> None:
    model = ready(make_model)
    for seq in (1, 2, 3):
        model.handle(wm.Motion(seq, wm.Command.FWD, 60, 30000))
    run(model, 1.5)
    assert model.wheel_setpoints_mps[0] > 0.2
    out = model.handle(wm.Stop(9, 0))
    # Before any further tick: targets zero, queue purged, latched, acknowledged first.
    assert model.wheel_setpoints_mps == (0.0, 0.0)
    assert model.queue_depth == 0
    assert out[0] == wm.StopAck(9, wm.ControllerState.STOP_LATCHED, model.latch_gen)
    aborted = [(m.seq, m.reason) for m in out if isinstance(m, wm.Status)]
    assert aborted == [(1, wm.AbortReason.STOP), (2, wm.AbortReason.STOP), (3, wm.AbortReason.STOP)]
    # Braking follows the accel limit, then STOPPED with the stopping distance.
    after = run(model, 2.0, until=lambda m: isinstance(m, wm.Stopped))
    stopped = [m for m in after if isinstance(m, wm.Stopped)]
    assert len(stopped) == 1 and stopped[0].stop_id == 9
    assert 40 <= stopped[0].distance_mm <= 70  # v^2/2a = 0.3^2/1.6 = 56 mm
    assert model.at_rest
    # Latched: motion refused; a repeated STOP is harmless.
    assert (
        one(model.handle(wm.Motion(4, wm.Command.FWD, 60, 100))).result == wm.AckResult.STOP_LATCHED
    )
    assert model.handle(wm.Stop(9, 0))[0] == wm.StopAck(
        9, wm.ControllerState.STOP_LATCHED, model.latch_gen
    )
    assert model.handle(wm.ClearStop(10, model.latch_gen)) == [
        wm.ClearAck(10, wm.ClearResult.CLEARED, model.latch_gen)
    ]
    assert model.handle(wm.ClearStop(11, model.latch_gen)) == [
        wm.ClearAck(11, wm.ClearResult.NOT_LATCHED, model.latch_gen)
    ]
    assert one(model.handle(wm.Motion(4, wm.Command.FWD, 60, 100))).result == wm.AckResult.ACCEPTED
    run(model, 3.0, until=completed(4))
    assert model.state == wm.ControllerState.IDLE


def test_stop_step_in_motion_is_an_emergency_stop(make_model: Make) -> None:
    model = ready(make_model)
    model.handle(wm.Motion(1, wm.Command.FWD, 60, 30000))
    run(model, 1.0)
    out = model.handle(wm.Motion(2, wm.Command.STOP, 0, 0))
    assert one(out, wm.Ack).result == wm.AckResult.ACCEPTED
    assert model.wheel_setpoints_mps == (0.0, 0.0)
    assert model.stop_latched


def test_retransmission_is_acknowledged_but_executed_once(make_model: Make) -> None:
    model = ready(make_model)
    first = model.handle(wm.Motion(5, wm.Command.FWD, 60, 2300))
    again = model.handle(wm.Motion(5, wm.Command.FWD, 60, 2300))
    assert one(first).result == wm.AckResult.ACCEPTED
    assert one(again).result == wm.AckResult.DUPLICATE
    out = run(model, 3.0)
    out += model.handle(wm.Motion(5, wm.Command.FWD, 60, 2300))  # late retransmission
    out += run(model, 2.0)
    started = [m for m in out if isinstance(m, wm.Status) and m.state == wm.StepState.STARTED]
    assert len(started) == 1
    assert model.twin.pose.x_m == pytest.approx(0.1, abs=0.005)


@pytest.mark.parametrize(
    ("motion", "field"),
    [
        (wm.Motion(1, 5, 10, 10), wm.AckField.COMMAND),
        (wm.Motion(1, wm.Command.FWD, 61, 10), wm.AckField.SPEED),
        (wm.Motion(1, wm.Command.FWD, 10, 30001), wm.AckField.DISTANCE),
    ],
)
def test_out_of_range_gets_nack_with_the_field(
    make_model: Make, motion: wm.Motion, field: int
) -> None:
    model = ready(make_model)
    ack = one(model.handle(motion), wm.Ack)
    assert (ack.result, ack.field) == (wm.AckResult.OUT_OF_RANGE, field)
    assert model.queue_depth == 0
    # A refused seq is not remembered: the corrected step with the same seq is taken.
    assert one(model.handle(wm.Motion(1, wm.Command.FWD, 10, 10))).result == wm.AckResult.ACCEPTED


def test_queue_is_bounded(make_model: Make) -> None:
    model = ready(make_model, queue_depth=3)
    results = [one(model.handle(wm.Motion(i, wm.Command.FWD, 10, 100))).result for i in range(5)]
    assert results == [wm.AckResult.ACCEPTED] * 3 + [wm.AckResult.QUEUE_FULL] * 2


def test_watchdog_stops_and_faults_then_recovers_on_clear(make_model: Make) -> None:
    model = ready(make_model)
    model.handle(wm.Motion(1, wm.Command.FWD, 60, 30000))
    run(model, 1.0)
    out = run(model, 0.5, heartbeat_s=None)  # the host goes silent
    faults = [m for m in out if isinstance(m, wm.Fault)]
    assert faults and faults[0].code == wm.FaultCode.WATCHDOG and faults[0].active == 1
    assert 250 <= faults[0].detail <= 260
    assert model.state == wm.ControllerState.FAULT
    assert model.wheel_setpoints_mps == (0.0, 0.0)
    assert any(isinstance(m, wm.Status) and m.reason == wm.AbortReason.WATCHDOG for m in out)
    # Frames again: the condition clears, but FAULT holds until CLEAR_STOP.
    back = model.handle(wm.HostHeartbeat(1))
    assert back == [wm.Fault(wm.FaultCode.WATCHDOG, 0, 0, model.latch_gen)]
    assert (
        one(model.handle(wm.Motion(2, wm.Command.FWD, 10, 10))).result == wm.AckResult.FAULT_ACTIVE
    )
    assert model.handle(wm.ClearStop(3, model.latch_gen))[0] == wm.ClearAck(
        3, wm.ClearResult.CLEARED, model.latch_gen
    )
    assert model.state == wm.ControllerState.IDLE


def test_stalled_wheel_aborts_the_step_with_a_stall_fault(make_model: Make) -> None:
    model = ready(make_model)
    Injector(model).apply(parse_fault("stall:right"))
    model.handle(wm.Motion(1, wm.Command.FWD, 30, 23000))
    out = run(model, 3.0, until=lambda m: isinstance(m, wm.Fault))
    assert wm.Fault(wm.FaultCode.STALL_RIGHT, 1, 23000, model.latch_gen) in out
    assert any(isinstance(m, wm.Status) and m.reason == wm.AbortReason.STALL for m in out)
    assert model.state == wm.ControllerState.FAULT


def test_encoder_dropout_fault_persists_until_the_encoder_returns(make_model: Make) -> None:
    model = ready(make_model)
    injector = Injector(model)
    out = injector.apply(parse_fault("encoder-dropout:left"))
    assert out[0] == wm.Fault(wm.FaultCode.ENCODER, 1, 0, model.latch_gen)
    assert model.state == wm.ControllerState.FAULT
    assert model.handle(wm.ClearStop(1, model.latch_gen))[0] == wm.ClearAck(
        1, wm.ClearResult.FAULT_PERSISTS, model.latch_gen
    )
    assert injector.apply(parse_fault("clear:encoder-dropout")) == [
        wm.Fault(wm.FaultCode.ENCODER, 0, 0, model.latch_gen)
    ]
    assert model.handle(wm.ClearStop(2, model.latch_gen))[0] == wm.ClearAck(
        2, wm.ClearResult.CLEARED, model.latch_gen
    )


def test_pose_dropout_reports_no_fix_without_stopping(make_model: Make) -> None:
    model = ready(make_model)
    out = Injector(model).apply(parse_fault("pose-dropout"))
    assert out == [wm.Fault(wm.FaultCode.POSE, 1, 0, model.latch_gen)]
    model.handle(wm.Motion(1, wm.Command.FWD, 30, 2300))
    after = run(model, 2.0)
    poses = [m for m in after if isinstance(m, wm.PoseMsg)]
    assert poses and all(p.sigma_cm == 0 for p in poses)
    assert any(isinstance(m, wm.Status) and m.state == wm.StepState.COMPLETED for m in after)


def test_reboot_gives_a_new_nonce_and_forgets_everything(make_model: Make) -> None:
    model = ready(make_model)
    model.handle(wm.Motion(1, wm.Command.FWD, 60, 30000))
    run(model, 1.0)
    old = model.boot_nonce
    (ident,) = Injector(model).apply(parse_fault("reboot"))
    assert isinstance(ident, wm.Ident) and ident.boot_nonce != old
    assert model.state == wm.ControllerState.BOOT and model.queue_depth == 0
    assert model.wheel_commands_mps == (0.0, 0.0)
    before_hello = run(model, 0.2)
    heartbeat = [m for m in before_hello if isinstance(m, wm.Heartbeat)][-1]
    assert heartbeat.boot_nonce == ident.boot_nonce and heartbeat.handshake_ok == 0
    # Protocol v3: the new boot's counts reach a host only after its HELLO.
    assert not [m for m in before_hello if isinstance(m, wm.Encoders)]
    model.handle(wm.Hello(wm.PROTOCOL_VERSION, wm.SCHEMA_HASH))
    assert [m for m in run(model, 0.1) if isinstance(m, wm.Encoders)][-1].left == 0


def test_hello_starts_a_new_session(make_model: Make) -> None:
    model = ready(make_model)
    model.handle(wm.Motion(1, wm.Command.FWD, 60, 30000))
    run(model, 0.5)
    out = model.handle(wm.Hello(wm.PROTOCOL_VERSION, wm.SCHEMA_HASH))
    aborted = one(out, wm.Status)
    assert (aborted.seq, aborted.state, aborted.reason) == (
        1,
        wm.StepState.ABORTED,
        wm.AbortReason.SESSION,
    )
    # The new session may reuse seq 1: it is a new step, not a duplicate.
    assert one(model.handle(wm.Motion(1, wm.Command.FWD, 10, 10))).result == wm.AckResult.ACCEPTED


def test_telemetry_rates_and_set_param(make_model: Make) -> None:
    model = ready(make_model)
    run(model, 0.5)
    out = run(model, 1.0)  # one second after a warm-up: rates are exact
    count = {
        kind: sum(isinstance(m, kind) for m in out)
        for kind in (wm.Encoders, wm.WheelSpeeds, wm.Imu, wm.PoseMsg, wm.Heartbeat)
    }
    assert count == {
        wm.Encoders: 50,
        wm.WheelSpeeds: 50,
        wm.Imu: 50,
        wm.PoseMsg: 10,
        wm.Heartbeat: 10,
    }
    assert model.handle(wm.SetParam(wm.Param.TELEMETRY_HZ, 100)) == [
        wm.ParamValue(wm.Param.TELEMETRY_HZ, wm.ParamResult.OK, 100)
    ]
    assert (
        one(model.handle(wm.SetParam(wm.Param.TELEMETRY_HZ, 500))).result
        == wm.ParamResult.OUT_OF_RANGE
    )
    assert one(model.handle(wm.SetParam(200, 1))).result == wm.ParamResult.UNKNOWN_PARAM
    run(model, 0.1)
    assert sum(isinstance(m, wm.Encoders) for m in run(model, 1.0)) == 100


def test_sensors_see_the_ground_encoders_do_not(make_model: Make) -> None:
    model = ready(make_model)
    Injector(model).apply(parse_fault("slip:left=0.1"))
    model.handle(wm.Motion(1, wm.Command.FWD, 60, 30000))
    out = run(model, 20.0, until=completed(1))
    yaw = model.twin.pose.yaw_rad
    imu_yaw = sum(m.yaw_rate_mrad_s for m in out if isinstance(m, wm.Imu)) / 1000.0 / 50.0
    assert imu_yaw == pytest.approx(yaw, abs=0.03)  # integrated gyro follows the true yaw
    last = [m for m in out if isinstance(m, wm.PoseMsg)][-1]
    assert math.radians(last.yaw_ddeg / 10.0) == pytest.approx(yaw, abs=0.05)
    enc = [m for m in out if isinstance(m, wm.Encoders)][-1]
    assert enc.left == pytest.approx(enc.right, abs=2)  # encoders: "straight"


def test_the_same_run_twice_gives_the_same_trajectory(make_model: Make, lab: WorldMap) -> None:
    def trace() -> list[tuple[float, float, float]]:
        model = ready(make_model, lab, seed=3)
        for seq, (cmd, dist) in enumerate(
            [(wm.Command.FWD, 9000), (wm.Command.LEFT, 5000), (wm.Command.FWD, 5000)]
        ):
            model.handle(wm.Motion(seq, cmd, 45, dist))
        poses = []
        for _ in range(200):
            run(model, 0.05)
            p = model.twin.pose
            poses.append((p.x_m, p.y_m, p.yaw_rad))
        return poses

    assert trace() == trace()


def test_driving_into_an_obstacle_stops_the_body_against_it(
    make_model: Make, lab: WorldMap, rover: RoverDescription
) -> None:
    goal = next(g for g in lab.goals if "collide" in g.note.lower() or "behind" in g.note.lower())
    model = ready(make_model, lab)
    start = model.twin.pose
    bearing = math.atan2(goal.y - start.y_m, goal.x - start.x_m)
    turn = wrap_rad(bearing - start.yaw_rad)
    model.handle(
        wm.Motion(
            1,
            wm.Command.LEFT if turn > 0 else wm.Command.RIGHT,
            20,
            turn_units_for_yaw(rover, turn),
        )
    )
    model.handle(wm.Motion(2, wm.Command.FWD, 60, 30000))
    model.handle(wm.Motion(3, wm.Command.FWD, 60, 30000))
    run(model, 25.0)
    hit = model.twin.first_collision
    assert hit is not None and hit.obstacle_id != "bounds"
    # The body is stopped against it: it went no further than the contact.
    end = model.twin.pose
    travelled = math.hypot(end.x_m - start.x_m, end.y_m - start.y_m)
    to_goal = math.hypot(goal.x - start.x_m, goal.y - start.y_m)
    assert travelled < to_goal
    assert _distance(end, hit.pose) < 0.05


def _distance(a: Pose2D, b: Pose2D) -> float:
    return math.hypot(a.x_m - b.x_m, a.y_m - b.y_m)
