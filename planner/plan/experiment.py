"""The planning part of the thesis's experiment (section 6.2), on one scenario map.

For each of N goals, from the map's start pose: plan the straight route, validate it on
the gate, and repair until approved or given up
(:meth:`PlannerOrchestrator.plan_mission`); each goal's outcome is a :class:`Trial`.

"Collides" is judged twice, independently: by the gate (footprint inflated by its
margin) and by plain geometry (the bare chassis footprint swept along the planner's
ideal path, :func:`footprint_hits`); a geometric hit the gate did not reject as a
collision is a miss. Goals: the map's suggested ones, then seeded random ones
(:func:`trial_goals`); the same seed gives the same numbers (wall times aside). The
thesis's figures and ours: docs/planner.md "The experiment".
"""

from __future__ import annotations

import logging
import math
import random
import time
from collections.abc import Sequence
from dataclasses import dataclass

from firmware_proto.model.geometry import Point, segment_polygon_distance, wrap_deg
from firmware_proto.model.pose import Pose
from firmware_proto.model.worldmap import BOUNDS_ID, WorldMap
from planner.plan.orchestrator import MissionResult, PlannerOrchestrator
from planner.plan.planner import HeuristicLowLevelPlanner, Itinerary

__all__ = [
    "ExperimentResult",
    "Trial",
    "footprint_hits",
    "run_planning_experiment",
    "trial_goals",
]

logger = logging.getLogger(__name__)

SAMPLE_M = 0.02
"""Spacing of the footprint samples along a drive, m."""
SAMPLE_DEG = 2.0
"""Spacing of the footprint samples along a turn, degrees."""


@dataclass(frozen=True)
class Trial:
    """One goal of the experiment.

    Attributes:
        name: the goal's name (the map's, or ``random_<i>``).
        geometric_collision: the map shows the straight plan's footprint (no margin)
            hitting something; ``hit``: what it hits first (``""`` if nothing).
        first_failure: the gate's verdict on the straight plan (``None``: approved).
        intercepted: the gate rejected the straight plan as a collision.
        approved: every leg was approved in the end (the goal is reachable).
        repair_cycles: repairs made over all legs.
        attempts: plans validated; ``legs``: plans in the approved mission.
        reason: why it was given up (``""`` when approved).
        wall_time_s: planning and validation time (the one non-deterministic field).
    """

    name: str
    goal: Pose
    geometric_collision: bool
    hit: str
    first_failure: str | None
    intercepted: bool
    approved: bool
    repair_cycles: int
    attempts: int
    legs: int
    reason: str
    wall_time_s: float


def _mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None


@dataclass(frozen=True)
class ExperimentResult:
    """The experiment on one map; summary figures are properties."""

    map_name: str
    trials: tuple[Trial, ...]

    @property
    def collision_share(self) -> float:
        """Share of straight plans the gate rejected as collisions."""
        return sum(t.intercepted for t in self.trials) / len(self.trials) if self.trials else 0.0

    @property
    def geometric_share(self) -> float:
        """Share of straight plans whose bare footprint hits something on the map."""
        return (
            sum(t.geometric_collision for t in self.trials) / len(self.trials)
            if self.trials
            else 0.0
        )

    @property
    def interception_share(self) -> float | None:
        """Of the straight plans that hit something on the map, the share the gate
        rejected as collisions (``None`` when none hit anything)."""
        hits = [t for t in self.trials if t.geometric_collision]
        return sum(t.intercepted for t in hits) / len(hits) if hits else None

    @property
    def approved_share(self) -> float:
        """Share of goals that ended with an approved mission."""
        return sum(t.approved for t in self.trials) / len(self.trials) if self.trials else 0.0

    @property
    def mean_repair_cycles(self) -> float | None:
        """Mean repair cycles to approval over the goals whose straight plan collided
        and that were approved (the thesis's figure)."""
        return _mean([t.repair_cycles for t in self.trials if t.intercepted and t.approved])

    @property
    def mean_repair_cycles_all(self) -> float | None:
        """Mean repair cycles over every approved goal."""
        return _mean([t.repair_cycles for t in self.trials if t.approved])

    def table(self) -> str:
        """The trials and the summary as a plain-text table."""
        lines = [
            f"map {self.map_name}: {len(self.trials)} goals",
            f"{'goal':<16} {'x':>6} {'y':>6} {'yaw':>6}  {'geo hit':<12} {'first verdict':<17} "
            f"{'ok':<3} {'cycles':>6} {'legs':>4}",
        ]
        for t in self.trials:
            lines.append(
                f"{t.name:<16} {t.goal.x:6.2f} {t.goal.y:6.2f} {t.goal.yaw_deg:6.1f}  "
                f"{(t.hit or '-'):<12} {(t.first_failure or 'approved'):<17} "
                f"{'yes' if t.approved else 'no':<3} {t.repair_cycles:6d} {t.legs:4d}"
            )

        def pct(v: float | None) -> str:
            return "n/a" if v is None else f"{100 * v:.0f} %"

        def num(v: float | None) -> str:
            return "n/a" if v is None else f"{v:.2f}"

        lines.append(
            f"collisions (gate) {pct(self.collision_share)}, (geometry) "
            f"{pct(self.geometric_share)}; intercepted {pct(self.interception_share)}; "
            f"approved {pct(self.approved_share)}; mean repair cycles "
            f"{num(self.mean_repair_cycles)} (colliding), {num(self.mean_repair_cycles_all)} (all)"
        )
        return "\n".join(lines)


