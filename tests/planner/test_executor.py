"""The executor against the whole rover side in virtual time (sim/world.py: the bridge,
the link relay with its round trip, the controller over its twin on one lockstep clock):
plans that end early for any reason leave the rover stopped and latched; progress during
a step; drift control that falls back to ``odom`` when POSE goes silent, and stops the
rover when it hears no pose at all.

What only real time shows stays in real time: Ctrl-C and SIGTERM reaching a running
``rover go`` (tests/planner/test_demo.py), the signal handling itself
(tests/planner/test_interrupt.py), the executor in ``rover demo`` end to end."""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from typing import Any

import pytest

from emulator.sensors import SensorConfig
from firmware_proto.model.plan import Plan
from firmware_proto.model.verdict import Verdict
from gate.server import GateServer
from planner.ground.cli_go import start_noise
from planner.ground.executor import ExecutionProgress, ExecutorConfig
from planner.plan.gate_client import GateClient, GateOptions
from sim.world import World, WorldConfig

START = (1.2, 3.0)  # the lab map's start, facing +x

# 1.3 m straight ahead at half speed: about 9 s of mission time.
LONG_STEP = {
    "goal": {"x": START[0] + 1.3, "y": START[1], "yaw_deg": 0.0},
    "commands": [{"command": "FWD", "speed": 30, "distance": 30000}],
}
TWO_STEPS = {
    "goal": {"x": START[0] + 1.5, "y": START[1], "yaw_deg": 0.0},
    "commands": [
        {"command": "FWD", "speed": 60, "distance": 23000},
        {"command": "FWD", "speed": 60, "distance": 11500},
    ],
}


@pytest.fixture(scope="module")
def verdicts(gate: GateServer) -> dict[str, Verdict]:
    """The gate's verdicts on the two plans (validated once)."""
    out = {}
    with GateClient(gate.url) as client:
        for name, plan in (("long", LONG_STEP), ("two", TWO_STEPS)):
            verdict = client.validate(plan, map_name="lab")
            assert verdict.approved, verdict.summary()
            out[name] = verdict
    return out


@pytest.fixture
def world() -> Iterator[Any]:
    """Factory of worlds (seed 5, 3 s round trip); every one closed after the test."""
    made: list[World] = []

    def make(
        *, faults: tuple[str, ...] = (), unrelayed: tuple[str, ...] = (), **executor: Any
    ) -> World:
        config = WorldConfig(
            seed=5, faults=faults, unrelayed=unrelayed, executor=tuple(executor.items())
        )
        made.append(World(config))
        return made[-1]

    yield make
    for w in made:
        w.close()


def assert_stopped_and_latched(w: World) -> None:
    """The rover comes to rest and holds its STOP latch."""
    assert w.run_until(w.at_rest, 5.0), "the rover did not come to rest"
    assert w.truth().stop_latched


def moving(w: World) -> bool:
    return any(abs(v) > 0.05 for v in w.truth().wheel_mps)


# -- ending early: STOP whatever the cause -------------------------------------------------


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_an_exception_from_on_progress_mid_step_stops_the_rover_then_propagates(
    verdicts: dict[str, Verdict], world: Any, error: type[BaseException]
) -> None:
    """An operator's display that crashes, or Ctrl-C landing in the executor's thread
    while it waits (the signal's own path is tests/planner/test_interrupt.py)."""
    w: World = world(progress_period_s=0.4)

    def explode(p: ExecutionProgress) -> None:
        if p.status == "running" and moving(w):
            raise error("the operator's display crashed")

    with pytest.raises(error):
        w.executor.execute(Plan.from_dict(LONG_STEP), verdicts["long"], on_progress=explode)
    assert_stopped_and_latched(w)
    assert w.truth().x_m < START[0] + 1.2  # stopped well before the step's end


def test_cancel_stops_the_rover(verdicts: dict[str, Verdict], world: Any) -> None:
    w: World = world(progress_period_s=0.4)
    cancel = threading.Event()

    def watch(p: ExecutionProgress) -> None:
        if p.status == "running" and moving(w):
            cancel.set()

    result = w.executor.execute(
        Plan.from_dict(LONG_STEP), verdicts["long"], on_progress=watch, cancel=cancel
    )
    assert result.outcome == "cancelled" and result.reason == "cancelled by the operator"
    assert result.stopped_s is not None  # the rover confirmed the STOP
    assert_stopped_and_latched(w)


# -- progress during a step ----------------------------------------------------------------


def test_progress_arrives_while_a_long_step_runs(verdicts: dict[str, Verdict], world: Any) -> None:
    w: World = world(progress_period_s=0.8)
    seen: list[ExecutionProgress] = []
    result = w.executor.execute(
        Plan.from_dict(LONG_STEP), verdicts["long"], on_progress=seen.append
    )
    assert result.completed, result.reason
    statuses = [p.status for p in seen]
    first_accepted = statuses.index("accepted")
    assert set(statuses[:first_accepted]) == {"published"}
    assert statuses[-1] == "completed" and seen[-1].final
    running = [p for p in seen if p.status == "running"]
    assert len(running) >= 8  # a 9 s step, a line every 0.8 s
    assert all(p.drift_linear_m is not None for p in running[1:])  # the ghost is compared
    etas = [p.eta_s for p in running]
    assert etas == sorted(etas, reverse=True)  # counting down
    assert seen[-1].eta_s == 0.0
    assert "step 1/1 running, ETA" in running[0].line()


