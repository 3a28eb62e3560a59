"""The rules protocols v3 and v4 added (docs/protocol.md), on both controllers in
lockstep: the Python model and the C firmware core (:mod:`emulator.firmware`), one test each.

- no sensor samples before a session, though the sensors are read on schedule all the
  same (the C core's HAL calls are the model's, which the differential test relies on);
- a CLEAR_STOP that repeats the id of the last CLEARED is answered CLEARED again and
  releases nothing; a reboot forgets the id;
- queued steps wait for a STOPPED still owed, and an id reported after a CLEARED that it
  predates is a new stop again;
- stall detection watches a step at speed 1;
- the serial frame counter restarts at 0 at every boot (the C core's own framing).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import pytest

from emulator.controller import ControllerConfig, ControllerModel, LatchCause
from emulator.firmware import FirmwareController, make_controller
from emulator.injection import Injector, parse_fault
from emulator.sensors import ImuReading
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    AbortReason,
    AckResult,
    ClearAck,
    ClearResult,
    ClearStop,
    Command,
    Encoders,
    Fault,
    FaultCode,
    Hello,
    Ident,
    Imu,
    Motion,
    PoseMsg,
    Status,
    StepState,
    Stop,
    Stopped,
    WheelSpeeds,
)
from tests.firmware_proto.c_harness import compiler

from .test_controller import one, run

SAMPLES = (Encoders, WheelSpeeds, Imu, PoseMsg)


@pytest.fixture(
    params=["python", pytest.param("c", marks=pytest.mark.firmware)],
)
def controller(
    request: pytest.FixtureRequest, rover: RoverDescription
) -> Callable[..., ControllerModel]:
    """Factory of booted controllers of one implementation (seeded, open plane)."""
    if request.param == "c" and compiler() is None:
        pytest.skip("gcc not found (set CC): the C firmware core cannot be built here")

    def make(*, seed: int = 5, hello: bool = True) -> ControllerModel:
        model = make_controller(request.param, rover, Twin(rover), ControllerConfig(), seed=seed)
        model.boot()
        if hello:
            model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
        return model

    return make


Make = Callable[..., ControllerModel]


def _count_imu_reads(model: ControllerModel) -> list[int]:
    reads = [0]
    read = model.imu.read

    def counted() -> ImuReading | None:
        reads[0] += 1
        return read()

    model.imu.read = counted  # type: ignore[method-assign]
    return reads


def test_no_sensor_samples_before_a_session_yet_the_sensors_are_read(controller: Make) -> None:
    model = controller(hello=False)
    reads = _count_imu_reads(model)
    before = run(model, 1.0, heartbeat_s=None)
    assert not [m for m in before if isinstance(m, SAMPLES)]
    # Read on schedule all the same (50 Hz: at boot, then every 20 ms up to 1 s), so that
    # noise draws do not depend on it.
    assert reads[0] == 51
    answer = model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    assert [m.NAME for m in answer] == ["IDENT"]
    during = run(model, 1.0)
    assert sum(isinstance(m, Encoders) for m in during) == 50
    assert sum(isinstance(m, PoseMsg) for m in during) >= 9
    # A mismatched HELLO ends the session: its IDENT is the last word about samples.
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 1))
    assert not [m for m in run(model, 1.0) if isinstance(m, SAMPLES)]
    assert reads[0] == 151


def test_a_new_boot_sends_samples_only_after_its_hello(controller: Make) -> None:
    model = controller()
    model.handle(Motion(1, Command.FWD, 60, 30000))
    run(model, 0.5)
    (ident,) = model.reboot()
    assert isinstance(ident, Ident)
    assert not [m for m in run(model, 0.5) if isinstance(m, SAMPLES)]
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    first = one(run(model, 0.1), Encoders)
    assert abs(first.left) < 50 and abs(first.right) < 50  # the new boot's count


def test_a_repeated_clear_id_is_cleared_again_and_releases_nothing(controller: Make) -> None:
    model = controller()
    model.handle(Stop(1, 0))
    run(model, 0.05)
    gen = model.latch_gen
    assert model.handle(ClearStop(5, gen)) == [ClearAck(5, ClearResult.CLEARED, gen)]
    # The repeat that crossed its answer, with no latch: CLEARED, not NOT_LATCHED.
    assert model.handle(ClearStop(5, gen)) == [ClearAck(5, ClearResult.CLEARED, gen)]
    model.handle(Stop(2, 0))
    run(model, 0.05)
    assert model.latch_gen == (gen + 1) & 0xFF
    # ... and with a latch set since: CLEARED again, and the latch holds.
    assert model.handle(ClearStop(5, gen)) == [ClearAck(5, ClearResult.CLEARED, gen + 1)]
    assert model.latch_causes == {LatchCause.STOP}
    assert one(model.handle(Motion(3, Command.FWD, 10, 10))).result == AckResult.STOP_LATCHED
    assert model.handle(ClearStop(6, gen + 1)) == [ClearAck(6, ClearResult.CLEARED, gen + 1)]
    assert not model.latch_causes
    # A reboot forgets the request: a CLEAR_STOP 6 is a new one (nothing latched).
    model.reboot()
    assert model.handle(ClearStop(6, gen + 1)) == [ClearAck(6, ClearResult.NOT_LATCHED, 0)]


def test_queued_steps_wait_for_an_owed_stopped(controller: Make) -> None:
    model = controller()
    model.handle(Motion(1, Command.FWD, 60, 30000))
    run(model, 1.0)
    model.handle(Stop(3, 0))
    # Cleared before the wheels are at rest: the STOPPED is still owed.
    gen = model.latch_gen
    assert model.handle(ClearStop(4, gen)) == [ClearAck(4, ClearResult.CLEARED, gen)]
    assert one(model.handle(Motion(2, Command.FWD, 30, 2300))).result == AckResult.ACCEPTED
    out = run(model, 2.0, until=lambda m: isinstance(m, Status) and m.seq == 2)
    stopped = one(out, Stopped)
    assert stopped.stop_id == 3 and stopped.distance_mm > 20 and stopped.duration_ms > 100
    started = one(out, Status)
    assert (started.seq, started.state) == (2, StepState.STARTED)
    assert out.index(stopped) < out.index(started)
    # STOPPED 3 predates the CLEARED: 3 is not remembered, a STOP 3 is a new stop.
    run(model, 2.0, until=lambda m: isinstance(m, Status) and m.state != StepState.STARTED)
    model.handle(Stop(3, 0))
    again = run(model, 0.05)
    assert [m.stop_id for m in again if isinstance(m, Stopped)] == [3]
    # Within its latch an id is remembered: a repeat gets no second STOPPED.
    model.handle(Stop(3, 0))
    assert not [m for m in run(model, 0.05) if isinstance(m, Stopped)]


def test_a_locked_wheel_is_caught_at_speed_one(controller: Make) -> None:
    model = controller()
    Injector(model).apply(parse_fault("stall:right"))
    model.handle(Motion(1, Command.FWD, 1, 2300))
    out = run(model, 3.0, until=lambda m: isinstance(m, Fault))
    fault = one(out, Fault)
    assert (fault.code, fault.active) == (FaultCode.STALL_RIGHT, 1)
    assert fault.detail > 2290  # the locked side's distance still to go
    ended = [m for m in out if isinstance(m, Status) and m.state != StepState.STARTED]
    assert [(m.seq, m.state, m.reason) for m in ended] == [
        (1, StepState.ABORTED, AbortReason.STALL)
    ]


def _seqs(model: FirmwareController, out: list[Message]) -> list[int]:
    assert len(model.frame_seqs) == len(out)
    return model.frame_seqs


@pytest.mark.firmware
def test_the_c_cores_frame_counter_restarts_at_every_boot(rover: RoverDescription) -> None:
    if compiler() is None:
        pytest.skip("gcc not found (set CC): the C firmware core cannot be built here")
    model = FirmwareController(rover, Twin(rover), ControllerConfig(), seed=2)
    assert _seqs(model, model.boot()) == [0]
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    run(model, 0.3)
    assert model.frame_seqs and model.frame_seqs[-1] > 10
    out = model.reboot()
    assert [m.NAME for m in out] == ["IDENT"] and _seqs(model, out) == [0]
    beat = model.tick()
    while not beat:
        beat = model.tick()
    assert _seqs(model, beat)[0] == 1


# -- protocol v4 (issue #40), on both controllers ----------------------------------------


def _clear(model: ControllerModel, clear_id: int, latch_gen: int) -> ClearAck:
    """CLEAR_STOP ``clear_id`` naming ``latch_gen``: its CLEAR_ACK."""
    (ack,) = [m for m in model.handle(ClearStop(clear_id, latch_gen)) if isinstance(m, ClearAck)]
    return ack


def test_v4_a_clear_asked_for_before_a_fault_releases_nothing(controller: Make) -> None:
    """Hole 1: a clear naming the generation before an encoder fault rose and went is
    answered LATCH_CHANGED; the latch holds until a clear names the fault's generation."""
    model = controller()
    model.handle(Stop(1, 0))
    before = model.latch_gen
    injector = Injector(model)
    injector.apply(parse_fault("encoder-dropout:left"))
    injector.apply(parse_fault("clear:encoder-dropout"))
    assert model.latch_gen == (before + 1) & 0xFF
    ack = _clear(model, 2, before)
    assert (ack.result, ack.latch_gen) == (ClearResult.LATCH_CHANGED, model.latch_gen)
    assert model.latch_causes == {LatchCause.STOP, LatchCause.FAULT}
    assert _clear(model, 3, model.latch_gen).result == ClearResult.CLEARED


