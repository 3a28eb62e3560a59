"""What each recorded step did, measured at rest before and after it.

Calibration compares each step replayed on the twin with what the rover did. The
comparison is made where the measurements are best and the clock does not matter: at
rest. The executor waits for ``completed`` to cross the link before it sends the next
step, so the rover rests a round trip between steps; over such a rest:

- the POSE samples (the ground-seeing sensor, about 1 cm of noise each) are averaged:
  the rover's pose before and after the step, to a few millimetres;
- the odometry's yaw (the gyro, integrated by the bridge) barely moves, and its change
  from the rest before to the rest after is the step's yaw change, to a small fraction of
  a degree, independent of the POSE's noise; its error is the two rests' and the gyro's
  random walk between them, whose rate the rests measure (the integrated yaw wanders
  at rest as it does moving);
- the odometry's position (the encoders) must have moved by the step's distance: the
  check that the boundaries found are a whole step (a step whose encoders disagree is
  skipped, never fitted).

The rests are found from the statuses: a step moves from its ``accepted`` to its end
status, both mapped onto the rover's clock by the recording's downlink delay; a rest is
what lies between two steps, less :data:`SETTLE_S` after the end (the body coming to
rest) and :data:`START_GUARD_S` before the next start. Guards are in mission seconds;
``speed_factor`` converts them to the recording's (wall) seconds for a run made faster
than real time (``rover demo --speed``).

Steps that cannot be measured so are skipped with the reason (``ObservedSteps.skipped``):
not completed; a STOP sent by the ground while it ran or within a round trip after it
ended (drift control saw it go wrong: a fault injected, say, not the ground); no rest
before or after (steps sent back to back); a rest that is not at rest (the POSE moves);
encoders that disagree.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from emulator.recording import FloatArray, Recording
from emulator.twin import Pose2D
from firmware_proto.model.geometry import wrap_rad
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import Command

__all__ = [
    "MAX_REST_S",
    "MIN_REST_SAMPLES",
    "SETTLE_S",
    "START_GUARD_S",
    "ObservedSteps",
    "StepObservation",
    "observe_steps",
]

logger = logging.getLogger(__name__)

SETTLE_S = 0.5
"""After a step's end status, mission seconds before the rover counts as at rest."""
START_GUARD_S = 0.05
"""Before a step's ``accepted``, mission seconds kept out of the rest before it."""
MAX_REST_S = 2.5
"""At most this much of a rest (mission seconds, nearest the step) is averaged."""
MIN_REST_SAMPLES = 3
"""POSE samples a rest needs to count."""
POSITION_SIGMA_FLOOR_M = 0.002
"""Smallest 1-sigma error taken for an averaged position (the sensor's own bias, the
twin's step size)."""
HEADING_SIGMA_FLOOR_RAD = 0.0005
"""Smallest 1-sigma error taken for a heading averaged at rest (the POSE's yaw): about
0.03 degree."""
YAW_SIGMA_FLOOR_RAD = 0.0003
"""Smallest 1-sigma error taken for a measured yaw change: about 0.02 degree (a gyro
quantised to 1 mrad/s; the noise itself is measured at rest, its random walk)."""
ENCODER_TOLERANCE = 0.01
"""Relative disagreement of the encoders' travel with a straight step's distance (plus
5 mm) beyond which the step is skipped."""


@dataclass(frozen=True)
class StepObservation:
    """One completed step measured at rest before and after it.

    Attributes:
        source: the recording it comes from.
        index: the step's index in that recording.
        command, speed, distance: the step.
        start, end: the rover's pose (POSE averaged) at rest before and after, map frame.
        yaw_change_rad: body yaw change over the step (the gyro's; the POSE's when the
            recording has no odometry), unwrapped.
        sigma_xy_m: 1-sigma error of the measured displacement, per axis, m.
        sigma_yaw_rad: 1-sigma error of ``yaw_change_rad``.
        sigma_heading_rad: 1-sigma error of the start pose's yaw (the POSE averaged at
            rest), which turns the measured displacement's frame (:meth:`covariance`).
    """

    source: str
    index: int
    command: int
    speed: int
    distance: int
    start: Pose2D
    end: Pose2D
    yaw_change_rad: float
    sigma_xy_m: float
    sigma_yaw_rad: float
    sigma_heading_rad: float = 0.0

    @property
    def step(self) -> tuple[int, int, int]:
        """``(command, speed, distance)``."""
        return (self.command, self.speed, self.distance)

    def displacement(self) -> tuple[float, float, float]:
        """``(forward_m, left_m, yaw_rad)``: the move in the frame of the start pose."""
        dx = self.end.x_m - self.start.x_m
        dy = self.end.y_m - self.start.y_m
        c, s = math.cos(self.start.yaw_rad), math.sin(self.start.yaw_rad)
        return (c * dx + s * dy, -s * dx + c * dy, self.yaw_change_rad)

    def covariance(self) -> np.ndarray:
        """The ``3 x 3`` covariance of :meth:`displacement`'s errors: the positions'
        (per axis), the yaw change's, and the start heading's, which turns a move of
        ``(f, l)`` by ``(l, -f)`` per radian."""
        f, left, _ = self.displacement()
        turn = np.array([left, -f, 0.0])
        cov = np.diag([self.sigma_xy_m**2, self.sigma_xy_m**2, self.sigma_yaw_rad**2])
        return cov + self.sigma_heading_rad**2 * np.outer(turn, turn)


