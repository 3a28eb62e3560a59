"""Plan validation: play a plan on the twin and judge the outcome.

:class:`Validator` holds the rover description and the maps (immutable) and builds a
fresh :class:`emulator.twin.Twin` per plan, so one validator may serve many threads.
Playback is :func:`emulator.playback.play` (the controller's step semantics, the map's
traction, no injected faults, no noise); the judgement, in this precedence (docs/gate.md
lists the failure types): ``collision`` (``start_in_collision`` when the start pose
touches) at the first contact of the margin-inflated footprint, ``stalled`` (no
progress, or past a step's time limit), ``goal_not_reached`` (position tolerance),
``yaw_not_reached`` (yaw tolerance), else approved.

The same plan and options give the same verdict bit for bit, in any thread or process
(the twin is deterministic; values are rounded to fixed decimals before encoding), apart
from ``wall_time_s``.
"""

from __future__ import annotations

import base64
import hashlib
import json
import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from importlib.metadata import PackageNotFoundError, version

import pymunk

from emulator.batch import BatchResult
from emulator.drive import nominal_step_duration_s
from emulator.ground import Ground
from emulator.playback import DEFAULT_SETTLE_S, PlaybackResult, play, step_time_limit_s
from emulator.twin import Pose2D, Twin
from firmware_proto.errors import DescriptionError, MapError
from firmware_proto.model.geometry import wrap_deg
from firmware_proto.model.plan import COMMAND_NAMES, Plan
from firmware_proto.model.pose import Point, Pose
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.verdict import (
    CollisionReport,
    Replay,
    StallReport,
    StepPrediction,
    Tolerances,
    Trajectory,
    Verdict,
)
from firmware_proto.model.worldmap import WorldMap, list_maps, load_map
from gate.config import MAX_TRAJECTORY_SAMPLES, GateConfig, PlaybackSettings
from gate.ensemble import ChunkJob, DefaultSpread, Spread, chunk_jobs, draw, run_chunk, summarise
from gate.errors import GateConfigError, GoalRangeError, OptionError
from gate.goal import GoalError, approach_heading_rad, goal_error
from gate.options import ResolvedOptions
from gate.trajectory import tag_samples

__all__ = ["GATE_SEED", "MAX_GOAL_ABS_M", "Job", "Validator", "gate_version", "load_maps"]

logger = logging.getLogger(__name__)

MAX_GOAL_ABS_M = 1.0e6
"""Largest goal coordinate accepted, m: beyond any map (error arithmetic overflows near 1e308)."""
GATE_SEED = 0
"""Seed a plain verdict records (one playback has no randomness; uncertainty: the request's)."""

_DIGITS = 6  # metres (1 um), degrees, seconds (1 us) in the verdict
_UNIT_DIGITS = 3  # encoder travel, distance units


def _r(value: float, digits: int = _DIGITS) -> float:
    return round(value, digits) + 0.0  # + 0.0: no negative zero in the JSON


def _pose(p: Pose2D) -> Pose:
    return Pose(_r(p.x_m), _r(p.y_m), _r(p.yaw_deg))


def gate_version() -> str:
    """This software's version (the installed ``rover-hil`` distribution)."""
    try:
        return version("rover-hil")
    except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        return "0+unknown"


def load_maps(default_map: str) -> tuple[dict[str, WorldMap], str]:
    """The shipped maps, plus ``default_map`` when it is a file; and the default's name.

    Raises:
        GateConfigError: the default map cannot be loaded, or a file map's name clashes with
            a different shipped map.
    """
    maps = {name: load_map(name) for name in list_maps()}
    try:
        world = load_map(default_map)
    except MapError as exc:
        raise GateConfigError(f"default map: {exc}") from exc
    known = maps.get(world.name)
    if known is not None and known.digest() != world.digest():
        raise GateConfigError(
            f"map file {default_map} is named {world.name!r}, like a different shipped map"
        )
    maps[world.name] = world
    return maps, world.name


