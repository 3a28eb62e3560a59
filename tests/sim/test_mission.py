"""The onboard mission in virtual time (sim/mission.py): the rover's sequencer, guard and
estimate over the bridge's link core, a controller and its twin, a ground across a lossy
3 s link; seeded faults, invariants, reproducers (docs/sim.md, "Missions").

The fast lane plays hand-picked missions (loss, slip, a ground STOP, bad uplinks, a broken
guard caught); the background part the heavier ones and a few seeds per controller; the
soak part 60 seeds per controller."""

from __future__ import annotations

import dataclasses

import pytest

from bridge.onboard.core import OnboardConfig, OnboardCore
from firmware_proto.wire.messages import Command
from sim.mission import MissionRig, MissionScenario, make_mission, run_mission
from sim.scenario import CONTROLLERS, MEDIA, ScenarioFault
from sim.soak import assignment

FWD, LEFT, RIGHT = int(Command.FWD), int(Command.LEFT), int(Command.RIGHT)
PLAN = ((FWD, 30, 23000), (LEFT, 30, 9000), (FWD, 40, 20000))


def _mission(**changes: object) -> MissionScenario:
    base = MissionScenario(
        seed=7,
        controller="python",
        medium="serial",
        tick_s=0.01,
        steps=PLAN,
        one_way_s=1.5,
        jitter_s=0.0,
        loss=0.0,
        token=True,
        slip=None,
        pose_silent=None,
        ground_stop_s=None,
        uplink_faults=(),
        wire_faults=(),
    )
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


def _ok(outcome: object) -> None:
    assert outcome.ok, "\n".join(  # type: ignore[attr-defined]
        [*outcome.scenario.describe(), *(v.line() for v in outcome.violations)]  # type: ignore[attr-defined]
    )


VIRTUAL = [pytest.mark.slow, pytest.mark.virtual]
"""The heavier missions run in the test command's background part, not the fast lane."""


@pytest.mark.parametrize(
    "controller", [pytest.param(c, marks=VIRTUAL if c == "c" else []) for c in CONTROLLERS]
)
def test_a_plan_at_30_percent_loss_and_jitter_runs_exactly_once(controller: str) -> None:
    outcome = run_mission(
        _mission(controller=controller, loss=0.3, jitter_s=0.2, uplink_faults=("dup",))
    )
    _ok(outcome)
    assert outcome.ended == "completed" and outcome.ground_heard
    counts = outcome.counts
    assert counts["onboard_accepted"] == 1 and counts["onboard_steps_sent"] == len(PLAN)
    assert counts["completed"] == len(PLAN)  # each step completed once at the controller
    assert counts["onboard_duplicates"] >= 1  # the copies came, and ran nothing


def test_slip_is_stopped_on_board_within_the_bound_and_reported_at_rest() -> None:
    outcome = run_mission(_mission(slip=(0, 0.3, "left", 0.03)))
    _ok(outcome)
    assert outcome.ended == "guard" and outcome.ground_heard
    truth = outcome.truth
    assert truth["worst_linear_m"] > 0.25 or truth["worst_angular_deg"] > 12.0
    # physical figures, from the twin (virtual time): STOP went out within the bound
    # after the true crossing; the rover drove a few centimetres after it.
    assert truth["stop_after_crossing_s"] < 0.5
    assert truth["overshoot_m"] < 0.15


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_late_callbacks_on_a_busy_rover_computer_stop_nothing(controller: str) -> None:
    """Review A5: the guard's prediction started each step when the program ran its
    ``accepted`` callback; on a busy computer hundreds of milliseconds late, and a turn
    exactly as predicted was stopped for its heading. Every ROS hop on the rover here
    is up to 0.35 s late (fast turns: the old alignment stopped this seed at 12.1 deg,
    the rover truly 3.3 deg off); the truth is aligned on when the controller took each
    step."""
    turns = ((RIGHT, 60, 15000), (LEFT, 60, 12000))
    outcome = run_mission(_mission(seed=6, controller=controller, steps=turns, ros_jitter_s=0.35))
    _ok(outcome)  # false-stop and delivered
    assert outcome.ended == "completed"
    assert outcome.truth["worst_angular_deg"] < 2.0


