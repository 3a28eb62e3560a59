"""The gate's answer to ``POST /validate_plan`` as frozen dataclasses: the one definition
the gate (which builds verdicts) and the planner (which reads them over HTTP and may not
import the gate) share.

They mirror the JSON one to one through one codec (:mod:`firmware_proto.model.jsoncodec`);
each field's ``spec`` is its meaning in the generated schema (:func:`verdict_schemas`,
the gate's ``GET /openapi.json``). Reading is strict about what it uses (a missing or
mistyped field raises :class:`~firmware_proto.errors.VerdictError` naming its JSON
pointer) and ignores fields it does not know. Pure: standard library only.

Units: metres in the map frame (x east, y north), yaw in degrees counter-clockwise from
+x, seconds of twin time unless a name says ``wall``. Errors are *goal minus predicted*:

- ``position_error_m``: along the goal-approach heading (of the last FWD or REV step,
  reversed for REV; the start-to-goal bearing when the plan never drives); positive:
  undershoot.
- ``lateral_error_m``: across that heading, positive when the goal lies to the left.
- ``yaw_error_deg``: goal yaw minus final yaw, wrapped to ``[-180, 180)``.
"""

from __future__ import annotations

import bisect
import json
from dataclasses import dataclass, field
from typing import Any, Final

from firmware_proto.errors import VerdictError
from firmware_proto.model.jsoncodec import JsonCodec, spec
from firmware_proto.model.plan import COMMAND_NAMES, MAX_PLAN_STEPS
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
    "verdict_schemas",
]

FAILURE_TYPES: Final = (
    "collision",
    "start_in_collision",
    "stalled",
    "goal_not_reached",
    "yaw_not_reached",
)
"""Values of a verdict's ``failure_type`` when a plan is rejected, in order of precedence
(docs/gate.md, ``POST /validate_plan``): ``collision`` (the margin-inflated footprint touched
something; ``collision`` says what), ``start_in_collision`` (the start pose already does: re-plan,
do not repair), ``stalled`` (a side made no progress or a step overran; ``stall`` says which),
``goal_not_reached`` (the final position is beyond the tolerance), ``yaw_not_reached`` (the
position is within it, the yaw is not)."""

_STEP: Final = {"minimum": 0, "maximum": MAX_PLAN_STEPS - 1}
_SHA: Final = {"pattern": "^[0-9a-f]{64}$"}
_PROBABILITY: Final = {"minimum": 0, "maximum": 1}
_CODEC: Final = JsonCodec(VerdictError, "verdict")


@dataclass(frozen=True)
class TrajectorySample:
    """One predicted pose (the pose's fields inline in the JSON)."""

    t_s: float = field(metadata=spec("Plan time (steps back to back, no pauses), s."))
    step: int = field(metadata=spec("The step this sample belongs to.", schema=_STEP))
    step_t_s: float = field(
        metadata=spec(
            "Time since that step started, s: what a drift monitor aligns on, since the "
            "executor pauses between steps for the link's round trip."
        )
    )
    pose: Pose = field(metadata=spec(inline=True))