@dataclass(frozen=True)
class Job:
    """One validation, ready to play: a schema-valid plan and concrete options; picklable
    (it crosses into worker processes)."""

    plan: Plan
    options: ResolvedOptions
    start: Pose


class Validator:
    """Plays plans on the twin and returns verdicts; safe to share between threads."""

    def __init__(
        self,
        rover: RoverDescription,
        maps: Mapping[str, WorldMap],
        settings: PlaybackSettings,
        default_map: str,
        *,
        spread: Spread | None = None,
        spread_map: str | None = None,
    ) -> None:
        """Args:
        settings: playback defaults (``dt_s`` is used for every plan).
        default_map: name of the map used when a request names none.
        spread: where the twins of a verdict with uncertainty are drawn from: a
            calibration (:meth:`emulator.calibration.Calibration.sample`); ``None`` for
            :class:`gate.ensemble.DefaultSpread` around the description's ground.
        spread_map: the map ``spread``'s region scales belong to (on other maps the
            drawn grounds' region scales are dropped, as the calibrated twin's are).

        Raises:
            GateConfigError: ``default_map`` is not among ``maps``.
        """
        if default_map not in maps:
            raise GateConfigError(f"default map {default_map!r} is not among {sorted(maps)}")
        self.rover = rover
        self.maps = dict(maps)
        self.settings = settings
        self.default_map = default_map
        self._rover_sha = rover.digest()
        self._map_sha = {name: world.digest() for name, world in self.maps.items()}
        self._version = gate_version()
        self.spread_name = "default" if spread is None else "calibration"
        self.spread: Spread = DefaultSpread(Ground.of_rover(rover)) if spread is None else spread
        self.spread_map = spread_map

    @classmethod
    def from_config(cls, config: GateConfig) -> Validator:
        """Load the rover description and the maps a configuration names.

        Raises:
            GateConfigError: the rover description or the default map cannot be loaded.
        """
        try:
            rover = load_rover(config.rover_path)
        except DescriptionError as exc:
            raise GateConfigError(str(exc)) from exc
        maps, default = load_maps(config.default_map)
        return cls(rover, maps, config.playback, default)

    def map_digest(self, name: str) -> str:
        """SHA-256 of a served map's canonical JSON."""
        return self._map_sha[name]

    @property
    def rover_digest(self) -> str:
        """SHA-256 of the rover description's values."""
        return self._rover_sha

    def prepare(self, plan: Plan, options: ResolvedOptions) -> Job:
        """Check the goal's range and the options against the maps; fix the start pose.

        Raises:
            GoalRangeError: a goal coordinate beyond :data:`MAX_GOAL_ABS_M`.
            OptionError: unknown map, or a start pose outside the map's bounds (a start on
                their edge is played: its footprint touches a wall).
        """
        far = [
            (f"/goal/{axis}", f"must be within +/-{MAX_GOAL_ABS_M:g} m, got {value:g}")
            for axis, value in (("x", plan.goal.x), ("y", plan.goal.y))
            if abs(value) > MAX_GOAL_ABS_M
        ]
        if far:
            raise GoalRangeError(far)
        world = self.maps.get(options.map)
        if world is None:
            raise OptionError("map", f"unknown map {options.map!r}; known: {', '.join(self.maps)}")
        start = options.start
        if start is None:
            start = Pose(world.start.x, world.start.y, world.start.yaw_deg)
        elif not (
            world.bounds.min_x <= start.x <= world.bounds.max_x
            and world.bounds.min_y <= start.y <= world.bounds.max_y
        ):
            b = world.bounds
            raise OptionError(
                "start",
                f"({start.x:g}, {start.y:g}) is outside map {world.name!r} "
                f"(x {b.min_x:g}..{b.max_x:g}, y {b.min_y:g}..{b.max_y:g})",
            )
        return Job(plan, options, start)

    def validate(self, plan: Plan, options: ResolvedOptions) -> Verdict:
        """Prepare and run one validation (see :meth:`run`).

        Raises:
            OptionError: see :meth:`prepare`.
        """
        return self.run(self.prepare(plan, options))

    def run(self, job: Job) -> Verdict:
        """Play the job's plan and judge it; ``wall_time_s`` is the time this took."""
        t0 = time.perf_counter()
        opts = job.options
        world = self.maps[opts.map]
        twin = self._make_twin(job)
        result = play(twin, job.plan.to_wire(), sample_period_s=self.sample_period_s(job))
        verdict = self._judge(job, result)
        if opts.render:
            from gate.render import render_png  # noqa: PLC0415 - Pillow only when asked

            png = render_png(world, self.rover, job.plan, verdict)
            verdict = replace(verdict, image_png_base64=base64.b64encode(png).decode("ascii"))
        wall = time.perf_counter() - t0
        logger.debug(
            "plan %s on %s: %s in %.1f ms",
            verdict.replay.plan_sha256[:12],
            opts.map,
            verdict.failure_type or "approved",
            wall * 1e3,
        )
        return replace(verdict, wall_time_s=_r(wall))

    def chunk_jobs(self, job: Job) -> list[ChunkJob]:
        """The chunks of ``job``'s verdict with uncertainty (``samples`` > 1): its twins
        drawn (seeded) and split (:mod:`gate.ensemble`), each ready for any worker."""
        opts = job.options
        heading = None if opts.start_sigma_deg is None else math.radians(opts.start_sigma_deg)
        draws = draw(
            self.spread,
            opts.samples,
            opts.seed,
            opts.slip_sigma,
            (opts.start_sigma_m, heading),
        )
        nominal = self.spread.ground
        if opts.map != self.spread_map:
            draws = [replace(d, ground=replace(d.ground, regions=())) for d in draws]
            nominal = replace(nominal, regions=())
        return chunk_jobs(
            self.rover,
            self.maps[opts.map],
            job.plan,
            draws,
            dt_s=self.settings.dt_s,
            safety_margin_m=opts.safety_margin_m,
            start=job.start,
            nominal=nominal if self.spread.step_error_scale > 0.0 else None,
        )

    def with_uncertainty(
        self, nominal: Verdict, job: Job, results: Sequence[BatchResult]
    ) -> Verdict:
        """``nominal`` (the single playback of ``job``) with the uncertainty its chunks'
        ``results`` (in chunk order) give."""
        opts = job.options
        uncertainty = summarise(
            results,
            job.plan,
            start=job.start,
            seed=opts.seed,
            spread=self.spread_name,
            slip_sigma=opts.slip_sigma,
            position_tolerance_m=opts.position_tolerance_m,
            yaw_tolerance_deg=opts.yaw_tolerance_deg,
        )
        return replace(nominal, uncertainty=uncertainty)

    def validate_uncertain(self, job: Job) -> Verdict:
        """:meth:`run` and, for ``samples`` > 1, its chunks one after the other in this
        thread (``rover gate check``; the server spreads them over its workers)."""
        t0 = time.perf_counter()
        nominal = self.run(job)
        if job.options.samples <= 1:
            return nominal
        results = [run_chunk(c) for c in self.chunk_jobs(job)]
        verdict = self.with_uncertainty(nominal, job, results)
        return replace(verdict, wall_time_s=_r(time.perf_counter() - t0))

    def twin_seconds(self, job: Job) -> float:
        """Twin seconds ``job``'s playback is expected to take: each step's nominal
        duration, then settling (what :mod:`gate.admission` costs it by; a stall may
        make it longer, up to the steps' time limits)."""
        return DEFAULT_SETTLE_S + sum(
            nominal_step_duration_s(self.rover, s.speed, s.distance) for s in job.plan.commands
        )

    def sample_period_s(self, job: Job) -> float:
        """The trajectory's sample period for ``job``: the requested one, or, when the
        plan's longest possible playback (every step to its time limit, then settling)
        would give more than :data:`~gate.config.MAX_TRAJECTORY_SAMPLES` samples at that
        rate, the shortest whole number of twin steps that keeps within it. A function
        of the plan and the options alone, so verdicts stay reproducible."""
        requested = 1.0 / job.options.sample_hz
        longest_s = DEFAULT_SETTLE_S + sum(
            step_time_limit_s(self.rover, s.speed, s.distance) for s in job.plan.commands
        )
        if longest_s / requested <= MAX_TRAJECTORY_SAMPLES:
            return requested
        dt = self.settings.dt_s
        return math.ceil(longest_s / MAX_TRAJECTORY_SAMPLES / dt) * dt

    def _make_twin(self, job: Job) -> Twin:
        """The twin a job plays on: the map's traction, no injected faults. The one hook
        a subclass may override (e.g. to inject a fault when testing verdicts)."""
        start = job.start
        return Twin(
            self.rover,
            self.maps[job.options.map],
            dt_s=self.settings.dt_s,
            safety_margin_m=job.options.safety_margin_m,
            start=Pose2D.from_deg(start.x, start.y, start.yaw_deg),
        )

    # -- judgement -----------------------------------------------------------------------
    def _judge(self, job: Job, result: PlaybackResult) -> Verdict:
        plan, opts, start = job.plan, job.options, job.start
        goal = plan.goal
        steps = self._steps(plan, result, start)
        heading = approach_heading_rad(
            [s.command for s in result.steps],
            [
                (
                    result.samples[0].pose if s.index == 0 else result.steps[s.index - 1].end_pose
                ).yaw_rad
                for s in result.steps
            ],
            (start.x, start.y, math.radians(start.yaw_deg)),
            (goal.x, goal.y),
        )
        final = result.final_pose
        err = goal_error(
            (final.x_m, final.y_m, final.yaw_deg), (goal.x, goal.y, goal.yaw_deg), heading
        )
        collision = self._collision(result)
        stall = (
            StallReport(
                result.stall.step_index,
                result.stall.reason,
                result.stall.side,
                _r(result.stall.time_s),
            )
            if result.stall is not None
            else None
        )
        tol = Tolerances(
            _r(opts.position_tolerance_m), _r(opts.yaw_tolerance_deg), _r(opts.safety_margin_m)
        )
        failure, failed_step, reason = _classify(plan, collision, stall, err, tol)
        samples = tuple(tag_samples(result, _pose, _r))
        plan_blob = json.dumps(plan.to_dict(), sort_keys=True, separators=(",", ":"))
        return Verdict(
            approved=failure is None,
            failure_type=failure,
            failure_reason=reason,
            failed_step=failed_step,
            goal=Pose(goal.x, goal.y, goal.yaw_deg),
            start_pose=start,
            final_pose=_pose(final),
            position_error_m=_r(err.longitudinal_m),
            lateral_error_m=_r(err.lateral_m),
            distance_error_m=_r(err.distance_m),
            yaw_error_deg=_r(err.yaw_deg),
            approach_heading_deg=_r(wrap_deg(math.degrees(heading))),
            collision=collision,
            stall=stall,
            tolerances=tol,
            steps=steps,
            trajectory=Trajectory(_r(result.sample_period_s), samples),
            sim_time_s=_r(result.sim_time_s),
            replay=Replay(
                seed=opts.seed if opts.samples > 1 else GATE_SEED,
                map=opts.map,
                map_sha256=self._map_sha[opts.map],
                rover=self.rover.name,
                rover_sha256=self._rover_sha,
                plan_sha256=hashlib.sha256(plan_blob.encode()).hexdigest(),
                start=start,
                dt_s=self.settings.dt_s,
                sample_hz=opts.sample_hz,
                render=opts.render,
                gate_version=self._version,
                pymunk_version=pymunk.version,
                query=opts.to_query(start),
            ),
        )

    def _steps(self, plan: Plan, result: PlaybackResult, start: Pose) -> tuple[StepPrediction, ...]:
        out: list[StepPrediction] = []
        previous = result.samples[0].pose
        for s in result.steps:
            planned = plan.commands[s.index]
            out.append(
                StepPrediction(
                    index=s.index,
                    command=COMMAND_NAMES[s.command],
                    speed=s.speed,
                    distance=s.distance,
                    start_time_s=_r(s.start_time_s),
                    end_time_s=_r(s.end_time_s),
                    expected_duration_s=_r(s.end_time_s - s.start_time_s),
                    nominal_duration_s=_r(
                        nominal_step_duration_s(self.rover, planned.speed, planned.distance)
                        if planned.command != "STOP"
                        else 0.0
                    ),
                    start_pose=_pose(previous),
                    end_pose=_pose(s.end_pose),
                    completed=s.completed,
                    left_travel_units=_r(s.left_travel_units, _UNIT_DIGITS),
                    right_travel_units=_r(s.right_travel_units, _UNIT_DIGITS),
                )
            )
            previous = s.end_pose
        return tuple(out)

    @staticmethod
    def _collision(result: PlaybackResult) -> CollisionReport | None:
        c = result.collision
        if c is None:
            return None
        step = result.collision_step or 0
        started = result.steps[step].start_time_s if step < len(result.steps) else 0.0
        return CollisionReport(
            obstacle_id=c.obstacle_id,
            contact=Point(_r(c.contact_x_m), _r(c.contact_y_m)),
            pose=_pose(c.pose),
            time_s=_r(c.time_s),
            step=step,
            step_t_s=_r(c.time_s - started),
        )