def _rectangle(pose: Pose, half_length_m: float, half_width_m: float) -> list[Point]:
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    return [
        (pose.x + dx * c - dy * s, pose.y + dx * s + dy * c)
        for dx, dy in (
            (half_length_m, half_width_m),
            (-half_length_m, half_width_m),
            (-half_length_m, -half_width_m),
            (half_length_m, -half_width_m),
        )
    ]


def _rectangle_hits(world: WorldMap, corners: Sequence[Point], margin_m: float) -> str | None:
    xs = [p[0] for p in corners]
    ys = [p[1] for p in corners]
    b = world.bounds
    if min(min(xs) - b.min_x, b.max_x - max(xs), min(ys) - b.min_y, b.max_y - max(ys)) < margin_m:
        return BOUNDS_ID
    for o in world.obstacles:
        x0, y0, x1, y1 = o.box
        if x1 < min(xs) - margin_m or x0 > max(xs) + margin_m:
            continue
        if y1 < min(ys) - margin_m or y0 > max(ys) + margin_m:
            continue
        edges = [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
        if o.kind == "polygon":
            # An obstacle wholly inside the footprint touches no edge: test a vertex.
            inside = _inside_convex(o.points[0], corners)
            d = 0.0 if inside else min(segment_polygon_distance(a, b, o.points) for a, b in edges)
        else:
            d = min(o.segment_distance(a, b) for a, b in edges)
            if _inside_convex(o.points[0], corners):
                d = -1.0
        if d <= margin_m:  # 0: touching or overlapping
            return o.id
    return None


def _inside_convex(p: Point, corners: Sequence[Point]) -> bool:
    sign = 0.0
    for i in range(len(corners)):
        a, b = corners[i], corners[(i + 1) % len(corners)]
        cross = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
        if cross == 0:
            continue
        if sign == 0:
            sign = cross
        elif (cross > 0) != (sign > 0):
            return False
    return True


def footprint_hits(
    planner: HeuristicLowLevelPlanner, world: WorldMap, route: Itinerary, margin_m: float = 0.0
) -> str | None:
    """What the chassis footprint, inflated by ``margin_m``, first hits when it follows
    the planner's ideal path along ``route`` (every step, however many plans it takes),
    sampled every :data:`SAMPLE_M` along drives and :data:`SAMPLE_DEG` along turns; the
    obstacle's id, ``"bounds"`` for a wall, ``None`` when nothing."""
    g = planner.rover.geometry
    half_l, half_w = g.chassis_length_m / 2, g.chassis_width_m / 2
    pose = route.start
    for ps in planner.steps_for(route):
        end = ps.end_pose
        if ps.is_turn:
            n = max(1, math.ceil(abs(ps.yaw_change_deg) / SAMPLE_DEG))
            samples = [
                Pose(pose.x, pose.y, pose.yaw_deg + ps.yaw_change_deg * i / n)
                for i in range(1, n + 1)
            ]
        else:
            n = max(1, math.ceil(math.dist(pose.xy, end.xy) / SAMPLE_M))
            samples = [
                Pose(
                    pose.x + (end.x - pose.x) * i / n,
                    pose.y + (end.y - pose.y) * i / n,
                    end.yaw_deg,
                )
                for i in range(1, n + 1)
            ]
        for sample in samples:
            hit = _rectangle_hits(world, _rectangle(sample, half_l, half_w), margin_m)
            if hit is not None:
                return hit
        pose = end
    return None


def trial_goals(
    world: WorldMap,
    planner: HeuristicLowLevelPlanner,
    n: int,
    *,
    seed: int = 0,
    min_distance_m: float = 3.0,
    margin_m: float = 0.1,
    include_suggested: bool = True,
) -> list[tuple[str, Pose]]:
    """``n`` goals: the map's suggested goals first (when asked), then random ones where
    the rover can turn on the spot (clearance of its circumradius plus ``margin_m`` and
    5 cm), at least ``min_distance_m`` from the start, with a random whole-degree yaw.
    Deterministic for a seed."""
    rng = random.Random(seed)
    out: list[tuple[str, Pose]] = []
    if include_suggested:
        out += [(g.name, g.pose) for g in world.goals[:n]]
    need = planner.rover.footprint_radius_m + margin_m + 0.05
    b = world.bounds
    tries = 0
    while len(out) < n:
        tries += 1
        if tries > 100_000:
            raise ValueError(f"map {world.name!r} has no room for {n} goals")
        x = round(rng.uniform(b.min_x, b.max_x), 2)
        y = round(rng.uniform(b.min_y, b.max_y), 2)
        yaw = float(rng.randrange(-180, 180))
        if math.dist((x, y), (world.start.x, world.start.y)) < min_distance_m:
            continue
        if world.point_blocked((x, y), need) is not None:
            continue
        out.append((f"random_{len(out)}", Pose(x, y, wrap_deg(yaw))))
    return out


def _trial(orchestrator: PlannerOrchestrator, world: WorldMap, name: str, goal: Pose) -> Trial:
    planner = orchestrator.planner
    start = world.start
    straight = planner.route(start, goal, world=world)
    hit = footprint_hits(planner, world, straight) or ""
    t0 = time.perf_counter()
    result: MissionResult = orchestrator.plan_mission(goal, start=start)
    wall = time.perf_counter() - t0
    first_failure: str | None = None
    intercepted = False
    for attempt in result.attempts:
        if attempt.repair is not None:
            break
        if not attempt.verdict.approved:
            first_failure = attempt.verdict.failure_type
            intercepted = first_failure == "collision"
            break
    return Trial(
        name=name,
        goal=goal,
        geometric_collision=bool(hit),
        hit=hit,
        first_failure=first_failure,
        intercepted=intercepted,
        approved=result.approved,
        repair_cycles=result.repair_cycles,
        attempts=len(result.attempts),
        legs=len(result.legs),
        reason=result.reason,
        wall_time_s=wall,
    )


def run_planning_experiment(
    orchestrator: PlannerOrchestrator,
    n_goals: int = 10,
    *,
    goals: Sequence[tuple[str, Pose]] | None = None,
    seed: int = 0,
    min_distance_m: float = 3.0,
) -> ExperimentResult:
    """Run the planning experiment on the orchestrator's map (its ``map_name`` is the
    scenario): on ``goals``, ``(name, pose)`` pairs, else on ``n_goals`` goals of
    :func:`trial_goals` drawn with ``seed``, at least ``min_distance_m`` (m) from the start.

    Raises:
        GateCallError: the gate failed.
    """
    world = orchestrator.world
    if goals is None:
        goals = trial_goals(
            world, orchestrator.planner, n_goals, seed=seed, min_distance_m=min_distance_m
        )
    trials = []
    for name, goal in goals:
        trial = _trial(orchestrator, world, name, goal)
        logger.info(
            "%s %s: first %s, %s after %d repair(s)",
            world.name,
            name,
            trial.first_failure or "approved",
            "approved" if trial.approved else "given up",
            trial.repair_cycles,
        )
        trials.append(trial)
    return ExperimentResult(world.name, tuple(trials))
