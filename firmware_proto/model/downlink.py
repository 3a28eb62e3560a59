"""What the rover reports about the plan it runs on board (docs/onboard.md, "Reports").

Every report is a whole snapshot of one plan's record (:class:`OnboardReport`). The rover
sends one at each event and the latest again every second, so a ground that lost some
over a lossy link still learns the end; it keeps the one with the highest ``seq``, which
counts within one ``boot`` (the sending onboard program's boot id, which the ground
signs its plans for). Times are the rover's clock (ROS time, s), as its poses' stamps.

Pure: no I/O, no clock.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from typing import Any, Final

from firmware_proto.errors import UplinkError
from firmware_proto.model.pose import Pose

__all__ = [
    "OUTCOMES",
    "STATES",
    "GuardStop",
    "OnboardReport",
    "RestReport",
    "decode_report",
]

STATES: Final = ("idle", "armed", "running", "completed", "stopped", "failed", "cancelled")
"""Where a plan is on board (``armed``: waits for the latch's release; the last four are ends)."""

OUTCOMES: Final = ("", "completed", "guard", "ground_stop", "cancelled", "failed", "blind")
"""How a plan ended: all steps done; the guard stopped it (drift); the ground's STOP; the ground
cancelled it; a step failed (its status says why); the guard had no pose. ``""``: not ended."""


def _pose(p: Pose) -> dict[str, float]:
    return {"x": p.x, "y": p.y, "yaw_deg": p.yaw_deg}


def _read_pose(obj: Any) -> Pose:
    return Pose(float(obj["x"]), float(obj["y"]), float(obj["yaw_deg"]))


@dataclass(frozen=True)
class GuardStop:
    """Where and why the guard stopped the plan.

    Attributes:
        step: the step that was running (0-based).
        stamp_s: the stamp of the estimate that confirmed the drift (rover clock, s).
        stop_s: when the guard sent STOP (rover clock, s).
        pose: the estimate then; ``predicted``: the prediction for that moment.
        linear_m, angular_deg: the drift.
        pose_age_s: how old the last POSE in the estimate was (the guard keeps guarding
            on the filter's estimate when POSE goes quiet).
    """

    step: int
    stamp_s: float
    stop_s: float
    pose: Pose
    predicted: Pose
    linear_m: float
    angular_deg: float
    pose_age_s: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        return {
            "step": self.step,
            "stamp_s": self.stamp_s,
            "stop_s": self.stop_s,
            "pose": _pose(self.pose),
            "predicted": _pose(self.predicted),
            "linear_m": self.linear_m,
            "angular_deg": self.angular_deg,
            "pose_age_s": self.pose_age_s if math.isfinite(self.pose_age_s) else None,
        }

    @classmethod
    def from_dict(cls, obj: Any) -> GuardStop:
        """Inverse of :meth:`to_dict`."""
        age = obj.get("pose_age_s")
        return cls(
            int(obj["step"]),
            float(obj["stamp_s"]),
            float(obj["stop_s"]),
            _read_pose(obj["pose"]),
            _read_pose(obj["predicted"]),
            float(obj["linear_m"]),
            float(obj["angular_deg"]),
            math.inf if age is None else float(age),
        )

    @property
    def reason(self) -> str:
        """One line, steps counted from 1."""
        return (
            f"drift in step {self.step + 1}: {self.linear_m:.3f} m, {self.angular_deg:.1f} deg "
            "off the prediction (stopped on board)"
        )


@dataclass(frozen=True)
class RestReport:
    """Where the rover came to rest after the plan ended, with the estimate's
    covariance (row-major 3x3 of x, y, yaw: m^2, m rad, rad^2).

    Attributes:
        stamp_s: when it was at rest (rover clock).
        pose, covariance: the estimate then.
        at_rest: the wheels stood still; ``False``: the rover did not settle in time
            and this is the estimate when the rover gave up waiting.
        moved_m: distance from the pose when the plan ended (the guard's detection, the
            STOP) to the pose at rest, m.
        time_to_rest_s: from then to rest, s.
    """

    stamp_s: float
    pose: Pose
    covariance: tuple[float, ...]
    at_rest: bool
    moved_m: float
    time_to_rest_s: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        return {
            "stamp_s": self.stamp_s,
            "pose": _pose(self.pose),
            "covariance": list(self.covariance),
            "at_rest": self.at_rest,
            "moved_m": self.moved_m,
            "time_to_rest_s": self.time_to_rest_s,
        }

    @classmethod
    def from_dict(cls, obj: Any) -> RestReport:
        """Inverse of :meth:`to_dict`."""
        cov = tuple(float(v) for v in obj["covariance"])
        if len(cov) != 9:
            raise ValueError("covariance: not 9 numbers")
        return cls(
            float(obj["stamp_s"]),
            _read_pose(obj["pose"]),
            cov,
            bool(obj["at_rest"]),
            float(obj["moved_m"]),
            float(obj["time_to_rest_s"]),
        )

    @property
    def sigma_xy_m(self) -> float:
        """1-sigma position error along the larger axis, m."""
        a, b, c = self.covariance[0], self.covariance[1], self.covariance[4]
        return math.sqrt(max(0.0, (a + c) / 2.0 + math.sqrt(((a - c) / 2.0) ** 2 + b * b)))

    @property
    def sigma_yaw_deg(self) -> float:
        """1-sigma heading error, degrees."""
        return math.degrees(math.sqrt(max(0.0, self.covariance[8])))


@dataclass(frozen=True)
class OnboardReport:
    """One snapshot of a plan's record on board (see the module docstring).

    Attributes:
        seq: grows with every report the rover's onboard program sends.
        event: what made this one (``accepted``, ``armed``, ``step``, ``guard_stop``,
            ``ended``, ``rest``, ``periodic``).
        t_s: when it was sent (rover clock).
        plan_id, verdict: the plan (0 and ``""``: none yet).
        state: one of :data:`STATES`.
        step, steps: the step running or last run (0-based) and how many there are.
        status: that step's last ``/command_status``.
        drift_linear_m, drift_angular_deg: the latest drift (``None`` before any).
        outcome, reason: how it ended (:data:`OUTCOMES`) and one sentence.
        guard: where the guard stopped it, if it did.
        rest: where the rover came to rest after it ended.
        extra: figures by name (the worst drift of the plan).
        boot: the boot id of the onboard program that sent it (``""``: unknown).
    """

    seq: int
    event: str
    t_s: float
    plan_id: int = 0
    verdict: str = ""
    state: str = "idle"
    step: int = 0
    steps: int = 0
    status: str = ""
    drift_linear_m: float | None = None
    drift_angular_deg: float | None = None
    outcome: str = ""
    reason: str = ""
    guard: GuardStop | None = None
    rest: RestReport | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    boot: str = ""

    @property
    def ended(self) -> bool:
        """The plan has ended (completed, stopped, failed or cancelled)."""
        return self.state in ("completed", "stopped", "failed", "cancelled")

    def with_(self, **changes: Any) -> OnboardReport:
        """A copy with ``changes``."""
        return replace(self, **changes)

    def shifted(self, offset_s: float) -> OnboardReport:
        """A copy with every time (``t_s``, the guard's and the rest's stamps) moved by
        ``offset_s``: from the sequencer's (monotonic) clock to the one reports are sent in."""
        guard = self.guard
        if guard is not None:
            guard = replace(guard, stamp_s=guard.stamp_s + offset_s, stop_s=guard.stop_s + offset_s)
        rest = self.rest
        if rest is not None:
            rest = replace(rest, stamp_s=rest.stamp_s + offset_s)
        return replace(self, t_s=self.t_s + offset_s, guard=guard, rest=rest)

    def to_json(self) -> str:
        """Compact JSON text."""
        return json.dumps(
            {
                "seq": self.seq,
                "event": self.event,
                "t_s": self.t_s,
                "plan_id": self.plan_id,
                "verdict": self.verdict,
                "state": self.state,
                "step": self.step,
                "steps": self.steps,
                "status": self.status,
                "drift_linear_m": self.drift_linear_m,
                "drift_angular_deg": self.drift_angular_deg,
                "outcome": self.outcome,
                "reason": self.reason,
                "guard": self.guard.to_dict() if self.guard else None,
                "rest": self.rest.to_dict() if self.rest else None,
                "boot": self.boot,
                **({"extra": self.extra} if self.extra else {}),
            },
            separators=(",", ":"),
            allow_nan=False,
        )

    def line(self) -> str:
        """One line for the operator."""
        text = f"plan {self.plan_id}: {self.state}"
        if self.steps:
            text += f", step {self.step + 1}/{self.steps}"
        if self.status:
            text += f" ({self.status})"
        if self.drift_linear_m is not None and self.drift_angular_deg is not None:
            text += f", drift {self.drift_linear_m:.3f} m {self.drift_angular_deg:.1f} deg"
        if self.outcome:
            text += f"; {self.outcome}: {self.reason}"
        return text


def _boot(value: Any) -> str:
    if not isinstance(value, str):
        raise TypeError("boot: not a string")
    return value


def decode_report(text: str) -> OnboardReport:
    """Read an :class:`OnboardReport` (ground side); UplinkError ``malformed`` when it is not
    one (not JSON, a field missing or mistyped, an unknown state or outcome)."""
    try:
        obj = json.loads(text)
        if not isinstance(obj, dict):
            raise TypeError("not an object")
        report = OnboardReport(
            int(obj["seq"]),
            str(obj["event"]),
            float(obj["t_s"]),
            int(obj["plan_id"]),
            str(obj["verdict"]),
            str(obj["state"]),
            int(obj["step"]),
            int(obj["steps"]),
            str(obj["status"]),
            None if obj["drift_linear_m"] is None else float(obj["drift_linear_m"]),
            None if obj["drift_angular_deg"] is None else float(obj["drift_angular_deg"]),
            str(obj["outcome"]),
            str(obj["reason"]),
            None if obj["guard"] is None else GuardStop.from_dict(obj["guard"]),
            None if obj["rest"] is None else RestReport.from_dict(obj["rest"]),
            dict(obj.get("extra") or {}),
            _boot(obj.get("boot", "")),
        )
    except (ValueError, TypeError, KeyError, RecursionError) as exc:
        raise UplinkError("malformed", f"not an onboard report: {exc}") from exc
    if report.state not in STATES or report.outcome not in OUTCOMES:
        raise UplinkError(
            "malformed", f"report: state {report.state!r}, outcome {report.outcome!r}"
        )
    return report
