"""Lockstep playback: sampling, per-step records, early ends on collision or stall,
settling, validation before anything moves."""

from __future__ import annotations

import pytest

from emulator.errors import CommandError, TwinConfigError
from emulator.playback import play
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import Command

from .builders import box, make_map

FWD, LEFT = Command.FWD, Command.LEFT


def test_samples_every_tenth_of_a_second_plus_the_final_pose(rover: RoverDescription) -> None:
    twin = Twin(rover, dt_s=0.002)
    result = play(twin, [(FWD, 60, 11500), (LEFT, 30, 4000)])
    times = [s.time_s for s in result.samples]
    assert times[0] == 0.0
    assert result.sample_period_s == pytest.approx(0.1)
    for k, t in enumerate(times[:-1]):
        assert t == pytest.approx(0.1 * k)
    assert times[-1] == result.sim_time_s
    assert result.samples[-1].pose == result.final_pose
    assert result.completed
    assert result.collision is None
    assert result.stall is None


def test_step_records(rover: RoverDescription) -> None:
    result = play(Twin(rover), [(FWD, 60, 11500), (LEFT, 30, 4000), (FWD, 30, 0)])
    first, turn, empty = result.steps
    assert (first.index, first.command, first.speed, first.distance) == (0, FWD, 60, 11500)
    assert first.start_time_s == 0.0
    assert turn.start_time_s == first.end_time_s
    assert first.end_pose.x_m == pytest.approx(0.5, abs=0.005)
    assert turn.left_travel_units == pytest.approx(-4000, abs=0.5)
    assert turn.right_travel_units == pytest.approx(4000, abs=0.5)
    assert turn.end_pose.yaw_rad > 0
    assert empty.completed
    assert empty.start_time_s == empty.end_time_s
    assert all(s.completed for s in result.steps)


def test_collision_ends_playback_at_its_step(rover: RoverDescription) -> None:
    world = make_map([box("wall", 1.2, -1.0, 1.4, 1.0)])
    steps = [(FWD, 60, 11500), (FWD, 60, 23000), (LEFT, 30, 5000)]
    result = play(Twin(rover, world), steps)
    assert result.collision is not None
    assert result.collision.obstacle_id == "wall"
    assert result.collision_step == 1
    assert len(result.steps) == 2
    assert not result.steps[1].completed
    assert not result.completed
    assert result.sim_time_s == pytest.approx(result.collision.time_s)


def test_time_limit_ends_a_step_that_takes_too_long(rover: RoverDescription) -> None:
    twin = Twin(rover)
    result = play(twin, [(FWD, 60, 23000)], time_limit_factor=0.5, time_limit_margin_s=0.0)
    assert result.stall is not None
    assert result.stall.reason == "time_limit"
    assert result.stall.step_index == 0
    assert result.sim_time_s == pytest.approx(0.5 * 3.708, abs=0.01)


def test_both_sides_locked_is_a_stall_on_both(rover: RoverDescription) -> None:
    twin = Twin(rover)
    twin.set_wheel_locked("left", True)
    twin.set_wheel_locked("right", True)
    result = play(twin, [(FWD, 60, 23000)], stall_window_s=0.5)
    assert result.stall is not None
    assert (result.stall.reason, result.stall.side) == ("no_encoder_progress", "both")
    assert result.stall.time_s == pytest.approx(0.5)
    assert result.final_pose.x_m == 0.0


def test_settling_after_the_last_step(rover: RoverDescription) -> None:
    twin = Twin(rover)
    twin.set_traction_scale(0.2, 0.2)  # the body slides on after the wheels stop
    result = play(twin, [(FWD, 60, 23000)])
    assert result.sim_time_s > result.steps[0].end_time_s
    assert result.final_pose.x_m > result.steps[0].end_pose.x_m
    v = twin.body_velocity
    assert abs(v.vx_mps) < 1e-3
    unsettled = play(Twin(rover), [(FWD, 60, 23000)], settle_s=0.0)
    assert unsettled.sim_time_s == unsettled.steps[0].end_time_s


def test_no_steps(rover: RoverDescription) -> None:
    result = play(Twin(rover), [])
    assert result.steps == ()
    assert len(result.samples) == 1
    assert result.completed


def test_invalid_step_is_refused_before_anything_moves(rover: RoverDescription) -> None:
    twin = Twin(rover)
    with pytest.raises(CommandError):
        play(twin, [(FWD, 60, 1000), (FWD, 61, 1000)])
    assert twin.steps == 0


@pytest.mark.parametrize(
    "kwargs", [{"sample_period_s": 0.0}, {"stall_window_s": -1.0}, {"settle_s": -1.0}]
)
def test_bad_parameters(rover: RoverDescription, kwargs: dict[str, float]) -> None:
    with pytest.raises(TwinConfigError):
        play(Twin(rover), [], **kwargs)
