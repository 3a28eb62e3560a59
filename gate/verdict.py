"""The gate's answer to ``POST /validate_plan``, as plain frozen dataclasses.

These mirror the JSON of the response one to one (:meth:`Verdict.to_dict` /
:meth:`Verdict.from_dict`; docs/gate.md and ``GET /openapi.json`` document the same
shape), so that a client may use them or work from the JSON alone. This module imports
nothing but the standard library.

Units: metres in the map frame (x east, y north), yaw in degrees counter-clockwise from
+x, times in seconds of twin time unless a name says ``wall``. Errors are signed and
computed as *goal minus predicted*:

- ``position_error_m``: along the goal-approach heading (the heading of the last FWD or
  REV step, reversed for REV; the start-to-goal bearing when the plan never drives).
  Positive: the rover stops short of the goal (undershoot); negative: it overshoots.
- ``lateral_error_m``: across that heading, positive when the goal lies to the left.
- ``yaw_error_deg``: goal yaw minus final yaw, wrapped to ``[-180, 180)``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from firmware_proto.verdict import FAILURE_TYPES

__all__ = [
    "FAILURE_TYPES",
    "CollisionReport",
    "Point",
    "Pose",
    "Replay",
    "StallReport",
    "StepPrediction",
    "Tolerances",
    "Trajectory",
    "TrajectorySample",
    "Verdict",
]


@dataclass(frozen=True)
class Point:
    """A point in the map frame, metres."""

    x: float
    y: float

    def to_dict(self) -> dict[str, Any]:
        """``{"x": ..., "y": ...}``."""
        return {"x": self.x, "y": self.y}

    @classmethod
    def from_dict(cls, obj: dict[str, Any]) -> Point:
        """Inverse of :meth:`to_dict`."""
        return cls(float(obj["x"]), float(obj["y"]))


@dataclass(frozen=True)
class Pose:
    """A planar pose: metres in the map frame, yaw in degrees counter-clockwise from +x
    (the same shape as a plan's ``goal``)."""

    x: float
    y: float
    yaw_deg: float

    def to_dict(self) -> dict[str, Any]:
        """``{"x": ..., "y": ..., "yaw_deg": ...}``."""
        return {"x": self.x, "y": self.y, "yaw_deg": self.yaw_deg}

    @classmethod
    def from_dict(cls, obj: dict[str, Any]) -> Pose:
        """Inverse of :meth:`to_dict`."""
        return cls(float(obj["x"]), float(obj["y"]), float(obj["yaw_deg"]))


@dataclass(frozen=True)
class TrajectorySample:
    """One predicted pose.

    Attributes:
        t_s: twin time since the plan started (steps back to back, no pauses).
        step: index of the step this sample belongs to.
        step_t_s: time since that step started: what a drift monitor aligns on, since
            the executor pauses between steps for the link's round trip.
        x, y, yaw_deg: the pose.
    """

    t_s: float
    step: int
    step_t_s: float
    x: float
    y: float
    yaw_deg: float

    def to_dict(self) -> dict[str, Any]:
        """The sample as JSON-ready data."""
        return {
            "t_s": self.t_s,
            "step": self.step,
            "step_t_s": self.step_t_s,
            "x": self.x,
            "y": self.y,
            "yaw_deg": self.yaw_deg,
        }

    @classmethod
    def from_dict(cls, obj: dict[str, Any]) -> TrajectorySample:
        """Inverse of :meth:`to_dict`."""
        return cls(
            float(obj["t_s"]),
            int(obj["step"]),
            float(obj["step_t_s"]),
            float(obj["x"]),
            float(obj["y"]),
            float(obj["yaw_deg"]),
        )


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

    @classmethod
    def from_dict(cls, obj: dict[str, Any]) -> Trajectory:
        """Inverse of :meth:`to_dict`."""
        return cls(
            float(obj["sample_period_s"]),
            tuple(TrajectorySample.from_dict(s) for s in obj["samples"]),
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
    def from_dict(cls, obj: dict[str, Any]) -> StepPrediction:
        """Inverse of :meth:`to_dict`."""
        return cls(
            index=int(obj["index"]),
            command=str(obj["command"]),
            speed=int(obj["speed"]),
            distance=int(obj["distance"]),
            start_time_s=float(obj["start_time_s"]),
            end_time_s=float(obj["end_time_s"]),
            expected_duration_s=float(obj["expected_duration_s"]),
            nominal_duration_s=float(obj["nominal_duration_s"]),
            start_pose=Pose.from_dict(obj["start_pose"]),
            end_pose=Pose.from_dict(obj["end_pose"]),
            completed=bool(obj["completed"]),
            left_travel_units=float(obj["left_travel_units"]),
            right_travel_units=float(obj["right_travel_units"]),
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
    def from_dict(cls, obj: dict[str, Any]) -> CollisionReport:
        """Inverse of :meth:`to_dict`."""
        return cls(
            str(obj["obstacle_id"]),
            Point.from_dict(obj["contact"]),
            Pose.from_dict(obj["pose"]),
            float(obj["time_s"]),
            int(obj["step"]),
            float(obj["step_t_s"]),
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
    def from_dict(cls, obj: dict[str, Any]) -> StallReport:
        """Inverse of :meth:`to_dict`."""
        return cls(int(obj["step"]), str(obj["reason"]), str(obj["side"]), float(obj["time_s"]))


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
    def from_dict(cls, obj: dict[str, Any]) -> Tolerances:
        """Inverse of :meth:`to_dict`."""
        return cls(float(obj["position_m"]), float(obj["yaw_deg"]), float(obj["safety_margin_m"]))


@dataclass(frozen=True)
class Replay:
    """Everything needed to reproduce the verdict bit for bit.

    Attributes:
        seed: seed of the playback's randomness. The gate plays without noise or
            injected faults, so it is always 0; it is recorded so that a replay states it.
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
    def from_dict(cls, obj: dict[str, Any]) -> Replay:
        """Inverse of :meth:`to_dict`."""
        return cls(
            seed=int(obj["seed"]),
            map=str(obj["map"]),
            map_sha256=str(obj["map_sha256"]),
            rover=str(obj["rover"]),
            rover_sha256=str(obj["rover_sha256"]),
            plan_sha256=str(obj["plan_sha256"]),
            start=Pose.from_dict(obj["start"]),
            dt_s=float(obj["dt_s"]),
            sample_hz=float(obj["sample_hz"]),
            render=bool(obj["render"]),
            gate_version=str(obj["gate_version"]),
            pymunk_version=str(obj["pymunk_version"]),
            query=str(obj["query"]),
        )


@dataclass(frozen=True)
class Verdict:
    """The response of ``POST /validate_plan``; see the module docstring for units and
    signs, and :data:`FAILURE_TYPES` for ``failure_type``.

    Attributes:
        approved: the plan is collision-free, made progress, and ends within tolerance.
        failure_type: ``None`` when approved, else one of :data:`FAILURE_TYPES`.
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
        image_png_base64: the rendered top-down view, when requested; else ``None``.
        wall_time_s: wall-clock time the validation took in the worker: the one field
            that differs between repeats of the same request.
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
    image_png_base64: str | None = None
    wall_time_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """The verdict as JSON-ready data, keys in documented order, ``wall_time_s``
        last; ``image_png_base64`` only when present."""
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
        if self.image_png_base64 is not None:
            out["image_png_base64"] = self.image_png_base64
        out["wall_time_s"] = self.wall_time_s
        return out

    def to_json(self) -> str:
        """Compact JSON text of :meth:`to_dict` (what the server sends)."""
        return json.dumps(self.to_dict(), separators=(",", ":"), allow_nan=False)

    @classmethod
    def from_dict(cls, obj: dict[str, Any]) -> Verdict:
        """Build a verdict from response JSON.

        Raises:
            KeyError, TypeError, ValueError: a field is missing or of the wrong type.
        """
        collision = obj["collision"]
        stall = obj["stall"]
        failed = obj["failed_step"]
        return cls(
            approved=bool(obj["approved"]),
            failure_type=None if obj["failure_type"] is None else str(obj["failure_type"]),
            failure_reason=str(obj["failure_reason"]),
            failed_step=None if failed is None else int(failed),
            goal=Pose.from_dict(obj["goal"]),
            start_pose=Pose.from_dict(obj["start_pose"]),
            final_pose=Pose.from_dict(obj["final_pose"]),
            position_error_m=float(obj["position_error_m"]),
            lateral_error_m=float(obj["lateral_error_m"]),
            distance_error_m=float(obj["distance_error_m"]),
            yaw_error_deg=float(obj["yaw_error_deg"]),
            approach_heading_deg=float(obj["approach_heading_deg"]),
            collision=None if collision is None else CollisionReport.from_dict(collision),
            stall=None if stall is None else StallReport.from_dict(stall),
            tolerances=Tolerances.from_dict(obj["tolerances"]),
            steps=tuple(StepPrediction.from_dict(s) for s in obj["steps"]),
            trajectory=Trajectory.from_dict(obj["trajectory"]),
            sim_time_s=float(obj["sim_time_s"]),
            replay=Replay.from_dict(obj["replay"]),
            image_png_base64=obj.get("image_png_base64"),
            wall_time_s=float(obj["wall_time_s"]),
        )