def test_a_guard_stop_lost_on_the_way_to_the_bridge_is_sent_again() -> None:
    """Review A7: the guard's STOP went out once; lost, the step ran to its end. Its
    first two copies lost here, the third stops the rover (``stop-reached``)."""
    outcome = run_mission(_mission(slip=(0, 0.3, "left", 0.03), lost_stops=2))
    _ok(outcome)
    assert outcome.ended == "guard" and outcome.ground_heard
    assert outcome.counts["onboard_stop_repeats"] >= 2
    assert outcome.truth["overshoot_m"] < 0.3


@pytest.mark.slow
@pytest.mark.virtual
def test_the_invariants_catch_a_stop_that_is_never_sent_again() -> None:
    class Once(MissionRig):
        def __init__(self, mission: MissionScenario) -> None:
            super().__init__(mission)
            self.onboard = OnboardCore(
                self.rover,
                OnboardConfig(token="sim-token", stop_repeats=0, boot=self.ground_boot),
            )
            self.cores = [self.onboard]

    outcome = Once(_mission(slip=(0, 0.3, "left", 0.03), lost_stops=1)).play()
    assert "stop-reached" in [v.rule for v in outcome.violations]


@pytest.mark.slow
@pytest.mark.virtual
def test_telemetry_gaps_do_not_stop_a_healthy_plan() -> None:
    outcome = run_mission(_mission(pose_silent=(2.5, 0.9), loss=0.3))
    _ok(outcome)
    assert outcome.ended == "completed"


def test_a_plan_stops_when_pose_stays_silent_while_it_drives() -> None:
    """Review A6: with POSE lost the plan ran on encoders alone, which cannot see a slip
    along the track. Drift control needs a sensor that sees the ground: the rover stops
    once it has driven the linear limit unseen."""
    outcome = run_mission(_mission(pose_silent=(2.5, 6.0)))
    _ok(outcome)
    assert outcome.ended == "blind" and outcome.ground_heard


def test_a_ground_stop_at_30_percent_loss_reaches_the_rover_and_ends_the_plan() -> None:
    outcome = run_mission(_mission(ground_stop_s=4.0, loss=0.3, jitter_s=0.2))
    _ok(outcome)
    assert outcome.ended == "ground_stop" and outcome.ground_heard
    assert outcome.counts["onboard_steps_sent"] < len(PLAN)


def test_bad_replayed_and_superseded_uplinks_are_refused_and_drive_nothing() -> None:
    outcome = run_mission(
        _mission(uplink_faults=("supersede", "replay", "tamper", "malformed", "misfit"))
    )
    _ok(outcome)
    assert outcome.ended == "completed"
    # tampered, malformed, misfit, the stale replay; the plan's own replay is a duplicate
    assert outcome.counts["onboard_refused"] >= 4
    assert outcome.counts["onboard_duplicates"] >= 1


@pytest.mark.parametrize(
    "restart_s", [1.0, 2.1, 4.0], ids=["before-it-arrives", "as-it-starts", "mid-plan"]
)
def test_a_restart_of_the_onboard_program_runs_no_copy_of_the_plan_again(
    restart_s: float,
) -> None:
    """Review A2: plans lived only in memory and a restart took any signed copy of the
    last ten minutes again (the ground's resends, a replay). The restarted program has a
    new boot id, and every copy signed for the old one is refused. (Mid-plan, the
    rover has also left the plan's start: a copy would be refused ``start_mismatch``
    too; as it starts, only the boot id tells.)"""
    outcome = run_mission(_mission(onboard_restart_s=restart_s, uplink_faults=("replay", "dup")))
    _ok(outcome)  # plan-once: no plan id started twice, across the restart too
    assert outcome.counts["refused:other_boot"] >= 2
    if restart_s > 2.0:  # it was running: the ending program stopped it
        assert outcome.ended == "failed" and outcome.counts["onboard_steps_sent"] >= 1