@dataclass(frozen=True)
class ObservedSteps:
    """The steps of recordings that can be measured, and those skipped with why."""

    observations: tuple[StepObservation, ...]
    skipped: tuple[tuple[str, int, str], ...]
    """``(source, step index, reason)``."""
    driving_s: float
    """Nominal duration of the observed steps, mission seconds."""


@dataclass(frozen=True)
class _Rest:
    x: float
    y: float
    yaw: float
    sigma: float
    yaw_sigma: float
    odom_xy: tuple[float, float] | None
    odom_yaw: float | None
    odom_sigma: float
    odom_t: float = 0.0
    """Mean time of the odometry samples averaged (rover clock)."""
    odom_walk: float = 0.0
    """How fast the gyro-integrated yaw wanders at rest, rad^2/s (its random walk)."""


def _window(t: FloatArray, lo: float, hi: float) -> tuple[int, int]:
    return int(np.searchsorted(t, lo, "left")), int(np.searchsorted(t, hi, "right"))


def _rest(
    rec: Recording, yaw_unwrapped: FloatArray, odom_yaw: FloatArray, lo: float, hi: float
) -> _Rest | str:
    """The averages of a rest in ``[lo, hi]`` (rover clock), or why there is none."""
    if hi - lo <= 0.0:
        return "no rest (steps back to back)"
    i, j = _window(rec.pose_t_s, lo, hi)
    n = j - i
    if n < MIN_REST_SAMPLES:
        return f"{n} POSE sample(s) at rest, need {MIN_REST_SAMPLES}"
    xy = rec.pose_xy_m[i:j]
    sigma = float(np.mean(rec.pose_sigma_m[i:j]))
    spread = float(np.max(np.std(xy, axis=0)))
    if spread > 3.0 * sigma + 0.01:
        return f"not at rest (POSE spread {spread * 1000:.0f} mm)"
    yaw = float(np.mean(yaw_unwrapped[i:j]))
    yaw_sigma = float(np.std(yaw_unwrapped[i:j], ddof=1)) / math.sqrt(n)
    odom_xy: tuple[float, float] | None = None
    odom_mean: float | None = None
    odom_sigma = 0.0
    odom_t = 0.0
    walk = 0.0
    k, m = _window(rec.odom_t_s, lo, hi)
    if m - k >= MIN_REST_SAMPLES:
        mean_xy = np.mean(rec.odom_xy_m[k:m], axis=0)
        odom_xy = (float(mean_xy[0]), float(mean_xy[1]))
        odom_mean = float(np.mean(odom_yaw[k:m]))
        odom_sigma = float(np.std(odom_yaw[k:m])) / math.sqrt(m - k)
        odom_t = float(np.mean(rec.odom_t_s[k:m]))
        gaps = np.diff(rec.odom_t_s[k:m])
        if len(gaps) and float(np.median(gaps)) > 0.0:
            walk = float(np.var(np.diff(odom_yaw[k:m]))) / float(np.median(gaps))
    return _Rest(
        float(np.mean(xy[:, 0])),
        float(np.mean(xy[:, 1])),
        yaw,
        sigma / math.sqrt(n),
        max(HEADING_SIGMA_FLOOR_RAD, yaw_sigma),
        odom_xy,
        odom_mean,
        odom_sigma,
        odom_t,
        walk,
    )


