"""Drift control: the rover's pose against the twin's prediction, time-aligned per step.

:class:`DriftMonitor` compares each pose (stamped at measurement) with the gate's
predicted pose at the same time into the same step (linear error m, heading error deg);
the rover started step *k* at about ``(t_pub + t_acc) / 2`` (publishing and hearing
``accepted``), the one-way delay standing in until ``accepted``. A violation over
``persistence`` consecutive samples makes :meth:`DriftMonitor.update` return a
:class:`DriftEvent` (once). Pure: no I/O, no threads; times are wall seconds,
``time_scale`` converts them to twin time. Details: docs/ground.md "Drift control".
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from firmware_proto.model.geometry import wrap_deg
from firmware_proto.model.pose import Pose
from firmware_proto.model.verdict import Verdict

__all__ = ["DriftEvent", "DriftMonitor", "DriftSample", "predicted_pose"]


def predicted_pose(verdict: Verdict, step: int, step_t_s: float) -> Pose:
    """The gate's predicted pose ``step_t_s`` seconds into ``step`` (before the plan:
    its start pose; a step without samples: its predicted end pose)."""
    if step < 0:
        return verdict.start_pose
    pose = verdict.trajectory.pose_at(step, step_t_s)
    if pose is not None:
        return pose
    if step < len(verdict.steps):
        return verdict.steps[step].end_pose
    return verdict.final_pose


@dataclass(frozen=True)
class DriftSample:
    """One comparison: when (wall clock), which step, and the errors."""

    t_s: float
    step: int
    """The plan step (0-based index) that was running."""
    linear_m: float
    angular_deg: float
    exceeded: bool


@dataclass(frozen=True)
class DriftEvent:
    """A persistent violation: the sample that confirmed it and what was compared."""

    t_s: float
    step: int
    """The plan step (0-based index) that was running."""
    linear_m: float
    angular_deg: float
    measured: Pose
    predicted: Pose
    samples_over: int

    @property
    def reason(self) -> str:
        """Human-readable cause; steps counted from 1, as the progress lines count them."""
        return (
            f"drift in step {self.step + 1}: {self.linear_m:.3f} m, {self.angular_deg:.1f} deg "
            f"off the prediction over {self.samples_over} samples"
        )


class DriftMonitor:
    """Compares reported poses with the gate's prediction, time-aligned per step."""

    def __init__(
        self,
        verdict: Verdict,
        *,
        linear_limit_m: float = 0.25,
        angular_limit_deg: float = 12.0,
        persistence: int = 3,
        one_way_delay_s: float = 1.5,
        time_scale: float = 1.0,
    ) -> None:
        """Args:
        verdict: the gate's verdict on the plan being executed (its prediction).
        linear_limit_m, angular_limit_deg: thresholds (docs/architecture.md, contract 6).
        persistence: consecutive samples over a threshold before a violation counts.
        one_way_delay_s: assumed ground-to-rover delay until a step's ``accepted`` gives
            a measurement, wall seconds.
        time_scale: twin seconds per wall second.
        """
        if linear_limit_m <= 0 or angular_limit_deg <= 0 or persistence < 1 or time_scale <= 0:
            raise ValueError("drift limits, persistence and time scale must be positive")
        self.verdict = verdict
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
    def predicted_at(self, stamp_s: float) -> tuple[int, Pose]:
        """The step in force at ``stamp_s`` and the predicted pose then."""
        step = self._step
        while step > 0 and stamp_s < self._starts.get(step, math.inf):
            step -= 1  # a pose measured before the current step started
        if step < 0:
            return -1, self.verdict.start_pose
        start = self._starts.get(step)
        if start is None or stamp_s < start:
            return step, predicted_pose(self.verdict, step, 0.0)
        return step, predicted_pose(self.verdict, step, (stamp_s - start) * self.time_scale)

    def update(self, x: float, y: float, yaw_deg: float, stamp_s: float) -> DriftEvent | None:
        """Compare one reported pose (map frame, measured at ``stamp_s``). Returns the
        :class:`DriftEvent` when this sample confirms a persistent violation (once)."""
        step, predicted = self.predicted_at(stamp_s)
        linear = math.hypot(x - predicted.x, y - predicted.y)
        angular = abs(wrap_deg(yaw_deg - predicted.yaw_deg))
        exceeded = linear > self.linear_limit_m or angular > self.angular_limit_deg
        self.history.append(DriftSample(stamp_s, step, linear, angular, exceeded))
        self._over = self._over + 1 if exceeded else 0
        if self.event is None and self._over >= self.persistence:
            self.event = DriftEvent(
                stamp_s, step, linear, angular, Pose(x, y, yaw_deg), predicted, self._over
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
