"""Step execution semantics shared by the controller model and the gate.

What the motor controller does with a MOTION step ``(command, speed, distance)``
(docs/architecture.md, Contracts 2 and 4; docs/twin.md, "Step semantics"): FWD and REV
drive both sides, LEFT turns counter-clockwise on the spot, RIGHT the opposite, STOP
brakes. Each side ramps toward ``speed`` at ``drive.wheel_accel_limit_mps2`` and brakes
so that its own encoder travel (for LEFT/RIGHT, along its arc) lands on ``distance``
units; the step is done when both sides arrived and are at rest. Slip is invisible
here, as it is to encoders.

Conversions between surface speeds, motor rates (with the mounting polarity) and
encoder distance units live here too, so that no caller re-derives the signs.
"""

from __future__ import annotations

import logging
import math

from emulator.errors import CommandError
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import Command

__all__ = [
    "DONE_TOLERANCE_UNITS",
    "StepProfile",
    "brake",
    "motor_omegas",
    "nominal_step_duration_s",
    "ramp",
    "side_directions",
    "stopping_distance_m",
    "travel_units",
    "turn_units_for_yaw",
    "yaw_for_turn_units",
]

logger = logging.getLogger(__name__)

DONE_TOLERANCE_UNITS = 0.5
"""A side within half a distance unit (22 um) of its distance counts as arrived."""

_DIRECTIONS: dict[int, tuple[int, int]] = {
    Command.STOP: (0, 0),
    Command.FWD: (1, 1),
    Command.REV: (-1, -1),
    Command.LEFT: (-1, 1),
    Command.RIGHT: (1, -1),
}


def side_directions(command: int) -> tuple[int, int]:
    """Direction of each side's wheels for a command, rover frame: ``(left, right)`` in
    ``{-1, 0, +1}`` (FWD ``(1, 1)``, LEFT ``(-1, 1)``, STOP ``(0, 0)``).

    Raises:
        CommandError: unknown command code.
    """
    try:
        return _DIRECTIONS[command]
    except KeyError:
        raise CommandError(f"unknown command code {command!r}") from None


def ramp(current: float, target: float, max_delta: float) -> float:
    """``current`` moved toward ``target`` by at most ``max_delta`` (>= 0)."""
    if target > current:
        return min(target, current + max_delta)
    return max(target, current - max_delta)


def brake(
    rover: RoverDescription, current_left_mps: float, current_right_mps: float, dt_s: float
) -> tuple[float, float]:
    """Wheel surface speeds one tick later when braking to rest at the accel limit.

    For STOP: call every tick with the speeds it returned last; both reach exactly zero.
    """
    dv = rover.drive.wheel_accel_limit_mps2 * dt_s
    return ramp(current_left_mps, 0.0, dv), ramp(current_right_mps, 0.0, dv)


def stopping_distance_m(rover: RoverDescription, speed_mps: float, dt_s: float = 0.0) -> float:
    """Wheel travel, m, while braking from ``speed_mps`` to rest at the accel limit;
    with ``dt_s > 0``, the discrete sum :func:`brake` travels (current tick counted).
    """
    a = rover.drive.wheel_accel_limit_mps2
    v = abs(speed_mps)
    if dt_s <= 0.0:
        return v * v / (2.0 * a)
    total, dv = 0.0, a * dt_s
    while v > 0.0:
        total += v * dt_s
        v = max(0.0, v - dv)
    return total


def motor_omegas(rover: RoverDescription, left_mps: float, right_mps: float) -> tuple[float, float]:
    """Motor rates, rad/s in the motor frame, for wheel surface speeds (rover frame,
    forward positive): ``omega = sign * v / wheel_radius``."""
    r = rover.geometry.wheel_radius_m
    d = rover.drive
    return d.left_wheel_sign * left_mps / r, d.right_wheel_sign * right_mps / r


def travel_units(
    rover: RoverDescription, left_angle_rad: float, right_angle_rad: float
) -> tuple[float, float]:
    """Encoder travel, distance units forward-positive (rover frame), for motor angles
    (motor frame, rad): ``sign * angle * wheel_radius * units_per_m``. Not rounded."""
    scale = rover.geometry.wheel_radius_m * rover.drive.distance_units_per_m
    d = rover.drive
    return d.left_wheel_sign * left_angle_rad * scale, d.right_wheel_sign * right_angle_rad * scale


def turn_units_for_yaw(rover: RoverDescription, yaw_rad: float) -> int:
    """Distance units of a LEFT/RIGHT step turning ``|yaw_rad|`` (the rover's model)."""
    return rover.turn_units_for_yaw(yaw_rad)


def yaw_for_turn_units(rover: RoverDescription, distance_units: float) -> float:
    """Predicted yaw, rad (unsigned), of a LEFT/RIGHT step of ``distance_units``."""
    return rover.yaw_for_turn_units(distance_units)


def nominal_step_duration_s(rover: RoverDescription, speed: int, distance: int) -> float:
    """Time, s, of a step's speed profile without slip, rest to rest."""
    return rover.step_duration_s(speed, distance)


def _braking_speed(rem_m: float, a_dt: float, dt_s: float) -> float:
    """Largest speed ``v`` for this tick from which braking tick by tick
    (``v, v - a*dt, ..., 0``) covers exactly ``rem_m`` or less: the piecewise linear
    ``D(v) = dt * ((m+1)*v - a*dt*m*(m+1)/2)`` of docs/twin.md solved for ``rem_m``.
    """
    unit = a_dt * dt_s  # travel of one tick at speed a*dt
    m = math.floor((math.sqrt(1.0 + 8.0 * rem_m / unit) - 1.0) / 2.0)
    while unit * m * (m + 1) / 2.0 > rem_m:  # guard the float floor both ways
        m -= 1
    while unit * (m + 1) * (m + 2) / 2.0 <= rem_m:
        m += 1
    return (rem_m / dt_s + a_dt * m * (m + 1) / 2.0) / (m + 1)


