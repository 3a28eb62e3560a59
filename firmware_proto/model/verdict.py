"""The gate's answer to ``POST /validate_plan``, as plain frozen dataclasses: the one
definition that the gate (which builds and serialises verdicts) and the planner (which
reads them over HTTP and may not import the gate) share.

These mirror the JSON one to one (:meth:`Verdict.to_dict` / :meth:`Verdict.from_dict`;
docs/gate.md and the gate's ``GET /openapi.json`` document the same shape), so a client
may use them or work from the JSON alone. Reading is strict about what it uses and
lenient about the rest: a missing or mistyped field raises
:class:`~firmware_proto.errors.VerdictError` naming its JSON pointer; a field it does
not know is ignored (a newer gate may add some). Pure: standard library only.

Units: metres in the map frame (x east, y north), yaw in degrees counter-clockwise from
+x, times in seconds of twin time unless a name says ``wall``. Errors are signed and
computed as *goal minus predicted*:

- ``position_error_m``: along the goal-approach heading (the heading of the last FWD or
  REV step, reversed for REV; the start-to-goal bearing when the plan never drives).
  Positive: the rover stops short of the goal (undershoot); negative: it overshoots.
- ``lateral_error_m``: across that heading, positive when the goal lies to the left.
- ``yaw_error_deg``: goal yaw minus final yaw, wrapped to ``[-180, 180)``.

What an executor's drift monitor needs is here: :attr:`Verdict.trajectory` (poses tagged
with the step index and the time since that step started, because the executor pauses
between steps for the link's round trip) and :attr:`Verdict.steps`. A verdict played on
several twins (``samples`` > 1) carries :class:`Uncertainty` as well.
"""

from __future__ import annotations

import bisect
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Final, TypeVar

from firmware_proto.errors import VerdictError
from firmware_proto.model.pose import Point, Pose

__all__ = [
    "FAILURE_TYPES",
    "CollisionReport",
    "EnvelopePoint",
    "GoalErrorPercentiles",
    "ObstacleHits",
    "Replay",
    "StallReport",
    "StepPrediction",
    "Tolerances",
    "Trajectory",
    "TrajectorySample",
    "Uncertainty",
    "Verdict",
]

FAILURE_TYPES: Final = (
    "collision",
    "start_in_collision",
    "stalled",
    "goal_not_reached",
    "yaw_not_reached",
)
"""Values of a verdict's ``failure_type`` when a plan is rejected, in order of
precedence:

- ``collision``: the margin-inflated footprint touched an obstacle or a wall; playback
  stopped at the first contact (``collision`` says where and with what);
- ``start_in_collision``: the start pose already touches something; no plan from this
  pose can be approved, so repairing the plan will not help;
- ``stalled``: a step made no progress (a side that should turn did not) or ran past
  its time limit (``stall`` says which and why);
- ``goal_not_reached``: the plan ran to the end but the final position is farther from
  the goal than the position tolerance;
- ``yaw_not_reached``: the position is within tolerance but the final yaw is not.
"""

_T = TypeVar("_T")


