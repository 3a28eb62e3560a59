"""Step semantics: ramps at the accel limit, encoder travel lands on the distance,
directions per command, conversions with the mounting polarity."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from emulator.drive import (
    StepProfile,
    brake,
    motor_omegas,
    nominal_step_duration_s,
    side_directions,
    stopping_distance_m,
    travel_units,
    turn_units_for_yaw,
    yaw_for_turn_units,
)
from emulator.errors import CommandError
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import Command

MOVING = [Command.FWD, Command.REV, Command.LEFT, Command.RIGHT]


def run_ideal(
    rover: RoverDescription, profile: StepProfile, dt: float, max_ticks: int = 200_000
) -> tuple[list[tuple[float, float]], tuple[float, float]]:
    """Drive the profile with encoders that follow its targets exactly."""
    travel = [0.0, 0.0]
    targets: list[tuple[float, float]] = [(0.0, 0.0)]
    upm = rover.drive.distance_units_per_m
    for _ in range(max_ticks):
        left, right = profile.update(travel[0], travel[1], dt)
        targets.append((left, right))
        if profile.done:
            break
        travel[0] += left * dt * upm
        travel[1] += right * dt * upm
    else:
        pytest.fail("profile never finished")
    return targets, (travel[0], travel[1])


@given(
    command=st.sampled_from(MOVING),
    speed=st.integers(1, 60),
    distance=st.integers(1, 30000),
    dt=st.sampled_from([0.001, 0.002, 0.005, 0.01, 0.02]),
)
def test_travel_lands_on_the_distance_within_the_accel_limit(
    rover: RoverDescription, command: Command, speed: int, distance: int, dt: float
) -> None:
    profile = StepProfile(rover, command, speed, distance)
    targets, (left, right) = run_ideal(rover, profile, dt)
    dl, dr = side_directions(command)
    assert dl * left == pytest.approx(distance, abs=0.5)
    assert dr * right == pytest.approx(distance, abs=0.5)
    vmax = rover.speed_to_mps(speed)
    dv = rover.drive.wheel_accel_limit_mps2 * dt
    for (l0, r0), (l1, r1) in itertools.pairwise(targets):
        assert abs(l1 - l0) <= dv + 1e-12
        assert abs(r1 - r0) <= dv + 1e-12
        assert abs(l1) <= vmax + 1e-12
        assert abs(r1) <= vmax + 1e-12
        # each side moves only in its own direction
        assert dl * l1 >= 0.0
        assert dr * r1 >= 0.0
    assert targets[-1] == (0.0, 0.0)


def test_one_metre_forward_takes_the_trapezoid_time(rover: RoverDescription) -> None:
    dt = 0.001
    profile = StepProfile(rover, Command.FWD, 60, 23000)
    targets, travel = run_ideal(rover, profile, dt)
    assert travel == pytest.approx((23000.0, 23000.0), abs=0.01)
    duration = (len(targets) - 2) * dt
    assert duration == pytest.approx(nominal_step_duration_s(rover, 60, 23000), abs=0.01)
    assert max(t[0] for t in targets) == pytest.approx(0.3)


@pytest.mark.parametrize(
    ("command", "signs"),
    [
        (Command.FWD, (1, 1)),
        (Command.REV, (-1, -1)),
        (Command.LEFT, (-1, 1)),
        (Command.RIGHT, (1, -1)),
        (Command.STOP, (0, 0)),
    ],
)
def test_side_directions(command: Command, signs: tuple[int, int]) -> None:
    assert side_directions(command) == signs


def test_left_turns_left_side_backwards(rover: RoverDescription) -> None:
    profile = StepProfile(rover, Command.LEFT, 30, 5000)
    left, right = profile.update(0.0, 0.0, 0.01)
    assert left < 0.0 < right
    assert left == -right


@pytest.mark.parametrize(
    ("command", "speed", "distance"),
    [(9, 10, 10), (-1, 10, 10), (1, 61, 10), (1, -1, 10), (1, 10, 30001), (1, 10, -5)],
)
def test_out_of_range_steps_are_refused(
    rover: RoverDescription, command: int, speed: int, distance: int
) -> None:
    with pytest.raises(CommandError):
        StepProfile(rover, command, speed, distance)


def test_non_integer_values_are_refused(rover: RoverDescription) -> None:
    with pytest.raises(CommandError):
        StepProfile(rover, Command.FWD, 10.5, 100)  # type: ignore[arg-type]
    with pytest.raises(CommandError):
        StepProfile(rover, Command.FWD, True, 100)


@pytest.mark.parametrize(("speed", "distance"), [(0, 1000), (30, 0)])
def test_nothing_to_do_is_done_at_once(rover: RoverDescription, speed: int, distance: int) -> None:
    profile = StepProfile(rover, Command.FWD, speed, distance)
    assert profile.done
    assert profile.update(0.0, 0.0, 0.001) == (0.0, 0.0)


def test_stop_step_brakes_at_the_limit(rover: RoverDescription) -> None:
    dt = 0.001
    profile = StepProfile(rover, Command.STOP, 0, 0, initial_left_mps=0.3, initial_right_mps=-0.2)
    started_at_rest = profile.done
    ticks = 0
    for ticks in range(1, 10_000):  # noqa: B007 - the count is the result
        profile.update(0.0, 0.0, dt)
        if profile.done:
            break
    assert not started_at_rest
    assert ticks == pytest.approx(0.3 / (rover.drive.wheel_accel_limit_mps2 * dt), abs=1)


def test_brake_reaches_rest_and_stopping_distance(rover: RoverDescription) -> None:
    dt = 0.001
    left, right = 0.3, -0.3
    travelled = 0.0
    while (left, right) != (0.0, 0.0):
        travelled += left * dt
        left, right = brake(rover, left, right, dt)
        assert right == -left
    assert travelled == pytest.approx(stopping_distance_m(rover, 0.3, dt), rel=1e-9)
    assert stopping_distance_m(rover, 0.3) == pytest.approx(0.3**2 / (2 * 0.8))


def test_motor_omegas_carry_the_polarity(rover: RoverDescription) -> None:
    speed = 60
    v = rover.speed_to_mps(speed)
    left, right = motor_omegas(rover, v, v)
    k = rover.drive.wheel_velocity_scale_rad_s
    assert left == pytest.approx(-speed * k)
    assert right == pytest.approx(speed * k)
    # one metre of forward travel on each side is 23000 units
    angle = 1.0 / rover.geometry.wheel_radius_m
    assert travel_units(rover, -angle, angle) == pytest.approx((23000.0, 23000.0))


@given(yaw=st.floats(0.01, 3.0))
def test_turn_model_round_trip(rover: RoverDescription, yaw: float) -> None:
    units = turn_units_for_yaw(rover, yaw)
    assert yaw_for_turn_units(rover, units) == pytest.approx(yaw, abs=1e-4)
    assert turn_units_for_yaw(rover, -yaw) == units


def test_turn_units_divide_the_ideal_arc_by_the_efficiency(rover: RoverDescription) -> None:
    ideal_units = math.pi / 2 * rover.geometry.track_width_m / 2 * 23000
    expected = ideal_units / rover.traction.turn_efficiency
    assert abs(turn_units_for_yaw(rover, math.pi / 2) - expected) <= 0.5
