"""``rover calibrate --drive``'s behaviour in virtual time: the designed calibration
(emulator/campaign.py) driving the lockstep rover (sim/calibration_runs.py: the controller
model at 1 ms on a ground of its own, the bridge's odometry, a 3 s round trip, the MCAP
writer of a real run), every plan validated by the gate's own validator first. The real
stack's run is tests/planner/test_calibrate_real.py.

Lockstep and fits: CPU, no wall clock (a ``virtual`` module, tests/lanes.py)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from emulator.campaign import IDLE_ROUNDS, Campaign, Driven, run_campaign
from emulator.errors import UnidentifiableError
from emulator.fit import MIN_DRIVING_S, MIN_STEPS, fit_ground
from emulator.ground import Ground, load_ground
from emulator.observations import observe_steps
from emulator.playback import measure_turn_efficiency
from emulator.recording import read_recording
from emulator.twin import Pose2D
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap
from gate.config import PlaybackSettings
from gate.validator import Validator
from planner.record.mcaprec import record_messages
from sim.calibration_runs import LockstepRover, field_map, validate_with_gate

LEFT, RIGHT, FWD, REV = 3, 4, 1, 2


class Gate:
    """The gate's validator in process, and the plans it was asked about."""

    def __init__(self, world: WorldMap, rover: RoverDescription, margin_m: float = 0.1) -> None:
        validator = Validator(rover, {world.name: world}, PlaybackSettings(), world.name)
        self._check = validate_with_gate(validator, margin_m=margin_m)
        self.asked: list[tuple[tuple[tuple[int, int, int], ...], bool]] = []

    def __call__(self, at: Pose2D, steps: list[tuple[int, int, int]], goal: Pose2D) -> Any:
        approved, reason, failed = self._check(at, steps, goal)
        self.asked.append((tuple(steps), approved))
        return approved, reason, failed


def _lab(lab: WorldMap) -> WorldMap:
    from dataclasses import replace

    return replace(lab, traction_regions=())


@pytest.fixture(scope="module")
def loose(rover: RoverDescription) -> Ground:
    return load_ground("loose", rover)


@pytest.fixture(scope="module")
def campaign(
    rover: RoverDescription, lab: WorldMap, loose: Ground, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Campaign, LockstepRover, Gate]:
    """A designed calibration of the loose ground on the lab map, from its start, with
    a budget of 20 s of driving."""
    world = _lab(lab)
    gate = Gate(world, rover)
    driver = LockstepRover(rover, world, loose, seed=21, validator=gate, recorder=record_messages)
    events: list[str] = []
    result = run_campaign(
        driver,
        rover,
        world,
        tmp_path_factory.mktemp("rounds"),
        budget_s=20.0,
        on_event=events.append,
    )
    assert any(line.startswith("round 1: ") for line in events)
    return result, driver, gate


def test_it_designs_drives_and_fits_within_its_budget(
    campaign: tuple[Campaign, LockstepRover, Gate], rover: RoverDescription, loose: Ground
) -> None:
    result, driver, gate = campaign
    assert result.refusal is None and result.calibration is not None
    assert result.driving_s <= 20.0 and driver.driving_s <= 20.0 * 1.05
    assert result.stopped
    cal = result.calibration
    truth = measure_turn_efficiency(
        loose.rover(rover), distance=rover.turn_units_for_yaw(math.pi / 2)
    )
    assert cal.turn_efficiency == pytest.approx(truth, abs=0.01)
    for name in cal.parameters:
        lo, hi = cal.interval(name)
        assert lo < cal.value(name) < hi
    assert cal.noise is not None and len(cal.targets) == len(cal.parameters)
    # Every plan driven was approved by the gate first, and it drove all of it, without
    # touching anything.
    driven = [r.steps for r in result.rounds if r.driven.recording is not None]
    assert driven == [steps for steps, approved in gate.asked if approved]
    assert all(r.measured == len(r.steps) for r in result.rounds if r.driven.approved)
    assert driver.twin.first_collision is None
    # Straight steps both ways and turns both ways, at more than one speed.
    steps = [s for r in result.rounds for s in r.steps]
    commands = {c for c, _, _ in steps}
    assert {FWD, REV} <= commands and {LEFT, RIGHT} <= commands
    assert len({s for c, s, _ in steps if c in (LEFT, RIGHT)}) >= 2


def test_its_recordings_calibrate_again_as_recorded_missions(
    campaign: tuple[Campaign, LockstepRover, Gate], rover: RoverDescription, lab: WorldMap
) -> None:
    result, _driver, _gate = campaign
    assert result.calibration is not None
    observed = observe_steps([read_recording(p) for p in result.recordings], rover)
    again, _ = fit_ground(observed, rover, _lab(lab), posterior=False)
    assert again.ground.values() == pytest.approx(result.calibration.ground.values(), rel=1e-3)


