"""Repairs of a rejected plan, one per failure type of the gate (thesis section 5.5).

A repair reads the rejection in a :class:`PlannerContext` and returns a :class:`Repair`
(a new leg to validate, what was done and why), or raises
:class:`~planner.errors.RepairError` when it has nothing to offer; the orchestrator then
gives up with that reason. :data:`REPAIRS` maps failure types to repairs; the
orchestrator takes another mapping to add or replace some.

- ``collision`` -> :func:`dogleg_repair`: the thesis's lateral dogleg, blind or screened
  against the map by a best-first search (:func:`_search`); approach waypoints for a
  goal with no room to turn.
- ``goal_not_reached`` -> :func:`goal_repair`: a FWD added or the last drive shortened
  by the longitudinal error; missed turns rescaled first.
- ``yaw_not_reached`` -> :func:`yaw_repair`: rescale the final turn or append one.
- ``stalled`` -> :func:`stall_repair`: a turn retried slower; a drive bypassed.
- ``start_in_collision`` -> :func:`start_repair`: not repairable.

Each repair, its formulas and its parameters: docs/planner.md "The repairs".
Units: metres, degrees (``_deg``), distance units of the protocol.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

from firmware_proto.model.geometry import Point, wrap_deg
from firmware_proto.model.plan import PlanStep
from firmware_proto.model.pose import Pose
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import BOUNDS_ID, Obstacle, WorldMap
from planner.errors import RepairError
from planner.plan.planner import (
    CORRECTION,
    GOAL_TURN,
    TURN,
    HeuristicLowLevelPlanner,
    Itinerary,
    LegPlan,
    PlannedStep,
)

__all__ = [
    "REPAIRS",
    "Detour",
    "FailureRecord",
    "PlannerContext",
    "Repair",
    "RepairFunction",
    "RepairSettings",
    "dogleg_repair",
    "goal_repair",
    "stall_repair",
    "start_repair",
    "yaw_repair",
]

logger = logging.getLogger(__name__)


def _grid(first: float, last: float, step: float) -> tuple[float, ...]:
    n = round((last - first) / step)
    return tuple(round(first + i * step, 6) for i in range(n + 1))


@dataclass(frozen=True)
class RepairSettings:
    """Parameters of the repairs; each and its default: docs/planner.md "Parameters".

    Distances in m (``_m``), angles in degrees (``_deg``); ``dogleg_growth`` multiplies
    the blind offset per repeat, ``slack_per_m`` adds m of clearance per metre of drive.
    """

    map_aware: bool = True
    dogleg_offset_m: float = 1.0
    dogleg_growth: float = 1.5
    offsets_m: tuple[float, ...] = _grid(0.2, 4.0, 0.1)
    turn_cost_m: float = 0.5
    search_expansions: int = 120
    search_width: int = 4
    max_waypoints: int = 10
    min_spacing_m: float = 0.2
    blocked_cost_m: float = 1.0
    centring_weight: float = 2.0
    edge_offset_step_m: float = 0.05
    edge_offset_reach_m: float = 1.0
    comfort_m: float = 0.15
    clearance_slack_m: float = 0.03
    slack_per_m: float = 0.01
    turn_slack_m: float = 0.0
    slack_growth_m: float = 0.05
    approach_offsets_m: tuple[float, ...] = _grid(0.6, 3.0, 0.1)
    approach_offset_m: float = 1.0
    approach_angle_deg: float = 20.0
    near_goal_m: float = 1.0
    min_correction_m: float = 0.005
    turn_calibration_deg: float = 0.05
    drive_calibration_m: float = 0.005


@dataclass(frozen=True)
class FailureRecord:
    """One rejection, as kept in ``previous_failures``: the verdict's fields, the
    0-based ``attempt``, and the route ``segment`` of the failed step (``None`` when
    unknown); ``obstacle_id`` and ``contact`` for a collision."""

    attempt: int
    failure_type: str
    failed_step: int | None
    reason: str
    segment: int | None
    obstacle_id: str | None
    contact: Point | None
    final_pose: Pose
    position_error_m: float
    lateral_error_m: float
    yaw_error_deg: float

    @classmethod
    def from_verdict(cls, attempt: int, leg: LegPlan, verdict: Verdict) -> FailureRecord:
        """Record a rejected verdict of ``leg``."""
        step = verdict.failed_step
        segment = leg.steps[step].segment if step is not None and step < len(leg.steps) else None
        c = verdict.collision
        return cls(
            attempt=attempt,
            failure_type=verdict.failure_type or "unknown",
            failed_step=step,
            reason=verdict.failure_reason,
            segment=segment,
            obstacle_id=c.obstacle_id if c else None,
            contact=c.contact if c else None,
            final_pose=verdict.final_pose,
            position_error_m=verdict.position_error_m,
            lateral_error_m=verdict.lateral_error_m,
            yaw_error_deg=verdict.yaw_error_deg,
        )


@dataclass(frozen=True)
class Detour:
    """Waypoints a collision repair put into the route, and why.

    Attributes:
        method: ``"dogleg"`` (one waypoint), ``"box"`` (two, parallel to the segment),
            ``"approach"`` (before the goal, on its yaw axis) or ``"shift"`` (a waypoint
            moved away from what its turn touched).
        obstacle_id: the obstacle that triggered it.
        segment: the route segment it replaced, ``(from, to)``.
        points: the waypoints it inserted, in route order.
        side: +1 right of the segment's heading, -1 left, 0 not lateral.
        offset_m: the lateral offset ``delta`` (or the approach distance), m.
        tries: 0 the first time; one more at each repeat around the same obstacle.
        screened: whether the map screened it clear of every obstacle.
    """

    method: str
    obstacle_id: str
    segment: tuple[Point, Point]
    points: tuple[Point, ...]
    side: int
    offset_m: float
    tries: int
    screened: bool = False


@dataclass(frozen=True)
class Repair:
    """What a repair produced: the new leg, a name and a sentence for the log and the
    report, and the detour when it changed the route."""

    name: str
    description: str
    leg: LegPlan
    detour: Detour | None = None


@dataclass(frozen=True)
class PlannerContext:
    """Everything a repair may read (the thesis's ``PlannerContext``).

    Attributes:
        leg, verdict: the rejected leg and its verdict.
        attempt: 0-based index of the rejected attempt.
        previous_failures: every rejection of this leg so far, this one last.
        history: the repairs that produced the leg's earlier attempts, in order.
        world: the map, when known.
        earlier: the leg's earlier attempts as ``(leg, verdict)``, oldest first (this
            one excluded).
    """

    planner: HeuristicLowLevelPlanner
    leg: LegPlan
    verdict: Verdict
    attempt: int
    previous_failures: tuple[FailureRecord, ...]
    history: tuple[Repair, ...]
    world: WorldMap | None
    settings: RepairSettings
    earlier: tuple[tuple[LegPlan, Verdict], ...] = ()

    @property
    def margin_m(self) -> float:
        """The gate's collision margin, as the verdict reports it, m."""
        return self.verdict.tolerances.safety_margin_m

    def drive_radius_m(self, tries: int, length_m: float = 0.0) -> float:
        """Clearance the centre line of a drive of ``length_m`` needs after ``tries``
        repeats: half the chassis width, the gate's margin and the slack, m."""
        s = self.settings
        slack = s.clearance_slack_m + s.slack_per_m * length_m + tries * s.slack_growth_m
        return self.planner.body_half_width_m + self.margin_m + slack

    def turn_radius_m(self, tries: int) -> float:
        """Clearance a point needs for turning on the spot after ``tries`` repeats: the
        footprint's circumradius, the gate's margin and the slack, m."""
        s = self.settings
        slack = s.turn_slack_m + tries * s.slack_growth_m
        return self.planner.rover.footprint_radius_m + self.margin_m + slack

    @property
    def use_map(self) -> bool:
        """Whether repairs screen candidates against the map."""
        return self.settings.map_aware and self.world is not None


