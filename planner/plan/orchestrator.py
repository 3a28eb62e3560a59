"""The orchestrator: plan, validate on the gate, repair, at most N attempts per plan.

:class:`PlannerOrchestrator` is the thesis's retry loop (section 5.5, Figure 6). For one
leg: the planner makes a plan, the gate plays it; a rejection goes into
``previous_failures`` and the repair for its ``failure_type`` (:data:`REPAIRS`) makes the
next plan, until the gate approves, ``max_attempts`` plans were rejected, or a repair has
nothing to offer. A route longer than one plan goes leg by leg (:meth:`plan_mission`).

The map comes from the gate (``GET /maps/{name}``). Gate errors propagate as the
:class:`~planner.plan.gate_client.GateClient` raises them; a rejected plan is a result
with ``approved=False``, not an error. Details: docs/planner.md "The orchestrator".
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

from firmware_proto.model.geometry import Point
from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Pose
from firmware_proto.model.verdict import CollisionReport, Verdict
from firmware_proto.model.worldmap import WorldMap
from planner.errors import (
    GateProtocolError,
    PlanTooLongError,
    RepairError,
    UnreachableGoalError,
)
from planner.plan.gate_client import GateClient, GateOptions
from planner.plan.planner import HeuristicLowLevelPlanner, Itinerary, LegPlan, check_pose
from planner.plan.repairs import (
    REPAIRS,
    FailureRecord,
    PlannerContext,
    Repair,
    RepairFunction,
    RepairSettings,
)

__all__ = ["Attempt", "MissionResult", "PlanResult", "PlannerOrchestrator"]

logger = logging.getLogger(__name__)

DEFAULT_MAX_LEGS = 8
"""Legs per mission: 8 plans of 12 steps cover about 80 m, far more than a map."""


@dataclass(frozen=True)
class Attempt:
    """One plan sent to the gate.

    Attributes:
        index: 0-based within its leg.
        leg: the plan with the planner's bookkeeping (``leg.plan`` is what was sent).
        verdict: the gate's answer.
        repair: the repair that produced this plan; ``None`` for the first attempt.
    """

    index: int
    leg: LegPlan
    verdict: Verdict
    repair: Repair | None = None

    @property
    def plan(self) -> Plan:
        """The plan sent."""
        return self.leg.plan

    @property
    def repair_name(self) -> str:
        """The repair's name, ``"initial"`` for the first attempt."""
        return self.repair.name if self.repair is not None else "initial"


@dataclass(frozen=True)
class PlanResult:
    """The outcome of one leg.

    Attributes:
        approved: the gate approved the last attempt.
        attempts: every attempt, in order (at most ``max_attempts``).
        previous_failures: every rejection, in order.
        reason: why the orchestrator gave up; ``""`` when approved.
        reaches_goal: whether the approved plan ends at the goal (``False`` for a leg
            of a longer route; then ``remaining`` holds the waypoints still ahead).
    """

    approved: bool
    attempts: tuple[Attempt, ...]
    previous_failures: tuple[FailureRecord, ...]
    reason: str = ""
    reaches_goal: bool = True
    remaining: tuple[Point, ...] = field(default=())

    @property
    def plan(self) -> Plan | None:
        """The approved plan, or ``None``."""
        return self.attempts[-1].plan if self.approved else None

    @property
    def leg(self) -> LegPlan | None:
        """The approved leg, or ``None``."""
        return self.attempts[-1].leg if self.approved else None

    @property
    def verdict(self) -> Verdict:
        """The last verdict (the approval, or the last rejection)."""
        return self.attempts[-1].verdict

    @property
    def verdicts(self) -> tuple[Verdict, ...]:
        """Every verdict, in order."""
        return tuple(a.verdict for a in self.attempts)

    @property
    def repair_cycles(self) -> int:
        """Repairs made: attempts after the first."""
        return max(0, len(self.attempts) - 1)

    def raise_for_status(self) -> PlanResult:
        """This result if approved, else raises :class:`UnreachableGoalError` (``result``
        and ``reason`` attached)."""
        if not self.approved:
            raise UnreachableGoalError(self)
        return self