class _Reader:
    """Typed field access with JSON pointers in the errors."""

    def __init__(self, obj: Any, pointer: str) -> None:
        if not isinstance(obj, Mapping):
            raise VerdictError(f"verdict: {pointer or '/'} is not an object", (pointer,))
        self.obj = obj
        self.pointer = pointer

    def _get(self, key: str) -> Any:
        if key not in self.obj:
            where = f"{self.pointer}/{key}"
            raise VerdictError(f"verdict: missing field {where}", (where,))
        return self.obj[key]

    def _bad(self, key: str, what: str) -> VerdictError:
        where = f"{self.pointer}/{key}"
        return VerdictError(f"verdict: {where} is not {what}", (where,))

    def number(self, key: str) -> float:
        value = self._get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self._bad(key, "a number")
        return float(value)

    def integer(self, key: str) -> int:
        value = self._get(key)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self._bad(key, "an integer")
        return value

    def boolean(self, key: str) -> bool:
        value = self._get(key)
        if not isinstance(value, bool):
            raise self._bad(key, "a boolean")
        return value

    def string(self, key: str) -> str:
        value = self._get(key)
        if not isinstance(value, str):
            raise self._bad(key, "a string")
        return value

    def numbers(self, key: str) -> tuple[float, ...]:
        value = self._get(key)
        if not isinstance(value, list) or any(
            isinstance(v, bool) or not isinstance(v, (int, float)) for v in value
        ):
            raise self._bad(key, "a list of numbers")
        return tuple(float(v) for v in value)

    def optional(self, key: str, read: Callable[[str], _T]) -> _T | None:
        return None if self.obj.get(key) is None else read(key)

    def child(self, key: str) -> _Reader:
        return _Reader(self._get(key), f"{self.pointer}/{key}")

    def items(self, key: str) -> list[_Reader]:
        value = self._get(key)
        if not isinstance(value, list):
            raise self._bad(key, "a list")
        return [_Reader(v, f"{self.pointer}/{key}/{i}") for i, v in enumerate(value)]

    def pose(self, key: str) -> Pose:
        r = self.child(key)
        return Pose(r.number("x"), r.number("y"), r.number("yaw_deg"))

    def point(self, key: str) -> Point:
        r = self.child(key)
        return Point(r.number("x"), r.number("y"))


@dataclass(frozen=True)
class TrajectorySample:
    """One predicted pose.

    Attributes:
        t_s: twin time since the plan started (steps back to back, no pauses).
        step: index of the step this sample belongs to.
        step_t_s: time since that step started: what a drift monitor aligns on, since
            the executor pauses between steps for the link's round trip.
        pose: the predicted pose.
    """

    t_s: float
    step: int
    step_t_s: float
    pose: Pose

    def to_dict(self) -> dict[str, Any]:
        """The sample as JSON-ready data (the pose's fields inline)."""
        p = self.pose
        return {
            "t_s": self.t_s,
            "step": self.step,
            "step_t_s": self.step_t_s,
            "x": p.x,
            "y": p.y,
            "yaw_deg": p.yaw_deg,
        }

    @classmethod
    def _read(cls, r: _Reader) -> TrajectorySample:
        pose = Pose(r.number("x"), r.number("y"), r.number("yaw_deg"))
        return cls(r.number("t_s"), r.integer("step"), r.number("step_t_s"), pose)


@dataclass(frozen=True)
class Trajectory:
    """The predicted trajectory.

    Each step contributes a sample at its start (``step_t_s == 0``), the samples of the
    fixed-rate grid that fall inside it (every ``sample_period_s`` of plan time), and one
    at its end; after the last step, samples of the settling phase (wheels stopped, the
    body coming to rest) carry the last step's index with ``step_t_s`` beyond its
    duration. Samples are in time order; a boundary time appears twice (end of one step,
    start of the next).
    """

    sample_period_s: float
    samples: tuple[TrajectorySample, ...]

    def to_dict(self) -> dict[str, Any]:
        """The trajectory as JSON-ready data."""
        return {
            "sample_period_s": self.sample_period_s,
            "samples": [s.to_dict() for s in self.samples],
        }

    def for_step(self, step: int) -> tuple[TrajectorySample, ...]:
        """The samples of one step, in time order."""
        return tuple(s for s in self.samples if s.step == step)

    def pose_at(self, step: int, step_t_s: float) -> Pose | None:
        """The predicted pose ``step_t_s`` into ``step``, linearly interpolated between
        its samples (held at the ends); ``None`` when the step has no samples.

        Yaw is interpolated along the shorter arc."""
        samples = self.for_step(step)
        if not samples:
            return None
        times = [s.step_t_s for s in samples]
        i = bisect.bisect_right(times, step_t_s)
        if i == 0:
            return samples[0].pose
        if i >= len(samples):
            return samples[-1].pose
        a, b = samples[i - 1], samples[i]
        span = b.step_t_s - a.step_t_s
        f = 0.0 if span <= 0 else (step_t_s - a.step_t_s) / span
        dyaw = (b.pose.yaw_deg - a.pose.yaw_deg + 180.0) % 360.0 - 180.0
        return Pose(
            a.pose.x + f * (b.pose.x - a.pose.x),
            a.pose.y + f * (b.pose.y - a.pose.y),
            a.pose.yaw_deg + f * dyaw,
        )


