"""A bug the simulator found in both controllers (docs/sim.md, "Bugs found", 5), fixed
in both and kept here as its regression test.

A step with speed 0 or distance 0 "is STARTED and COMPLETED in the same control tick"
(docs/protocol.md, STATUS) when the wheels are at rest. Started while a wheel still
turns against the new step's direction (the previous step ended early: a new session,
or a clear before rest), it never completed: its profile had nowhere to go and no speed
to get there, so the wheel it braked never arrived (``emulator/drive.py``
``StepProfile`` and the C core's profile alike), and the host's steps behind it waited
for ever; the simulator's ``never-stuck`` invariant caught it (``rover sim
--zero-steps``). Such a step now brakes both wheels to rest, as STOP does, and
completes."""

from __future__ import annotations

import pytest

from firmware_proto.model.rover import load_rover
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Ack,
    AckResult,
    Command,
    Fault,
    Hello,
    HostHeartbeat,
    Motion,
    Status,
    StepState,
)
from sim.controllers import build_controller
from sim.scenario import CONTROLLERS


@pytest.mark.parametrize("controller", CONTROLLERS)
@pytest.mark.parametrize(("speed", "distance"), [(25, 0), (0, 800)])
def test_a_zero_step_started_while_a_wheel_turns_completes(
    controller: str, speed: int, distance: int
) -> None:
    c = build_controller(controller, load_rover(None), 0.01, 8, seed=3)
    hello = Hello(PROTOCOL_VERSION, SCHEMA_HASH)
    c.handle(hello)
    c.handle(Motion(1, Command.LEFT, 40, 3000))
    for i in range(60):  # turning: the left wheel runs backward
        if i % 10 == 0:  # the host's heartbeat feeds the watchdog
            c.handle(HostHeartbeat(i))
        c.tick()
    c.handle(hello)  # a new session aborts the turn: the wheels brake, no latch
    out = c.handle(Motion(1, Command.FWD, speed, distance))
    assert [(m.seq, m.result) for m in out if isinstance(m, Ack)] == [(1, AckResult.ACCEPTED)]
    for i in range(300):  # three seconds
        if i % 10 == 0:
            c.handle(HostHeartbeat(100 + i))
        out += c.tick()
    started = [m.seq for m in out if isinstance(m, Status) and m.state == StepState.STARTED]
    ended = [m for m in out if isinstance(m, Status) and m.state != StepState.STARTED]
    assert started == [1]
    assert [(m.seq, m.state) for m in ended] == [(1, StepState.COMPLETED)]
    assert not any(isinstance(m, Fault) for m in out)