@dataclass(frozen=True)
class Trajectory:
    """The predicted trajectory, in time order.

    Each step has a sample at its start (``step_t_s == 0``), the fixed-rate grid's samples
    inside it, and one at its end (a boundary time appears twice); after the last step,
    settling samples carry its index with ``step_t_s`` beyond its duration.
    """

    sample_period_s: float = field(
        metadata=spec(
            "The period used, s: 1/sample_hz rounded to whole twin steps, or longer when "
            "the plan could otherwise give more fixed-rate samples than the gate's bound "
            "(see the sample_hz parameter)."
        )
    )
    samples: tuple[TrajectorySample, ...] = field(
        metadata=spec("Fixed-rate samples, plus each step's start and end and the final pose.")
    )

    def for_step(self, step: int) -> tuple[TrajectorySample, ...]:
        """The samples of one step, in time order."""
        return tuple(s for s in self.samples if s.step == step)

    def pose_at(self, step: int, step_t_s: float) -> Pose | None:
        """The predicted pose ``step_t_s`` into ``step``, interpolated between its samples (yaw
        along the shorter arc; held at the ends); ``None`` when the step has no samples."""
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
    """What the twin predicts for one step."""

    index: int = field(metadata=spec("The step's position in the plan.", schema=_STEP))
    command: str = field(metadata=spec(schema={"enum": list(COMMAND_NAMES.values())}))
    speed: int
    distance: int
    start_time_s: float = field(metadata=spec("Plan time at the step's start, s."))
    end_time_s: float = field(metadata=spec("Plan time at its end, s."))
    expected_duration_s: float = field(
        metadata=spec(
            "end - start: how long the twin took, slip included, s; an executor's step "
            "timeout starts from it."
        )
    )
    nominal_duration_s: float = field(
        metadata=spec("The step's ideal trapezoidal speed profile without slip, s.")
    )
    start_pose: Pose
    end_pose: Pose
    completed: bool = field(
        metadata=spec("It ran to its distance (false when a collision or stall cut it).")
    )
    left_travel_units: float = field(
        metadata=spec("Encoder travel of the left side, distance units, forward positive.")
    )
    right_travel_units: float = field(metadata=spec("The same of the right side."))

    @property
    def yaw_change_deg(self) -> float:
        """Predicted yaw change over the step, degrees, wrapped to ``[-180, 180)``."""
        return (self.end_pose.yaw_deg - self.start_pose.yaw_deg + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class CollisionReport:
    """The first contact of the margin-inflated footprint."""

    obstacle_id: str = field(metadata=spec('The map obstacle\'s id, or "bounds" for the walls.'))
    contact: Point = field(metadata=spec("Contact point on the obstacle's surface."))
    pose: Pose = field(metadata=spec("The rover's pose at contact."))
    time_s: float = field(metadata=spec("Plan time of the contact, s."))
    step: int = field(metadata=spec("The step during which it happened.", schema=_STEP))
    step_t_s: float = field(metadata=spec("Time since that step started, s."))


@dataclass(frozen=True)
class StallReport:
    """Why playback stopped for lack of progress."""

    step: int = field(metadata=spec("The step that stalled.", schema=_STEP))
    reason: str = field(metadata=spec(schema={"enum": ["no_encoder_progress", "time_limit"]}))
    side: str = field(
        metadata=spec(
            "The side without progress; empty for time_limit.",
            schema={"enum": ["left", "right", "both", ""]},
        )
    )
    time_s: float = field(metadata=spec("Plan time of the detection, s."))


@dataclass(frozen=True)
class Tolerances:
    """What the verdict was judged against."""

    position_m: float = field(metadata=spec("Accepted distance from the goal, m."))
    yaw_deg: float = field(metadata=spec("Accepted yaw error, degrees."))
    safety_margin_m: float = field(metadata=spec("Footprint inflation for collisions, m."))


@dataclass(frozen=True)
class Replay:
    """Everything needed to reproduce the verdict bit for bit."""

    seed: int = field(
        metadata=spec(
            "Seed of the draws of a verdict played on several twins (the request's seed); "
            "0 for a single playback, which has no randomness."
        )
    )
    map: str = field(metadata=spec("Map name."))
    map_sha256: str = field(metadata=spec("SHA-256 of the map's canonical content.", schema=_SHA))
    rover: str = field(metadata=spec("Rover description name."))
    rover_sha256: str = field(metadata=spec("SHA-256 of its values.", schema=_SHA))
    plan_sha256: str = field(
        metadata=spec("SHA-256 of the plan's canonical JSON (sorted keys, no spaces).", schema=_SHA)
    )
    start: Pose = field(metadata=spec("The start pose used."))
    dt_s: float = field(metadata=spec("The twin's fixed physics step, s."))
    sample_hz: float = field(
        metadata=spec(
            "Requested trajectory rate, Hz (the period used is trajectory.sample_period_s)."
        )
    )
    render: bool = field(metadata=spec("Whether a picture was requested."))
    gate_version: str
    pymunk_version: str
    query: str = field(
        metadata=spec("The query string that reproduces these options on /validate_plan.")
    )


@dataclass(frozen=True)
class ObstacleHits:
    """The samples of an uncertain verdict that hit one obstacle."""

    obstacle_id: str = field(metadata=spec('The obstacle ("bounds" for the walls).'))
    count: int = field(metadata=spec("How many samples touched it first.", schema={"minimum": 1}))
    step: int = field(
        metadata=spec(
            "The step during which most of them did (the earliest on a tie).", schema=_STEP
        )
    )
    contact: Point = field(metadata=spec("Mean contact point of the hits during that step, m."))


@dataclass(frozen=True)
class GoalErrorPercentiles:
    """Percentiles of the goal errors over the samples that played to the end (no
    collision, no stall); each list has one value per entry of ``percentiles``, of the
    verdict's error of that name (same signs)."""

    samples: int = field(
        metadata=spec(
            "Samples that played to the end (0: every one collided or stalled, and the "
            "lists are empty)."
        )
    )
    percentiles: tuple[float, ...] = field(metadata=spec("Which percentiles, in percent."))
    distance_m: tuple[float, ...]
    position_m: tuple[float, ...]
    lateral_m: tuple[float, ...]
    yaw_deg: tuple[float, ...]


@dataclass(frozen=True)
class EnvelopePoint:
    """Where the samples still playing are at one moment of one step."""

    step: int = field(metadata=spec(schema=_STEP))
    step_t_s: float
    samples: int = field(metadata=spec("Samples still playing at that moment."))
    pose: Pose = field(
        metadata=spec(inline={"x": {"description": "Mean position and (circular) mean yaw."}})
    )
    major_m: float = field(
        metadata=spec(
            "Semi-axes of the ellipse that holds the positions at the envelope's level "
            "under a normal fit, m.",
            schema={"minimum": 0},
        )
    )
    minor_m: float = field(metadata=spec(schema={"minimum": 0}))
    angle_deg: float = field(metadata=spec("Major axis, degrees counter-clockwise from +x."))
    yaw_sd_deg: float = field(
        metadata=spec(
            "Standard deviation of the yaw about the mean, degrees.", schema={"minimum": 0}
        )
    )


@dataclass(frozen=True)
class Uncertainty:
    """A plan played on ``samples`` twins drawn from the twin's parameter uncertainty
    and a slip distribution (docs/gate.md, "Verdicts with their uncertainty")."""

    samples: int = field(metadata=spec("How many twins.", schema={"minimum": 2}))
    seed: int = field(metadata=spec("The seed of the draws (same request, same answer)."))
    spread: str = field(
        metadata=spec(
            "The calibrated twin's covariance, or the gate's documented default spread.",
            schema={"enum": ["calibration", "default"]},
        )
    )
    slip_sigma: float = field(metadata=spec("1-sigma of each side's friction factor (log-normal)."))
    collision_probability: float = field(
        metadata=spec(
            "Share of samples whose footprint touched something (start included).",
            schema=_PROBABILITY,
        )
    )
    stall_probability: float = field(metadata=spec("Share that stalled.", schema=_PROBABILITY))
    approved_probability: float = field(
        metadata=spec("Share that the verdict's tolerances approve.", schema=_PROBABILITY)
    )
    collisions: tuple[ObstacleHits, ...] = field(metadata=spec("Per obstacle hit, most first."))
    goal_error: GoalErrorPercentiles
    level: float = field(metadata=spec("The probability the envelope's ellipses hold."))
    envelope: tuple[EnvelopePoint, ...] = field(
        metadata=spec(
            "Per step, the samples' spread at moments of it (each step's end among them), "
            "in time order."
        )
    )

    def for_step(self, step: int) -> tuple[EnvelopePoint, ...]:
        """The envelope points of one step, in time order."""
        return tuple(p for p in self.envelope if p.step == step)


@dataclass(frozen=True)
class Verdict:
    """The response of ``POST /validate_plan``; see the module docstring for units and
    signs, and :data:`FAILURE_TYPES` for ``failure_type``. Each field's meaning is its
    ``spec``, the ``description`` of the gate's OpenAPI schema."""

    approved: bool = field(
        metadata=spec(
            "Collision free, made progress, and ends within both tolerances (judged on "
            "the nominal twin, also with uncertainty)."
        )
    )
    failure_type: str | None = field(
        metadata=spec(
            "null when approved, else one of FAILURE_TYPES, in order of precedence (a "
            "newer gate may add types).",
            schema={"enum": list(FAILURE_TYPES)},
        )
    )
    failure_reason: str = field(metadata=spec('One sentence for people ("" when approved).'))
    failed_step: int | None = field(
        metadata=spec(
            "The colliding or stalled step; the last step for goal_not_reached and "
            "yaw_not_reached; 0 for start_in_collision; null when approved.",
            schema=_STEP,
        )
    )
    goal: Pose = field(metadata=spec("The plan's goal."))
    start_pose: Pose = field(metadata=spec("Where playback started."))
    final_pose: Pose = field(
        metadata=spec(
            "Where the twin came to rest (wheels stopped, up to 1 s of settling), or the "
            "pose at the first contact."
        )
    )
    position_error_m: float = field(
        metadata=spec(
            "Signed, goal minus final, along the approach heading: > 0 the rover stops "
            "short of the goal (undershoot), < 0 it goes past it (overshoot)."
        )
    )
    lateral_error_m: float = field(
        metadata=spec("Signed, across the approach heading: > 0 the goal lies to the left.")
    )
    distance_error_m: float = field(
        metadata=spec(
            "Euclidean distance to the goal (what pos_tol_m is compared with).",
            schema={"minimum": 0},
        )
    )
    yaw_error_deg: float = field(
        metadata=spec(
            "Goal yaw minus final yaw, wrapped to [-180, 180): > 0 turn further left.",
            schema={"minimum": -180, "exclusiveMaximum": 180},
        )
    )
    approach_heading_deg: float = field(
        metadata=spec(
            "The heading of the last FWD step (REV: reversed) as it started; the "
            "start-to-goal bearing when the plan never drives."
        )
    )
    collision: CollisionReport | None
    stall: StallReport | None
    tolerances: Tolerances
    steps: tuple[StepPrediction, ...] = field(
        metadata=spec("One prediction per step played (fewer than planned when cut short).")
    )
    trajectory: Trajectory
    sim_time_s: float = field(metadata=spec("Twin time played, settling included, s."))
    replay: Replay
    uncertainty: Uncertainty | None = field(
        default=None,
        metadata=spec("Only when the request asked for samples > 1.", omit_none=True),
    )
    image_png_base64: str | None = field(
        default=None,
        metadata=spec(
            "Only with render=1: a PNG of the map, the plan and the prediction.",
            schema={"contentEncoding": "base64"},
            omit_none=True,
        ),
    )
    wall_time_s: float = field(
        default=0.0,
        metadata=spec(
            "Wall-clock time the validation took in its worker, s: the one field that "
            "differs between repeats of the same request."
        ),
    )

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
        """The verdict as JSON-ready data, keys in field order, ``wall_time_s`` last;
        ``uncertainty`` and ``image_png_base64`` only when present."""
        return _CODEC.encode(self)

    def to_json(self) -> str:
        """Compact JSON text of :meth:`to_dict` (what the gate sends)."""
        return json.dumps(_CODEC.encode(self), separators=(",", ":"), allow_nan=False)

    @classmethod
    def from_dict(cls, obj: Any) -> Verdict:
        """Read the parsed response JSON of ``POST /validate_plan``; VerdictError when a field
        is missing or mistyped (its pointer in the message and in ``pointers``)."""
        verdict: Verdict = _CODEC.decode(cls, obj)
        return verdict

    @classmethod
    def from_json(cls, text: str | bytes) -> Verdict:
        """Parse and read verdict JSON; VerdictError as :meth:`from_dict`, or not JSON (``""``)."""
        try:
            obj = json.loads(text)
        except (ValueError, RecursionError) as exc:
            raise VerdictError(f"verdict: not JSON: {exc}", ("",)) from exc
        return cls.from_dict(obj)


def verdict_schemas(ref: str = "#/components/schemas/") -> dict[str, Any]:
    """The JSON Schema (2020-12) of :class:`Verdict` and of every class it holds, by
    class name, generated from the dataclasses (what the gate's OpenAPI document
    serves); references point at ``ref + name``."""
    return _CODEC.schemas(Verdict, ref=ref)