@dataclass(frozen=True)
class StepPrediction:
    """What the twin predicts for one step.

    Attributes:
        index: the step's position in the plan (0-based).
        command, speed, distance: the step as planned.
        start_time_s, end_time_s: twin time at its start and end (plan time).
        expected_duration_s: ``end - start``: how long the twin took, slip included; an
            executor's per-step timeout should start from it.
        nominal_duration_s: the step's ideal trapezoidal speed profile without slip.
        start_pose, end_pose: poses at its start and end.
        completed: it ran to its distance (false when a collision or stall cut it).
        left_travel_units, right_travel_units: encoder travel of each side, distance
            units, forward positive (what the rover's encoders should count).
    """

    index: int
    command: str
    speed: int
    distance: int
    start_time_s: float
    end_time_s: float
    expected_duration_s: float
    nominal_duration_s: float
    start_pose: Pose
    end_pose: Pose
    completed: bool
    left_travel_units: float
    right_travel_units: float

    @property
    def yaw_change_deg(self) -> float:
        """Predicted yaw change over the step, degrees, wrapped to ``[-180, 180)``."""
        return (self.end_pose.yaw_deg - self.start_pose.yaw_deg + 180.0) % 360.0 - 180.0

    def to_dict(self) -> dict[str, Any]:
        """The step as JSON-ready data."""
        return {
            "index": self.index,
            "command": self.command,
            "speed": self.speed,
            "distance": self.distance,
            "start_time_s": self.start_time_s,
            "end_time_s": self.end_time_s,
            "expected_duration_s": self.expected_duration_s,
            "nominal_duration_s": self.nominal_duration_s,
            "start_pose": self.start_pose.to_dict(),
            "end_pose": self.end_pose.to_dict(),
            "completed": self.completed,
            "left_travel_units": self.left_travel_units,
            "right_travel_units": self.right_travel_units,
        }

    @classmethod
    def _read(cls, s: _Reader) -> StepPrediction:
        return cls(
            index=s.integer("index"),
            command=s.string("command"),
            speed=s.integer("speed"),
            distance=s.integer("distance"),
            start_time_s=s.number("start_time_s"),
            end_time_s=s.number("end_time_s"),
            expected_duration_s=s.number("expected_duration_s"),
            nominal_duration_s=s.number("nominal_duration_s"),
            start_pose=s.pose("start_pose"),
            end_pose=s.pose("end_pose"),
            completed=s.boolean("completed"),
            left_travel_units=s.number("left_travel_units"),
            right_travel_units=s.number("right_travel_units"),
        )


@dataclass(frozen=True)
class CollisionReport:
    """The first contact of the margin-inflated footprint.

    Attributes:
        obstacle_id: the map obstacle's id, or ``"bounds"`` for the walls.
        contact: contact point on the obstacle's surface.
        pose: the rover's pose at contact.
        time_s: plan time of the contact.
        step: the step during which it happened.
        step_t_s: time since that step started.
    """

    obstacle_id: str
    contact: Point
    pose: Pose
    time_s: float
    step: int
    step_t_s: float

    def to_dict(self) -> dict[str, Any]:
        """The collision as JSON-ready data."""
        return {
            "obstacle_id": self.obstacle_id,
            "contact": self.contact.to_dict(),
            "pose": self.pose.to_dict(),
            "time_s": self.time_s,
            "step": self.step,
            "step_t_s": self.step_t_s,
        }

    @classmethod
    def _read(cls, c: _Reader) -> CollisionReport:
        return cls(
            c.string("obstacle_id"),
            c.point("contact"),
            c.pose("pose"),
            c.number("time_s"),
            c.integer("step"),
            c.number("step_t_s"),
        )


@dataclass(frozen=True)
class StallReport:
    """Why playback stopped for lack of progress.

    Attributes:
        step: the step that stalled.
        reason: ``"no_encoder_progress"`` or ``"time_limit"``.
        side: ``"left"``, ``"right"``, ``"both"`` (no progress) or ``""`` (time limit).
        time_s: plan time of the detection.
    """

    step: int
    reason: str
    side: str
    time_s: float

    def to_dict(self) -> dict[str, Any]:
        """The stall as JSON-ready data."""
        return {"step": self.step, "reason": self.reason, "side": self.side, "time_s": self.time_s}

    @classmethod
    def _read(cls, s: _Reader) -> StallReport:
        return cls(s.integer("step"), s.string("reason"), s.string("side"), s.number("time_s"))