@dataclass(frozen=True)
class MissionResult:
    """The outcome of a mission, leg by leg.

    Attributes:
        goal: the mission's goal; ``start``: where it starts.
        legs: one :class:`PlanResult` per leg planned, in order; planning stops at the
            first leg that is not approved.
        reason: why it stopped short; ``""`` when every leg was approved.
    """

    goal: Pose
    start: Pose
    legs: tuple[PlanResult, ...]
    reason: str = ""

    @property
    def approved(self) -> bool:
        """Every leg approved and the last one reaches the goal."""
        return bool(self.legs) and all(r.approved for r in self.legs) and self.legs[-1].reaches_goal

    @property
    def plans(self) -> tuple[Plan, ...]:
        """The approved plans, in order of execution."""
        return tuple(r.plan for r in self.legs if r.plan is not None)

    @property
    def verdicts(self) -> tuple[Verdict, ...]:
        """The verdict of each approved plan (its predicted trajectory), in order."""
        return tuple(r.verdict for r in self.legs if r.approved)

    @property
    def attempts(self) -> tuple[Attempt, ...]:
        """Every attempt of every leg, in order."""
        return tuple(a for r in self.legs for a in r.attempts)

    @property
    def repair_cycles(self) -> int:
        """Repairs made over all legs."""
        return sum(r.repair_cycles for r in self.legs)

    @property
    def predicted_end(self) -> Pose | None:
        """Where the gate predicts the rover ends after the approved legs."""
        approved = [r for r in self.legs if r.approved]
        return approved[-1].verdict.final_pose if approved else None

    def raise_for_status(self) -> MissionResult:
        """This result if approved, else raises :class:`UnreachableGoalError`."""
        if not self.approved:
            raise UnreachableGoalError(self)
        return self