RepairFunction = Callable[[PlannerContext], Repair]
"""A repair: a rejection in, a new leg out (or :class:`RepairError`)."""


# -- helpers ---------------------------------------------------------------------------
def _rebuild(ctx: PlannerContext, steps: Sequence[PlannedStep]) -> LegPlan:
    """A leg with these steps, their end poses predicted again, the old leg's goal."""
    leg = ctx.leg
    poses = ctx.planner.predict(leg.start, [s.step for s in steps])
    fresh = [replace(s, end_pose=p) for s, p in zip(steps, poses, strict=True)]
    return ctx.planner.make_leg(
        leg.route, fresh, reaches_goal=leg.reaches_goal, remaining=leg.remaining, goal=leg.goal
    )


def _with_waypoints(ctx: PlannerContext, waypoints: Sequence[Point]) -> LegPlan:
    return ctx.planner.plan_leg(ctx.leg.route.with_waypoints(waypoints))


def _turn_step(
    ctx: PlannerContext, yaw_deg: float, segment: int, kind: str = CORRECTION
) -> PlannedStep | None:
    p = ctx.planner
    pose = Pose(0.0, 0.0, 0.0)  # end poses are predicted again by _rebuild
    steps = p.turn_steps(math.radians(yaw_deg), pose, kind=kind, segment=segment)
    if len(steps) != 1:
        return None
    return steps[0]


def _scaled_turn(ctx: PlannerContext, ps: PlannedStep, factor: float) -> PlannedStep | None:
    """``ps`` with its distance scaled by ``factor`` (> 0), or ``None`` when that leaves
    the step's limits."""
    units = round(ps.step.distance * factor)
    if not 1 <= units <= ctx.planner.max_step_units:
        return None
    return replace(
        ps,
        step=replace(ps.step, distance=units),
        yaw_change_deg=ps.yaw_change_deg * units / ps.step.distance,
    )