@dataclass(frozen=True)
class Tolerances:
    """What the verdict was judged against: goal distance (m), yaw (deg), and the
    inflation of the footprint for collisions (m)."""

    position_m: float
    yaw_deg: float
    safety_margin_m: float

    def to_dict(self) -> dict[str, Any]:
        """The tolerances as JSON-ready data."""
        return {
            "position_m": self.position_m,
            "yaw_deg": self.yaw_deg,
            "safety_margin_m": self.safety_margin_m,
        }

    @classmethod
    def _read(cls, t: _Reader) -> Tolerances:
        return cls(t.number("position_m"), t.number("yaw_deg"), t.number("safety_margin_m"))


@dataclass(frozen=True)
class Replay:
    """Everything needed to reproduce the verdict bit for bit.

    Attributes:
        seed: seed of the draws of a verdict played on several twins (the request's
            ``seed``); 0 for a single playback, which has no randomness.
        map: map name; ``map_sha256`` its canonical content's SHA-256.
        rover: rover description name; ``rover_sha256`` its values' SHA-256.
        plan_sha256: SHA-256 of the plan's canonical JSON (sorted keys, no spaces).
        start: the start pose used.
        dt_s: the twin's fixed physics step.
        sample_hz: requested trajectory rate (the period actually used is in
            ``trajectory.sample_period_s``).
        render: whether a picture was requested.
        gate_version: version of this software; ``pymunk_version`` of the physics engine.
        query: the query string that reproduces these options on ``/validate_plan``.
    """

    seed: int
    map: str
    map_sha256: str
    rover: str
    rover_sha256: str
    plan_sha256: str
    start: Pose
    dt_s: float
    sample_hz: float
    render: bool
    gate_version: str
    pymunk_version: str
    query: str

    def to_dict(self) -> dict[str, Any]:
        """The replay record as JSON-ready data."""
        return {
            "seed": self.seed,
            "map": self.map,
            "map_sha256": self.map_sha256,
            "rover": self.rover,
            "rover_sha256": self.rover_sha256,
            "plan_sha256": self.plan_sha256,
            "start": self.start.to_dict(),
            "dt_s": self.dt_s,
            "sample_hz": self.sample_hz,
            "render": self.render,
            "gate_version": self.gate_version,
            "pymunk_version": self.pymunk_version,
            "query": self.query,
        }

    @classmethod
    def _read(cls, r: _Reader) -> Replay:
        return cls(
            seed=r.integer("seed"),
            map=r.string("map"),
            map_sha256=r.string("map_sha256"),
            rover=r.string("rover"),
            rover_sha256=r.string("rover_sha256"),
            plan_sha256=r.string("plan_sha256"),
            start=r.pose("start"),
            dt_s=r.number("dt_s"),
            sample_hz=r.number("sample_hz"),
            render=r.boolean("render"),
            gate_version=r.string("gate_version"),
            pymunk_version=r.string("pymunk_version"),
            query=r.string("query"),
        )


@dataclass(frozen=True)
class ObstacleHits:
    """The samples of an uncertain verdict that hit one obstacle.

    Attributes:
        obstacle_id: the obstacle (``"bounds"`` for the walls).
        count: how many samples touched it first.
        step: the step during which most of them did (the earliest on a tie).
        contact: the mean contact point of those at that step, m.
    """

    obstacle_id: str
    count: int
    step: int
    contact: Point

    def to_dict(self) -> dict[str, Any]:
        """As JSON-ready data."""
        return {
            "obstacle_id": self.obstacle_id,
            "count": self.count,
            "step": self.step,
            "contact": self.contact.to_dict(),
        }

    @classmethod
    def _read(cls, r: _Reader) -> ObstacleHits:
        return cls(
            r.string("obstacle_id"), r.integer("count"), r.integer("step"), r.point("contact")
        )