def test_a_step_is_never_said_running_before_the_rover_accepted_it(
    verdicts: dict[str, Verdict], world: Any
) -> None:
    """A round trip longer than the progress period: until 'accepted' comes back, the
    step is only 'published' (it was said 'running' before 'accepted')."""
    w: World = world(progress_period_s=0.4)
    seen: list[ExecutionProgress] = []
    result = w.executor.execute(
        Plan.from_dict(LONG_STEP), verdicts["long"], on_progress=seen.append
    )
    assert result.completed, result.reason
    statuses = [p.status for p in seen]
    first_accepted = statuses.index("accepted")
    assert first_accepted >= 3, statuses  # several progress lines during the round trip
    assert set(statuses[:first_accepted]) == {"published"}, statuses
    assert "running" in statuses[first_accepted:]


def test_a_fault_names_the_step_as_progress_numbers_it(
    verdicts: dict[str, Verdict], world: Any
) -> None:
    """Progress says 'step 2/2 fault:...'; the reason says the same step, not 'step 1'."""
    w: World = world(faults=("stall:left@d=1.2",), drift_control=False)
    seen: list[ExecutionProgress] = []
    result = w.executor.execute(Plan.from_dict(TWO_STEPS), verdicts["two"], on_progress=seen.append)
    assert not result.completed
    final = [p for p in seen if p.final and p.status != "completed"]
    assert final, [p.line() for p in seen]
    said = final[-1].line().split(",")[0].rsplit(" ", 1)[0]  # "step 2/2"
    assert said == "step 2/2"
    assert result.reason.startswith(said + ": "), (said, result.reason)


# -- drift control's pose ------------------------------------------------------------------


def test_drift_control_falls_back_to_odom_when_pose_goes_silent(
    verdicts: dict[str, Verdict], world: Any
) -> None:
    # The ground-seeing sensor loses its fix half a metre into the first step.
    w: World = world(faults=("pose-dropout@d=0.5",))
    assert w.executor.config.pose_source == "auto"
    result = w.executor.execute(Plan.from_dict(TWO_STEPS), verdicts["two"])
    assert result.completed, result.reason  # a lost sensor is not a reason to stop...
    assert w.executor.pose_source_in_use == "odom"
    assert any("fell back to odom" in note for note in result.notes), result.notes
    assert any("fault:pose" in note for note in result.notes), result.notes
    # ... and odom continued where POSE left off: at rest, it says where the rover is.
    assert result.reported_pose is not None
    truth = w.truth()
    assert math.hypot(result.reported_pose.x - truth.x_m, result.reported_pose.y - truth.y_m) < 0.1
    # A pose from odom states no error of its own.
    assert w.executor.reported_sigma is None


def test_the_reported_pose_carries_the_error_the_rover_stated_with_it(world: Any) -> None:
    """A pose from ``odom_ground`` comes with the 1-sigma errors of its covariance: the
    POSE sensor's noise per axis, and the heading's as the bridge states it; what ``rover
    go`` gives the gate with a start it did not average (planner/ground/cli_go.py)."""
    w: World = world()
    assert w.executor.settled_pose(5.0) is not None
    sigma = w.executor.reported_sigma
    noise_m = SensorConfig().pose_noise_m
    assert sigma == pytest.approx((noise_m, math.degrees(math.sqrt(noise_m**2 / 0.25))))
    options = start_noise(GateOptions(samples=20), sigma)
    assert dict(options.query_items())["start_sigma_m"] == repr(noise_m)
    assert start_noise(options, None) == options


def test_drift_control_blind_without_pose_stops_the_rover(
    verdicts: dict[str, Verdict], world: Any
) -> None:
    w: World = world(pose_source="odom_ground", faults=("pose-dropout@d=0.2",))
    result = w.executor.execute(Plan.from_dict(LONG_STEP), verdicts["long"])
    assert result.outcome == "blind", result.reason
    assert result.reason.startswith("drift control blind: no pose from odom_ground")
    assert result.stopped_s is not None
    assert_stopped_and_latched(w)


def test_a_link_that_relays_no_pose_makes_drift_control_blind(
    verdicts: dict[str, Verdict], world: Any
) -> None:
    w: World = world(unrelayed=("odom", "odom_ground"))
    result = w.executor.execute(Plan.from_dict(LONG_STEP), verdicts["long"])
    assert result.outcome == "blind", result.reason
    assert "no pose from odom_ground or odom" in result.reason
    assert result.stopped_s is not None
    assert_stopped_and_latched(w)


def test_blind_stop_is_off_without_drift_control(verdicts: dict[str, Verdict], world: Any) -> None:
    w: World = world(unrelayed=("odom", "odom_ground"), drift_control=False)
    result = w.executor.execute(Plan.from_dict(LONG_STEP), verdicts["long"])
    assert result.completed, result.reason


@pytest.mark.parametrize(
    ("overrides", "complaint"),
    [
        ({"pose_source": "gps"}, "pose_source"),
        ({"drift_linear_m": math.nan}, "drift_linear_m"),
        ({"drift_angular_deg": -1.0}, "drift_angular_deg"),
        ({"drift_persistence": 0}, "drift_persistence"),
        ({"pose_stale_s": 1.5}, "blind_margin_s must exceed pose_stale_s"),
        ({"link_rtt_s": math.inf}, "link_rtt_s"),
    ],
)
def test_executor_config_refuses_nonsense(overrides: dict[str, Any], complaint: str) -> None:
    with pytest.raises(ValueError, match=complaint):
        ExecutorConfig(**overrides)