def test_v4_a_refused_clear_stays_refused_after_the_fault_goes(controller: Make) -> None:
    """Hole 2: the repeat of a clear answered FAULT_PERSISTS gets FAULT_PERSISTS again
    once the condition is gone; a new request releases."""
    model = controller()
    injector = Injector(model)
    injector.apply(parse_fault("encoder-dropout:left"))
    gen = model.latch_gen
    assert _clear(model, 5, gen).result == ClearResult.FAULT_PERSISTS
    injector.apply(parse_fault("clear:encoder-dropout"))
    assert _clear(model, 5, gen).result == ClearResult.FAULT_PERSISTS
    assert model.latch_causes == {LatchCause.FAULT}
    assert _clear(model, 6, gen).result == ClearResult.CLEARED


def test_v4_a_new_hosts_first_clear_with_the_last_ones_id_still_releases(
    controller: Make,
) -> None:
    """Hole 8: a bridge started again numbered its clears from 1, and its first clear
    (id 1) matched the old bridge's last CLEARED: v3 answered CLEARED and released
    nothing. The latch set since has a new generation, so it is a new request."""
    model = controller()
    model.handle(Stop(1, 0))
    assert _clear(model, 1, model.latch_gen).result == ClearResult.CLEARED
    model.handle(Stop(2, 0))  # the watchdog or an operator, after the old bridge died
    assert model.latch_causes
    assert _clear(model, 1, model.latch_gen).result == ClearResult.CLEARED
    assert not model.latch_causes


def test_v4_a_boot_nonce_differs_from_the_one_before(rover: RoverDescription) -> None:
    """Hole 5: an RNG that gives the same number again (no entropy, a fixed seed) must
    not make a reboot look like the same boot."""

    class _Fixed(ControllerModel):
        def _init_state(self) -> None:
            self._rng.seed(7)  # the same draw at every boot
            super()._init_state()

    model = _Fixed(rover, Twin(rover), ControllerConfig(), seed=1)
    nonces = [model.boot_nonce]
    for _ in range(3):
        model.reboot()
        nonces.append(model.boot_nonce)
    assert all(a != b for a, b in itertools.pairwise(nonces))