@dataclass(frozen=True)
class GoalErrorPercentiles:
    """Percentiles of the goal errors over the samples that played to the end (no
    collision, no stall); each list has one value per entry of ``percentiles``.

    Attributes:
        samples: how many samples they are over (0: every one collided or stalled, and
            the lists are empty).
        percentiles: which percentiles, in percent (5, 50, 95...).
        distance_m, position_m, lateral_m, yaw_deg: of ``distance_error_m``,
            ``position_error_m``, ``lateral_error_m`` and ``yaw_error_deg`` (same signs
            as the verdict's).
    """

    samples: int
    percentiles: tuple[float, ...]
    distance_m: tuple[float, ...]
    position_m: tuple[float, ...]
    lateral_m: tuple[float, ...]
    yaw_deg: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        """As JSON-ready data."""
        return {
            "samples": self.samples,
            "percentiles": list(self.percentiles),
            "distance_m": list(self.distance_m),
            "position_m": list(self.position_m),
            "lateral_m": list(self.lateral_m),
            "yaw_deg": list(self.yaw_deg),
        }

    @classmethod
    def _read(cls, r: _Reader) -> GoalErrorPercentiles:
        return cls(
            r.integer("samples"),
            r.numbers("percentiles"),
            r.numbers("distance_m"),
            r.numbers("position_m"),
            r.numbers("lateral_m"),
            r.numbers("yaw_deg"),
        )


@dataclass(frozen=True)
class EnvelopePoint:
    """Where the samples still playing are at one moment of one step.

    Attributes:
        step, step_t_s: the moment (as the trajectory tags it).
        samples: how many samples are still playing then (not yet collided).
        pose: their mean pose (yaw: the circular mean).
        major_m, minor_m, angle_deg: the ellipse that holds their positions at the
            envelope's level (``Uncertainty.level``) under a normal fit: semi-axes, m,
            and the major axis's direction, degrees counter-clockwise from +x.
        yaw_sd_deg: the standard deviation of their yaw about the mean, degrees.
    """

    step: int
    step_t_s: float
    samples: int
    pose: Pose
    major_m: float
    minor_m: float
    angle_deg: float
    yaw_sd_deg: float

    def to_dict(self) -> dict[str, Any]:
        """As JSON-ready data (the pose's fields inline)."""
        return {
            "step": self.step,
            "step_t_s": self.step_t_s,
            "samples": self.samples,
            "x": self.pose.x,
            "y": self.pose.y,
            "yaw_deg": self.pose.yaw_deg,
            "major_m": self.major_m,
            "minor_m": self.minor_m,
            "angle_deg": self.angle_deg,
            "yaw_sd_deg": self.yaw_sd_deg,
        }

    @classmethod
    def _read(cls, r: _Reader) -> EnvelopePoint:
        return cls(
            r.integer("step"),
            r.number("step_t_s"),
            r.integer("samples"),
            Pose(r.number("x"), r.number("y"), r.number("yaw_deg")),
            r.number("major_m"),
            r.number("minor_m"),
            r.number("angle_deg"),
            r.number("yaw_sd_deg"),
        )


