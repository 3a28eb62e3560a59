"""The latch and fault rules of docs/protocol.md ("Latch and faults", "Watchdog", "STOP
semantics", "Receive errors") on the controller model, in lockstep.

Each test pins one normative sentence: what sets which latch bit, that ``fault_bits``
follow the conditions and not the latch, what CLEAR_STOP answers, when the watchdog is
armed, and how MOTION STOP and wrong-direction frames are handled.
"""

from __future__ import annotations

from emulator.controller import ControllerModel, LatchCause
from emulator.injection import Injector, parse_fault
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    AbortReason,
    Ack,
    AckField,
    AckResult,
    ClearAck,
    ClearResult,
    ClearStop,
    Command,
    ControllerState,
    Fault,
    FaultCode,
    Heartbeat,
    Hello,
    HostHeartbeat,
    Motion,
    Param,
    ParamResult,
    ParamValue,
    SetParam,
    Status,
    Stop,
    StopAck,
    Stopped,
)

from .test_controller import Make, one, ready, run

WATCHDOG_BIT = 1 << (FaultCode.WATCHDOG - 1)


def latch_bits(model: ControllerModel) -> tuple[int, int, int, int]:
    """``(stop_latched, latch_stop, latch_watchdog, latch_fault)`` of a fresh HEARTBEAT."""
    hb = model.heartbeat()
    return hb.stop_latched, hb.latch_stop, hb.latch_watchdog, hb.latch_fault


def silent_until_watchdog(model: ControllerModel) -> list[Message]:
    return run(model, 1.5, heartbeat_s=None, until=lambda m: isinstance(m, Stopped))


def test_watchdog_latch_outlives_its_condition_and_says_so(make_model: Make) -> None:
    model = ready(make_model)
    model.handle(Motion(1, Command.FWD, 60, 30000))
    run(model, 0.5)
    out = silent_until_watchdog(model)
    assert Fault(FaultCode.WATCHDOG, 1, one(out, Fault).detail, model.latch_gen) in out
    assert one(out, Status).reason == AbortReason.WATCHDOG
    assert one(out, Stopped).stop_id == 0
    hb = model.heartbeat()
    assert (hb.state, hb.fault_bits) == (ControllerState.FAULT, WATCHDOG_BIT)
    assert latch_bits(model) == (1, 0, 1, 0)
    # A valid frame ends the condition, not the latch: the bit clears, latch_watchdog holds.
    assert model.handle(HostHeartbeat(1)) == [Fault(FaultCode.WATCHDOG, 0, 0, model.latch_gen)]
    hb = model.heartbeat()
    assert (hb.state, hb.fault_bits) == (ControllerState.FAULT, 0)
    assert latch_bits(model) == (1, 0, 1, 0)
    assert one(model.handle(Motion(2, Command.FWD, 10, 10))).result == AckResult.FAULT_ACTIVE
    assert model.handle(ClearStop(3, model.latch_gen)) == [
        ClearAck(3, ClearResult.CLEARED, model.latch_gen)
    ]
    assert latch_bits(model) == (0, 0, 0, 0)
    assert model.state == ControllerState.IDLE
    assert model.handle(ClearStop(4, model.latch_gen)) == [
        ClearAck(4, ClearResult.NOT_LATCHED, model.latch_gen)
    ]


def test_a_second_trip_reports_the_condition_again(make_model: Make) -> None:
    model = ready(make_model)
    silent_until_watchdog(model)
    model.handle(HostHeartbeat(1))
    again = run(model, 0.5, heartbeat_s=None, until=lambda m: isinstance(m, Fault))
    assert [m for m in again if isinstance(m, Fault)] == [
        Fault(FaultCode.WATCHDOG, 1, one(again, Fault).detail, model.latch_gen)
    ]


def test_stop_during_a_watchdog_latch_adds_its_bit_and_keeps_fault(make_model: Make) -> None:
    model = ready(make_model)
    silent_until_watchdog(model)
    out = model.handle(Stop(7, 0))
    assert out[0] == StopAck(7, ControllerState.FAULT, model.latch_gen)
    assert latch_bits(model) == (1, 1, 1, 0)  # an automatic clear is no longer allowed
    assert model.handle(ClearStop(8, model.latch_gen)) == [
        ClearAck(8, ClearResult.CLEARED, model.latch_gen)
    ]
    assert latch_bits(model) == (0, 0, 0, 0)


def test_watchdog_is_armed_by_a_matching_hello_only(make_model: Make) -> None:
    model = make_model()
    model.boot()
    model.handle(HostHeartbeat(1))  # a frame, but no session
    assert not any(isinstance(m, Fault) for m in run(model, 1.0, heartbeat_s=None))
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 1))  # mismatched: still no session
    assert not any(isinstance(m, Fault) for m in run(model, 1.0, heartbeat_s=None))
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    assert any(isinstance(m, Fault) for m in run(model, 1.0, heartbeat_s=None))
    # A mismatched HELLO disarms it again.
    model.handle(ClearStop(1, model.latch_gen))
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 1))
    assert not model.handshake_ok
    assert not any(isinstance(m, Fault) for m in run(model, 1.0, heartbeat_s=None))


