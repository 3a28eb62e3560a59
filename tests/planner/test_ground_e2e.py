"""Ground station end to end with real parts: the gate (a `rover gate` process, over
HTTP), the executor, the link relay, the bridge node and the emulator on a real pty.

ROS topics run on the in-process port (one process, several nodes); the DDS variant of
the same node wiring is covered in tests/bridge/test_node.py.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from firmware_proto.model.plan import Plan
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import WorldMap, load_map
from planner.plan.gate_client import GateClient
from tests.rig import HilRig

# Missions in real time on an in-process rig (emulator, bridge and relay threads in this
# worker): run after the rest, as the whole-mission tests are (marker serial: two at a
# time, never beside the host part's tests). Its emulator and bridge threads are
# real-time, but they share this process's interpreter lock with threads that are not:
# beside the host part's tests the bridge's heartbeats came 255 ms late (watchdog trips
# in 5 tests of one run).
pytestmark = pytest.mark.serial

SPEED = 4.0
ONE_WAY_S = 0.05


def validate(url: str, plan: dict[str, Any], map_name: str = "lab") -> Verdict:
    with GateClient(url) as client:
        return client.validate(plan, map_name=map_name)


@pytest.fixture
def hil() -> Iterator[Callable[..., HilRig]]:
    """Factory: emulator (lab map) + bridge + relay + executor; all closed after."""
    rigs: list[HilRig] = []

    def make(faults: tuple[str, ...] = ()) -> HilRig:
        rigs.append(HilRig("lab", speed=SPEED, rtt_s=2 * ONE_WAY_S * SPEED, seed=5, faults=faults))
        return rigs[-1]

    yield make
    for rig in rigs:
        rig.close()


def _wait(pred: Callable[[], bool], what: str, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise TimeoutError(what)
        time.sleep(0.01)


def _plan(world: WorldMap, rover: RoverDescription) -> dict[str, Any]:
    s = world.start  # (1.2, 3.0) facing +x: turn south, drive 2 m in the open
    return {
        "goal": {"x": s.x, "y": s.y - 2.0, "yaw_deg": -90.0},
        "commands": [
            {"command": "RIGHT", "speed": 30, "distance": rover.turn_units_for_yaw(math.pi / 2)},
            {"command": "FWD", "speed": 60, "distance": 23000},
            {"command": "FWD", "speed": 60, "distance": 23000},
        ],
    }


def test_approved_plan_reaches_the_goal_within_tolerance(
    gate_process_url: str, hil: Callable[..., HilRig]
) -> None:
    rover, world = load_rover(), load_map("lab")
    plan = _plan(world, rover)
    verdict = validate(gate_process_url, plan)
    assert verdict.approved, verdict.summary()
    h = hil()
    result = h.executor.execute(Plan.from_dict(plan), verdict)
    assert result.completed, result.reason
    assert [s.status for s in result.steps] == ["completed"] * 3
    truth = h.emulator.status()
    goal = plan["goal"]
    assert math.hypot(truth.x_m - goal["x"], truth.y_m - goal["y"]) < 0.10
    assert abs(truth.yaw_deg - goal["yaw_deg"]) < 3.0
    # The rover followed the ghost: well inside drift control's STOP threshold. (0.106 m
    # once, on a slow host where the rig's emulator fell behind and caught up in a burst.)
    assert result.worst_drift[0] < 0.15
    assert result.reported_pose is not None


def test_slip_makes_drift_control_stop_the_rover(
    gate_process_url: str, hil: Callable[..., HilRig]
) -> None:
    rover, world = load_rover(), load_map("lab")
    s = world.start
    plan = {
        "goal": {"x": s.x + 1.5, "y": s.y, "yaw_deg": 0.0},
        "commands": [
            {"command": "FWD", "speed": 60, "distance": 23000},
            {"command": "FWD", "speed": 60, "distance": 11500},
        ],
    }
    verdict = validate(gate_process_url, plan)
    assert verdict.approved
    h = hil(faults=("slip:both=0.1",))  # the encoders still report the full travel
    result = h.executor.execute(Plan.from_dict(plan), verdict)
    assert result.outcome == "drift", result.reason
    assert result.drift is not None and result.drift.linear_m > 0.25
    assert result.stop_latency_s is not None and result.stop_latency_s < 1.0
    assert result.stopped_s is not None  # the rover confirmed the STOP
    _wait(lambda: h.emulator.status().wheel_mps == (0.0, 0.0), "rover at rest")
    truth = h.emulator.status()
    assert truth.stop_latched
    # Where the rover came to rest, against where the twin said it would be when the
    # drift was detected: within 0.25 m + braking distance + the 3-sample confirmation.
    predicted = result.drift.predicted
    braking = rover.max_speed_mps**2 / (2 * rover.drive.wheel_accel_limit_mps2)
    assert math.hypot(truth.x_m - predicted.x, truth.y_m - predicted.y) < 0.25 + braking + 0.1
    # The rest of the plan was purged: step 1 was never published.
    assert len(result.steps) == 1


def test_rejected_step_aborts_and_stops(hil: Callable[..., HilRig]) -> None:
    h = hil()
    h.emulator.call(lambda: None)
    plan = Plan.from_dict(
        {
            "goal": {"x": 0, "y": 0, "yaw_deg": 0},
            "commands": [{"command": "FWD", "speed": 10, "distance": 100}],
        }
    )
    h.executor.stop()  # latch the rover first: the next step is refused by the bridge
    result = h.executor.execute(plan)
    assert result.outcome == "rejected" and "stop_latched" in result.reason
    assert result.stopped_s is not None


ONE_STEP = {
    "goal": {"x": 0, "y": 0, "yaw_deg": 0},
    "commands": [{"command": "FWD", "speed": 60, "distance": 23000}],
}


def test_killed_emulator_ends_the_plan_without_hanging(hil: Callable[..., HilRig]) -> None:
    h = hil()
    h.emulator.close()  # the controller dies: the bridge loses it
    result = h.executor.execute(Plan.from_dict(ONE_STEP))
    assert not result.completed
    assert result.outcome in ("fault", "rejected", "timeout"), result.reason
    assert result.elapsed_s < h.executor.step_timeout_s(0, (1, 60, 23000), None) + 1.0


def test_timeout_fires_when_nothing_comes_back(hil: Callable[..., HilRig]) -> None:
    h = hil()
    h.relay.close()  # the link goes dark: no status, no confirmation
    timeout = h.executor.step_timeout_s(0, (1, 60, 23000), None)
    result = h.executor.execute(Plan.from_dict(ONE_STEP))
    assert result.outcome == "timeout"
    assert "STOP not confirmed" in result.reason
    assert result.elapsed_s >= timeout  # it waited the whole budget, and no longer than bounded
    assert (
        result.elapsed_s
        < timeout + h.executor.config.link_rtt_s + h.executor.config.step_margin_s + 1.0
    )
