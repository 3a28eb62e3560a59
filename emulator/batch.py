"""Many twins played in one physics world: the same plan on N grounds at once.

:func:`play_batch` plays one plan, as :func:`emulator.playback.play` does, on N twins
that differ only in their ground and a friction factor per side: one pymunk space, each
twin with its own copy of the map far enough apart that none meet, state and forces
through :mod:`pymunk.batch`, the :mod:`emulator.traction` forces in C
(:mod:`emulator.batch_kernel`) or numpy. Time step,
step semantics, wheel commands (computed once: ideal motors), collisions and settling
are a single playback's; traction regions are a point test that may differ from the
twin's probes by a step near a corner. A batch twin agrees with
:class:`~emulator.twin.Twin` to about 1e-9 m and depends only on its parameters and
index; deterministic; no injected faults. docs/gate.md has more.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pymunk
import pymunk.batch

from emulator import batch_kernel
from emulator.drive import StepProfile, motor_omegas, nominal_step_duration_s, travel_units
from emulator.errors import TwinConfigError
from emulator.ground import Ground
from emulator.playback import (
    DEFAULT_SETTLE_S,
    DEFAULT_STALL_WINDOW_S,
    REST_SPEED_MPS,
    REST_YAW_RATE_RAD_S,
    Stall,
    _no_progress,
)
from emulator.traction import ROLLING_SPEED_SCALE_MPS, TractionModel
from emulator.twin import (
    COLLISION_SLOP_M,
    CONTACT_FRICTION,
    MAX_DT_S,
    WALL_THICKNESS_M,
    Pose2D,
)
from firmware_proto.model.geometry import convex_parts
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import (
    BOUNDS_ID,
    CircleObstacle,
    PolygonObstacle,
    SegmentObstacle,
    WorldMap,
)

__all__ = ["BatchDraw", "BatchResult", "Schedule", "play_batch", "schedule"]

logger = logging.getLogger(__name__)

_CAT_CHASSIS, _CAT_SENSOR, _CAT_OBSTACLE = 1, 2, 4
_CT_SENSOR, _CT_OBSTACLE = 2, 3
_WHEEL_PROBE_RADIUS_M = 0.001
"""A wheel is on a region when its contact is within this of it, m: the twin's probe radius."""
_GAP_M = 2.0 * (WALL_THICKNESS_M + 1.0) + 2.0
"""Space between two copies of the map: twice the walls and the largest margin (1 m),
and 2 m more, so that no shape of one twin ever overlaps another's."""
_TINY = 1e-9
_BODY = pymunk.batch.BodyFields


@dataclass(frozen=True)
class BatchDraw:
    """What one twin of a batch drives on.

    Attributes:
        ground: its traction parameters and region scales (unnamed regions keep the
            map's scale).
        slip_left, slip_right: factors on each side's wheel friction (> 0; 1 nominal).
        start_dx_m, start_dy_m, start_dyaw_rad: the start pose's error (map frame).
        step_error: the plan's step error (:func:`gate.ensemble.step_error`) added to
            its final pose, in units of that error; applied by
            :func:`gate.ensemble.run_chunk`, not by :func:`play_batch`.
    """

    ground: Ground
    slip_left: float = 1.0
    slip_right: float = 1.0
    start_dx_m: float = 0.0
    start_dy_m: float = 0.0
    start_dyaw_rad: float = 0.0
    step_error: float = 0.0


@dataclass(frozen=True)
class Schedule:
    """The wheel commands of a plan, shared by every ground (see the module docstring).

    Attributes:
        surface_mps: ``(ticks, 2)`` wheel surface speed of each side per tick, m/s.
        step_ticks: ``(start, end)`` tick of each step played.
        completed: whether each step played ran to its distance.
        travel_units: ``(left, right)`` encoder travel of each step played.
        stall: a stall that ends the plan (then no settling), else ``None``.
    """

    surface_mps: np.ndarray
    step_ticks: tuple[tuple[int, int], ...]
    completed: tuple[bool, ...]
    travel_units: tuple[tuple[float, float], ...]
    stall: Stall | None

    @property
    def ticks(self) -> int:
        """Ticks of the steps, settling excluded."""
        return len(self.surface_mps)