class StepProfile:
    """Wheel speed targets of one MOTION step, fed by encoder travel.

    Call :meth:`update` once per control tick; :attr:`done` turns true once both sides
    have travelled ``distance`` and their targets are zero, and every update returns
    ``(0.0, 0.0)`` after. A step with speed 0 or distance 0 is done at once from rest,
    else it brakes to rest as a STOP step does.
    """

    def __init__(
        self,
        rover: RoverDescription,
        command: int,
        speed: int,
        distance: int,
        *,
        initial_left_mps: float = 0.0,
        initial_right_mps: float = 0.0,
    ) -> None:
        """Args:
        rover: the rover description (speed scale, units, accel limit, limits).
        command: command code (``firmware_proto.wire.messages.Command``).
        speed: speed units, ``0..drive.max_speed``.
        distance: distance units, ``0..drive.max_distance``.
        initial_left_mps, initial_right_mps: wheel speeds at the start (rover frame).

        Raises:
            CommandError: unknown command, or speed or distance out of range.
        """
        d = rover.drive
        self.directions = side_directions(command)
        if isinstance(speed, bool) or not isinstance(speed, int) or not 0 <= speed <= d.max_speed:
            raise CommandError(f"speed must be an integer in 0..{d.max_speed}, got {speed!r}")
        if (
            isinstance(distance, bool)
            or not isinstance(distance, int)
            or not 0 <= distance <= d.max_distance
        ):
            raise CommandError(
                f"distance must be an integer in 0..{d.max_distance}, got {distance!r}"
            )
        self.rover = rover
        self.command = Command(command)
        self.speed = speed
        self.distance = distance
        self._units_per_m = float(d.distance_units_per_m)
        self._accel = d.wheel_accel_limit_mps2
        moving = command != Command.STOP and speed > 0 and distance > 0
        self._vmax = rover.speed_to_mps(speed) if moving else 0.0
        self._goal_units = float(distance) if moving else 0.0
        dl, dr = self.directions
        # Current target of each side along its direction of travel (m/s, may be < 0).
        self._u = [initial_left_mps * dl if dl else 0.0, initial_right_mps * dr if dr else 0.0]
        # A zero step brakes the speeds themselves: along a direction it could never arrive.
        self._brakes = not moving
        if self._brakes:
            self._u = [initial_left_mps, initial_right_mps]
        self._done = not moving and self._u == [0.0, 0.0]
        self._arrived = [not moving, not moving]

    @property
    def done(self) -> bool:
        """Both sides arrived and at rest."""
        return self._done

    @property
    def targets_mps(self) -> tuple[float, float]:
        """The targets returned by the last :meth:`update` (rover frame)."""
        return self._signed()

    def remaining_units(
        self, left_travel_units: float, right_travel_units: float
    ) -> tuple[float, float]:
        """Distance units each side still has to go (negative: past it)."""
        dl, dr = self.directions
        return (
            self._goal_units - dl * left_travel_units,
            self._goal_units - dr * right_travel_units,
        )

    def update(
        self, left_travel_units: float, right_travel_units: float, dt_s: float
    ) -> tuple[float, float]:
        """Wheel surface speed targets ``(left_mps, right_mps)`` for the next ``dt_s``, from
        each side's encoder travel since the step started (units; rover frame, forward +)."""
        if self._done:
            return (0.0, 0.0)
        a_dt = self._accel * dt_s
        if self._brakes:
            left, right = self._u
            self._u = [ramp(left, 0.0, a_dt), ramp(right, 0.0, a_dt)]
            self._done = self._u == [0.0, 0.0]
            return (self._u[0], self._u[1])
        dl, dr = self.directions
        goal = self._goal_units
        # Beyond this distance the braking curve allows more than cruise speed.
        vmax = self._vmax
        cruise_m = vmax * vmax / (2.0 * self._accel) + vmax * dt_s + a_dt * dt_s
        u = self._u
        u[0], self._arrived[0] = self._side(
            u[0], goal - dl * left_travel_units, a_dt, dt_s, cruise_m
        )
        u[1], self._arrived[1] = self._side(
            u[1], goal - dr * right_travel_units, a_dt, dt_s, cruise_m
        )
        self._done = self._arrived[0] and self._arrived[1] and u[0] == 0.0 and u[1] == 0.0
        return (dl * u[0], dr * u[1])

    def _side(
        self, u: float, rem_units: float, a_dt: float, dt_s: float, cruise_m: float
    ) -> tuple[float, bool]:
        """Next target along the direction of travel, and whether the side has arrived."""
        if rem_units <= DONE_TOLERANCE_UNITS:
            return (u - a_dt if u > a_dt else (u + a_dt if u < -a_dt else 0.0)), True
        rem_m = rem_units / self._units_per_m
        want = (
            self._vmax if rem_m > cruise_m else min(self._vmax, _braking_speed(rem_m, a_dt, dt_s))
        )
        if want > u + a_dt:
            return u + a_dt, False
        if want < u - a_dt:
            return u - a_dt, False
        return want, False

    def _signed(self) -> tuple[float, float]:
        if self._brakes:
            return (self._u[0], self._u[1])
        dl, dr = self.directions
        return (dl * self._u[0], dr * self._u[1])

    def __repr__(self) -> str:
        return (
            f"StepProfile({self.command.name}, speed={self.speed}, distance={self.distance},"
            f" done={self._done})"
        )