def observe_steps(
    recordings: list[Recording], rover: RoverDescription, *, speed_factor: float = 1.0
) -> ObservedSteps:
    """Measure every completed step of ``recordings`` at rest (module docstring).

    Args:
        recordings: read with :func:`emulator.recording.read_recording`.
        rover: the rover description (units, the nominal step durations).
        speed_factor: mission seconds per second of the recording's clock.
    """
    if not (math.isfinite(speed_factor) and speed_factor > 0.0):
        raise ValueError(f"speed_factor must be > 0, got {speed_factor}")
    settle = SETTLE_S / speed_factor
    guard = START_GUARD_S / speed_factor
    longest = MAX_REST_S / speed_factor
    observations: list[StepObservation] = []
    skipped: list[tuple[str, int, str]] = []
    driving = 0.0
    for rec in recordings:
        yaw_unwrapped = np.unwrap(rec.pose_yaw_rad) if len(rec.pose_yaw_rad) else rec.pose_yaw_rad
        odom_yaw = np.unwrap(rec.odom_yaw_rad) if len(rec.odom_yaw_rad) else rec.odom_yaw_rad
        delay = 0.0 if math.isnan(rec.downlink_delay_s) else rec.downlink_delay_s
        moves = [
            (
                rec.to_rover_clock(s.accepted_s),
                rec.to_rover_clock(s.ended_s) if s.ended_s is not None else math.inf,
                s,
            )
            for s in rec.steps
            if s.accepted_s is not None
        ]
        for k, (start, end, step) in enumerate(moves):
            if not step.completed:
                skipped.append(
                    (rec.path, step.index, f"not completed ({step.outcome or 'no end'})")
                )
                continue
            # Drift control sees a step go wrong up to a round trip after it ended.
            late = step.ended_s + 2.0 * delay if step.ended_s is not None else math.inf
            if any(step.sent_s <= t <= late for t in rec.stops_s):
                skipped.append((rec.path, step.index, "the ground sent STOP during or after it"))
                continue
            prev_end = moves[k - 1][1] + settle if k > 0 else -math.inf
            next_start = moves[k + 1][0] - guard if k + 1 < len(moves) else math.inf
            before = _rest(
                rec, yaw_unwrapped, odom_yaw, max(prev_end, start - guard - longest), start - guard
            )
            after = _rest(
                rec, yaw_unwrapped, odom_yaw, end + settle, min(next_start, end + settle + longest)
            )
            reason = _check(step.command, step.distance, rover, before, after)
            if reason:
                skipped.append((rec.path, step.index, reason))
                continue
            assert isinstance(before, _Rest)
            assert isinstance(after, _Rest)
            if before.odom_yaw is not None and after.odom_yaw is not None:
                dyaw = after.odom_yaw - before.odom_yaw
                # The rests' averages, and the gyro's random walk between them (its rate
                # measured at rest: the same white noise integrated while it moved).
                walk = (before.odom_walk + after.odom_walk) / 2.0
                span = max(0.0, after.odom_t - before.odom_t)
                sigma_yaw = math.sqrt(before.odom_sigma**2 + after.odom_sigma**2 + walk * span)
            else:
                dyaw = after.yaw - before.yaw
                sigma_yaw = math.hypot(before.sigma, after.sigma) / 0.5  # POSE yaw: ~sigma/0.5 m
            observations.append(
                StepObservation(
                    source=rec.path,
                    index=step.index,
                    command=step.command,
                    speed=step.speed,
                    distance=step.distance,
                    start=Pose2D(before.x, before.y, wrap_rad(before.yaw)),
                    end=Pose2D(after.x, after.y, wrap_rad(after.yaw)),
                    yaw_change_rad=dyaw,
                    sigma_xy_m=max(POSITION_SIGMA_FLOOR_M, math.hypot(before.sigma, after.sigma)),
                    sigma_yaw_rad=max(YAW_SIGMA_FLOOR_RAD, sigma_yaw),
                    sigma_heading_rad=before.yaw_sigma,
                )
            )
            driving += rover.step_duration_s(step.speed, step.distance)
    for source, index, reason in skipped:
        logger.info("%s step %d skipped: %s", source, index, reason)
    return ObservedSteps(tuple(observations), tuple(skipped), driving)


def _check(
    command: int, distance: int, rover: RoverDescription, before: _Rest | str, after: _Rest | str
) -> str:
    """Why a step cannot be used, or ``""``."""
    if isinstance(before, str):
        return f"before it: {before}"
    if isinstance(after, str):
        return f"after it: {after}"
    if before.odom_xy is None or after.odom_xy is None:
        return ""
    moved = math.dist(before.odom_xy, after.odom_xy)
    if command in (Command.FWD, Command.REV):
        want = rover.units_to_m(distance)
        if abs(moved - want) > ENCODER_TOLERANCE * want + 0.005:
            return f"encoders moved {moved:.3f} m for a {want:.3f} m step"
    elif moved > 0.02:
        return f"encoders moved {moved:.3f} m in a turn on the spot"
    return ""