def schedule(
    rover: RoverDescription,
    steps: Sequence[tuple[int, int, int]],
    dt_s: float,
    *,
    stall_window_s: float = DEFAULT_STALL_WINDOW_S,
    time_limit_factor: float = 1.5,
    time_limit_margin_s: float = 2.0,
) -> Schedule:
    """The wheel speeds :func:`emulator.playback.play` commands for ``steps``, per tick.

    Raises:
        CommandError: a step is invalid.
    """
    profiles = [StepProfile(rover, c, s, d) for c, s, d in steps]
    stall_every = max(1, round(stall_window_s / dt_s))
    kl, kr = travel_units(rover, 1.0, 1.0)
    ml, mr = motor_omegas(rover, 1.0, 1.0)
    g, d = rover.geometry, rover.drive
    per_rad = (d.left_wheel_sign * g.wheel_radius_m, d.right_wheel_sign * g.wheel_radius_m)
    angle_l = angle_r = 0.0
    surface: list[tuple[float, float]] = []
    bounds: list[tuple[int, int]] = []
    completed: list[bool] = []
    travel: list[tuple[float, float]] = []
    stall: Stall | None = None
    for index, profile in enumerate(profiles):
        a0l, a0r = angle_l, angle_r
        start = len(surface)
        limit = round(
            (
                time_limit_factor * nominal_step_duration_s(rover, profile.speed, profile.distance)
                + time_limit_margin_s
            )
            / dt_s
        )
        taken = 0
        last_l = last_r = 0.0
        while True:
            tl, tr = (angle_l - a0l) * kl, (angle_r - a0r) * kr
            ul, ur = profile.update(tl, tr, dt_s)
            if profile.done:
                break
            wl, wr = float(ul * ml), float(ur * mr)
            surface.append((wl * per_rad[0], wr * per_rad[1]))
            angle_l += wl * dt_s
            angle_r += wr * dt_s
            taken += 1
            if taken % stall_every == 0:
                t_s = len(surface) * dt_s
                stall = _no_progress(profile, index, t_s, (tl, tr), (last_l, last_r))
                last_l, last_r = tl, tr
                if stall is not None:
                    break
            if taken >= limit:
                stall = Stall(index, len(surface) * dt_s, "time_limit")
                break
        bounds.append((start, len(surface)))
        completed.append(profile.done)
        travel.append(((angle_l - a0l) * kl, (angle_r - a0r) * kr))
        if stall is not None:
            break
    array = np.array(surface, dtype=np.float64).reshape(-1, 2)
    return Schedule(array, tuple(bounds), tuple(completed), tuple(travel), stall)


@dataclass(frozen=True)
class BatchResult:
    """What :func:`play_batch` observed; ``N`` twins, poses as ``(x_m, y_m, yaw_rad)``
    in the map frame (yaw wrapped to ``[-pi, pi)``).

    Attributes:
        schedule: the shared wheel commands and step boundaries.
        dt_s: the physics step.
        record_ticks: the ticks after which poses were recorded: every
            ``record_every`` ticks and each step's end, sorted, no repeats.
        poses: ``(len(record_ticks), N, 3)``; NaN once a twin had stopped (collided,
            or came to rest after the last step).
        final: ``(N, 3)`` where each twin stopped: at rest, at its collision, or where
            the plan ended (a stall).
        final_tick: ``(N,)`` the tick it stopped at.
        collision_tick: ``(N,)`` the tick of its first contact (0: the start pose
            touches), ``-1`` for none.
        collision_step: ``(N,)`` the step during which it touched, ``-1`` for none.
        collision_obstacle: per twin, the obstacle touched first, or ``None``.
        collision_contact: ``(N, 2)`` the contact point (NaN for none).
    """

    schedule: Schedule
    dt_s: float
    record_ticks: tuple[int, ...]
    poses: np.ndarray
    final: np.ndarray
    final_tick: np.ndarray
    collision_tick: np.ndarray
    collision_step: np.ndarray
    collision_obstacle: tuple[str | None, ...]
    collision_contact: np.ndarray

    @property
    def size(self) -> int:
        """How many twins."""
        return len(self.final)


