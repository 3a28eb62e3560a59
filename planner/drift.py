"""Drift control: the rover's pose against the twin's prediction, time-aligned per step.

The gate predicts, for every step of an approved plan, where the rover will be at each
moment since that step started (``trajectory.samples`` with ``step`` and ``step_t_s``).
The executor runs steps with pauses between them (each one waits a link round trip for
``completed``), so the prediction is aligned on each step's own start, not on one clock.

When did the rover start step *k*? The executor publishes it at ``t_pub`` and hears
``accepted`` back at ``t_acc``; the bridge accepts as soon as it sees the step, so the
rover started at about ``(t_pub + t_acc) / 2`` (one one-way delay after publishing). Until
``accepted`` arrives the configured one-way delay stands in. Pose stamps are the time the
pose was measured (the bridge subtracts the sensor's latency), on the same clock.

:class:`DriftMonitor` compares each pose with the predicted pose at the same step time:
linear error (metres) and heading error (degrees). Only a violation that persists over
``persistence`` consecutive samples counts (one noisy fix does not stop the rover);
then :meth:`DriftMonitor.update` returns a :class:`DriftEvent` (once). Pure: no I/O, no
threads; times are seconds on the wall clock, ``time_scale`` converts them to twin time
when the rover runs faster than real time.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = [
    "DriftEvent",
    "DriftMonitor",
    "DriftSample",
    "PoseXY",
    "ReferenceTrajectory",
    "angle_diff_deg",
]


def angle_diff_deg(a_deg: float, b_deg: float) -> float:
    """``a - b`` wrapped to [-180, 180)."""
    return (a_deg - b_deg + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class PoseXY:
    """A planar pose in the map frame: metres and degrees (counter-clockwise from +x)."""

    x: float
    y: float
    yaw_deg: float


@dataclass(frozen=True)
class _Sample:
    step_t_s: float
    pose: PoseXY


class ReferenceTrajectory:
    """The predicted poses of each step of a plan, by time since that step started."""

    def __init__(
        self,
        steps: Mapping[int, Sequence[tuple[float, PoseXY]]],
        durations_s: Mapping[int, float],
        end_poses: Mapping[int, PoseXY],
        start_pose: PoseXY,
    ) -> None:
        """Args:
        steps: per step index, ``(step_t_s, pose)`` samples in time order.
        durations_s: expected duration of each step, twin seconds.
        end_poses: each step's predicted end pose.
        start_pose: the plan's start pose.
        """
        self._steps = {k: [_Sample(t, p) for t, p in v] for k, v in steps.items()}
        self._times = {k: [s.step_t_s for s in v] for k, v in self._steps.items()}
        self.durations_s = dict(durations_s)
        self.end_poses = dict(end_poses)
        self.start_pose = start_pose

    @property
    def step_count(self) -> int:
        """Number of steps predicted."""
        return len(self.durations_s)

    @classmethod
    def from_verdict(cls, verdict: Mapping[str, Any]) -> ReferenceTrajectory:
        """Build from a gate verdict's JSON (``trajectory.samples`` and ``steps``).

        Raises:
            ValueError: the verdict carries no trajectory.
        """
        trajectory = verdict.get("trajectory") or {}
        raw_samples = trajectory.get("samples") or []
        raw_steps = verdict.get("steps") or []
        if not raw_steps:
            raise ValueError("the verdict has no predicted steps")
        steps: dict[int, list[tuple[float, PoseXY]]] = {}
        for s in raw_samples:
            steps.setdefault(int(s["step"]), []).append(
                (float(s["step_t_s"]), PoseXY(float(s["x"]), float(s["y"]), float(s["yaw_deg"])))
            )
        durations = {int(s["index"]): float(s["expected_duration_s"]) for s in raw_steps}
        ends = {int(s["index"]): _pose(s["end_pose"]) for s in raw_steps}
        start = _pose(raw_steps[0]["start_pose"])
        return cls(steps, durations, ends, start)

    def pose_at(self, step: int, step_t_s: float) -> PoseXY:
        """Predicted pose ``step_t_s`` seconds after ``step`` started (interpolated;
        before the start: the previous step's end; after its end: its end pose)."""
        samples = self._steps.get(step)
        if step_t_s <= 0.0 or not samples:
            if step <= 0:
                return self.start_pose
            return self.end_poses.get(step - 1, self.start_pose)
        times = self._times[step]
        i = bisect.bisect_right(times, step_t_s)
        if i >= len(samples):
            return self.end_poses.get(step, samples[-1].pose)
        a, b = samples[i - 1], samples[i]
        span = b.step_t_s - a.step_t_s
        f = 0.0 if span <= 0 else (step_t_s - a.step_t_s) / span
        yaw = a.pose.yaw_deg + f * angle_diff_deg(b.pose.yaw_deg, a.pose.yaw_deg)
        return PoseXY(
            a.pose.x + f * (b.pose.x - a.pose.x),
            a.pose.y + f * (b.pose.y - a.pose.y),
            angle_diff_deg(yaw, 0.0),
        )


def _pose(obj: Mapping[str, Any]) -> PoseXY:
    return PoseXY(float(obj["x"]), float(obj["y"]), float(obj["yaw_deg"]))


@dataclass(frozen=True)
class DriftSample:
    """One comparison: when (wall clock), which step, and the errors."""

    t_s: float
    step: int
    linear_m: float
    angular_deg: float
    exceeded: bool


@dataclass(frozen=True)
class DriftEvent:
    """A persistent violation: the sample that confirmed it and what was compared."""

    t_s: float
    step: int
    linear_m: float
    angular_deg: float
    measured: PoseXY
    predicted: PoseXY
    samples_over: int

    @property
    def reason(self) -> str:
        """Human-readable cause."""
        return (
            f"drift at step {self.step}: {self.linear_m:.3f} m, {self.angular_deg:.1f} deg "
            f"off the prediction over {self.samples_over} samples"
        )


class DriftMonitor:
    """Compares reported poses with a :class:`ReferenceTrajectory`; see the module doc."""

    def __init__(
        self,
        reference: ReferenceTrajectory,
        *,
        linear_limit_m: float = 0.25,
        angular_limit_deg: float = 12.0,
        persistence: int = 3,
        one_way_delay_s: float = 1.5,
        time_scale: float = 1.0,
    ) -> None:
        """Args:
        reference: the gate's prediction for the plan being executed.
        linear_limit_m, angular_limit_deg: thresholds (DESIGN.md contract 6).
        persistence: consecutive samples over a threshold before a violation counts.
        one_way_delay_s: assumed ground-to-rover delay until a step's ``accepted`` gives
            a measurement, wall seconds.
        time_scale: twin seconds per wall second.
        """
        if linear_limit_m <= 0 or angular_limit_deg <= 0 or persistence < 1 or time_scale <= 0:
            raise ValueError("drift limits, persistence and time scale must be positive")
        self.reference = reference
        self.linear_limit_m = linear_limit_m
        self.angular_limit_deg = angular_limit_deg
        self.persistence = persistence
        self.one_way_delay_s = one_way_delay_s
        self.time_scale = time_scale
        self.history: list[DriftSample] = []
        self.event: DriftEvent | None = None
        self._step = -1
        self._step_start: float | None = None
        self._over = 0
        self._starts: dict[int, float] = {}

    # -- the executor tells where the plan is ---------------------------------------------
    def step_published(self, step: int, t_pub: float) -> None:
        """Step ``step`` was published at ``t_pub`` (wall clock)."""
        self._step = step
        self._starts[step] = t_pub + self.one_way_delay_s
        self._step_start = self._starts[step]

    def step_accepted(self, step: int, t_pub: float, t_acc: float) -> None:
        """The rover acknowledged it: its start is halfway through the round trip."""
        if step in self._starts:
            self._starts[step] = (t_pub + t_acc) / 2.0
            if step == self._step:
                self._step_start = self._starts[step]

    # -- poses ----------------------------------------------------------------------------
    def predicted_at(self, stamp_s: float) -> tuple[int, PoseXY]:
        """The step in force at ``stamp_s`` and the predicted pose then."""
        step = self._step
        while step > 0 and stamp_s < self._starts.get(step, math.inf):
            step -= 1  # a pose measured before the current step started
        if step < 0:
            return -1, self.reference.start_pose
        start = self._starts.get(step)
        if start is None or stamp_s < start:
            return step, self.reference.pose_at(step, 0.0)
        return step, self.reference.pose_at(step, (stamp_s - start) * self.time_scale)

    def update(self, x: float, y: float, yaw_deg: float, stamp_s: float) -> DriftEvent | None:
        """Compare one reported pose (map frame, measured at ``stamp_s``). Returns the
        :class:`DriftEvent` when this sample confirms a persistent violation (once)."""
        step, predicted = self.predicted_at(stamp_s)
        linear = math.hypot(x - predicted.x, y - predicted.y)
        angular = abs(angle_diff_deg(yaw_deg, predicted.yaw_deg))
        exceeded = linear > self.linear_limit_m or angular > self.angular_limit_deg
        self.history.append(DriftSample(stamp_s, step, linear, angular, exceeded))
        self._over = self._over + 1 if exceeded else 0
        if self.event is None and self._over >= self.persistence:
            self.event = DriftEvent(
                stamp_s, step, linear, angular, PoseXY(x, y, yaw_deg), predicted, self._over
            )
            return self.event
        return None

    @property
    def worst(self) -> tuple[float, float]:
        """Largest linear (m) and angular (deg) errors seen."""
        if not self.history:
            return 0.0, 0.0
        return max(s.linear_m for s in self.history), max(s.angular_deg for s in self.history)

    @staticmethod
    def samples_of(history: Iterable[DriftSample]) -> list[tuple[float, float, float]]:
        """``(t, linear, angular)`` triples, for plots and reports."""
        return [(s.t_s, s.linear_m, s.angular_deg) for s in history]