def _side_of(a: Point, b: Point, p: Point) -> float:
    """Signed distance of ``p`` from the line ``a``->``b``: positive on the left, m."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    length = math.hypot(dx, dy)
    if length == 0:
        return 0.0
    return (dx * (p[1] - a[1]) - dy * (p[0] - a[0])) / length


def _away_side(a: Point, b: Point, contact: Point | None) -> int:
    """``side`` (+1 right, -1 left) that moves the path away from ``contact``; +1 when
    the contact is unknown or on the line (the thesis's default)."""
    if contact is None:
        return 1
    s = _side_of(a, b, contact)
    return -1 if s < -0.02 else 1


def _dogleg_point(a: Point, b: Point, anchor_m: float, side: int, delta_m: float) -> Point:
    """The thesis's waypoint: ``anchor_m`` along ``a``->``b``, then ``side * delta_m``
    to the right of its bearing."""
    bearing = math.atan2(b[1] - a[1], b[0] - a[0])
    x = a[0] + anchor_m * math.cos(bearing) + side * delta_m * math.sin(bearing)
    y = a[1] + anchor_m * math.sin(bearing) - side * delta_m * math.cos(bearing)
    return (round(x, 6), round(y, 6))


def _find_run(waypoints: Sequence[Point], points: Sequence[Point]) -> tuple[int, int] | None:
    """Index range ``[i, j)`` of ``waypoints`` spanning ``points`` (first to last)."""
    idx = [i for i, w in enumerate(waypoints) if w in points]
    if not idx or waypoints[idx[0]] != points[0] or waypoints[idx[-1]] != points[-1]:
        return None
    return idx[0], idx[-1] + 1


def _prior_detour(
    ctx: PlannerContext, obstacle_id: str, step: PlannedStep
) -> tuple[Detour, int, int] | None:
    """The latest detour, still in the route, that this collision repeats: one around
    the same obstacle, or a screened one whose waypoints (or the segments joining them)
    the failed step belongs to. ``(detour, i, j)``: its waypoints are ``waypoints[i:j]``."""
    waypoints = ctx.leg.route.waypoints
    for repair in reversed(ctx.history):
        d = repair.detour
        if d is None or not d.points:
            continue
        run = _find_run(waypoints, d.points)
        if run is None:
            continue
        i, j = run
        # Waypoint ``w`` is route point ``w + 1``: the detour's segments are ``i..j``,
        # its turns at the start of segments ``i + 1..j``.
        inside = i <= step.segment <= j if step.kind != TURN else i < step.segment <= j
        # A screened detour that still collides needs more room; one the map already
        # showed blocked elsewhere gets a nested dogleg instead. An approach is only
        # repeated for what happens on it: turning at the goal, or driving in.
        if d.method == "approach" and not (step.kind == GOAL_TURN or step.segment == j):
            continue
        if d.obstacle_id == obstacle_id or (inside and d.screened):
            return d, i, j
    return None


def _step_span(route: Itinerary, step: PlannedStep) -> tuple[Point, Point]:
    """Where a step happens: its segment for a drive, ``(a, a)`` for a turn at ``a``."""
    a, b = route.segment(step.segment)
    return (a, a) if step.kind == TURN else (a, b)


def _first_tries(ctx: PlannerContext, a: Point, b: Point) -> int:
    """Repeats to start a fresh detour with: as many as it takes for the map to show
    the collided segment blocked (when the gate finds a collision the map does not, the
    rover strays further than the slack allows), at most 3."""
    if not ctx.use_map:
        return 0
    world = ctx.world
    assert world is not None

    def clear(tries: int) -> bool:
        if a == b:
            return world.point_blocked(a, ctx.turn_radius_m(tries)) is None
        return _segment_blocker(ctx, a, b, tries) is None

    tries = 0
    while tries < 3 and clear(tries):
        tries += 1
    return tries


# -- map-aware search ------------------------------------------------------------------
@dataclass(frozen=True)
class _Candidate:
    method: str
    points: tuple[Point, ...]
    side: int
    offset_m: float
    cost: float


def _segment_blocker(ctx: PlannerContext, a: Point, b: Point, tries: int) -> str | None:
    """What the map puts in the way of a drive from ``a`` to ``b``, or ``None``."""
    world = ctx.world
    assert world is not None
    radius_m = ctx.drive_radius_m(tries, math.dist(a, b))
    blocker = world.segment_blocked(a, b, radius_m)
    if blocker is None:
        return None
    # A rover already closer to something than that (a tight start) may still drive
    # away from it: ask no more than the ends already have.
    cap = radius_m + 0.02
    need = min(radius_m, world.clearance(a, cap)[0] - 0.01, world.clearance(b, cap)[0] - 0.01)
    return blocker if need >= radius_m else world.segment_blocked(a, b, max(need, 0.0))


def _dogleg_candidates(
    ctx: PlannerContext,
    a: Point,
    b: Point,
    *,
    obstacle: Obstacle | None,
    contact: Point | None,
    turn_r: float,
) -> list[_Candidate]:
    """Every dogleg of ``a``->``b`` around ``obstacle`` the search considers, cheapest first."""
    length = math.dist(a, b)
    if length < 1e-6:
        return []
    u = ((b[0] - a[0]) / length, (b[1] - a[1]) / length)
    if contact is not None:
        s_contact = (contact[0] - a[0]) * u[0] + (contact[1] - a[1]) * u[1]
    else:
        s_contact = length / 2
    if obstacle is not None:
        s_min, s_max = obstacle.extent_along(a, u)
        if contact is None:
            s_contact = (s_min + s_max) / 2
    else:
        s_min, s_max = s_contact - 0.3, s_contact + 0.3

    def clamp(s: float) -> float:
        return min(max(s, 0.0), length)

    anchors: list[float] = []
    for s in (clamp((s_min + s_max) / 2), clamp(s_contact), length / 2):
        if all(abs(s - t) > 0.05 for t in anchors):
            anchors.append(s)
    s1, s2 = clamp(s_min - turn_r), clamp(s_max + turn_r)
    out: list[_Candidate] = []
    for side in (1, -1):
        for delta in ctx.settings.offsets_m:
            for s in anchors:
                w = _dogleg_point(a, b, s, side, delta)
                cost = math.dist(a, w) + math.dist(w, b) - length + ctx.settings.turn_cost_m
                out.append(_Candidate("dogleg", (w,), side, delta, cost))
            if s2 - s1 > 0.05:
                w1 = _dogleg_point(a, b, s1, side, delta)
                w2 = _dogleg_point(a, b, s2, side, delta)
                cost = (
                    math.dist(a, w1)
                    + math.dist(w1, w2)
                    + math.dist(w2, b)
                    - length
                    + 2 * ctx.settings.turn_cost_m
                )
                out.append(_Candidate("box", (w1, w2), side, delta, cost))
    if obstacle is not None:
        out += _edge_boxes(ctx, a, b, obstacle, turn_r)
    out.sort(key=lambda c: c.cost)  # stable: generation order breaks ties
    return out


def _edge_boxes(
    ctx: PlannerContext, a: Point, b: Point, obstacle: Obstacle, turn_r: float
) -> list[_Candidate]:
    """Two-waypoint detours parallel to the obstacle's own edges (a wall, a barrier)
    rather than to the segment: how a rover lines up with a gap beside it."""
    length = math.dist(a, b)
    ux, uy = (b[0] - a[0]) / length, (b[1] - a[1]) / length
    pts = obstacle.points
    if obstacle.kind == "polygon":
        edges = [(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
    elif obstacle.kind == "segment":
        edges = [(pts[0], pts[1])]
    else:
        return []
    directions: list[Point] = []
    for p, q in edges:
        e = math.dist(p, q)
        if e < 1e-6:
            continue
        d = ((q[0] - p[0]) / e, (q[1] - p[1]) / e)
        along = d[0] * ux + d[1] * uy
        if abs(along) < 0.5:  # more than 60 degrees off the way to go
            continue
        if abs(along) > 0.985:  # within 10 degrees of the segment: the plain boxes cover it
            continue
        if along < 0:
            d = (-d[0], -d[1])
        if all(abs(d[0] * o[0] + d[1] * o[1]) < 0.9999 for o in directions):
            directions.append(d)
    step = ctx.settings.edge_offset_step_m
    out: list[_Candidate] = []
    for d in directions:
        n = (d[1], -d[0])
        s_min, s_max = obstacle.extent_along(a, d)
        l_min, l_max = obstacle.extent_along(a, n)
        lo = l_min - ctx.settings.edge_offset_reach_m
        count = round((l_max - l_min + 2 * ctx.settings.edge_offset_reach_m) / step)
        for i in range(count + 1):
            c = lo + i * step
            w1 = (
                round(a[0] + (s_min - turn_r) * d[0] + c * n[0], 6),
                round(a[1] + (s_min - turn_r) * d[1] + c * n[1], 6),
            )
            w2 = (
                round(a[0] + (s_max + turn_r) * d[0] + c * n[0], 6),
                round(a[1] + (s_max + turn_r) * d[1] + c * n[1], 6),
            )
            cost = (
                math.dist(a, w1)
                + math.dist(w1, w2)
                + math.dist(w2, b)
                - length
                + 2 * ctx.settings.turn_cost_m
            )
            side = -1 if _side_of(a, b, w1) > 0 else 1
            out.append(_Candidate("box", (w1, w2), side, abs(_side_of(a, b, w1)), cost))
    return out


def _route_length(pts: Sequence[Point]) -> float:
    return sum(math.dist(pts[i], pts[i + 1]) for i in range(len(pts) - 1))


def _room(ctx: PlannerContext, seg_pts: Sequence[Point], tries: int) -> float:
    """Least clearance to spare at the inner points and along the segments of
    ``seg_pts``, beyond what turning and driving need, m."""
    world = ctx.world
    assert world is not None
    turn_r = ctx.turn_radius_m(tries)
    enough = ctx.settings.comfort_m
    spare = min(
        (world.clearance(w, turn_r + enough)[0] - turn_r for w in seg_pts[1:-1]), default=enough
    )
    for i in range(len(seg_pts) - 1):
        need = ctx.drive_radius_m(tries, math.dist(seg_pts[i], seg_pts[i + 1]))
        got = world.segment_clearance(seg_pts[i], seg_pts[i + 1], need + enough)[0]
        spare = min(spare, got - need)
    return spare


@dataclass(frozen=True, order=True)
class _Node:
    priority: float
    order: int
    points: tuple[Point, ...] = field(compare=False)
    blockers: tuple[str | None, ...] = field(compare=False)
    tightness: float = field(compare=False)
    first: _Candidate | None = field(compare=False)


def _search(
    ctx: PlannerContext,
    a: Point,
    b: Point,
    *,
    obstacle_id: str,
    contact: Point | None,
    tries: int,
    avoid: Sequence[tuple[Point, ...]] = (),
) -> tuple[_Candidate, bool] | None:
    """Doglegs on the map, best first, applied to the first blocked segment at most
    ``search_expansions`` times: ``(candidate, True)`` for the cheapest route from ``a``
    to ``b`` the map shows clear, else ``(best partial route, False)``; ``None`` when no
    dogleg even clears ``obstacle_id``.

    Priority: length, plus ``turn_cost_m`` per waypoint, ``blocked_cost_m`` per blocked
    segment and ``centring_weight`` times the spare room each dogleg lacks."""
    world = ctx.world
    assert world is not None
    s = ctx.settings
    turn_r = ctx.turn_radius_m(tries)
    counter = itertools.count()

    def node(
        pts: tuple[Point, ...],
        blockers: tuple[str | None, ...],
        tightness: float,
        first: _Candidate | None,
    ) -> _Node:
        priority = (
            _route_length(pts)
            + s.turn_cost_m * (len(pts) - 2)
            + s.blocked_cost_m * sum(x is not None for x in blockers)
            + s.centring_weight * tightness
        )
        return _Node(priority, next(counter), pts, blockers, tightness, first)

    heap = [node((a, b), (obstacle_id,), 0.0, None)]
    seen: set[tuple[Point, ...]] = set()
    best: _Node | None = None
    expansions = 0
    while heap and expansions < s.search_expansions:
        current = heapq.heappop(heap)
        if all(x is None for x in current.blockers):
            best = current
            break
        if current.first is not None and (
            best is None
            or (sum(x is not None for x in current.blockers), current.priority)
            < (sum(x is not None for x in best.blockers), best.priority)
        ):
            best = current
        expansions += 1
        i = next(k for k, x in enumerate(current.blockers) if x is not None)
        blocker = current.blockers[i]
        assert blocker is not None
        sa, sb = current.points[i], current.points[i + 1]
        root = current.first is None
        cands = _dogleg_candidates(
            ctx,
            sa,
            sb,
            obstacle=world.obstacle(blocker),
            contact=contact if root else None,
            turn_r=turn_r,
        )
        children = 0
        room_left = s.max_waypoints - (len(current.points) - 2)
        for cand in cands:
            if root and cand.points in avoid:
                continue
            if len(cand.points) > room_left:
                continue
            # No doubling back: new waypoints keep their distance from the route's points.
            if any(math.dist(w, q) < s.min_spacing_m for w in cand.points for q in current.points):
                continue
            if any(world.point_blocked(w, turn_r) is not None for w in cand.points):
                continue
            seg_pts = (sa, *cand.points, sb)
            new = tuple(
                _segment_blocker(ctx, seg_pts[k], seg_pts[k + 1], tries)
                for k in range(len(seg_pts) - 1)
            )
            if blocker in new:
                continue
            pts = current.points[: i + 1] + cand.points + current.points[i + 1 :]
            if pts in seen:
                continue
            seen.add(pts)
            tight = current.tightness + s.comfort_m - min(_room(ctx, seg_pts, tries), s.comfort_m)
            blockers = current.blockers[:i] + new + current.blockers[i + 1 :]
            heapq.heappush(heap, node(pts, blockers, tight, current.first or cand))
            children += 1
            if children >= s.search_width:
                break
    if best is None or best.first is None:
        return None
    clear = all(x is None for x in best.blockers)
    inner = best.points[1:-1]
    method = best.first.method if inner == best.first.points else best.first.method + "+"
    return replace(best.first, points=inner, method=method, cost=best.priority), clear


# -- collision -------------------------------------------------------------------------
def _detour(
    ctx: PlannerContext,
    a: Point,
    b: Point,
    *,
    insert_at: int,
    drop: int,
    obstacle_id: str,
    contact: Point | None,
    tries: int,
    first_side: int,
    avoid: Sequence[tuple[Point, ...]] = (),
) -> Repair:
    """Replace ``drop`` waypoints at ``insert_at`` by a dogleg around ``obstacle_id`` on
    segment ``a``->``b``."""
    s = ctx.settings
    route = ctx.leg.route
    chosen: _Candidate | None = None
    screened = False
    if ctx.use_map:
        assert ctx.world is not None
        # Into a goal with no room to turn: aim for an approach point instead, then
        # arrive along the goal's yaw.
        end = b
        approach: tuple[Point, ...] = ()
        goal = route.goal
        if (
            b == goal.xy
            and insert_at + drop == len(route.waypoints)
            and ctx.world.point_blocked(b, ctx.turn_radius_m(tries)) is not None
        ):
            found_point = _approach_point(ctx, a, tries, ())
            if found_point is not None:
                end = found_point[0]
                approach = (end,)
        found = _search(
            ctx, a, end, obstacle_id=obstacle_id, contact=contact, tries=tries, avoid=avoid
        )
        if found is not None:
            chosen, screened = found
            chosen = replace(chosen, points=chosen.points + approach)
    if chosen is None:
        # The thesis: midpoint of the segment, side alternating, delta growing.
        side = first_side if tries % 2 == 0 else -first_side
        delta = s.dogleg_offset_m * s.dogleg_growth**tries
        w = _dogleg_point(a, b, math.dist(a, b) / 2, side, delta)
        chosen = _Candidate("dogleg", (w,), side, delta, 0.0)
    waypoints = route.waypoints[:insert_at] + chosen.points + route.waypoints[insert_at + drop :]
    detour = Detour(
        chosen.method,
        obstacle_id,
        (a, b),
        chosen.points,
        chosen.side,
        chosen.offset_m,
        tries,
        screened,
    )
    where = ", ".join(f"({x:.2f}, {y:.2f})" for x, y in chosen.points)
    side_word = "right" if chosen.side > 0 else "left"
    description = (
        f"{chosen.method} around {obstacle_id!r}: {chosen.offset_m:.2f} m to the {side_word} "
        f"of the segment ({a[0]:.2f}, {a[1]:.2f}) -> ({b[0]:.2f}, {b[1]:.2f}), via {where}"
        + (" (screened clear on the map)" if screened else "")
        + (f", repeat {tries}" if tries else "")
    )
    return Repair("dogleg", description, _with_waypoints(ctx, waypoints), detour)


def _approach_point(
    ctx: PlannerContext, before: Point, tries: int, avoid: Sequence[tuple[Point, ...]]
) -> tuple[Point, bool] | None:
    """The nearest point on the goal's yaw axis, behind the goal, where the rover can
    turn and from which it can drive straight in, preferring one that ``before`` can
    reach straight; ``(point, reachable)``, or ``None`` when the map offers none."""
    world = ctx.world
    assert world is not None
    goal = ctx.leg.route.goal
    c, s = math.cos(goal.yaw_rad), math.sin(goal.yaw_rad)
    turn_r = ctx.turn_radius_m(tries)
    fallback: Point | None = None
    for d in ctx.settings.approach_offsets_m:
        w = (round(goal.x - d * c, 6), round(goal.y - d * s, 6))
        if (w,) in avoid or world.point_blocked(w, turn_r) is not None:
            continue
        if _segment_blocker(ctx, w, goal.xy, tries) is not None:
            continue
        if _segment_blocker(ctx, before, w, tries) is None:
            return w, True
        if fallback is None:
            fallback = w
    return (fallback, False) if fallback is not None else None


def _approach(
    ctx: PlannerContext, obstacle_id: str, tries: int, avoid: Sequence[tuple[Point, ...]] = ()
) -> Repair:
    """Add a waypoint before the goal on its yaw axis, so the rover arrives aligned."""
    route = ctx.leg.route
    goal = route.goal
    before = route.points[-2]
    w: Point | None = None
    screened = False
    if ctx.use_map:
        found = _approach_point(ctx, before, tries, avoid)
        if found is not None:
            w, screened = found
    if w is None:
        d = ctx.settings.approach_offset_m * ctx.settings.dogleg_growth**tries
        w = (
            round(goal.x - d * math.cos(goal.yaw_rad), 6),
            round(goal.y - d * math.sin(goal.yaw_rad), 6),
        )
    distance = math.dist(w, goal.xy)
    waypoints = (*route.waypoints, w)
    detour = Detour("approach", obstacle_id, (before, goal.xy), (w,), 0, distance, tries, screened)
    description = (
        f"approach: arrive along the goal yaw {goal.yaw_deg:.1f} deg from ({w[0]:.2f}, "
        f"{w[1]:.2f}), {distance:.2f} m before the goal (turning there touched {obstacle_id!r})"
    )
    return Repair("approach", description, _with_waypoints(ctx, waypoints), detour)


def _redo(
    ctx: PlannerContext, prior: Detour, start: int, end: int, contact: Point | None
) -> Repair:
    """Repeat a detour that still collides with its obstacle: blind, the other side and
    a larger offset; on the map, more slack and not the same points."""
    tries = prior.tries + 1
    avoid = (prior.points,)
    if prior.method == "approach":
        route = ctx.leg.route
        trimmed = route.waypoints[:start] + route.waypoints[end:]
        inner = replace(ctx, leg=replace(ctx.leg, route=route.with_waypoints(trimmed)))
        return _approach(inner, prior.obstacle_id, tries, avoid)
    a, b = prior.segment
    first_side = prior.side if prior.tries % 2 == 0 else -prior.side
    return _detour(
        ctx,
        a,
        b,
        insert_at=start,
        drop=end - start,
        obstacle_id=prior.obstacle_id,
        contact=contact,
        tries=tries,
        first_side=first_side or 1,
        avoid=avoid,
    )


def _shift(ctx: PlannerContext, index: int, contact: Point, obstacle_id: str) -> Repair:
    """Move waypoint ``index`` away from what its turn touched, far enough to turn."""
    route = ctx.leg.route
    w = route.waypoints[index]
    dx, dy = w[0] - contact[0], w[1] - contact[1]
    dist = math.hypot(dx, dy)
    if dist < 1e-6:
        raise RepairError(f"waypoint ({w[0]:.2f}, {w[1]:.2f}) lies on {obstacle_id!r}")
    move = max(0.1, ctx.turn_radius_m(0) - dist + 0.05)
    new = (round(w[0] + dx / dist * move, 6), round(w[1] + dy / dist * move, 6))
    waypoints = (*route.waypoints[:index], new, *route.waypoints[index + 1 :])
    detour = Detour("shift", obstacle_id, (w, w), (new,), 0, move, 0)
    description = (
        f"shift waypoint ({w[0]:.2f}, {w[1]:.2f}) by {move:.2f} m away from "
        f"{obstacle_id!r} to ({new[0]:.2f}, {new[1]:.2f}): turning there touched it"
    )
    return Repair("shift", description, _with_waypoints(ctx, waypoints), detour)


def dogleg_repair(ctx: PlannerContext) -> Repair:
    """Repair a collision (docs/planner.md "Collision: the dogleg").

    Raises:
        RepairError: the verdict names no step of this leg, or the rover touches
            something turning on the spot at the leg's start (no waypoint to move).
    """
    v = ctx.verdict
    c = v.collision
    k = c.step if c is not None else v.failed_step
    leg = ctx.leg
    if k is None or not 0 <= k < len(leg.steps):
        raise RepairError(f"the collision names step {k}, which this plan does not have")
    ps = leg.steps[k]
    route = leg.route
    contact = c.contact if c is not None else None
    obstacle_id = c.obstacle_id if c is not None else BOUNDS_ID

    if ctx.use_map and ps.kind != GOAL_TURN and _first_tries(ctx, *_step_span(route, ps)) > 0:
        # The map shows the way clear: the rover strayed from it. Make the turns and
        # drives before the collision do what they meant to, and try the same route.
        steps = list(leg.steps)
        changes = _recalibrate(ctx, steps, before=k, drives=True)
        already = any(r.name == "recalibrate" for r in ctx.history[-1:])
        if changes and not already:
            return Repair(
                "recalibrate",
                f"the map shows the way clear of {obstacle_id!r}, the twin strayed: "
                + "; ".join(changes),
                _rebuild(ctx, steps),
            )

    prior = _prior_detour(ctx, obstacle_id, ps)
    if prior is not None:
        detour, start, end = prior
        return _redo(ctx, detour, start, end, contact)

    last_segment = route.segment_count - 1
    goal = route.goal
    final_turn = abs(
        wrap_deg(
            goal.yaw_deg
            - math.degrees(math.atan2(goal.y - route.points[-2][1], goal.x - route.points[-2][0]))
        )
    )
    near_goal = contact is not None and math.dist(contact, goal.xy) < ctx.settings.near_goal_m + (
        ctx.planner.rover.footprint_radius_m
    )
    if ctx.use_map:
        # On the map, an approach is for a goal with no room to turn, nothing else.
        assert ctx.world is not None
        near_goal = near_goal and ctx.world.point_blocked(goal.xy, ctx.turn_radius_m(0)) is not None
    if ps.kind == GOAL_TURN or (
        ps.segment == last_segment
        and leg.reaches_goal
        and near_goal
        and final_turn > ctx.settings.approach_angle_deg
    ):
        return _approach(ctx, obstacle_id, 0)
    if ps.kind == TURN:
        if ps.segment == 0:
            raise RepairError(
                f"turning on the spot at the start {route.start} touches {obstacle_id!r}: "
                "the rover has no room to turn there"
            )
        if contact is None:
            raise RepairError(f"turn {k} touches {obstacle_id!r} but the gate gave no contact")
        return _shift(ctx, ps.segment - 1, contact, obstacle_id)
    a, b = route.segment(ps.segment)
    first_side = _away_side(a, b, contact)
    tries = _first_tries(ctx, a, b)
    return _detour(
        ctx,
        a,
        b,
        insert_at=ps.segment,
        drop=0,
        obstacle_id=obstacle_id,
        contact=contact,
        tries=tries,
        first_side=first_side,
    )


# -- goal, yaw, stall ------------------------------------------------------------------
def _turn_key(steps: Sequence[PlannedStep], index: int) -> tuple[str, str, int, int] | None:
    """What identifies a turn across attempts whose plans differ elsewhere: its command,
    kind, segment and rank among the turns of that kind on that segment."""
    ps = steps[index]
    if not ps.is_turn:
        return None
    rank = sum(
        1 for s in steps[:index] if s.is_turn and s.kind == ps.kind and s.segment == ps.segment
    )
    return (ps.step.command, ps.kind, ps.segment, rank)


def _secant_factor(
    ctx: PlannerContext, index: int, steps: Sequence[PlannedStep], intended_deg: float
) -> float | None:
    """When an earlier attempt ran the same turn (:func:`_turn_key`) with another
    distance, the factor on its distance that the line through both outcomes gives for
    ``intended_deg`` (the response is not quite proportional; a ratio can oscillate)."""
    ps = steps[index]
    u1 = ps.step.distance
    a1 = ctx.verdict.steps[index].yaw_change_deg
    key = _turn_key(steps, index)
    for leg, verdict in reversed(ctx.earlier):
        same = [j for j in range(len(leg.steps)) if _turn_key(leg.steps, j) == key]
        if not same or len(verdict.steps) <= same[0] or not verdict.steps[same[0]].completed:
            continue
        j = same[0]
        u2 = leg.steps[j].step.distance
        a2 = verdict.steps[j].yaw_change_deg
        if u2 == u1 or abs(a2 - a1) < 1e-3 or (a2 - a1) * (u2 - u1) * a1 <= 0:
            continue  # same point, or not a monotone response: no line to follow
        units = u1 + (intended_deg - a1) * (u2 - u1) / (a2 - a1)
        return units / u1 if units > 0 else None
    return None


def _recalibrate(
    ctx: PlannerContext,
    steps: list[PlannedStep],
    *,
    before: int | None = None,
    drives: bool = False,
) -> list[str]:
    """Rescale the steps before step ``before`` whose predicted outcome missed their
    intent (turns by yaw, with ``drives`` drives by ground covered); returns what
    changed, one phrase per step."""
    changed: list[str] = []
    s = ctx.settings
    predictions = ctx.verdict.steps
    last = len(predictions) if before is None else min(before, len(predictions))
    for i, ps in enumerate(steps[:last]):
        pred = predictions[i]
        if not pred.completed:
            continue
        if ps.is_turn:
            achieved = pred.yaw_change_deg
            intended = ps.yaw_change_deg
            if abs(achieved) < 1e-3 or achieved * intended <= 0:
                continue
            if abs(achieved - intended) <= s.turn_calibration_deg:
                continue
            factor = _secant_factor(ctx, i, steps, intended) or intended / achieved
            new = _scaled_turn(ctx, ps, factor)
            if new is None or new.step.distance == ps.step.distance:
                continue
            steps[i] = replace(new, yaw_change_deg=intended)
            changed.append(
                f"turn {i} {ps.step.distance} -> {new.step.distance} units "
                f"(twin turned {achieved:+.2f} deg for {intended:+.2f})"
            )
        elif drives and ps.is_linear and ps.travel_m > 0:
            a, b = pred.start_pose, pred.end_pose
            covered = (b.x - a.x) * math.cos(a.yaw_rad) + (b.y - a.y) * math.sin(a.yaw_rad)
            if covered < 0.01 or abs(covered - ps.travel_m) <= s.drive_calibration_m:
                continue
            units = round(ps.step.distance * ps.travel_m / covered)
            if not 1 <= units <= ctx.planner.max_step_units or units == ps.step.distance:
                continue
            steps[i] = replace(ps, step=replace(ps.step, distance=units))
            changed.append(
                f"drive {i} {ps.step.distance} -> {units} units (twin covered "
                f"{covered:.3f} m for {ps.travel_m:.3f})"
            )
    return changed


def goal_repair(ctx: PlannerContext) -> Repair:
    """Repair a goal miss (docs/planner.md "Goal not reached").

    Raises:
        RepairError: the plan has no linear step to lengthen or shorten, no room for a
            corrective step, or nothing to correct.
    """
    v = ctx.verdict
    p = ctx.planner
    steps = list(ctx.leg.steps)
    changes = _recalibrate(ctx, steps)
    linear = [i for i, s in enumerate(steps) if s.is_linear]
    # Lateral miss with no turn to blame: re-aim the last run of drives.
    if not changes and linear and abs(v.lateral_error_m) > v.tolerances.position_m / 2:
        first = linear[-1]
        while first - 1 in linear:
            first -= 1
        run_m = sum(abs(steps[i].travel_m) for i in range(first, linear[-1] + 1))
        angle_deg = math.degrees(math.atan2(v.lateral_error_m, max(run_m, 0.1)))
        before = first - 1
        if before >= 0 and steps[before].is_turn:
            ps = steps[before]
            target = ps.yaw_change_deg + angle_deg
            if ps.yaw_change_deg * target > 0:
                new = _scaled_turn(ctx, ps, target / ps.yaw_change_deg)
                if new is not None:
                    steps[before] = new
                    changes.append(f"re-aim turn {before} by {angle_deg:+.2f} deg")
        elif len(steps) < p.max_steps:
            turn = _turn_step(ctx, angle_deg, steps[first].segment)
            if turn is not None:
                steps.insert(first, turn)
                linear = [i for i, s in enumerate(steps) if s.is_linear]
                changes.append(f"re-aim before step {first} by {angle_deg:+.2f} deg")
        # The final turn, if any, now has to undo the re-aim.
        if changes and steps[-1].is_turn and steps[-1].kind == GOAL_TURN:
            ps = steps[-1]
            target = ps.yaw_change_deg - angle_deg
            if ps.yaw_change_deg * target > 0:
                new = _scaled_turn(ctx, ps, target / ps.yaw_change_deg)
                if new is not None:
                    steps[-1] = new
    error_m = v.position_error_m
    if abs(error_m) >= ctx.settings.min_correction_m:
        if not linear:
            raise RepairError("goal repair: the plan has no FWD or REV step to correct")
        last = linear[-1]
        units = p.rover.m_to_units(abs(error_m))
        ps = steps[last]
        if error_m > 0:
            if len(steps) < p.max_steps:
                extra = PlannedStep(
                    PlanStep("FWD", p.approach_speed, units),
                    CORRECTION,
                    ps.segment,
                    0.0,
                    0.0,
                    ps.end_pose,
                )
                steps.insert(last + 1, extra)
                changes.append(f"undershoot {error_m:.3f} m: FWD {units} units after step {last}")
            elif ps.step.distance + units <= p.max_step_units:
                steps[last] = replace(ps, step=replace(ps.step, distance=ps.step.distance + units))
                changes.append(f"undershoot {error_m:.3f} m: step {last} +{units} units")
            else:
                raise RepairError(
                    f"goal repair: {error_m:.3f} m short, but the plan is full and step {last} "
                    "is at its longest"
                )
        else:
            remaining = units
            for i in reversed(linear):
                if remaining <= 0:
                    break
                ps = steps[i]
                cut = min(remaining, ps.step.distance - 1)
                if cut > 0:
                    steps[i] = replace(ps, step=replace(ps.step, distance=ps.step.distance - cut))
                    remaining -= cut
            changes.append(
                f"overshoot {-error_m:.3f} m: last linear steps -{units - remaining} units"
            )
    if not changes:
        raise RepairError(
            f"goal repair: nothing to correct (longitudinal {error_m:+.3f} m, lateral "
            f"{v.lateral_error_m:+.3f} m)"
        )
    return Repair("goal_repair", "; ".join(changes), _rebuild(ctx, steps))


def yaw_repair(ctx: PlannerContext) -> Repair:
    """Repair a final yaw miss: rescale the last turn to what the twin predicts, or
    append a corrective turn.

    Raises:
        RepairError: no room for a corrective turn.
    """
    v = ctx.verdict
    err = v.yaw_error_deg
    steps = list(ctx.leg.steps)
    last = len(steps) - 1
    if steps[last].is_turn and last < len(v.steps):
        achieved = v.steps[last].yaw_change_deg
        desired = achieved + err
        if abs(achieved) > 1e-3 and achieved * desired > 0:
            new = _scaled_turn(ctx, steps[last], desired / achieved)
            if new is not None:
                steps[last] = replace(new, kind=steps[last].kind)
                return Repair(
                    "yaw_repair",
                    f"final turn {ctx.leg.steps[last].step.distance} -> {new.step.distance} "
                    f"units for {err:+.2f} deg",
                    _rebuild(ctx, steps),
                )
    if len(steps) >= ctx.planner.max_steps:
        raise RepairError(f"yaw repair: {err:+.2f} deg off, and the plan has no room for a turn")
    turn = _turn_step(ctx, err, steps[last].segment)
    if turn is None:
        raise RepairError(f"yaw repair: cannot make a single turn of {err:+.2f} deg")
    steps.append(turn)
    return Repair(
        "yaw_repair",
        f"corrective {turn.step.command} {turn.step.distance} units for {err:+.2f} deg",
        _rebuild(ctx, steps),
    )


def stall_repair(ctx: PlannerContext) -> Repair:
    """Repair a stall: a turn is retried at the fine turn speed; a drive is bypassed
    like an obstacle where it stalled.

    Raises:
        RepairError: the stalled turn is already at the lowest speed, or no step named.
    """
    v = ctx.verdict
    k = v.stall.step if v.stall is not None else v.failed_step
    if k is None or not 0 <= k < len(ctx.leg.steps):
        raise RepairError(f"the stall names step {k}, which this plan does not have")
    ps = ctx.leg.steps[k]
    if ps.is_turn:
        slow = ctx.planner.fine_turn_speed
        if ps.step.speed <= slow:
            raise RepairError(f"step {k} stalls turning even at speed {ps.step.speed}")
        steps = list(ctx.leg.steps)
        steps[k] = replace(ps, step=replace(ps.step, speed=slow))
        return Repair("stall_repair", f"turn {k} at speed {slow}", _rebuild(ctx, steps))
    stop = v.steps[k].end_pose if k < len(v.steps) else v.final_pose
    ahead = (
        stop.x + 0.5 * math.cos(stop.yaw_rad),
        stop.y + 0.5 * math.sin(stop.yaw_rad),
    )
    a, b = ctx.leg.route.segment(ps.segment)
    tries = sum(1 for f in ctx.previous_failures[:-1] if f.failure_type == "stalled")
    blind = replace(ctx, settings=replace(ctx.settings, map_aware=False))
    repair = _detour(
        blind,
        a,
        b,
        insert_at=ps.segment,
        drop=0,
        obstacle_id="stall",
        contact=ahead,
        tries=tries,
        first_side=_away_side(a, b, ahead),
    )
    return replace(repair, name="stall_repair", description="stalled drive: " + repair.description)


def start_repair(ctx: PlannerContext) -> Repair:
    """A start pose in collision cannot be repaired by changing the plan: always raises
    :class:`~planner.errors.RepairError`."""
    raise RepairError(
        "the start pose already touches an obstacle "
        f"({ctx.verdict.failure_reason}); no plan from it can be approved"
    )


REPAIRS: Mapping[str, RepairFunction] = {
    "collision": dogleg_repair,
    "goal_not_reached": goal_repair,
    "yaw_not_reached": yaw_repair,
    "stalled": stall_repair,
    "start_in_collision": start_repair,
}
"""The repair of each failure type."""
