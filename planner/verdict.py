"""The gate's verdict as the planner reads it: JSON of ``POST /validate_plan`` ->
frozen dataclasses.

The planner talks to the gate over HTTP only and does not import the gate package
(DESIGN.md), so it parses the documented JSON (docs/gate.md) into its own types here.
Unknown fields are ignored (a newer gate may add some); a missing or mistyped field the
planner relies on raises :class:`~planner.errors.GateProtocolError` naming its pointer.

Units: metres in the map frame, yaw in degrees counter-clockwise from +x, times in
seconds of twin time. Errors are *goal minus predicted*: ``position_error_m`` along the
approach heading (positive: the rover stops short, an undershoot), ``lateral_error_m``
across it (positive: the goal lies to the left), ``yaw_error_deg`` wrapped to
``[-180, 180)``.

What an executor's drift monitor needs is here: :attr:`Verdict.trajectory` (poses
tagged with the step index and the time since that step started, because the executor
pauses between steps for the link's round trip) and :attr:`Verdict.steps` (each step's
end pose and expected duration).
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from firmware_proto.verdict import FAILURE_TYPES
from planner.errors import GateProtocolError
from planner.geometry import Point, Pose

__all__ = [
    "FAILURE_TYPES",
    "CollisionInfo",
    "StallInfo",
    "StepPrediction",
    "Tolerances",
    "Trajectory",
    "TrajectorySample",
    "Verdict",
]

_T = TypeVar("_T")


class _Reader:
    """Typed field access with JSON pointers in the errors."""

    def __init__(self, obj: Any, pointer: str) -> None:
        if not isinstance(obj, Mapping):
            raise GateProtocolError(f"verdict: {pointer or '/'} is not an object", [pointer])
        self.obj = obj
        self.pointer = pointer

    def _get(self, key: str) -> Any:
        if key not in self.obj:
            raise GateProtocolError(
                f"verdict: missing field {self.pointer}/{key}", [f"{self.pointer}/{key}"]
            )
        return self.obj[key]

    def _bad(self, key: str, what: str) -> GateProtocolError:
        where = f"{self.pointer}/{key}"
        return GateProtocolError(f"verdict: {where} is not {what}", [where])

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


@dataclass(frozen=True)
class TrajectorySample:
    """One predicted pose.

    Attributes:
        t_s: twin time since the plan started (steps back to back).
        step: index of the step it belongs to.
        step_t_s: time since that step started (what a drift monitor aligns on).
        pose: the predicted pose.
    """

    t_s: float
    step: int
    step_t_s: float
    pose: Pose


@dataclass(frozen=True)
class Trajectory:
    """The predicted trajectory: samples in time order, every ``sample_period_s`` of
    plan time plus one at each step's start and end (a boundary time appears twice);
    settling samples after the last step carry its index."""

    sample_period_s: float
    samples: tuple[TrajectorySample, ...]

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
        index: its position in the plan (0-based).
        command, speed, distance: the step as planned.
        start_time_s, end_time_s: plan time at its start and end.
        expected_duration_s: how long the twin took (slip included); an executor's
            per-step timeout starts from it.
        nominal_duration_s: the ideal trapezoidal profile's duration, without slip.
        start_pose, end_pose: predicted poses at its start and end.
        completed: it ran to its distance (false when a collision or a stall cut it).
        left_travel_units, right_travel_units: encoder travel per side, forward positive.
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


@dataclass(frozen=True)
class CollisionInfo:
    """The first contact of the margin-inflated footprint.

    Attributes:
        obstacle_id: the map obstacle's id, ``"bounds"`` for the walls.
        contact: the contact point on the obstacle's surface.
        pose: the rover's pose at contact.
        time_s: plan time of the contact; ``step``, ``step_t_s``: during which step and
            how far into it.
    """

    obstacle_id: str
    contact: Point
    pose: Pose
    time_s: float
    step: int
    step_t_s: float


@dataclass(frozen=True)
class StallInfo:
    """Why playback stopped for lack of progress: ``reason`` is
    ``"no_encoder_progress"`` (``side`` left/right/both) or ``"time_limit"``."""

    step: int
    reason: str
    side: str
    time_s: float


@dataclass(frozen=True)
class Tolerances:
    """What the verdict was judged against: goal distance, m; yaw, degrees; footprint
    inflation for collisions, m."""

    position_m: float
    yaw_deg: float
    safety_margin_m: float


@dataclass(frozen=True)
class Verdict:
    """The gate's answer to one plan.

    Attributes:
        approved: collision-free, made progress, and ends within tolerance.
        failure_type: ``None`` when approved, else one of :data:`FAILURE_TYPES` (or a
            newer type this planner does not know).
        failure_reason: one human-readable sentence (``""`` when approved).
        failed_step: the colliding or stalled step, or the last step for a goal or yaw
            miss; ``None`` when approved.
        goal, start_pose, final_pose: the plan's goal, where playback started, where
            the twin came to rest (or the pose at contact).
        position_error_m, lateral_error_m, distance_error_m, yaw_error_deg: see the
            module docstring; ``distance_error_m`` is the unsigned Euclidean one.
        approach_heading_deg: the heading ``position_error_m`` is measured along.
        collision, stall: details of those failures, else ``None``.
        tolerances: what it was judged against.
        steps: one prediction per step played (fewer than planned when cut short).
        trajectory: the predicted trajectory.
        sim_time_s: twin time played, settling included.
        map_name, map_sha256, rover_sha256, plan_sha256, replay_query: what reproduces
            the verdict.
        image_png_base64: the rendered top-down view when asked for, else ``None``.
        wall_time_s: how long the gate's worker took.
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
    collision: CollisionInfo | None
    stall: StallInfo | None
    tolerances: Tolerances
    steps: tuple[StepPrediction, ...]
    trajectory: Trajectory
    sim_time_s: float
    map_name: str
    map_sha256: str
    rover_sha256: str
    plan_sha256: str
    replay_query: str
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

    @classmethod
    def from_dict(cls, obj: Any) -> Verdict:
        """Parse the response JSON of ``POST /validate_plan``.

        Raises:
            GateProtocolError: a field is missing or of the wrong type (its pointer is
                in the message and in ``pointers``).
        """
        r = _Reader(obj, "")
        collision = None
        if r.obj.get("collision") is not None:
            c = r.child("collision")
            contact = c.child("contact")
            collision = CollisionInfo(
                c.string("obstacle_id"),
                (contact.number("x"), contact.number("y")),
                c.pose("pose"),
                c.number("time_s"),
                c.integer("step"),
                c.number("step_t_s"),
            )
        stall = None
        if r.obj.get("stall") is not None:
            s = r.child("stall")
            stall = StallInfo(
                s.integer("step"), s.string("reason"), s.string("side"), s.number("time_s")
            )
        t = r.child("tolerances")
        traj = r.child("trajectory")
        replay = r.child("replay")
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
            collision=collision,
            stall=stall,
            tolerances=Tolerances(
                t.number("position_m"), t.number("yaw_deg"), t.number("safety_margin_m")
            ),
            steps=tuple(_step(s) for s in r.items("steps")),
            trajectory=Trajectory(
                traj.number("sample_period_s"),
                tuple(
                    TrajectorySample(
                        s.number("t_s"),
                        s.integer("step"),
                        s.number("step_t_s"),
                        Pose(s.number("x"), s.number("y"), s.number("yaw_deg")),
                    )
                    for s in traj.items("samples")
                ),
            ),
            sim_time_s=r.number("sim_time_s"),
            map_name=replay.string("map"),
            map_sha256=replay.string("map_sha256"),
            rover_sha256=replay.string("rover_sha256"),
            plan_sha256=replay.string("plan_sha256"),
            replay_query=replay.string("query"),
            image_png_base64=r.optional("image_png_base64", r.string),
            wall_time_s=r.number("wall_time_s") if "wall_time_s" in r.obj else 0.0,
        )


def _step(s: _Reader) -> StepPrediction:
    return StepPrediction(
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