def _classify(
    plan: Plan,
    collision: CollisionReport | None,
    stall: StallReport | None,
    err: GoalError,
    tol: Tolerances,
) -> tuple[str | None, int | None, str]:
    """``(failure_type, failed_step, reason)``, in the order of precedence."""
    last = len(plan.commands) - 1
    distance_m, longitudinal_m, lateral_m = err.distance_m, err.longitudinal_m, err.lateral_m
    yaw_err_deg = err.yaw_deg
    if collision is not None:
        where = f"({collision.contact.x:.3f}, {collision.contact.y:.3f})"
        if collision.time_s == 0.0:
            return (
                "start_in_collision",
                0,
                f"the start pose already touches {collision.obstacle_id!r} at {where} "
                f"(safety margin {tol.safety_margin_m:g} m)",
            )
        step = plan.commands[collision.step]
        return (
            "collision",
            collision.step,
            f"step {collision.step} ({step.command}) touches {collision.obstacle_id!r} at "
            f"{where} after {collision.step_t_s:.2f} s (safety margin {tol.safety_margin_m:g} m)",
        )
    if stall is not None:
        step = plan.commands[stall.step]
        if stall.reason != "no_encoder_progress":
            why = "it ran past its time limit"
        elif stall.side == "both":
            why = "neither side made encoder progress"
        else:
            why = f"the {stall.side} side made no encoder progress"
        return "stalled", stall.step, f"step {stall.step} ({step.command}) stalled: {why}"
    if distance_m > tol.position_m:
        along = "short of" if longitudinal_m > 0 else "past"
        side = "left" if lateral_m > 0 else "right"
        return (
            "goal_not_reached",
            last,
            f"ends {distance_m:.3f} m from the goal (tolerance {tol.position_m:g} m): "
            f"{abs(longitudinal_m):.3f} m {along} it along the approach, "
            f"{abs(lateral_m):.3f} m to its {side}",
        )
    if abs(yaw_err_deg) > tol.yaw_deg:
        return (
            "yaw_not_reached",
            last,
            f"ends {yaw_err_deg:+.2f} deg off the goal yaw (tolerance {tol.yaw_deg:g} deg)",
        )
    return None, None, ""