def test_fault_persists_until_the_condition_goes_then_clears(make_model: Make) -> None:
    model = ready(make_model)
    injector = Injector(model)
    injector.apply(parse_fault("encoder-dropout:left"))
    bit = 1 << (FaultCode.ENCODER - 1)
    assert latch_bits(model) == (1, 0, 0, 1) and model.heartbeat().fault_bits == bit
    assert model.handle(ClearStop(1, model.latch_gen)) == [
        ClearAck(1, ClearResult.FAULT_PERSISTS, model.latch_gen)
    ]
    assert latch_bits(model) == (1, 0, 0, 1)
    assert injector.apply(parse_fault("clear:encoder-dropout")) == [
        Fault(FaultCode.ENCODER, 0, 0, model.latch_gen)
    ]
    assert model.heartbeat().fault_bits == 0 and latch_bits(model) == (1, 0, 0, 1)
    assert model.handle(ClearStop(2, model.latch_gen)) == [
        ClearAck(2, ClearResult.CLEARED, model.latch_gen)
    ]
    assert model.state == ControllerState.IDLE


def test_stall_is_an_event_its_condition_ends_at_rest(make_model: Make) -> None:
    model = ready(make_model)
    Injector(model).apply(parse_fault("stall:right"))
    model.handle(Motion(1, Command.FWD, 30, 23000))
    out = run(model, 4.0, until=lambda m: isinstance(m, Fault) and m.active == 0)
    faults = [m for m in out if isinstance(m, (Fault, Stopped))]
    gen = model.latch_gen
    assert faults == [Fault(FaultCode.STALL_RIGHT, 1, 23000, gen), Stopped(0, *faults[1][1:]),
                      Fault(FaultCode.STALL_RIGHT, 0, 0, gen)]  # fmt: skip
    assert model.heartbeat().fault_bits == 0
    assert latch_bits(model) == (1, 0, 0, 1) and model.state == ControllerState.FAULT
    assert model.handle(ClearStop(1, model.latch_gen)) == [
        ClearAck(1, ClearResult.CLEARED, model.latch_gen)
    ]


def test_motion_stop_ignores_speed_and_distance(make_model: Make) -> None:
    model = ready(make_model)
    model.handle(Motion(1, Command.FWD, 60, 30000))
    run(model, 0.5)
    out = model.handle(Motion(2, Command.STOP, 255, 65535))
    assert out[0] == Ack(2, AckResult.ACCEPTED, AckField.NONE, 0)
    assert model.wheel_setpoints_mps == (0.0, 0.0)
    assert latch_bits(model) == (1, 1, 0, 0)
    assert one(model.handle(Motion(2, Command.STOP, 0, 0))).result == AckResult.DUPLICATE
    stopped = [m for m in run(model, 2.0) if isinstance(m, Stopped)]
    assert [m.stop_id for m in stopped] == [0]


def test_every_new_stop_id_gets_its_own_stopped(make_model: Make) -> None:
    model = ready(make_model)
    model.handle(Stop(1, 0))
    model.handle(Stop(1, 0))  # a repeat: shares the first one's STOPPED
    assert [m.stop_id for m in run(model, 0.1) if isinstance(m, Stopped)] == [1]
    model.handle(Stop(2, 0))  # latched and at rest: reported on the next tick
    (stopped,) = [m for m in run(model, 0.01) if isinstance(m, Stopped)]
    assert (stopped.stop_id, stopped.distance_mm) == (2, 0)
    # A late repeat, after its STOPPED: acknowledged, not reported again.
    assert model.handle(Stop(1, 0)) == [StopAck(1, ControllerState.STOP_LATCHED, model.latch_gen)]
    assert not [m for m in run(model, 0.1) if isinstance(m, Stopped)]
    # After CLEARED an id may come back as a new stop.
    model.handle(ClearStop(3, model.latch_gen))
    model.handle(Stop(1, 0))
    assert [m.stop_id for m in run(model, 0.1) if isinstance(m, Stopped)] == [1]


def test_a_latch_set_in_boot_clears_back_to_boot(make_model: Make) -> None:
    model = make_model()
    model.boot()
    assert model.handle(Stop(1, 0))[0] == StopAck(1, ControllerState.STOP_LATCHED, model.latch_gen)
    assert model.handle(ClearStop(2, model.latch_gen)) == [
        ClearAck(2, ClearResult.CLEARED, model.latch_gen)
    ]
    assert model.state == ControllerState.BOOT


def test_wrong_direction_frames_are_counted_and_do_not_feed_the_watchdog(
    make_model: Make,
) -> None:
    model = ready(make_model)
    echo = model.heartbeat()
    before = model.rx_errors
    out: list[Message] = []
    for _ in range(400):  # 0.4 s of our own heartbeats echoed back, every tick
        out += model.handle(echo)
        out += model.tick()
    assert model.rx_errors == before + 400
    assert Fault(FaultCode.WATCHDOG, 1, one(out, Fault).detail, model.latch_gen) in out
    assert isinstance(echo, Heartbeat)
    assert LatchCause.WATCHDOG in model.latch_causes


def test_parameters_are_lost_at_reboot(make_model: Make) -> None:
    model = ready(make_model)
    assert model.handle(SetParam(Param.WATCHDOG_MS, 1000))[0] == ParamValue(
        Param.WATCHDOG_MS, ParamResult.OK, 1000
    )
    model.reboot()
    assert model.handle(SetParam(Param.WATCHDOG_MS, 0))[0] == ParamValue(
        Param.WATCHDOG_MS, ParamResult.OUT_OF_RANGE, 250
    )