@dataclass(frozen=True)
class Uncertainty:
    """A plan played on ``samples`` twins drawn from the twin's parameter uncertainty
    and a slip distribution (docs/gate.md, "Verdicts with their uncertainty").

    Attributes:
        samples: how many twins.
        seed: the seed of the draws (same request, same seed: same answer).
        spread: ``"calibration"`` (the calibrated twin's covariance) or ``"default"``
            (the gate's documented default spread).
        slip_sigma: the 1-sigma spread of each side's friction factor (log-normal).
        collision_probability: the fraction of samples whose footprint touched
            something (start included).
        stall_probability: the fraction that stalled.
        approved_probability: the fraction that the verdict's tolerances approve.
        collisions: per obstacle hit, most hits first.
        goal_error: percentiles of the goal errors.
        level: the probability the envelope's ellipses hold (0.95).
        envelope: per step, the samples' spread at moments of it (each step's end among
            them), in time order.
    """

    samples: int
    seed: int
    spread: str
    slip_sigma: float
    collision_probability: float
    stall_probability: float
    approved_probability: float
    collisions: tuple[ObstacleHits, ...]
    goal_error: GoalErrorPercentiles
    level: float
    envelope: tuple[EnvelopePoint, ...]

    def to_dict(self) -> dict[str, Any]:
        """As JSON-ready data."""
        return {
            "samples": self.samples,
            "seed": self.seed,
            "spread": self.spread,
            "slip_sigma": self.slip_sigma,
            "collision_probability": self.collision_probability,
            "stall_probability": self.stall_probability,
            "approved_probability": self.approved_probability,
            "collisions": [c.to_dict() for c in self.collisions],
            "goal_error": self.goal_error.to_dict(),
            "level": self.level,
            "envelope": [p.to_dict() for p in self.envelope],
        }

    def for_step(self, step: int) -> tuple[EnvelopePoint, ...]:
        """The envelope points of one step, in time order."""
        return tuple(p for p in self.envelope if p.step == step)

    @classmethod
    def _read(cls, r: _Reader) -> Uncertainty:
        return cls(
            samples=r.integer("samples"),
            seed=r.integer("seed"),
            spread=r.string("spread"),
            slip_sigma=r.number("slip_sigma"),
            collision_probability=r.number("collision_probability"),
            stall_probability=r.number("stall_probability"),
            approved_probability=r.number("approved_probability"),
            collisions=tuple(ObstacleHits._read(c) for c in r.items("collisions")),
            goal_error=GoalErrorPercentiles._read(r.child("goal_error")),
            level=r.number("level"),
            envelope=tuple(EnvelopePoint._read(p) for p in r.items("envelope")),
        )


