"""A bug the simulator found in both controllers (docs/sim.md, "Bugs found"), kept as a
strict expected failure until they are fixed: when it passes, pytest fails it (strict
xfail) and the marker goes.

A step with speed 0 or distance 0 "is STARTED and COMPLETED in the same control tick"
(docs/protocol.md, STATUS). Started while a wheel still turns against the new step's
direction (the previous step ended early: a new session, or a clear before rest), it
never completes: its profile has nowhere to go and no speed to get there, so the wheel
it brakes never arrives (``emulator/drive.py`` ``StepProfile`` and the C core's profile
alike). The host's steps behind it wait for ever; the simulator's ``never-stuck``
invariant caught it (``rover sim --zero-steps``)."""

from __future__ import annotations

import pytest

from firmware_proto.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Command,
    Hello,
    Motion,
    Status,
    StepState,
)
from firmware_proto.rover import load_rover
from sim.controllers import build_controller
from sim.scenario import CONTROLLERS


@pytest.mark.xfail(
    strict=True,
    reason="both controllers: a zero step started while a wheel turns never completes "
    "(found by the simulator; the controllers are another branch's to fix)",
)
@pytest.mark.parametrize("controller", CONTROLLERS)
@pytest.mark.parametrize(("speed", "distance"), [(25, 0), (0, 800)])
def test_a_zero_step_started_while_a_wheel_turns_completes(
    controller: str, speed: int, distance: int
) -> None:
    c = build_controller(controller, load_rover(None), 0.01, 8, seed=3)
    hello = Hello(PROTOCOL_VERSION, SCHEMA_HASH)
    c.handle(hello)
    c.handle(Motion(1, Command.LEFT, 40, 3000))
    for _ in range(60):  # turning: the left wheel runs backward
        c.tick()
    c.handle(hello)  # a new session aborts the turn: the wheels brake, no latch
    out = c.handle(Motion(1, Command.FWD, speed, distance))
    for _ in range(300):  # three seconds
        out += c.tick()
    ended = [m for m in out if isinstance(m, Status) and m.state != StepState.STARTED]
    assert [(m.seq, m.state) for m in ended] == [(1, StepState.COMPLETED)]
