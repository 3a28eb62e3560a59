"""The physics twin: a top-down pymunk world with the rover, its wheels and a map.

The rover is one rigid body with the chassis footprint and mass of the rover
description; four wheels touch the ground at ``(+-wheelbase/2, +-track/2)``. Each side's
motor is driven in the *motor frame* (:meth:`Twin.set_motor_omegas`); the mounting
polarity of the description (left -1, right +1) turns motor rotation into wheel surface
speed, so FWD at speed ``s`` is ``omega = sign * s * k`` (docs/architecture.md, Contracts 4). Motors
are ideal velocity sources: the wheel turns at exactly the commanded rate, whatever the
load (acceleration limits belong to the step profile of :mod:`emulator.drive`).

Each physics step the wheel-ground forces of :mod:`emulator.traction` (slip-driven,
saturating at ``mu * N``, plus rolling resistance) are summed into one force and torque
on the body; pymunk integrates it and resolves contacts with the map's obstacles and
walls (the body stops against them). Per-side traction scale and locked sides can be
injected; map traction regions scale the friction of each wheel inside them.

Collision *reporting* uses a sensor shape: the footprint inflated by ``safety_margin_m``
(rounded corners). The first time it touches an obstacle or a wall, the twin records a
:class:`Collision` (obstacle id, contact point on the obstacle, pose, time). Detection
runs every step on the pose after the step; at the 0.3 m/s top speed the body moves
0.3 mm per 1 ms step (3 mm at 10 ms), far less than any footprint, so no wall can be
passed through between two checks; only grazing contacts shallower than one step's
motion may go unseen (add a safety margin to be conservative).

The twin has a fixed time step and no randomness: the same construction and the same
calls give the same trajectory bit for bit, in one process or in several (no hashing,
no wall clock, no threads). Sensor noise belongs to the controller model, not here.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import pymunk

from emulator.errors import CommandError, InjectionError, TwinConfigError
from emulator.traction import TractionModel
from firmware_proto.model.geometry import convex_parts, wrap_rad
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import (
    BOUNDS_ID,
    CircleObstacle,
    PolygonObstacle,
    SegmentObstacle,
    WorldMap,
)

__all__ = [
    "GATE_DT_S",
    "MAX_DT_S",
    "SERVED_TICK_WALL_S",
    "SIDES",
    "BodyAcceleration",
    "BodyVelocity",
    "Collision",
    "Pose2D",
    "Twin",
    "served_dt_s",
]

logger = logging.getLogger(__name__)

SIDES = ("left", "right")
"""Side names accepted by :meth:`Twin.set_wheel_locked`."""

MAX_DT_S = 0.02
"""Largest accepted time step, s. The slip force is integrated linearly-implicitly and
stays stable beyond it, but turns drift from the 1 ms reference (0.27 degree over four
quarter turns at 20 ms) and contacts are checked less often."""

GATE_DT_S = 0.01
"""Step recommended for plan validation: a 12-step, 55 s plan ends within 3 mm and
0.2 degree of the 1 ms reference at a tenth of the steps, so the 500x real-time target
holds with a factor of two to spare for a loaded machine (docs/twin.md)."""

SERVED_TICK_WALL_S = 0.001
"""The wall time between two control periods of a served emulator (``rover emulate``,
the tests' rigs) when its step is not given: 1 ms, a 1 kHz controller."""


def served_dt_s(speed_factor: float) -> float:
    """The twin step, s, of an emulator served at ``speed_factor`` twin seconds per wall
    second when none is given: :data:`SERVED_TICK_WALL_S` of wall time (so its CPU per
    wall second does not grow with the speed factor: at 4x, a 1 ms step cost a whole core
    of a slow host), never coarser than :data:`GATE_DT_S`, the gate's own step."""
    if speed_factor <= 0.0:
        raise ValueError(f"speed_factor must be > 0, got {speed_factor}")
    return min(GATE_DT_S, SERVED_TICK_WALL_S * max(1.0, speed_factor))


WALL_THICKNESS_M = 1.0
"""The bounds are built as solid slabs this thick outside the room (cannot be passed)."""

CONTACT_FRICTION = 0.5
"""Coulomb friction between the chassis and obstacles (sliding along a wall)."""

COLLISION_SLOP_M = 0.0005
"""Overlap pymunk tolerates between resting shapes (its default, 0.1, assumes pixels)."""

_WHEEL_PROBE_RADIUS_M = 0.001

# Collision categories (bit masks) and collision types.
_CAT_CHASSIS, _CAT_SENSOR, _CAT_OBSTACLE, _CAT_WHEEL, _CAT_REGION = 1, 2, 4, 8, 16
_CT_CHASSIS, _CT_SENSOR, _CT_OBSTACLE, _CT_WHEEL, _CT_REGION = 1, 2, 3, 4, 5


@dataclass(frozen=True)
class Pose2D:
    """A planar pose: metres in the map frame, yaw counter-clockwise from +x in radians."""

    x_m: float
    y_m: float
    yaw_rad: float

    @property
    def yaw_deg(self) -> float:
        """Yaw in degrees."""
        return math.degrees(self.yaw_rad)

    @classmethod
    def from_deg(cls, x_m: float, y_m: float, yaw_deg: float) -> Pose2D:
        """A pose from a yaw in degrees (maps and plans use degrees)."""
        return cls(x_m, y_m, math.radians(yaw_deg))


@dataclass(frozen=True)
class BodyVelocity:
    """Velocity of the body in its own frame: x forward, y left (m/s), yaw rate (rad/s)."""

    vx_mps: float
    vy_mps: float
    yaw_rate_rad_s: float


@dataclass(frozen=True)
class BodyAcceleration:
    """Acceleration over the last step in the body frame (what an IMU measures, without
    gravity, which is normal to the plane): m/s^2 and rad/s^2."""

    ax_mps2: float
    ay_mps2: float
    yaw_accel_rad_s2: float


@dataclass(frozen=True)
class Collision:
    """The first contact of the (margin-inflated) footprint with an obstacle or a wall.

    Attributes:
        obstacle_id: the map obstacle's id, or ``"bounds"`` for the walls.
        contact_x_m, contact_y_m: contact point on the obstacle's surface, map frame
            (mean of pymunk's contact points).
        pose: the rover's pose when the contact was detected.
        time_s: twin time of the step that detected it.
    """

    obstacle_id: str
    contact_x_m: float
    contact_y_m: float
    pose: Pose2D
    time_s: float

    @property
    def contact_point(self) -> tuple[float, float]:
        """``(x, y)`` of the contact point, m."""
        return (self.contact_x_m, self.contact_y_m)


class Twin:
    """The rover in a pymunk world, advanced in fixed steps with :meth:`step`.

    Not thread-safe: one twin belongs to one thread at a time (build one per request or
    per worker; construction costs well under a millisecond for the shipped maps).
    """

    def __init__(
        self,
        rover: RoverDescription,
        world: WorldMap | None = None,
        *,
        dt_s: float = 0.001,
        safety_margin_m: float = 0.0,
        start: Pose2D | None = None,
    ) -> None:
        """Args:
        rover: the rover description (geometry, mass, drive polarity, traction).
        world: the map; ``None`` is an open plane without walls.
        dt_s: fixed physics step, s, in ``(0, MAX_DT_S]``.
        safety_margin_m: inflation of the footprint used for collision reporting, m
            (>= 0). The physical chassis is never inflated.
        start: initial pose; default the map's start pose, else the origin.

        Raises:
            TwinConfigError: ``dt_s`` or ``safety_margin_m`` out of range.
        """
        if not (math.isfinite(dt_s) and 0.0 < dt_s <= MAX_DT_S):
            raise TwinConfigError(f"dt_s must be in (0, {MAX_DT_S}], got {dt_s}")
        if not (math.isfinite(safety_margin_m) and safety_margin_m >= 0.0):
            raise TwinConfigError(f"safety_margin_m must be finite and >= 0, got {safety_margin_m}")
        self.rover = rover
        self.world = world
        self.dt_s = float(dt_s)
        self.safety_margin_m = float(safety_margin_m)
        if start is None:
            start = (
                Pose2D.from_deg(world.start.x, world.start.y, world.start.yaw_deg)
                if world is not None
                else Pose2D(0.0, 0.0, 0.0)
            )
        self.start = start

        g, d = rover.geometry, rover.drive
        self._model = TractionModel.from_rover(rover)
        # Motor rate -> wheel surface speed (rover frame, forward positive), per side.
        self._surface_per_rad = (
            d.left_wheel_sign * g.wheel_radius_m,
            d.right_wheel_sign * g.wheel_radius_m,
        )

        self._steps = 0
        self._omega = [0.0, 0.0]  # commanded motor rates, motor frame, rad/s
        self._angle = [0.0, 0.0]  # cumulative motor angles, rad
        self._locked = [False, False]
        self._u_left = 0.0  # wheel surface speeds in effect, rover frame, m/s
        self._u_right = 0.0
        self._side_scale = [1.0, 1.0]
        self._region_scale = [1.0, 1.0, 1.0, 1.0]
        self._limits = self._model.friction_limits_n(self.wheel_mu_scales)
        self._v_prev = (0.0, 0.0, 0.0)
        self._first_collision: Collision | None = None
        self._pending: tuple[str, float, float] | None = None

        self._space = space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        space.collision_slop = COLLISION_SLOP_M
        mass = rover.mass.mass_kg
        size = (g.chassis_length_m, g.chassis_width_m)
        self._body = body = pymunk.Body(mass, pymunk.moment_for_box(mass, size))
        body.position = (start.x_m, start.y_m)
        body.angle = start.yaw_rad
        half_l, half_w = size[0] / 2.0, size[1] / 2.0
        box = [(-half_l, -half_w), (half_l, -half_w), (half_l, half_w), (-half_l, half_w)]
        self._chassis = chassis = pymunk.Poly(body, box)
        chassis.friction = CONTACT_FRICTION
        chassis.elasticity = 0.0
        chassis.collision_type = _CT_CHASSIS
        chassis.filter = pymunk.ShapeFilter(categories=_CAT_CHASSIS, mask=_CAT_OBSTACLE)
        self._sensor = sensor = pymunk.Poly(body, box, radius=self.safety_margin_m)
        sensor.sensor = True
        sensor.collision_type = _CT_SENSOR
        sensor.filter = pymunk.ShapeFilter(categories=_CAT_SENSOR, mask=_CAT_OBSTACLE)
        space.add(body, chassis, sensor)

        self._obstacle_ids: dict[pymunk.Shape, str] = {}
        self._wheel_index: dict[pymunk.Shape, int] = {}
        self._region_index: dict[pymunk.Shape, int] = {}
        self._region_counts: list[list[int]] = []
        if world is not None:
            self._add_world(world)
        space.on_collision(_CT_SENSOR, _CT_OBSTACLE, begin=self._on_contact)
        if world is not None and world.traction_regions:
            space.on_collision(
                _CT_WHEEL, _CT_REGION, begin=self._on_region_enter, separate=self._on_region_leave
            )
        self._prime()
        logger.debug(
            "twin ready: map %s, dt %.4f s, margin %.3f m, start %s",
            world.name if world else None,
            self.dt_s,
            self.safety_margin_m,
            start,
        )

    # -- construction -----------------------------------------------------------------
    def _add_world(self, world: WorldMap) -> None:
        space, static = self._space, self._space.static_body
        shapes: list[pymunk.Shape] = []

        def obstacle(shape: pymunk.Shape, oid: str) -> None:
            shape.friction = CONTACT_FRICTION
            shape.elasticity = 0.0
            shape.collision_type = _CT_OBSTACLE
            shape.filter = pymunk.ShapeFilter(
                categories=_CAT_OBSTACLE, mask=_CAT_CHASSIS | _CAT_SENSOR
            )
            self._obstacle_ids[shape] = oid
            shapes.append(shape)

        b, t = world.bounds, WALL_THICKNESS_M
        for x0, y0, x1, y1 in (
            (b.min_x - t, b.min_y - t, b.max_x + t, b.min_y),  # south
            (b.min_x - t, b.max_y, b.max_x + t, b.max_y + t),  # north
            (b.min_x - t, b.min_y, b.min_x, b.max_y),  # west
            (b.max_x, b.min_y, b.max_x + t, b.max_y),  # east
        ):
            obstacle(pymunk.Poly(static, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]), BOUNDS_ID)
        for o in world.obstacles:
            if isinstance(o, PolygonObstacle):
                for part in convex_parts(o.points):
                    obstacle(pymunk.Poly(static, list(part)), o.id)
            elif isinstance(o, CircleObstacle):
                obstacle(pymunk.Circle(static, o.radius_m, offset=o.center), o.id)
            elif isinstance(o, SegmentObstacle):
                obstacle(pymunk.Segment(static, o.a, o.b, o.radius_m), o.id)

        if world.traction_regions:
            for i, (x, y) in enumerate(self._model.wheel_positions_m):
                probe = pymunk.Circle(self._body, _WHEEL_PROBE_RADIUS_M, offset=(x, y))
                probe.sensor = True
                probe.collision_type = _CT_WHEEL
                probe.filter = pymunk.ShapeFilter(categories=_CAT_WHEEL, mask=_CAT_REGION)
                self._wheel_index[probe] = i
                shapes.append(probe)
            self._region_counts = [[0] * len(world.traction_regions) for _ in range(4)]
            for r_index, region in enumerate(world.traction_regions):
                for part in convex_parts(region.polygon):
                    shape = pymunk.Poly(static, list(part))
                    shape.sensor = True
                    shape.collision_type = _CT_REGION
                    shape.filter = pymunk.ShapeFilter(categories=_CAT_REGION, mask=_CAT_WHEEL)
                    self._region_index[shape] = r_index
                    shapes.append(shape)
        space.add(*shapes)

    def _prime(self) -> None:
        """Run one collision-detection pass at rest so that contacts and regions that
        hold at the start pose are known before the first step.

        The body has no velocity and no force, so this step does not move it; the
        chassis is masked out meanwhile so that a start inside an obstacle is reported
        (at time 0) rather than pushed out before anyone could see it.
        """
        self._chassis.filter = pymunk.ShapeFilter(categories=_CAT_CHASSIS, mask=0)
        self._space.step(self.dt_s)
        self._chassis.filter = pymunk.ShapeFilter(categories=_CAT_CHASSIS, mask=_CAT_OBSTACLE)
        self._finish_collision()

    # -- callbacks (run inside space.step) -----------------------------------------------
    def _on_contact(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        if self._first_collision is not None or self._pending is not None:
            return
        _sensor, other = arbiter.shapes
        points = arbiter.contact_point_set.points
        if points:
            cx = sum(p.point_b.x for p in points) / len(points)
            cy = sum(p.point_b.y for p in points) / len(points)
        else:  # pragma: no cover - pymunk always reports a point for a new contact
            cx, cy = self._body.position
        self._pending = (self._obstacle_ids.get(other, "?"), cx, cy)

    def _on_region_enter(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        self._region_change(arbiter, +1)

    def _on_region_leave(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        self._region_change(arbiter, -1)

    def _region_change(self, arbiter: pymunk.Arbiter, delta: int) -> None:
        probe, region = arbiter.shapes
        wheel = self._wheel_index[probe]
        counts = self._region_counts[wheel]
        counts[self._region_index[region]] += delta
        scale = 1.0
        assert self.world is not None
        for r_index, count in enumerate(counts):
            if count > 0:
                scale = self.world.traction_regions[r_index].mu_scale
        self._region_scale[wheel] = scale
        self._limits = self._model.friction_limits_n(self.wheel_mu_scales)

    def _finish_collision(self) -> None:
        if self._pending is not None and self._first_collision is None:
            oid, cx, cy = self._pending
            self._first_collision = Collision(oid, cx, cy, self.pose, self.time_s)
            logger.debug("collision with %s at t=%.3f s", oid, self.time_s)
        self._pending = None

    # -- inputs -------------------------------------------------------------------------
    def set_motor_omegas(self, left_rad_s: float, right_rad_s: float) -> None:
        """Command each side's motors, rad/s in the motor frame (polarity applied by the
        caller: FWD is ``(left_sign * s * k, right_sign * s * k)``).

        The wheels turn at exactly this rate from the next step on (ideal velocity
        control), unless the side is locked.

        Raises:
            CommandError: a rate is not finite.
        """
        if not (math.isfinite(left_rad_s) and math.isfinite(right_rad_s)):
            raise CommandError(f"motor rates must be finite, got {left_rad_s}, {right_rad_s}")
        self._omega[0] = float(left_rad_s)
        self._omega[1] = float(right_rad_s)
        self._update_surface()

    def set_traction_scale(self, left: float, right: float) -> None:
        """Scale the friction of each side's wheels (slip injection), ``0 < scale <= 1``.

        Multiplies any map region's scale. ``(1, 1)`` restores nominal traction.

        Raises:
            InjectionError: a scale is outside ``(0, 1]`` or not finite.
        """
        for name, value in (("left", left), ("right", right)):
            if not (math.isfinite(value) and 0.0 < value <= 1.0):
                raise InjectionError(f"{name} traction scale must be in (0, 1], got {value}")
        self._side_scale = [float(left), float(right)]
        self._limits = self._model.friction_limits_n(self.wheel_mu_scales)
        logger.debug("traction scale set to left %.3f, right %.3f", left, right)

    def set_wheel_locked(self, side: str, locked: bool) -> None:
        """Lock (stall) or release one side's wheels: a locked side does not turn,
        whatever its motor command, and its encoder stops counting.

        Raises:
            InjectionError: ``side`` is not ``"left"`` or ``"right"``.
        """
        if side not in SIDES:
            raise InjectionError(f"side must be one of {', '.join(SIDES)}, got {side!r}")
        self._locked[SIDES.index(side)] = bool(locked)
        self._update_surface()
        logger.debug("%s wheels %s", side, "locked" if locked else "released")

    def _update_surface(self) -> None:
        lock_l, lock_r = self._locked
        self._u_left = 0.0 if lock_l else self._omega[0] * self._surface_per_rad[0]
        self._u_right = 0.0 if lock_r else self._omega[1] * self._surface_per_rad[1]

    # -- stepping -------------------------------------------------------------------------
    def step(self) -> None:
        """Advance one fixed step of ``dt_s``: wheel forces, integration, contacts.

        At exact rest (no velocity, no wheel surface speed, no contact with an obstacle)
        the ground's force is zero (every slip is) and a physics step would move nothing
        and change no contact: it is not taken, only counted (37 % of the wire soak's
        steps; the same digests, 5-10 % less CPU: docs/twin.md)."""
        body = self._body
        vxw, vyw = body.velocity
        w = body.angular_velocity
        if (
            vxw == 0.0
            and vyw == 0.0
            and w == 0.0
            and self._u_left == 0.0
            and self._u_right == 0.0
            and self._first_collision is None
            and self._pending is None
        ):
            self._v_prev = (0.0, 0.0, 0.0)
            self._steps += 1
            return
        c, s = body.rotation_vector
        fx, fy, tz = self._model.step_wrench(
            c * vxw + s * vyw,
            c * vyw - s * vxw,
            w,
            self._u_left,
            self._u_right,
            self._limits,
            self.dt_s,
        )
        body.apply_force_at_local_point((fx, fy))  # body frame, at the centre of mass
        body.torque = tz
        self._v_prev = (vxw, vyw, w)
        self._space.step(self.dt_s)
        self._steps += 1
        dt = self.dt_s
        angle = self._angle
        if not self._locked[0]:
            angle[0] += self._omega[0] * dt
        if not self._locked[1]:
            angle[1] += self._omega[1] * dt
        if self._pending is not None:
            self._finish_collision()

    def advance(self, duration_s: float) -> int:
        """Step for ``duration_s`` (rounded to whole steps); returns the step count."""
        n = max(0, round(duration_s / self.dt_s))
        for _ in range(n):
            self.step()
        return n

    # -- outputs --------------------------------------------------------------------------
    @property
    def steps(self) -> int:
        """Steps taken since construction."""
        return self._steps

    @property
    def time_s(self) -> float:
        """Twin time, s (``steps * dt_s``; no accumulated rounding)."""
        return self._steps * self.dt_s

    @property
    def pose(self) -> Pose2D:
        """Ground-truth pose; yaw wrapped to ``[-pi, pi)``."""
        x, y = self._body.position
        return Pose2D(x, y, wrap_rad(self._body.angle))

    @property
    def position_m(self) -> tuple[float, float]:
        """:attr:`pose`'s ``(x, y)``, without the yaw (cheaper: no wrap, no Pose2D)."""
        x, y = self._body.position
        return x, y

    @property
    def yaw_unwrapped_rad(self) -> float:
        """Yaw without wrapping (counts whole turns), rad."""
        return float(self._body.angle)

    @property
    def body_velocity(self) -> BodyVelocity:
        """Velocity in the body frame."""
        body = self._body
        vxw, vyw = body.velocity
        c, s = body.rotation_vector
        return BodyVelocity(c * vxw + s * vyw, c * vyw - s * vxw, body.angular_velocity)

    @property
    def body_acceleration(self) -> BodyAcceleration:
        """Mean acceleration over the last step, in the body frame at its end (zero
        before the first step). Includes contact forces."""
        if self._steps == 0:
            return BodyAcceleration(0.0, 0.0, 0.0)
        ax, ay = self._linear_acceleration()
        return BodyAcceleration(ax, ay, (self._body.angular_velocity - self._v_prev[2]) / self.dt_s)

    def imu_truth(self) -> tuple[float, float, float]:
        """``(yaw rate, ax, ay)``: :attr:`body_velocity`'s yaw rate and
        :attr:`body_acceleration`'s two linear components, the same values, read together
        (what the IMU samples at the telemetry rate)."""
        w = self._body.angular_velocity
        if self._steps == 0:
            return w, 0.0, 0.0
        ax, ay = self._linear_acceleration()
        return w, ax, ay

    def _linear_acceleration(self) -> tuple[float, float]:
        """The mean linear acceleration over the last step, body frame at its end (after
        the first step)."""
        body = self._body
        vxw, vyw = body.velocity
        px, py, _ = self._v_prev
        axw, ayw = (vxw - px) / self.dt_s, (vyw - py) / self.dt_s
        c, s = body.rotation_vector
        return c * axw + s * ayw, c * ayw - s * axw

    @property
    def motor_angles_rad(self) -> tuple[float, float]:
        """Cumulative motor angles (left, right), rad, motor frame: what encoders count."""
        return (self._angle[0], self._angle[1])

    @property
    def motor_omegas_rad_s(self) -> tuple[float, float]:
        """Commanded motor rates (left, right), rad/s, motor frame."""
        return (self._omega[0], self._omega[1])

    @property
    def wheel_surface_speeds_mps(self) -> tuple[float, float]:
        """Wheel surface speed of each side in effect, m/s, rover frame, forward positive
        (zero on a locked side)."""
        return (self._u_left, self._u_right)

    @property
    def traction_scale(self) -> tuple[float, float]:
        """Injected friction scale per side (left, right)."""
        return (self._side_scale[0], self._side_scale[1])

    @property
    def wheel_locked(self) -> tuple[bool, bool]:
        """Whether each side (left, right) is locked."""
        return (self._locked[0], self._locked[1])

    @property
    def wheel_mu_scales(self) -> tuple[float, float, float, float]:
        """Effective friction scale per wheel (FL, RL, FR, RR): side scale times the map
        region's scale."""
        sl, sr = self._side_scale
        rs = self._region_scale
        return (sl * rs[0], sl * rs[1], sr * rs[2], sr * rs[3])

    @property
    def first_collision(self) -> Collision | None:
        """The first contact of the inflated footprint with an obstacle or wall, if any."""
        return self._first_collision