def test_a_plan_the_gate_rejects_is_not_driven_and_another_is_designed(
    rover: RoverDescription, lab: WorldMap, loose: Ground, tmp_path: Path
) -> None:
    # Facing the table 0.7 m away: room for the design's margins, not for a gate that
    # wants 0.3 m around the footprint.
    world = _lab(lab)
    gate = Gate(world, rover, margin_m=0.3)
    start = Pose2D(2.9, 3.0, 0.0)
    driver = LockstepRover(
        rover, world, loose, seed=22, start=start, validator=gate, recorder=record_messages
    )
    result = run_campaign(driver, rover, world, tmp_path, budget_s=16.0)
    rejected = [r for r in result.rounds if not r.driven.approved]
    assert rejected and all(r.driven.recording is None for r in rejected)
    assert all("touches" in r.driven.reason for r in rejected)
    assert any(r.driven.approved for r in result.rounds)  # it went on with other steps
    assert driver.twin.first_collision is None


class _RoverThatNeverRuns:
    """A lockstep rover whose plans the gate approves but of which no step ever runs (the
    rover never answers): the driver's failure that is neither a rejection nor an error."""

    def __init__(self, rover: LockstepRover) -> None:
        self.rover = rover
        self.speed_factor = rover.speed_factor
        self.plans: list[Sequence[tuple[int, int, int]]] = []

    def pose(self) -> Pose2D:
        return self.rover.pose()

    def drive(self, steps: Sequence[tuple[int, int, int]], *, goal: Pose2D, path: Path) -> Driven:
        self.plans.append(tuple(steps))
        return Driven(True, None, "NOT REACHED: the rover never answered")


def test_plans_that_run_no_step_end_the_campaign_after_a_few_rounds(
    rover: RoverDescription, lab: WorldMap, loose: Ground, tmp_path: Path
) -> None:
    """Nothing driven leaves the design where it was: it would ask for the same plan
    round after round until the budget, which no round spends, ran out (2026-11-30, a
    real stack: 57 rounds of one plan in 5 minutes)."""
    world = _lab(lab)
    driver = _RoverThatNeverRuns(LockstepRover(rover, world, loose, seed=23))
    events: list[str] = []
    result = run_campaign(driver, rover, world, tmp_path, budget_s=20.0, on_event=events.append)
    assert len(driver.plans) == len(result.rounds) == IDLE_ROUNDS
    assert result.stopped == (
        f"{IDLE_ROUNDS} approved plans in a row ran no step "
        "(the last: NOT REACHED: the rover never answered)"
    )
    assert result.driving_s == 0.0 and result.calibration is None
    assert isinstance(result.refusal, UnidentifiableError)
    assert "nothing could be driven and measured" in str(result.refusal)


def test_a_refusal_names_the_parameter_and_the_steps_that_fix_it(
    rover: RoverDescription, loose: Ground, tmp_path: Path
) -> None:
    # Fast turns and one short straight step: the slow turns plans are made of are left
    # uncertain.
    quarter = rover.turn_units_for_yaw(math.pi / 2)
    steps = [(LEFT, 60, quarter), (RIGHT, 60, quarter)] * 2 + [(LEFT, 60, quarter)]
    steps += [(FWD, 60, rover.m_to_units(1.0) // 3), (RIGHT, 60, quarter), (LEFT, 60, quarter)]
    world = field_map()
    driver = LockstepRover(rover, world, loose, seed=9)
    record_messages(tmp_path / "fast.mcap", driver.drive_steps(steps).messages)
    recordings = [read_recording(tmp_path / "fast.mcap")]
    with pytest.raises(UnidentifiableError) as caught:
        fit_ground(observe_steps(recordings, rover), rover, world, posterior=False)
    refusal = caught.value
    assert refusal.parameter in str(refusal) and refusal.advice
    assert f"cannot identify {refusal.parameter}:" in str(refusal) and "; drive " in str(refusal)
    # The advice, driven on the same ground, makes it identifiable.
    record_messages(tmp_path / "advised.mcap", driver.drive_steps(list(refusal.advice)).messages)
    recordings.append(read_recording(tmp_path / "advised.mcap"))
    calibration, _ = fit_ground(observe_steps(recordings, rover), rover, world, posterior=False)
    truth = measure_turn_efficiency(loose.rover(rover), distance=quarter)
    assert calibration.turn_efficiency == pytest.approx(truth, abs=0.01)


def test_a_tight_budget_still_buys_a_first_fits_driving(
    rover: RoverDescription, lab: WorldMap, loose: Ground, tmp_path: Path
) -> None:
    # 16 s of budget from the lab's start (what tests/planner/test_calibrate_real.py
    # gives a real stack): the first plan must reach a first fit's 15 s, not stop at
    # 14.8 s with no step short enough for the 1.2 s left. A gate that wants 5 m around
    # the footprint rejects every plan, so only the designs are made.
    gate = Gate(lab, rover, margin_m=5.0)
    driver = LockstepRover(rover, lab, loose, seed=23, validator=gate, recorder=record_messages)
    result = run_campaign(driver, rover, lab, tmp_path, budget_s=16.0)
    assert result.rounds and not any(r.driven.approved for r in result.rounds)
    for r in result.rounds:
        assert len(r.steps) >= MIN_STEPS
        assert MIN_DRIVING_S <= sum(rover.step_duration_s(s, d) for _c, s, d in r.steps) <= 16.0
    assert driver.driving_s == 0.0 and result.refusal is not None