@dataclass(frozen=True)
class Verdict:
    """The response of ``POST /validate_plan``; see the module docstring for units and
    signs, and :data:`FAILURE_TYPES` for ``failure_type``.

    Attributes:
        approved: the plan is collision-free, made progress, and ends within tolerance
            (judged on the nominal twin, also when ``uncertainty`` is present).
        failure_type: ``None`` when approved, else one of :data:`FAILURE_TYPES` (or a
            newer type this client does not know).
        failure_reason: one human-readable sentence (``""`` when approved).
        failed_step: the step that failed: the colliding or stalled step, or the last
            step for ``goal_not_reached`` / ``yaw_not_reached``; ``None`` when approved.
        goal: the plan's goal; ``start_pose`` where playback started; ``final_pose``
            where the twin came to rest (or the pose at contact).
        position_error_m, lateral_error_m, distance_error_m, yaw_error_deg: the final
            pose against the goal (``distance_error_m`` is the unsigned Euclidean one).
        approach_heading_deg: the heading the longitudinal error is measured along.
        collision, stall: details of those failures, else ``None``.
        tolerances: what the verdict was judged against.
        steps: one prediction per step played (fewer than planned when cut short).
        trajectory: the predicted trajectory.
        sim_time_s: twin time played, settling included.
        replay: what reproduces this verdict.
        uncertainty: the spread over twins drawn from the parameter uncertainty, when
            the request asked for more than one sample; else ``None``.
        image_png_base64: the rendered top-down view, when requested; else ``None``.
        wall_time_s: wall-clock time the validation took: the one field that differs
            between repeats of the same request.
    """

    approved: bool
    failure_type: str | None
    failure_reason: str
    failed_step: int | None
    goal: Pose
    start_pose: Pose
    final_pose: Pose
    position_error_m: float
    lateral_error_m: float
    distance_error_m: float
    yaw_error_deg: float
    approach_heading_deg: float
    collision: CollisionReport | None
    stall: StallReport | None
    tolerances: Tolerances
    steps: tuple[StepPrediction, ...]
    trajectory: Trajectory
    sim_time_s: float
    replay: Replay
    uncertainty: Uncertainty | None = None
    image_png_base64: str | None = None
    wall_time_s: float = 0.0

    @property
    def expected_duration_s(self) -> float:
        """Sum of the steps' expected durations, s (the plan's drive time, without the
        pauses an executor makes between steps)."""
        return sum(s.expected_duration_s for s in self.steps)

    def summary(self) -> str:
        """One line: approved, or the failure with its step and reason."""
        if self.approved:
            return f"approved, ends at {self.final_pose}"
        return f"{self.failure_type} at step {self.failed_step}: {self.failure_reason}"

    def to_dict(self) -> dict[str, Any]:
        """The verdict as JSON-ready data, keys in documented order, ``wall_time_s``
        last; ``uncertainty`` and ``image_png_base64`` only when present."""
        out: dict[str, Any] = {
            "approved": self.approved,
            "failure_type": self.failure_type,
            "failure_reason": self.failure_reason,
            "failed_step": self.failed_step,
            "goal": self.goal.to_dict(),
            "start_pose": self.start_pose.to_dict(),
            "final_pose": self.final_pose.to_dict(),
            "position_error_m": self.position_error_m,
            "lateral_error_m": self.lateral_error_m,
            "distance_error_m": self.distance_error_m,
            "yaw_error_deg": self.yaw_error_deg,
            "approach_heading_deg": self.approach_heading_deg,
            "collision": self.collision.to_dict() if self.collision else None,
            "stall": self.stall.to_dict() if self.stall else None,
            "tolerances": self.tolerances.to_dict(),
            "steps": [s.to_dict() for s in self.steps],
            "trajectory": self.trajectory.to_dict(),
            "sim_time_s": self.sim_time_s,
            "replay": self.replay.to_dict(),
        }
        if self.uncertainty is not None:
            out["uncertainty"] = self.uncertainty.to_dict()
        if self.image_png_base64 is not None:
            out["image_png_base64"] = self.image_png_base64
        out["wall_time_s"] = self.wall_time_s
        return out

    def to_json(self) -> str:
        """Compact JSON text of :meth:`to_dict` (what the gate sends)."""
        return json.dumps(self.to_dict(), separators=(",", ":"), allow_nan=False)

    @classmethod
    def from_dict(cls, obj: Any) -> Verdict:
        """Read the response JSON of ``POST /validate_plan`` (parsed).

        Raises:
            VerdictError: a field is missing or of the wrong type (its pointer is in the
                message and in ``pointers``).
        """
        r = _Reader(obj, "")
        traj = r.child("trajectory")
        return cls(
            approved=r.boolean("approved"),
            failure_type=r.optional("failure_type", r.string),
            failure_reason=r.string("failure_reason"),
            failed_step=r.optional("failed_step", r.integer),
            goal=r.pose("goal"),
            start_pose=r.pose("start_pose"),
            final_pose=r.pose("final_pose"),
            position_error_m=r.number("position_error_m"),
            lateral_error_m=r.number("lateral_error_m"),
            distance_error_m=r.number("distance_error_m"),
            yaw_error_deg=r.number("yaw_error_deg"),
            approach_heading_deg=r.number("approach_heading_deg"),
            collision=(
                None
                if r.obj.get("collision") is None
                else CollisionReport._read(r.child("collision"))
            ),
            stall=None if r.obj.get("stall") is None else StallReport._read(r.child("stall")),
            tolerances=Tolerances._read(r.child("tolerances")),
            steps=tuple(StepPrediction._read(s) for s in r.items("steps")),
            trajectory=Trajectory(
                traj.number("sample_period_s"),
                tuple(TrajectorySample._read(s) for s in traj.items("samples")),
            ),
            sim_time_s=r.number("sim_time_s"),
            replay=Replay._read(r.child("replay")),
            uncertainty=(
                None
                if r.obj.get("uncertainty") is None
                else Uncertainty._read(r.child("uncertainty"))
            ),
            image_png_base64=r.optional("image_png_base64", r.string),
            wall_time_s=r.number("wall_time_s") if "wall_time_s" in r.obj else 0.0,
        )

    @classmethod
    def from_json(cls, text: str | bytes) -> Verdict:
        """Parse and read verdict JSON.

        Raises:
            VerdictError: not JSON (pointer ``""``), or see :meth:`from_dict`.
        """
        try:
            obj = json.loads(text)
        except (ValueError, RecursionError) as exc:
            raise VerdictError(f"verdict: not JSON: {exc}", ("",)) from exc
        return cls.from_dict(obj)