class _World:
    """N bodies, each with its own copy of the map, in one pymunk space."""

    def __init__(
        self,
        rover: RoverDescription,
        world: WorldMap | None,
        draws: Sequence[BatchDraw],
        dt_s: float,
        margin_m: float,
        start: Pose2D,
    ) -> None:
        n = len(draws)
        self.n = n
        self.world = world
        self.space = space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        space.collision_slop = COLLISION_SLOP_M
        g = rover.geometry
        if world is not None:
            b = world.bounds
            cell_w, cell_h = b.max_x - b.min_x + _GAP_M, b.max_y - b.min_y + _GAP_M
        else:
            cell_w = cell_h = 2.0 * rover.footprint_radius_m + 2.0 * margin_m + _GAP_M + 1e3
        cols = max(1, math.ceil(math.sqrt(n)))
        self.offsets = np.array(
            [((i % cols) * cell_w, (i // cols) * cell_h) for i in range(n)], dtype=np.float64
        ).reshape(n, 2)
        mass = rover.mass.mass_kg
        size = (g.chassis_length_m, g.chassis_width_m)
        half_l, half_w = size[0] / 2.0, size[1] / 2.0
        box = [(-half_l, -half_w), (half_l, -half_w), (half_l, half_w), (-half_l, half_w)]
        static = space.static_body
        self.bodies: list[pymunk.Body] = []
        self.chassis: list[pymunk.Poly] = []
        self._twin_of: dict[pymunk.Shape, int] = {}
        self._obstacle_of: dict[pymunk.Shape, str] = {}
        shapes: list[Any] = []
        chassis_filter = pymunk.ShapeFilter(categories=_CAT_CHASSIS, mask=_CAT_OBSTACLE)
        sensor_filter = pymunk.ShapeFilter(categories=_CAT_SENSOR, mask=_CAT_OBSTACLE)
        obstacle_filter = pymunk.ShapeFilter(
            categories=_CAT_OBSTACLE, mask=_CAT_CHASSIS | _CAT_SENSOR
        )
        for i in range(n):
            ox, oy = (float(v) for v in self.offsets[i])
            body = pymunk.Body(mass, pymunk.moment_for_box(mass, size))
            d = draws[i]
            body.position = (start.x_m + d.start_dx_m + ox, start.y_m + d.start_dy_m + oy)
            body.angle = start.yaw_rad + d.start_dyaw_rad
            chassis = pymunk.Poly(body, box)
            chassis.friction = CONTACT_FRICTION
            chassis.elasticity = 0.0
            chassis.collision_type = 1
            chassis.filter = chassis_filter
            sensor = pymunk.Poly(body, box, radius=margin_m)
            sensor.sensor = True
            sensor.collision_type = _CT_SENSOR
            sensor.filter = sensor_filter
            self._twin_of[sensor] = i
            shapes += [body, chassis, sensor]
            self.bodies.append(body)
            self.chassis.append(chassis)
            if world is None:
                continue
            own: list[tuple[pymunk.Shape, str]] = []
            bb, t = world.bounds, WALL_THICKNESS_M
            for x0, y0, x1, y1 in (
                (bb.min_x - t, bb.min_y - t, bb.max_x + t, bb.min_y),
                (bb.min_x - t, bb.max_y, bb.max_x + t, bb.max_y + t),
                (bb.min_x - t, bb.min_y, bb.min_x, bb.max_y),
                (bb.max_x, bb.min_y, bb.max_x + t, bb.max_y),
            ):
                corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
                own.append((pymunk.Poly(static, [(x + ox, y + oy) for x, y in corners]), BOUNDS_ID))
            for o in world.obstacles:
                if isinstance(o, PolygonObstacle):
                    for part in convex_parts(o.points):
                        poly = pymunk.Poly(static, [(x + ox, y + oy) for x, y in part])
                        own.append((poly, o.id))
                elif isinstance(o, CircleObstacle):
                    center = (o.center[0] + ox, o.center[1] + oy)
                    own.append((pymunk.Circle(static, o.radius_m, offset=center), o.id))
                elif isinstance(o, SegmentObstacle):
                    a, b2 = (o.a[0] + ox, o.a[1] + oy), (o.b[0] + ox, o.b[1] + oy)
                    own.append((pymunk.Segment(static, a, b2, o.radius_m), o.id))
            for shape, oid in own:
                shape.friction = CONTACT_FRICTION
                shape.elasticity = 0.0
                shape.collision_type = _CT_OBSTACLE
                shape.filter = obstacle_filter
                self._obstacle_of[shape] = oid
                shapes.append(shape)
        space.add(*shapes)
        self.pending: dict[int, tuple[str, float, float]] = {}
        space.on_collision(_CT_SENSOR, _CT_OBSTACLE, begin=self._on_contact)
        self.buffer = pymunk.batch.Buffer()
        self.force = np.zeros(3 * (n + 1), dtype=np.float64)  # + the static body, last
        self.force_buffer = pymunk.batch.Buffer()
        self.force_buffer.set_float_buf(self.force)

    def _on_contact(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        sensor, other = arbiter.shapes
        i = self._twin_of[sensor]
        points = arbiter.contact_point_set.points
        if points:
            cx = sum(p.point_b.x for p in points) / len(points)
            cy = sum(p.point_b.y for p in points) / len(points)
        else:  # pragma: no cover - pymunk always reports a point for a new contact
            cx, cy = self.bodies[i].position
        found = (self._obstacle_of.get(other, "?"), cx, cy)
        # Several contacts in one step: the least by (id, point), whatever pymunk's order.
        if i not in self.pending or found < self.pending[i]:
            self.pending[i] = found

    def state(self) -> np.ndarray:
        """``(N, 6)``: x, y, angle, vx, vy (world frame), angular velocity."""
        self.buffer.clear()
        pymunk.batch.get_space_bodies(
            self.space,
            _BODY.POSITION | _BODY.ANGLE | _BODY.VELOCITY | _BODY.ANGULAR_VELOCITY,
            self.buffer,
        )
        return np.frombuffer(self.buffer.float_buf(), dtype=np.float64).reshape(-1, 6)[: self.n]

    def apply(self, fx: np.ndarray, fy: np.ndarray, tz: np.ndarray) -> None:
        """Set each body's force (world frame) and torque for the next step."""
        n = self.n
        f = self.force
        f[0 : 3 * n : 3] = fx
        f[1 : 3 * n : 3] = fy
        f[2 : 3 * n : 3] = tz
        self.push()

    def push(self) -> None:
        """Give the bodies the forces and torques in :attr:`force` (``3 * (N + 1)``:
        ``fx, fy, tz`` per body, the static body last) for the next step."""
        pymunk.batch.set_space_bodies(self.space, _BODY.FORCE | _BODY.TORQUE, self.force_buffer)


class _Forces:
    """:class:`emulator.traction.TractionModel`'s equations, in order, for N twins at once."""

    def __init__(
        self, rover: RoverDescription, world: WorldMap | None, draws: Sequence[BatchDraw]
    ) -> None:
        model = TractionModel.from_rover(rover)
        n = len(draws)
        self.hx, self.hy = model.half_wheelbase_m, model.half_track_m
        self.mass, self.inertia = model.mass_kg, model.inertia_kg_m2
        self.inv_vrr = 1.0 / ROLLING_SPEED_SCALE_MPS
        normal = model.normal_n
        grounds = [d.ground for d in draws]
        self.s0 = np.array([gr.slip_saturation_mps for gr in grounds])
        self.kappa = np.array([gr.slip_saturation_ratio for gr in grounds])
        self.rr = np.array([gr.rolling_resistance * normal for gr in grounds])
        self.mu_long_n = np.array([gr.mu_longitudinal * normal for gr in grounds])
        self.mu_lat_n = np.array([gr.mu_lateral * normal for gr in grounds])
        # Side factor per wheel (FL, RL, FR, RR), twin along the second axis.
        sides = np.array([[d.slip_left, d.slip_right] for d in draws]).reshape(n, 2).T
        self.side = sides[[0, 0, 1, 1], :]
        regions = world.traction_regions if world is not None else ()
        self.region_scales = np.ones((n, max(1, len(regions))))
        for i, gr in enumerate(grounds):
            for r_index, region in enumerate(regions):
                scale = gr.region_scale(region.id)
                self.region_scales[i, r_index] = region.mu_scale if scale is None else scale
        self.wheel_region = np.ones((4, n))
        self.lx = np.empty((4, n))
        self.ly = np.empty((4, n))
        self._update_limits()
        self.wheel_x = np.array([[p[0]] for p in model.wheel_positions_m])
        self.wheel_y = np.array([[p[1]] for p in model.wheel_positions_m])
        # Each region's convex parts as edges: start points and unit directions (CCW).
        self.parts: list[list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]] = []
        for region in regions:
            parts = []
            for part in convex_parts(region.polygon):
                pts = np.array(part, dtype=np.float64)
                d = np.roll(pts, -1, axis=0) - pts
                d /= np.hypot(d[:, 0], d[:, 1])[:, None]
                parts.append((pts[:, 0:1], pts[:, 1:2], d[:, 0:1], d[:, 1:2]))
            self.parts.append(parts)
        self._on: np.ndarray | None = None
        # Each wheel's (FL, RL, FR, RR) inverse saturation and normalised slips, written row
        # by row each step (np.stack's cost per call was a fifth of a small batch's step).
        self._inv = np.empty((4, n))
        self._nx = np.empty((4, n))
        self._ny = np.empty((4, n))

    def _update_limits(self) -> None:
        scale = self.side * self.wheel_region
        np.multiply(self.mu_long_n, scale, out=self.lx)
        np.multiply(self.mu_lat_n, scale, out=self.ly)

    def place(self, x: np.ndarray, y: np.ndarray, c: np.ndarray, s: np.ndarray) -> None:
        """Update each wheel's region scale from the poses (map frame): the last region
        in map order within :data:`_WHEEL_PROBE_RADIUS_M` of its contact point, else 1."""
        if not self.parts:
            return
        wx = x + c * self.wheel_x - s * self.wheel_y  # (4, N)
        wy = y + s * self.wheel_x + c * self.wheel_y
        on = np.zeros((len(self.parts), *wx.shape), dtype=bool)
        for r_index, parts in enumerate(self.parts):
            for px, py, dx, dy in parts:
                # Left of every edge (CCW), within the probe's radius: (E, 4, N) -> (4, N).
                cross = dx[:, :, None] * (wy[None] - py[:, :, None]) - dy[:, :, None] * (
                    wx[None] - px[:, :, None]
                )
                on[r_index] |= (cross >= -_WHEEL_PROBE_RADIUS_M).all(axis=0)
        if self._on is not None and np.array_equal(on, self._on):
            return
        self._on = on
        scale = np.ones_like(wx)
        for r_index in range(len(self.parts)):
            scale = np.where(on[r_index], self.region_scales[:, r_index][None, :], scale)
        self.wheel_region = scale
        self._update_limits()

    def step(
        self,
        vx: np.ndarray,
        vy: np.ndarray,
        w: np.ndarray,
        ul: float | np.ndarray,
        ur: float | np.ndarray,
        dt_s: float,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body-frame force and torque of one step (``TractionModel.step_wrench``); the
        wheel speeds ``ul``, ``ur`` shared by every twin or one per twin."""
        hx, hy = self.hx, self.hy
        inv_sl = 1.0 / (self.s0 + self.kappa * abs(ul))
        inv_sr = 1.0 / (self.s0 + self.kappa * abs(ur))
        gl = vx - w * hy
        gr = vx + w * hy
        lat_f = -(vy + w * hx)
        lat_b = -(vy - w * hx)
        inv, nx, ny = self._inv, self._nx, self._ny
        inv[0] = inv[1] = inv_sl
        inv[2] = inv[3] = inv_sr
        nx[0] = nx[1] = (ul - gl) * inv_sl
        nx[2] = nx[3] = (ur - gr) * inv_sr
        np.multiply(lat_f, inv_sl, out=ny[0])
        np.multiply(lat_b, inv_sl, out=ny[1])
        np.multiply(lat_f, inv_sr, out=ny[2])
        np.multiply(lat_b, inv_sr, out=ny[3])
        nx2 = nx * nx
        sig2 = np.maximum(nx2 + ny * ny, _TINY * _TINY)
        sig = np.sqrt(sig2)
        th = np.tanh(sig)
        a = th / sig
        b = 1.0 - th * th
        cx2 = nx2 / sig2
        cxy = nx * ny / sig2
        cy2 = 1.0 - cx2
        lx, ly = self.lx, self.ly
        fxw = lx * a * nx
        fyw = ly * a * ny
        ai = a * inv
        dfx = lx * inv * (a * cy2 + b * cx2)
        dfy = ly * inv * (a * cx2 + b * cy2)
        cross_w = (lx + ly) * inv * (b - a) * cxy
        xl = gl * self.inv_vrr
        xr = gr * self.inv_vrr
        tl = np.tanh(xl)
        tr = np.tanh(xr)
        rr = self.rr
        fx_l = fxw[0] + fxw[1] - 2.0 * rr * tl
        fx_r = fxw[2] + fxw[3] - 2.0 * rr * tr
        fy_f = fyw[0] + fyw[2]
        fy_b = fyw[1] + fyw[3]
        rr_slope = 2.0 * rr * self.inv_vrr
        cx = dfx[0] + dfx[1] + dfx[2] + dfx[3] + rr_slope * ((1.0 - tl * tl) + (1.0 - tr * tr))
        cy = dfy[0] + dfy[1] + dfy[2] + dfy[3]
        cross = cross_w[0] + cross_w[3] - cross_w[1] - cross_w[2]
        cz = np.maximum(hy * hy * cx + hx * hx * cy - hx * hy * cross, 0.0)
        ratio_l = np.divide(tl, xl, out=np.ones_like(tl), where=np.abs(xl) > _TINY)
        ratio_r = np.divide(tr, xr, out=np.ones_like(tr), where=np.abs(xr) > _TINY)
        kx = (lx * ai).sum(axis=0) + rr_slope * (ratio_l + ratio_r)
        ky = (ly * ai).sum(axis=0)
        kz = hy * hy * kx + hx * hx * ky
        m, inertia = self.mass, self.inertia
        cx = np.maximum(cx, kx - m / dt_s)
        cy = np.maximum(cy, ky - m / dt_s)
        cz = np.maximum(cz, kz - inertia / dt_s)
        fx = (fx_l + fx_r) * m / (m + dt_s * cx)
        fy = (fy_f + fy_b) * m / (m + dt_s * cy)
        tz = (hy * (fx_r - fx_l) + hx * (fy_f - fy_b)) * inertia / (inertia + dt_s * cz)
        return fx, fy, tz


def _wrap(angle: np.ndarray) -> np.ndarray:
    out = np.mod(angle + math.pi, 2.0 * math.pi) - math.pi
    return np.where((angle >= -math.pi) & (angle < math.pi), angle, out)


def play_batch(
    rover: RoverDescription,
    world: WorldMap | None,
    draws: Sequence[BatchDraw],
    steps: Sequence[tuple[int, int, int]],
    *,
    dt_s: float,
    safety_margin_m: float,
    start: Pose2D,
    record_every_s: float,
    settle_s: float = DEFAULT_SETTLE_S,
    kernel: str = "auto",
) -> BatchResult:
    """Play ``steps`` on one twin per draw (see the module docstring).

    Args:
        rover: the rover description; its traction is replaced by each draw's ground.
        world: the map (region scales replaced by each ground's), or ``None``.
        draws: one per twin (at least one).
        steps: ``(command, speed, distance)`` triples.
        dt_s: physics step, s, in ``(0, MAX_DT_S]``.
        safety_margin_m: inflation of the collision sensor, m (>= 0).
        start: the start pose of every twin.
        record_every_s: record period, s (rounded to ticks); each step's end too.
        settle_s: longest settling after the last step, s.
        kernel: one of :data:`emulator.batch_kernel.KERNELS`: ``auto`` computes the
            forces in C where the kernel builds, else with numpy (said once in the log).

    Raises:
        CommandError: a step is invalid (nothing is played).
        TwinConfigError: no draw, or a step, margin, period or kernel out of range.
        NativeBuildError: ``kernel="c"`` and the C kernel cannot be built here.
    """
    if not draws:
        raise TwinConfigError("a batch needs at least one draw")
    if not (math.isfinite(dt_s) and 0.0 < dt_s <= MAX_DT_S):
        raise TwinConfigError(f"dt_s must be in (0, {MAX_DT_S}], got {dt_s}")
    if not (math.isfinite(safety_margin_m) and 0.0 <= safety_margin_m <= 1.0):
        raise TwinConfigError(f"safety_margin_m must be in [0, 1], got {safety_margin_m}")
    if not (math.isfinite(record_every_s) and record_every_s > 0.0):
        raise TwinConfigError(f"record_every_s must be > 0, got {record_every_s}")
    lib = batch_kernel.choose(kernel)
    plan = schedule(rover, steps, dt_s)
    n = len(draws)
    space = _World(rover, world, draws, dt_s, safety_margin_m, start)
    forces = _Forces(rover, world, draws)
    record_every = max(1, round(record_every_s / dt_s))
    ends = {end for _, end in plan.step_ticks if end > 0}
    settle_ticks = 0 if plan.stall is not None else round(settle_s / dt_s)
    last_tick = plan.ticks + settle_ticks
    record = sorted({k for k in range(record_every, last_tick + 1, record_every)} | ends)
    row_of = {k: r for r, k in enumerate(record)}
    poses = np.full((len(record), n, 3), np.nan)
    final = np.full((n, 3), np.nan)
    final_tick = np.full(n, -1, dtype=np.int64)
    hit_tick = np.full(n, -1, dtype=np.int64)
    hit_step = np.full(n, -1, dtype=np.int64)
    hit_obstacle: list[str | None] = [None] * n
    hit_contact = np.full((n, 2), np.nan)
    active = np.ones(n, dtype=bool)
    offsets = space.offsets
    # The step each tick belongs to: step i moves the twin in ticks (start, end].
    step_of_tick = np.zeros(last_tick + 1, dtype=np.int64)
    for index, (a, b) in enumerate(plan.step_ticks):
        step_of_tick[a + 1 : b + 1] = index
    step_of_tick[plan.ticks + 1 :] = max(0, len(plan.step_ticks) - 1)

    def map_state(raw: np.ndarray | None = None) -> np.ndarray:
        """The twins' state in the map frame: ``raw`` (this step's, from
        :meth:`_World.state`) or the space's now."""
        state: np.ndarray = (space.state() if raw is None else raw).copy()
        state[:, 0:2] -= offsets
        state[:, 2] = _wrap(state[:, 2])
        return state

    def note_collisions(tick: int, state: np.ndarray) -> None:
        for i, (oid, cx, cy) in sorted(space.pending.items()):
            if not active[i]:
                continue
            active[i] = False
            hit_tick[i] = tick
            hit_step[i] = step_of_tick[tick]
            hit_obstacle[i] = oid
            hit_contact[i] = (cx - offsets[i, 0], cy - offsets[i, 1])
            final[i] = state[i, 0:3]
            final_tick[i] = tick
        space.pending.clear()

    # Prime: contacts and regions at the start pose, the chassis masked out (as a twin).
    for chassis in space.chassis:
        chassis.filter = pymunk.ShapeFilter(categories=_CAT_CHASSIS, mask=0)
    space.space.step(dt_s)
    for chassis in space.chassis:
        chassis.filter = pymunk.ShapeFilter(categories=_CAT_CHASSIS, mask=_CAT_OBSTACLE)
    if plan.step_ticks:
        note_collisions(0, map_state())
    else:
        space.pending.clear()
    surface = plan.surface_mps
    native: batch_kernel.Forces | None = None
    if lib is not None:
        prepared = batch_kernel.Prepared(forces, dt_s=dt_s, probe_m=_WHEEL_PROBE_RADIUS_M)
        native = batch_kernel.Forces(lib, prepared, offsets, space.force)
    for tick in range(1, last_tick + 1):
        if not active.any():
            break
        raw = space.state()
        settling = tick > plan.ticks
        if settling or native is None:
            angle, vxw, vyw, w = raw[:, 2], raw[:, 3], raw[:, 4], raw[:, 5]
            c, s = np.cos(angle), np.sin(angle)
            vx = c * vxw + s * vyw
            vy = c * vyw - s * vxw
        if settling:  # stop the twins already at rest
            rest = (np.abs(w) < REST_YAW_RATE_RAD_S) & (np.hypot(vx, vy) < REST_SPEED_MPS)
            resting = np.flatnonzero(rest & active)
            if len(resting):
                state = map_state(raw)  # raw stays valid: the space's buffer is not read again
                final[resting] = state[resting, 0:3]
                final_tick[resting] = tick - 1
                active[resting] = False
            if not active.any():
                break
            ul = ur = 0.0
        else:
            ul, ur = float(surface[tick - 1, 0]), float(surface[tick - 1, 1])
        if native is not None:
            native(raw, ul, ur)
            space.push()
        else:
            forces.place(raw[:, 0] - offsets[:, 0], raw[:, 1] - offsets[:, 1], c, s)
            fx, fy, tz = forces.step(vx, vy, w, ul, ur, dt_s)
            space.apply(c * fx - s * fy, s * fx + c * fy, tz)
        space.space.step(dt_s)
        row = row_of.get(tick)
        if row is not None or space.pending:
            state = map_state()
            if row is not None:
                poses[row, active] = state[active, 0:3]
            if space.pending:
                note_collisions(tick, state)
    if active.any():
        state = map_state()
        final[active] = state[active, 0:3]
        final_tick[active] = last_tick
    logger.debug(
        "batch of %d twins: %d ticks, %d collided", n, last_tick, int((hit_tick >= 0).sum())
    )
    return BatchResult(
        schedule=plan,
        dt_s=dt_s,
        record_ticks=tuple(record),
        poses=poses,
        final=final,
        final_tick=final_tick,
        collision_tick=hit_tick,
        collision_step=hit_step,
        collision_obstacle=tuple(hit_obstacle),
        collision_contact=hit_contact,
    )
