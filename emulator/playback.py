"""Lockstep playback of a list of steps on a twin, as fast as the machine allows.

:func:`play` executes ``(command, speed, distance)`` steps with the controller's step
semantics (:class:`emulator.drive.StepProfile`) and returns what it observed
(:class:`PlaybackResult`). The first collision or stall ends playback (a step past its
time limit is a stall, so playback always terminates); after the last step the twin
settles, wheels stopped, for at most ``settle_s``. Verdicts are the gate's business.
docs/twin.md, "Playback".
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable
from dataclasses import dataclass

from emulator.drive import (
    StepProfile,
    motor_omegas,
    nominal_step_duration_s,
    travel_units,
    turn_units_for_yaw,
)
from emulator.errors import TwinConfigError
from emulator.traction import ideal_spin_yaw_rad
from emulator.twin import Collision, Pose2D, Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import Command

__all__ = [
    "DEFAULT_SAMPLE_PERIOD_S",
    "DEFAULT_SETTLE_S",
    "DEFAULT_STALL_WINDOW_S",
    "PlaybackResult",
    "Stall",
    "StepResult",
    "TimedPose",
    "measure_turn_efficiency",
    "play",
    "step_time_limit_s",
]

logger = logging.getLogger(__name__)

DEFAULT_SAMPLE_PERIOD_S = 0.1
"""Trajectory sample period, s of twin time (what a drift monitor compares against)."""

DEFAULT_SETTLE_S = 1.0
"""Longest time the twin runs after the last step for the body to come to rest, s."""

DEFAULT_STALL_WINDOW_S = 1.0
"""A moving side without a whole unit of encoder progress for this long is stalled, s."""

REST_SPEED_MPS = 1e-3
"""Body speed below which the rover counts as at rest after the last step, m/s."""

REST_YAW_RATE_RAD_S = 1e-3
"""Yaw rate below which the rover counts as at rest after the last step, rad/s."""


@dataclass(frozen=True)
class TimedPose:
    """A pose of the trajectory at twin time ``time_s``."""

    time_s: float
    pose: Pose2D


@dataclass(frozen=True)
class StepResult:
    """What one step did.

    Attributes:
        index: position in the step list (0-based).
        command, speed, distance: the step as given.
        start_time_s, end_time_s: twin time when it started and ended.
        end_pose: the pose when it ended (completed, or cut by a collision or stall).
        left_travel_units, right_travel_units: encoder travel of each side during the
            step, distance units, rover frame, forward positive (not rounded).
        completed: the profile finished (both sides reached the distance, at rest).
    """

    index: int
    command: int
    speed: int
    distance: int
    start_time_s: float
    end_time_s: float
    end_pose: Pose2D
    left_travel_units: float
    right_travel_units: float
    completed: bool


@dataclass(frozen=True)
class Stall:
    """Playback ended because a step made no progress.

    Attributes:
        step_index: the step that stalled.
        time_s: twin time of the detection.
        reason: ``"no_encoder_progress"`` or ``"time_limit"``.
        side: ``"left"``, ``"right"`` or ``"both"`` for no progress, else ``""``.
    """

    step_index: int
    time_s: float
    reason: str
    side: str = ""


@dataclass(frozen=True)
class PlaybackResult:
    """Everything :func:`play` observed.

    Attributes:
        samples: poses every ``sample_period_s`` from time 0, and the final pose.
        steps: one :class:`StepResult` per step started.
        collision: the first collision, or ``None``.
        collision_step: the step during which it happened (0: at the start), or ``None``.
        stall: why playback stopped for lack of progress, or ``None``.
        sim_time_s: twin time spent (including settling).
        final_pose: the pose at the end.
        sample_period_s: the actual sample period (a whole number of steps).
        dt_s: the twin's physics step.
    """

    samples: tuple[TimedPose, ...]
    steps: tuple[StepResult, ...]
    collision: Collision | None
    collision_step: int | None
    stall: Stall | None
    sim_time_s: float
    final_pose: Pose2D
    sample_period_s: float
    dt_s: float

    @property
    def completed(self) -> bool:
        """Every given step completed without collision or stall."""
        return (
            self.collision is None and self.stall is None and all(s.completed for s in self.steps)
        )


def step_time_limit_s(rover: RoverDescription, speed: int, distance: int) -> float:
    """Default time limit of one step: 1.5 x its nominal duration + 2 s."""
    return 1.5 * nominal_step_duration_s(rover, speed, distance) + 2.0


def play(
    twin: Twin,
    steps: Iterable[tuple[int, int, int]],
    *,
    sample_period_s: float = DEFAULT_SAMPLE_PERIOD_S,
    settle_s: float = DEFAULT_SETTLE_S,
    stall_window_s: float = DEFAULT_STALL_WINDOW_S,
    time_limit_factor: float = 1.5,
    time_limit_margin_s: float = 2.0,
) -> PlaybackResult:
    """Play ``steps`` on ``twin`` in lockstep and return what happened.

    Args:
        twin: the twin, at the start pose (it is advanced, not reset).
        steps: ``(command, speed, distance)`` triples (``Plan.to_wire()``).
        sample_period_s: trajectory sample period, s (rounded to whole steps, >= 1).
        settle_s: longest settling time after the last step, s (0: none).
        stall_window_s: encoder no-progress window, s.
        time_limit_factor, time_limit_margin_s: a step's time limit is
            ``factor * nominal duration + margin``.

    Raises:
        CommandError: a step is invalid; nothing is played then.
        TwinConfigError: a period or window is not positive.
    """
    for name, value in (("sample_period_s", sample_period_s), ("stall_window_s", stall_window_s)):
        if not (math.isfinite(value) and value > 0.0):
            raise TwinConfigError(f"{name} must be > 0, got {value}")
    if not (math.isfinite(settle_s) and settle_s >= 0.0):
        raise TwinConfigError(f"settle_s must be >= 0, got {settle_s}")
    rover = twin.rover
    dt = twin.dt_s
    # Validate every step before moving anything.
    profiles = [StepProfile(rover, c, s, d) for c, s, d in steps]
    sample_every = max(1, round(sample_period_s / dt))
    stall_every = max(1, round(stall_window_s / dt))
    kl, kr = travel_units(rover, 1.0, 1.0)  # units per motor radian, with polarity
    ml, mr = motor_omegas(rover, 1.0, 1.0)  # motor rad/s per m/s, with polarity

    samples = [TimedPose(twin.time_s, twin.pose)]
    results: list[StepResult] = []
    collision = twin.first_collision
    collision_step: int | None = 0 if collision is not None and profiles else None
    stall: Stall | None = None

    for index, profile in enumerate(profiles):
        if collision is not None:
            break
        a0l, a0r = twin.motor_angles_rad
        start_t = twin.time_s
        limit_steps = round(
            (
                time_limit_factor * nominal_step_duration_s(rover, profile.speed, profile.distance)
                + time_limit_margin_s
            )
            / dt
        )
        taken = 0
        last_l = last_r = 0.0
        tl = tr = 0.0
        while True:
            al, ar = twin.motor_angles_rad
            tl = (al - a0l) * kl
            tr = (ar - a0r) * kr
            ul, ur = profile.update(tl, tr, dt)
            if profile.done:
                break
            twin.set_motor_omegas(ul * ml, ur * mr)
            twin.step()
            taken += 1
            if twin.steps % sample_every == 0:
                samples.append(TimedPose(twin.time_s, twin.pose))
            collision = twin.first_collision
            if collision is not None:
                collision_step = index
                break
            if taken % stall_every == 0:
                stall = _no_progress(profile, index, twin.time_s, (tl, tr), (last_l, last_r))
                last_l, last_r = tl, tr
                if stall is not None:
                    break
            if taken >= limit_steps:
                stall = Stall(index, twin.time_s, "time_limit")
                break
        twin.set_motor_omegas(0.0, 0.0)
        al, ar = twin.motor_angles_rad
        results.append(
            StepResult(
                index=index,
                command=int(profile.command),
                speed=profile.speed,
                distance=profile.distance,
                start_time_s=start_t,
                end_time_s=twin.time_s,
                end_pose=twin.pose,
                left_travel_units=(al - a0l) * kl,
                right_travel_units=(ar - a0r) * kr,
                completed=profile.done,
            )
        )
        if stall is not None:
            logger.debug("playback stalled: %s", stall)
            break

    if collision is None and stall is None:
        for _ in range(round(settle_s / dt)):
            v = twin.body_velocity
            if (
                abs(v.yaw_rate_rad_s) < REST_YAW_RATE_RAD_S
                and math.hypot(v.vx_mps, v.vy_mps) < REST_SPEED_MPS
            ):
                break
            twin.step()
            if twin.steps % sample_every == 0:
                samples.append(TimedPose(twin.time_s, twin.pose))
            if twin.first_collision is not None:
                collision = twin.first_collision
                collision_step = len(profiles) - 1 if profiles else None
                break
    final = TimedPose(twin.time_s, twin.pose)
    if samples[-1].time_s != final.time_s:
        samples.append(final)
    return PlaybackResult(
        samples=tuple(samples),
        steps=tuple(results),
        collision=collision,
        collision_step=collision_step,
        stall=stall,
        sim_time_s=twin.time_s,
        final_pose=final.pose,
        sample_period_s=sample_every * dt,
        dt_s=dt,
    )


def _no_progress(
    profile: StepProfile,
    index: int,
    time_s: float,
    travel: tuple[float, float],
    before: tuple[float, float],
) -> Stall | None:
    """A stall if a side that still has distance to go moved less than one unit since
    the previous check (``before``)."""
    rem_l, rem_r = profile.remaining_units(*travel)
    stuck_l = rem_l > 1.0 and abs(travel[0] - before[0]) < 1.0
    stuck_r = rem_r > 1.0 and abs(travel[1] - before[1]) < 1.0
    if stuck_l or stuck_r:
        side = "both" if stuck_l and stuck_r else ("left" if stuck_l else "right")
        return Stall(index, time_s, "no_encoder_progress", side)
    return None


def measure_turn_efficiency(
    rover: RoverDescription,
    *,
    command: int = Command.LEFT,
    speed: int = 30,
    distance: int | None = None,
    dt_s: float = 0.001,
) -> float:
    """Body yaw achieved / ideal yaw from wheel arc travel, for one in-place spin
    (``command`` LEFT or RIGHT) from rest on an open plane, read after settling: how
    ``traction.turn_efficiency`` is calibrated (docs/twin.md). ``distance`` defaults to
    the description's 90 degrees; ``dt_s`` is the physics step, s.
    """
    if distance is None:
        distance = turn_units_for_yaw(rover, math.pi / 2.0)
    twin = Twin(rover, dt_s=dt_s)
    step = play(twin, [(int(command), speed, distance)]).steps[0]
    arc_m = rover.units_to_m((abs(step.left_travel_units) + abs(step.right_travel_units)) / 2.0)
    return abs(twin.yaw_unwrapped_rad) / ideal_spin_yaw_rad(arc_m, rover.geometry.track_width_m)
