"""The heuristic low-level planner: a route of points -> turn and drive steps.

:class:`HeuristicLowLevelPlanner` is the thesis's planner (section 5.5): each segment of
start, waypoints and goal is a turn on the spot to its bearing (the shorter way), then
FWD; at the goal, a turn to the goal yaw, by the rover description's turn model. Every
plan is schema-valid and within the description's limits; a route longer than one plan
becomes legs (:meth:`HeuristicLowLevelPlanner.plan_mission`), each ending at its
predicted pose. Rules and speeds: docs/planner.md "The heuristic planner". Units:
metres, degrees (``_deg``) or radians (``_rad``), distance and speed units of the protocol.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from firmware_proto.model.geometry import Point, wrap_deg, wrap_rad
from firmware_proto.model.plan import MAX_PLAN_STEPS, Goal, Plan, PlanStep
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import BOUNDS_ID, WorldMap
from planner.errors import (
    GoalInObstacleError,
    InvalidPoseError,
    OutOfBoundsError,
    PlanTooLongError,
)

__all__ = [
    "CORRECTION",
    "DRIVE",
    "GOAL_TURN",
    "NOOP",
    "TURN",
    "HeuristicLowLevelPlanner",
    "Itinerary",
    "LegPlan",
    "PlannedStep",
    "check_pose",
]

logger = logging.getLogger(__name__)

TURN = "turn"
"""Step kind: turn on the spot to the bearing of a segment."""
DRIVE = "drive"
"""Step kind: drive (part of) a segment."""
GOAL_TURN = "goal_turn"
"""Step kind: turn to the goal yaw at the end of the route."""
CORRECTION = "correction"
"""Step kind: added or changed by a repair (goal or yaw repair)."""
NOOP = "noop"
"""Step kind: ``FWD`` at speed 0 over 0 units, the whole plan when the rover is already
at the goal (a plan holds at least one step; a STOP step would latch the rover)."""

DEFAULT_DRIVE_SPEED = 60
DEFAULT_APPROACH_SPEED = 30
DEFAULT_TURN_SPEED = 20
DEFAULT_FINE_TURN_SPEED = 10
DEFAULT_FINE_TURN_DEG = 15.0
DEFAULT_MIN_TURN_DEG = 0.25
DEFAULT_MIN_DRIVE_M = 0.005
DEFAULT_LATERAL_TOLERANCE_M = 0.005
_ROUND = 6  # digits of the plan goal's coordinates (micrometres, micro-degrees)


@dataclass(frozen=True)
class PlannedStep:
    """One step of a plan with the planner's bookkeeping.

    Attributes:
        step: the step as sent (command, speed, distance).
        kind: :data:`TURN`, :data:`DRIVE`, :data:`GOAL_TURN`, :data:`CORRECTION` or
            :data:`NOOP`.
        segment: the route segment it serves (segment ``i`` runs from route point ``i``
            to point ``i + 1``; a goal turn belongs to the last segment).
        yaw_change_deg: intended signed yaw change (counter-clockwise positive), 0 for
            a drive.
        travel_m: intended signed ground travel along the heading, 0 for a turn.
        end_pose: the pose the planner predicts after the step.
    """

    step: PlanStep
    kind: str
    segment: int
    yaw_change_deg: float
    travel_m: float
    end_pose: Pose

    @property
    def is_turn(self) -> bool:
        """Whether it is a LEFT or RIGHT step."""
        return self.step.command in ("LEFT", "RIGHT")

    @property
    def is_linear(self) -> bool:
        """Whether it is a FWD or REV step that moves."""
        return self.step.command in ("FWD", "REV") and self.step.distance > 0


@dataclass(frozen=True)
class Itinerary:
    """Where to go: the start pose, intermediate points (no yaw), the goal pose."""

    start: Pose
    waypoints: tuple[Point, ...]
    goal: Pose

    @property
    def points(self) -> tuple[Point, ...]:
        """Start, waypoints and goal positions: segment ``i`` runs from ``points[i]`` to
        ``points[i + 1]``."""
        return (self.start.xy, *self.waypoints, self.goal.xy)

    @property
    def segment_count(self) -> int:
        """Number of segments (waypoints + 1)."""
        return len(self.waypoints) + 1

    def segment(self, index: int) -> tuple[Point, Point]:
        """Ends of segment ``index``."""
        pts = self.points
        return pts[index], pts[index + 1]

    @property
    def length_m(self) -> float:
        """Length of the polyline, m."""
        pts = self.points
        return sum(math.dist(pts[i], pts[i + 1]) for i in range(len(pts) - 1))

    def with_waypoints(self, waypoints: Sequence[Point]) -> Itinerary:
        """The same start and goal through other waypoints."""
        return replace(self, waypoints=tuple(waypoints))

    def __str__(self) -> str:
        via = " -> ".join(f"({x:.2f}, {y:.2f})" for x, y in self.waypoints)
        return f"{self.start} -> {via + ' -> ' if via else ''}{self.goal}"


@dataclass(frozen=True)
class LegPlan:
    """One plan (at most 12 steps) along a route, with its bookkeeping.

    Attributes:
        route: the route it follows (from the leg's start).
        steps: the steps with their bookkeeping; ``plan.commands`` are their ``step``.
        plan: the schema-valid plan; its goal is ``route.goal`` when ``reaches_goal``,
            else the pose predicted after the last step.
        reaches_goal: whether the leg ends at the route's goal.
        remaining: the waypoints still ahead when it does not (the goal excluded).
    """

    route: Itinerary
    steps: tuple[PlannedStep, ...]
    plan: Plan
    reaches_goal: bool
    remaining: tuple[Point, ...] = field(default=())

    @property
    def start(self) -> Pose:
        """The pose the leg starts from."""
        return self.route.start

    @property
    def goal(self) -> Pose:
        """The plan's goal."""
        return self.plan.goal

    @property
    def predicted_end(self) -> Pose:
        """The pose the planner predicts after the last step."""
        return self.steps[-1].end_pose if self.steps else self.route.start

    def wire(self) -> list[tuple[int, int, int]]:
        """The ``[command, speed, distance]`` form of every step (``/wheel_instructions``)."""
        return self.plan.to_wire()


def check_pose(
    name: str,
    pose: Pose | Point,
    *,
    world: WorldMap | None = None,
    body_half_width_m: float = 0.0,
) -> None:
    """Refuse a pose the planner cannot aim for.

    Args:
        name: what it is, for the message (``"goal"``, ``"via[0]"``...).
        pose: a pose or a bare point.
        world: the map; without one only finiteness is checked.
        body_half_width_m: when > 0, the pose must be at least this far from every
            obstacle surface (the rover's body must fit there); 0 skips the check.

    Raises:
        InvalidPoseError: a coordinate is NaN or infinite.
        OutOfBoundsError: it lies outside the map's bounds.
        GoalInObstacleError: it lies in an obstacle, or closer to one than
            ``body_half_width_m``.
    """
    values = (pose.x, pose.y, pose.yaw_deg) if isinstance(pose, Pose) else tuple(pose)
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
        raise InvalidPoseError(name, f"coordinates must be finite numbers, got {values}")
    x, y = values[0], values[1]
    if world is None:
        return
    if not world.bounds.contains(x, y):
        raise OutOfBoundsError(
            name, f"({x:g}, {y:g}) lies outside map {world.name!r} ({world.bounds})"
        )
    if body_half_width_m > 0:
        clearance, oid = world.clearance((x, y))
        if clearance < body_half_width_m:
            where = "inside" if clearance <= 0 else "too close to"
            what = "the wall" if oid == BOUNDS_ID else f"obstacle {oid!r}"
            raise GoalInObstacleError(
                name,
                f"({x:g}, {y:g}) lies {where} {what} (clearance {clearance:.2f} m; the "
                f"rover needs {body_half_width_m:.2f} m)",
                oid,
                clearance,
            )


class HeuristicLowLevelPlanner:
    """Turn-drive-turn plans for a skid-steer rover.

    Args:
        rover: the rover description (units, speed scale, limits, turn model).
        world: the map, if known: goals and waypoints are then checked against its
            bounds and obstacles.
        drive_speed, approach_speed: speed units of drives, and of the last drive into
            the goal.
        turn_speed, fine_turn_speed: speed units of turns, and of turns smaller than
            ``fine_turn_deg``.
        min_turn_deg, min_drive_m: smaller turns and drives are skipped (a turn toward
            a target only if the drive still passes within ``lateral_tolerance_m``, m).
        max_step_units: the longest step, distance units (at most the description's
            ``max_distance``).
        max_steps: steps per plan (at most 12, the schema's limit).

    Raises:
        ValueError: a speed outside ``1..max_speed``, a limit out of range, a negative
            threshold.
    """

    def __init__(
        self,
        rover: RoverDescription,
        *,
        world: WorldMap | None = None,
        drive_speed: int = DEFAULT_DRIVE_SPEED,
        approach_speed: int = DEFAULT_APPROACH_SPEED,
        turn_speed: int = DEFAULT_TURN_SPEED,
        fine_turn_speed: int = DEFAULT_FINE_TURN_SPEED,
        fine_turn_deg: float = DEFAULT_FINE_TURN_DEG,
        min_turn_deg: float = DEFAULT_MIN_TURN_DEG,
        min_drive_m: float = DEFAULT_MIN_DRIVE_M,
        lateral_tolerance_m: float = DEFAULT_LATERAL_TOLERANCE_M,
        max_step_units: int | None = None,
        max_steps: int = MAX_PLAN_STEPS,
    ) -> None:
        top = rover.drive.max_speed
        for key, speed in (
            ("drive_speed", drive_speed),
            ("approach_speed", approach_speed),
            ("turn_speed", turn_speed),
            ("fine_turn_speed", fine_turn_speed),
        ):
            if not 1 <= speed <= min(top, 60):
                raise ValueError(f"{key} must be in 1..{min(top, 60)}, got {speed}")
        limit = min(rover.drive.max_distance, 30000)
        max_units = limit if max_step_units is None else max_step_units
        if not 1 <= max_units <= limit:
            raise ValueError(f"max_step_units must be in 1..{limit}, got {max_units}")
        if not 1 <= max_steps <= MAX_PLAN_STEPS:
            raise ValueError(f"max_steps must be in 1..{MAX_PLAN_STEPS}, got {max_steps}")
        if min(min_turn_deg, min_drive_m, fine_turn_deg, lateral_tolerance_m) < 0:
            raise ValueError(
                "min_turn_deg, min_drive_m, fine_turn_deg and lateral_tolerance_m must be >= 0"
            )
        self.rover = rover
        self.world = world
        self.drive_speed = drive_speed
        self.approach_speed = approach_speed
        self.turn_speed = turn_speed
        self.fine_turn_speed = fine_turn_speed
        self.fine_turn_deg = fine_turn_deg
        self.min_turn_deg = min_turn_deg
        self.min_drive_m = min_drive_m
        self.lateral_tolerance_m = lateral_tolerance_m
        self.max_step_units = max_units
        self.max_steps = max_steps

    # -- geometry of the rover ----------------------------------------------------------
    @property
    def body_half_width_m(self) -> float:
        """Half the chassis width, m: the least clearance a pose needs to hold the rover."""
        return self.rover.geometry.chassis_width_m / 2.0

    # -- routes -------------------------------------------------------------------------
    def route(
        self, start: Pose, goal: Pose, via: Sequence[Point] = (), *, world: WorldMap | None = None
    ) -> Itinerary:
        """A checked route (:func:`check_pose`, against ``world`` or the planner's map;
        the start need only be finite and in bounds, the goal must hold the rover).

        Raises:
            InvalidPoseError, OutOfBoundsError, GoalInObstacleError: a bad pose.
        """
        world = world if world is not None else self.world
        check_pose("start", start, world=world)
        for i, point in enumerate(via):
            check_pose(f"via[{i}]", point, world=world)
        check_pose("goal", goal, world=world, body_half_width_m=self.body_half_width_m)
        return Itinerary(
            Pose(float(start.x), float(start.y), float(start.yaw_deg)),
            tuple((float(x), float(y)) for x, y in via),
            Pose(float(goal.x), float(goal.y), float(goal.yaw_deg)),
        )

    # -- steps --------------------------------------------------------------------------
    def turn_steps(
        self, yaw_change_rad: float, pose: Pose, *, kind: str, segment: int, force: bool = False
    ) -> list[PlannedStep]:
        """Steps that turn the rover on the spot by ``yaw_change_rad`` (sign: positive
        is LEFT, counter-clockwise), split so that none exceeds ``max_step_units``;
        empty below ``min_turn_deg`` unless ``force`` (and below one unit always)."""
        if abs(math.degrees(yaw_change_rad)) < self.min_turn_deg and not force:
            return []
        command = "LEFT" if yaw_change_rad > 0 else "RIGHT"
        sign = 1.0 if yaw_change_rad > 0 else -1.0
        units = self.rover.turn_units_for_yaw(yaw_change_rad)
        if units == 0:
            return []
        speed = (
            self.fine_turn_speed
            if abs(math.degrees(yaw_change_rad)) < self.fine_turn_deg
            else self.turn_speed
        )
        out: list[PlannedStep] = []
        for part in _split(units, self.max_step_units):
            dyaw_deg = sign * math.degrees(self.rover.yaw_for_turn_units(part))
            pose = Pose(pose.x, pose.y, wrap_deg(pose.yaw_deg + dyaw_deg))
            out.append(
                PlannedStep(PlanStep(command, speed, part), kind, segment, dyaw_deg, 0.0, pose)
            )
        return out

    def drive_steps(
        self,
        distance_m: float,
        pose: Pose,
        *,
        segment: int,
        kind: str = DRIVE,
        last_speed: int | None = None,
    ) -> list[PlannedStep]:
        """FWD steps over ``distance_m`` along the current heading, split so that none
        exceeds ``max_step_units``; the last one at ``last_speed`` (default
        ``drive_speed``); empty below ``min_drive_m``."""
        if distance_m < self.min_drive_m:
            return []
        units = self.rover.m_to_units(distance_m)
        if units == 0:
            return []
        parts = _split(units, self.max_step_units)
        c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
        out: list[PlannedStep] = []
        for i, part in enumerate(parts):
            speed = (
                last_speed if (last_speed is not None and i == len(parts) - 1) else self.drive_speed
            )
            d = self.rover.units_to_m(part)
            pose = Pose(pose.x + d * c, pose.y + d * s, pose.yaw_deg)
            out.append(PlannedStep(PlanStep("FWD", speed, part), kind, segment, 0.0, d, pose))
        return out

    def steps_for(self, route: Itinerary) -> tuple[PlannedStep, ...]:
        """Every step of a route, however many (no leg splitting)."""
        pose = route.start
        steps: list[PlannedStep] = []
        pts = route.points
        last = len(pts) - 2
        for seg in range(len(pts) - 1):
            target = pts[seg + 1]
            dist = math.dist(pose.xy, target)
            if dist < self.min_drive_m:
                continue
            bearing = math.atan2(target[1] - pose.y, target[0] - pose.x)
            dyaw = wrap_rad(bearing - pose.yaw_rad)
            # Skip a small turn only if the drive still passes within lateral_tolerance_m.
            must = dist * abs(math.sin(dyaw)) > self.lateral_tolerance_m
            turn = self.turn_steps(dyaw, pose, kind=TURN, segment=seg, force=must)
            if turn:
                pose = turn[-1].end_pose
            steps += turn
            # Drive along the heading actually reached (the turn is quantised), as far
            # as the target's projection on it.
            ahead = (target[0] - pose.x) * math.cos(pose.yaw_rad) + (target[1] - pose.y) * math.sin(
                pose.yaw_rad
            )
            drive = self.drive_steps(
                ahead, pose, segment=seg, last_speed=self.approach_speed if seg == last else None
            )
            if drive:
                pose = drive[-1].end_pose
            steps += drive
        final = math.radians(route.goal.yaw_deg) - pose.yaw_rad
        steps += self.turn_steps(wrap_rad(final), pose, kind=GOAL_TURN, segment=last)
        return tuple(steps)

    def predict(self, start: Pose, steps: Sequence[PlanStep]) -> list[Pose]:
        """The pose after each step by the planner's ideal kinematics (the turn model, no slip)."""
        pose = start
        out: list[Pose] = []
        for st in steps:
            if st.command in ("LEFT", "RIGHT"):
                sign = 1.0 if st.command == "LEFT" else -1.0
                dyaw = sign * math.degrees(self.rover.yaw_for_turn_units(st.distance))
                pose = Pose(pose.x, pose.y, wrap_deg(pose.yaw_deg + dyaw))
            elif st.command in ("FWD", "REV") and st.speed > 0:
                d = self.rover.units_to_m(st.distance) * (1.0 if st.command == "FWD" else -1.0)
                pose = Pose(
                    pose.x + d * math.cos(pose.yaw_rad),
                    pose.y + d * math.sin(pose.yaw_rad),
                    pose.yaw_deg,
                )
            out.append(pose)
        return out

    # -- plans --------------------------------------------------------------------------
    def make_leg(
        self,
        route: Itinerary,
        steps: Sequence[PlannedStep],
        *,
        reaches_goal: bool,
        remaining: Sequence[Point] = (),
        goal: Pose | None = None,
    ) -> LegPlan:
        """Wrap steps into a :class:`LegPlan` whose goal is ``goal``, else the route's
        when ``reaches_goal``, else the predicted end pose.

        Raises:
            PlanTooLongError: more than ``max_steps`` steps.
            ValueError: a step longer than ``max_step_units`` or faster than 60.
        """
        steps = list(steps)
        if len(steps) > self.max_steps:
            raise PlanTooLongError(len(steps), self.max_steps)
        for i, ps in enumerate(steps):
            st = ps.step
            if not (0 <= st.distance <= self.max_step_units and 0 <= st.speed <= 60):
                raise ValueError(f"step {i} {st} is outside the planner's limits")
        if not steps:
            steps = [
                PlannedStep(
                    PlanStep("FWD", 0, 0), NOOP, route.segment_count - 1, 0.0, 0.0, route.start
                )
            ]
        if goal is not None:
            pass
        elif reaches_goal:
            goal = route.goal
        else:
            end = steps[-1].end_pose
            goal = Pose(round(end.x, _ROUND), round(end.y, _ROUND), round(end.yaw_deg, _ROUND))
        plan = Plan(Goal(goal.x, goal.y, goal.yaw_deg), tuple(s.step for s in steps))
        return LegPlan(route, tuple(steps), plan, reaches_goal, tuple(remaining))

    def leg_of(self, start: Pose, plan: Plan) -> LegPlan:
        """A plan made elsewhere (``rover go --plan FILE``) as a leg from ``start``: its
        steps unchanged with predicted poses, the route straight to the plan's goal."""
        route = Itinerary(start, (), Pose(plan.goal.x, plan.goal.y, plan.goal.yaw_deg))
        poses = self.predict(start, plan.commands)
        steps: list[PlannedStep] = []
        before = start
        for step, pose in zip(plan.commands, poses, strict=True):
            turn = step.command in ("LEFT", "RIGHT")
            kind = NOOP if step.speed == 0 or step.distance == 0 else (TURN if turn else DRIVE)
            dyaw = wrap_deg(pose.yaw_deg - before.yaw_deg) if turn else 0.0
            travel = (
                0.0
                if turn
                else math.dist(before.xy, pose.xy) * (-1.0 if step.command == "REV" else 1.0)
            )
            steps.append(PlannedStep(step, kind, 0, dyaw, travel, pose))
            before = pose
        return LegPlan(route, tuple(steps), plan, True)

    def plan_leg(self, route: Itinerary) -> LegPlan:
        """The first leg of a route: all of it when it fits in ``max_steps`` steps, else
        the longest prefix that ends with a drive (the leg then ends at the predicted
        pose there, and ``remaining`` holds the waypoints still ahead)."""
        steps = self.steps_for(route)
        if len(steps) <= self.max_steps:
            return self.make_leg(route, steps, reaches_goal=True)
        cut = max(
            (i + 1 for i in range(self.max_steps) if steps[i].kind == DRIVE), default=self.max_steps
        )
        head = steps[:cut]
        last = head[-1]
        seg = last.segment
        target = route.points[seg + 1]
        # Segment ``seg`` ends at waypoint ``seg`` (the goal is never a waypoint): once
        # reached, the route goes on from the next one; otherwise it is still ahead.
        reached = math.dist(last.end_pose.xy, target) < max(self.min_drive_m, 1e-6)
        remaining = route.waypoints[seg + 1 :] if reached else route.waypoints[seg:]
        logger.debug(
            "route needs %d steps: leg of %d, %d waypoints remain", len(steps), cut, len(remaining)
        )
        return self.make_leg(route, head, reaches_goal=False, remaining=remaining)

    def plan(self, start: Pose, goal: Pose, *, via: Sequence[Point] = ()) -> Plan:
        """One plan from ``start`` through ``via`` to ``goal``.

        Raises:
            InvalidPoseError, OutOfBoundsError, GoalInObstacleError: see :meth:`route`.
            PlanTooLongError: the route needs more than ``max_steps`` steps (use
                :meth:`plan_mission`).
        """
        route = self.route(start, goal, via)
        steps = self.steps_for(route)
        return self.make_leg(route, steps, reaches_goal=True).plan

    def plan_mission(
        self, start: Pose, goal: Pose, *, via: Sequence[Point] = (), max_legs: int = 64
    ) -> tuple[LegPlan, ...]:
        """Every leg of a route, each planned from where the previous one is predicted to
        end (the planner's own prediction; the orchestrator uses the gate's instead).

        Raises:
            InvalidPoseError, OutOfBoundsError, GoalInObstacleError: see :meth:`route`.
            PlanTooLongError: more than ``max_legs`` legs would be needed.
        """
        route = self.route(start, goal, via)
        legs: list[LegPlan] = []
        while True:
            leg = self.plan_leg(route)
            legs.append(leg)
            if leg.reaches_goal:
                return tuple(legs)
            if len(legs) >= max_legs:
                raise PlanTooLongError(len(legs) * self.max_steps, max_legs * self.max_steps)
            route = Itinerary(leg.predicted_end, leg.remaining, route.goal)


def _split(units: int, max_units: int) -> list[int]:
    """``units`` as the fewest, most equal parts of at most ``max_units``, larger first."""
    n = -(-units // max_units)
    base, extra = divmod(units, n)
    return [base + 1] * extra + [base] * (n - extra)