class PlannerOrchestrator:
    """Plan, validate and repair; not thread-safe (one per thread).

    Args:
        planner: the heuristic planner (its rover description gives the attempt budget).
        gate: the gate client.
        map_name: the map to validate on; ``None`` for the gate's default.
        max_attempts: plans per leg, the first included; default the rover
            description's ``safety.max_repair_attempts``.
        max_legs: legs per mission.
        world: the map, if already known; else read from the gate when first needed.
        options: overrides of the gate's tolerances and margin, for every request.
        repair_settings: parameters of the repairs.
        repairs: replacements or additions to :data:`REPAIRS`, by failure type
            (``None`` removes one: that failure type then ends the loop).
        max_collision_p: the highest share of the gate's sampled twins that may
            collide; more, and an approved plan counts as a ``collision`` on the obstacle
            hit most. Needs ``options.samples`` > 1; ``None``: the nominal verdict decides.

    Raises:
        ValueError: ``max_attempts`` or ``max_legs`` below 1, or ``max_collision_p``
            outside [0, 1] or without samples.
    """

    def __init__(
        self,
        planner: HeuristicLowLevelPlanner,
        gate: GateClient,
        *,
        map_name: str | None = None,
        max_attempts: int | None = None,
        max_legs: int = DEFAULT_MAX_LEGS,
        world: WorldMap | None = None,
        options: GateOptions | None = None,
        repair_settings: RepairSettings | None = None,
        repairs: Mapping[str, RepairFunction | None] | None = None,
        max_collision_p: float | None = None,
    ) -> None:
        attempts = (
            planner.rover.safety.max_repair_attempts if max_attempts is None else max_attempts
        )
        if attempts < 1:
            raise ValueError(f"max_attempts must be >= 1, got {attempts}")
        if max_legs < 1:
            raise ValueError(f"max_legs must be >= 1, got {max_legs}")
        self.planner = planner
        self.gate = gate
        self.map_name = map_name
        self.max_attempts = attempts
        self.max_legs = max_legs
        self.options = options or GateOptions()
        if max_collision_p is not None:
            if not 0.0 <= max_collision_p <= 1.0:
                raise ValueError(f"max_collision_p must be in [0, 1], got {max_collision_p}")
            if (self.options.samples or 1) < 2:
                raise ValueError("max_collision_p needs options.samples > 1")
        self.max_collision_p = max_collision_p
        self.repair_settings = repair_settings or RepairSettings()
        merged = {**REPAIRS, **(repairs or {})}
        self.repairs: dict[str, RepairFunction] = {
            k: fn for k, fn in merged.items() if fn is not None
        }
        self._world = world

    # -- the map ------------------------------------------------------------------------
    @property
    def world(self) -> WorldMap:
        """The map validated on, read from the gate on first use (:class:`GateCallError`:
        the gate cannot say)."""
        if self._world is None:
            self._world = self.gate.get_map(self.map_name)
            logger.debug(
                "map %r from the gate: %d obstacles", self._world.name, len(self._world.obstacles)
            )
        return self._world

    def _route(self, goal: Pose, start: Pose | None, via: Sequence[Point]) -> Itinerary:
        world = self.world
        return self.planner.route(
            start if start is not None else world.start, goal, via, world=world
        )

    # -- one leg ------------------------------------------------------------------------
    def plan(
        self, goal: Pose, *, start: Pose | None = None, via: Sequence[Point] = ()
    ) -> PlanResult:
        """Plan, validate and repair one leg toward ``goal`` from ``start`` (``None``:
        the map's) through ``via``. When the route needs more than one plan, the approved
        plan ends on the way (``reaches_goal`` false; see :meth:`plan_mission`).

        Raises:
            InvalidPoseError, OutOfBoundsError, GoalInObstacleError: bad goal, start or
                waypoint (nothing is sent to the gate).
            GateCallError: the gate failed.
        """
        return self.plan_route(self._route(goal, start, via))

    def plan_route(self, route: Itinerary) -> PlanResult:
        """:meth:`plan` for a checked route (:meth:`HeuristicLowLevelPlanner.route`)."""
        return self.run_leg(self.planner.plan_leg(route))

    def run_leg(self, leg: LegPlan) -> PlanResult:
        """The loop behind :meth:`plan`, for a leg made or edited by hand (raises
        :class:`GateCallError` when the gate fails)."""
        attempts: list[Attempt] = []
        failures: list[FailureRecord] = []
        history: list[Repair] = []
        repair: Repair | None = None
        while True:
            verdict = self._validate(leg)
            attempts.append(Attempt(len(attempts), leg, verdict, repair))
            if verdict.approved:
                logger.info(
                    "plan approved after %d attempt(s): %d steps to %s",
                    len(attempts),
                    len(leg.plan.commands),
                    leg.goal,
                )
                return PlanResult(
                    True,
                    tuple(attempts),
                    tuple(failures),
                    reaches_goal=leg.reaches_goal,
                    remaining=leg.remaining,
                )
            failure = FailureRecord.from_verdict(len(attempts) - 1, leg, verdict)
            failures.append(failure)
            logger.info("attempt %d rejected: %s", len(attempts), verdict.summary())
            if len(attempts) >= self.max_attempts:
                reason = (
                    f"gave up after {len(attempts)} attempts; the last was rejected with "
                    f"{verdict.failure_type} at step {verdict.failed_step}: "
                    f"{verdict.failure_reason}"
                )
                return self._give_up(attempts, failures, reason, leg)
            repair_fn = self.repairs.get(failure.failure_type)
            if repair_fn is None:
                reason = (
                    f"no repair for failure type {failure.failure_type!r}: {verdict.failure_reason}"
                )
                return self._give_up(attempts, failures, reason, leg)
            context = PlannerContext(
                planner=self.planner,
                leg=leg,
                verdict=verdict,
                attempt=len(attempts) - 1,
                previous_failures=tuple(failures),
                history=tuple(history),
                world=self._world,
                settings=self.repair_settings,
                earlier=tuple((a.leg, a.verdict) for a in attempts[:-1]),
            )
            try:
                repair = repair_fn(context)
            except PlanTooLongError as exc:
                return self._give_up(
                    attempts, failures, f"the repair does not fit in one plan: {exc}", leg
                )
            except RepairError as exc:
                reason = f"gave up after {len(attempts)} attempt(s): {exc}"
                return self._give_up(attempts, failures, reason, leg)
            history.append(repair)
            logger.info("repair %d: %s", len(history), repair.description)
            leg = repair.leg

    def check_plan(self, plan: Plan, *, start: Pose | None = None) -> MissionResult:
        """Validate a plan made elsewhere (``rover go --plan FILE``) once, without repair;
        the confidence check applies.

        Raises:
            InvalidPoseError, OutOfBoundsError: a start pose off the map.
            GateCallError: the gate failed.
        """
        world = self.world
        where = start if start is not None else world.start
        check_pose("start", where, world=world)
        leg = self.planner.leg_of(where, plan)
        verdict = self._validate(leg)
        attempt = Attempt(0, leg, verdict)
        if verdict.approved:
            result = PlanResult(True, (attempt,), ())
            return MissionResult(leg.goal, where, (result,))
        failure = FailureRecord.from_verdict(0, leg, verdict)
        reason = (
            f"the plan was rejected with {verdict.failure_type} at step {verdict.failed_step}: "
            f"{verdict.failure_reason}"
        )
        rejected = PlanResult(False, (attempt,), (failure,), reason)
        return MissionResult(leg.goal, where, (rejected,), reason)

    def _give_up(
        self, attempts: list[Attempt], failures: list[FailureRecord], reason: str, leg: LegPlan
    ) -> PlanResult:
        logger.warning("planning gave up: %s", reason)
        return PlanResult(
            False,
            tuple(attempts),
            tuple(failures),
            reason=reason,
            reaches_goal=leg.reaches_goal,
            remaining=leg.remaining,
        )

    def _validate(self, leg: LegPlan) -> Verdict:
        verdict = self.gate.validate(
            leg.plan, map_name=self.map_name, start=leg.start, options=self.options
        )
        return self._require_confidence(verdict)

    def _require_confidence(self, verdict: Verdict) -> Verdict:
        """An approved verdict whose samples collide more often than ``max_collision_p``
        allows, as a rejected ``collision`` on the obstacle hit most (so the dogleg
        repair moves the route away from it)."""
        limit = self.max_collision_p
        u = verdict.uncertainty
        if limit is None or not verdict.approved:
            return verdict
        if u is None:
            raise GateProtocolError("the gate's verdict carries no uncertainty", ["/uncertainty"])
        if u.collision_probability <= limit or not u.collisions:
            return verdict
        top = u.collisions[0]
        step = verdict.steps[min(top.step, len(verdict.steps) - 1)]
        reason = (
            f"collision probability {u.collision_probability:.3f} over {u.samples} samples "
            f"is above {limit:g}; most of them touch {top.obstacle_id!r} in step {top.step} "
            f"({top.count} samples) near ({top.contact.x:.3f}, {top.contact.y:.3f})"
        )
        collision = CollisionReport(
            top.obstacle_id,
            top.contact,
            step.end_pose,
            step.end_time_s,
            step.index,
            step.expected_duration_s,
        )
        return replace(
            verdict,
            approved=False,
            failure_type="collision",
            failure_reason=reason,
            failed_step=step.index,
            collision=collision,
        )

    # -- missions -----------------------------------------------------------------------
    def plan_mission(
        self, goal: Pose, *, start: Pose | None = None, via: Sequence[Point] = ()
    ) -> MissionResult:
        """Plan and validate a whole mission, leg by leg: each leg is :meth:`plan` from
        the pose the gate predicts at the end of the previous approved leg. Stops at the
        first leg not approved, or after ``max_legs`` legs.

        Raises:
            InvalidPoseError, OutOfBoundsError, GoalInObstacleError: bad input.
            GateCallError: the gate failed.
        """
        route = self._route(goal, start, via)
        legs: list[PlanResult] = []
        while True:
            result = self.plan_route(route)
            legs.append(result)
            if not result.approved:
                return MissionResult(
                    route.goal,
                    legs[0].attempts[0].leg.start,
                    tuple(legs),
                    f"leg {len(legs)}: {result.reason}",
                )
            if result.reaches_goal:
                return MissionResult(route.goal, legs[0].attempts[0].leg.start, tuple(legs))
            if len(legs) >= self.max_legs:
                return MissionResult(
                    route.goal,
                    legs[0].attempts[0].leg.start,
                    tuple(legs),
                    f"the goal is still not reached after {len(legs)} legs",
                )
            route = Itinerary(result.verdict.final_pose, result.remaining, route.goal)