@pytest.mark.slow
@pytest.mark.virtual
@pytest.mark.parametrize("kind", ["reboot", "cut"])
def test_a_controller_reboot_or_link_loss_mid_plan_ends_it_without_running_a_step_twice(
    kind: str,
) -> None:
    fault = ScenarioFault(kind, 4.0, 0.0 if kind == "reboot" else 0.8)
    outcome = run_mission(_mission(wire_faults=(fault,)))
    _ok(outcome)
    assert outcome.ended == "failed" and outcome.ground_heard


@pytest.mark.slow
@pytest.mark.virtual
def test_the_invariants_catch_a_guard_that_does_not_guard() -> None:
    class Blind(MissionRig):
        def __init__(self, mission: MissionScenario) -> None:
            super().__init__(mission)
            self.onboard = OnboardCore(
                self.rover,
                OnboardConfig(token="sim-token", persistence=10**6, boot=self.ground_boot),
            )
            self.cores = [self.onboard]

    outcome = Blind(_mission(slip=(0, 0.3, "left", 0.03))).play()
    assert [v.rule for v in outcome.violations][:1] == ["guard-bound"]


@pytest.mark.slow
@pytest.mark.virtual
def test_a_seed_always_plays_the_same_way_and_says_how_to_play_it_again() -> None:
    a, b = (run_mission(make_mission(213), trace=True) for _ in range(2))
    assert a.trace == b.trace and a.ended == b.ended == "guard"
    assert (
        a.scenario.reproducer
        == "rover sim --mission --seed 213 --controller python --medium serial"
    )


@pytest.mark.slow
@pytest.mark.virtual
@pytest.mark.parametrize("controller", CONTROLLERS)
def test_a_few_seeds_of_each_controller(controller: str) -> None:
    first = {"python": 0, "c": 10_000}[controller]
    for seed in range(first, first + 6):
        _, medium = assignment(seed, (controller,), MEDIA)
        _ok(run_mission(make_mission(seed, controller=controller, medium=medium)))


@pytest.mark.slow
@pytest.mark.virtual
@pytest.mark.soak
@pytest.mark.timeout(1800)
@pytest.mark.parametrize("controller", CONTROLLERS)
def test_seeded_missions_keep_every_invariant(controller: str) -> None:
    first = {"python": 100, "c": 10_100}[controller]
    failures = []
    ended: dict[str, int] = {}
    for seed in range(first, first + 60):
        _, medium = assignment(seed, (controller,), MEDIA)
        outcome = run_mission(make_mission(seed, controller=controller, medium=medium))
        ended[outcome.ended] = ended.get(outcome.ended, 0) + 1
        if not outcome.ok:
            failures.append(f"{outcome.scenario.reproducer}: {outcome.violations[0].line()}")
    assert failures == []
    # the faults happened: plans completed, were guarded, stopped by the ground, failed
    # (a POSE silence over 1 s while driving may end a plan blind: review A6)
    assert ended.get("completed", 0) > 20 and ended.get("guard", 0) >= 1, ended
    assert ended.get("ground_stop", 0) >= 1 and ended.get("failed", 0) >= 1, ended


@pytest.mark.slow
@pytest.mark.virtual
def test_rover_sim_plays_a_mission_from_its_seed(capsys: pytest.CaptureFixture[str]) -> None:
    from sim.cli_sim import main

    assert main(["--mission", "--seed", "213"]) == 0
    out = capsys.readouterr().out
    assert "mission seed 213" in out and "passed" in out and "ended guard" in out
    assert main(["--mission", "--seeds", "0..1"]) == 0
    assert "2 missions, 0 failed" in capsys.readouterr().out
