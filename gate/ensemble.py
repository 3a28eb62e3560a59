"""Verdicts with their uncertainty: one plan on N twins drawn from what the gate does not
know about the ground.

A request with ``samples=N`` (N > 1) and ``seed=S`` is played on N twins. Each twin's
ground is drawn, with ``numpy.random.default_rng(S)``, from the parameter spread (a
calibrated twin's covariance, ``rover gate --twin FILE``, else :data:`DEFAULT_SPREAD`:
each of the fitted parameters log-normal with a relative 1-sigma of 20 %), then each
side's friction factor from the slip distribution (log-normal, 1-sigma ``slip_sigma``:
the request's, else the server's default, a calibrated twin's own estimate), then,
the start pose's error (the request's own, ``start_sigma_m`` and ``start_sigma_deg``,
else, with a calibrated twin, the rest-averaged pose's noise the calibration measured),
then each twin's share of the plan's step error (the model
discrepancy a calibrated twin states: below). Every draw comes in antithetic pairs,
mirrored about the nominal twin, so the bands are centred on the point prediction.

The draws happen here, once, in the server; the twins are played in chunks of fixed size
(:func:`chunk_sizes`, a function of N alone) by :func:`run_chunk`, which needs nothing but its
:class:`ChunkJob`: on the gate's process pool, or on a Dask cluster
(:mod:`gate.cluster`). :func:`summarise` turns the chunks' results, concatenated in
chunk order, into the verdict's :class:`~firmware_proto.model.verdict.Uncertainty`: the
same request and seed give the same bytes wherever the chunks ran.

Each twin is judged as the nominal one is (collision, stall, goal and yaw tolerances),
so ``approved_probability`` is the fraction the verdict's own rules approve.

**Step error** (:func:`step_error`): the gate plays at its 10 ms step, the rover runs in
continuous time. A calibration fitted at the gate's step absorbs that step's bias for
the steps it measured, all from rest, but not for a plan run back to back (a step
starting while the one before brakes), where the bias differs. Its estimate is the
nominal twin's final pose at :data:`STEP_ERROR_DT_S` less at the gate's step; a
calibrated twin (``step_error_scale`` > 0) states its 1-sigma in units of it, and each
twin's final pose is moved by its own normal share of it (antithetic, so the bands stay
centred on the point prediction). The final poses (goal errors, approval) carry it; the
envelope (poses along the way) and the collisions do not. Every chunk computes the same
estimate (two playbacks of the nominal twin), so the chunks stay self-contained.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from emulator.batch import BatchDraw, BatchResult, play_batch
from emulator.calibration import FIT_PARAMETERS, mirrored
from emulator.ground import Ground
from emulator.playback import play
from emulator.twin import Pose2D, Twin
from firmware_proto.model.geometry import wrap_rad
from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Point, Pose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.verdict import (
    EnvelopePoint,
    GoalErrorPercentiles,
    ObstacleHits,
    Uncertainty,
)
from firmware_proto.model.worldmap import WorldMap
from firmware_proto.wire.messages import Command
from gate.goal import approach_heading_rad, goal_error

__all__ = [
    "CHUNK_SIZE",
    "DEFAULT_SPREAD",
    "ENVELOPE_LEVEL",
    "ENVELOPE_PERIOD_S",
    "PERCENTILES",
    "STEP_ERROR_DT_S",
    "ChunkJob",
    "DefaultSpread",
    "Spread",
    "chunk_jobs",
    "chunk_sizes",
    "draw",
    "run_chunk",
    "step_error",
    "summarise",
]

CHUNK_SIZE = 100
"""Twins per chunk (at most): one chunk is one :func:`emulator.batch.play_batch`. A step
of 100 twins costs little more than one of 50, and N = 200 still makes two chunks for
two workers."""
DEFAULT_SPREAD = 0.2
"""Relative 1-sigma of each fitted ground parameter (log-normal) when the gate has no
calibration: a ground known to about 20 % (docs/gate.md)."""
ENVELOPE_PERIOD_S = 1.0
"""Envelope points inside a step are this far apart in twin time (plus each step's end)."""
ENVELOPE_LEVEL = 0.95
"""Probability held by each envelope ellipse (a normal fit of the positions)."""
PERCENTILES = (5.0, 50.0, 95.0)
"""The goal errors' percentiles reported."""
STEP_ERROR_DT_S = 0.002
"""The finer step of :func:`step_error`, s: within 0.1 mm and 0.01 degree of 1 ms over a
12-step plan (docs/twin.md), at five times the gate step's cost."""

_DIGITS = 6


def _r(value: float) -> float:
    return round(float(value), _DIGITS) + 0.0


class Spread(Protocol):
    """Where grounds are drawn from: :class:`emulator.calibration.Calibration` or
    :class:`DefaultSpread`."""

    def sample(
        self, rng: np.random.Generator | int, n: int, *, antithetic: bool = False
    ) -> list[Ground]:
        """``n`` grounds drawn with ``rng`` (in mirrored pairs with ``antithetic``)."""
        ...

    @property
    def start_sigma(self) -> tuple[float, float]:
        """``(position_m, heading_rad)``: 1-sigma error of a start pose."""
        ...

    @property
    def ground(self) -> Ground:
        """The nominal ground (the point prediction's)."""
        ...

    @property
    def step_error_scale(self) -> float:
        """1-sigma of the model discrepancy in units of a plan's :func:`step_error`."""
        ...


@dataclass(frozen=True)
class DefaultSpread:
    """Independent log-normal spread around a ground: each of
    :data:`~emulator.calibration.FIT_PARAMETERS` times ``exp(N(0, sigma))``."""

    ground: Ground
    sigma: float = DEFAULT_SPREAD

    @property
    def start_sigma(self) -> tuple[float, float]:
        """No start-pose error: the gate knows nothing of the rover's sensors."""
        return 0.0, 0.0

    @property
    def step_error_scale(self) -> float:
        """No model discrepancy stated: without a calibration nothing absorbed the gate
        step's bias, and the parameters' 20 % spread dwarfs it."""
        return 0.0

    def sample(
        self, rng: np.random.Generator | int, n: int, *, antithetic: bool = False
    ) -> list[Ground]:
        """``n`` grounds drawn with ``rng`` (a generator, or a seed for a new one); with
        ``antithetic`` in mirrored pairs (``exp(+d)``, ``exp(-d)``)."""
        gen = np.random.default_rng(rng) if isinstance(rng, int) else rng
        if antithetic:
            half = gen.normal(0.0, self.sigma, size=((n + 1) // 2, len(FIT_PARAMETERS)))
            factors = np.exp(mirrored(half)[:n])
        else:
            factors = np.exp(gen.normal(0.0, self.sigma, size=(n, len(FIT_PARAMETERS))))
        base = self.ground.values()
        return [
            self.ground.with_values(
                **{p: base[p] * float(f) for p, f in zip(FIT_PARAMETERS, row, strict=True)}
            )
            for row in factors
        ]


def draw(
    spread: Spread,
    n: int,
    seed: int,
    slip_sigma: float,
    start_sigma: tuple[float | None, float | None] = (None, None),
) -> list[BatchDraw]:
    """The ``n`` twins of a request: grounds from ``spread``, then each side's slip
    factor, then the start pose's offset (``start_sigma``, ``(position_m,
    heading_rad)`` 1-sigma: the start's own noise, as measured with the plan; each
    ``None`` is ``spread.start_sigma``'s, a calibrated twin's rests'), then each twin's
    share of the plan's step error (normal, 1-sigma ``spread.step_error_scale``), all
    from ``numpy.random.default_rng(seed)``, each in antithetic pairs: twins ``2k`` and
    ``2k + 1`` are mirror images about the nominal one (``+d`` and ``-d`` in log
    friction, in slip, in the start's offset, in the step error), so that the samples'
    spread is centred on the nominal prediction wherever it is linear in them
    (docs/gate.md). The step error's shares come last: the draws before them are those
    of a spread without it."""
    rng = np.random.default_rng(seed)
    half = (n + 1) // 2
    grounds = spread.sample(rng, n, antithetic=True)
    slips = np.exp(mirrored(rng.normal(0.0, slip_sigma, size=(half, 2)))[:n])
    position, heading = (
        given if given is not None else default
        for given, default in zip(start_sigma, spread.start_sigma, strict=True)
    )
    offsets = mirrored(rng.normal(0.0, 1.0, size=(half, 3)))[:n] * (position, position, heading)
    shares = mirrored(rng.normal(0.0, 1.0, size=half))[:n] * spread.step_error_scale
    return [
        BatchDraw(g, float(s[0]), float(s[1]), float(o[0]), float(o[1]), float(o[2]), float(e))
        for g, s, o, e in zip(grounds, slips, offsets, shares, strict=True)
    ]


def step_error(
    rover: RoverDescription,
    world: WorldMap | None,
    ground: Ground,
    steps: Sequence[tuple[int, int, int]],
    *,
    dt_s: float,
    safety_margin_m: float,
    start: Pose2D,
    fine_dt_s: float = STEP_ERROR_DT_S,
) -> tuple[float, float, float]:
    """The plan's step error: the final pose of the twin on ``ground`` played at
    ``fine_dt_s`` less at ``dt_s`` (the gate's step), ``(dx_m, dy_m, dyaw_rad)`` in the
    map frame (yaw wrapped). Zero when ``fine_dt_s >= dt_s``, or when either playback
    collides or stalls (such a plan's twins are judged by that, not by where they
    end). Deterministic: two playbacks of one twin, about six times the cost of the
    nominal one at 2 ms against 10 ms."""
    if fine_dt_s >= dt_s:
        return 0.0, 0.0, 0.0
    finals = []
    for dt in (dt_s, fine_dt_s):
        twin = Twin(
            ground.rover(rover),
            ground.world(world, strict=False),
            dt_s=dt,
            safety_margin_m=safety_margin_m,
            start=start,
        )
        result = play(twin, steps)
        if result.collision is not None or result.stall is not None:
            return 0.0, 0.0, 0.0
        finals.append(result.final_pose)
    coarse, fine = finals
    return (
        fine.x_m - coarse.x_m,
        fine.y_m - coarse.y_m,
        wrap_rad(fine.yaw_rad - coarse.yaw_rad),
    )


def chunk_sizes(n: int) -> list[int]:
    """How ``n`` twins are split: ``max(2, ceil(n / CHUNK_SIZE))`` chunks (at most
    ``n``), sizes differing by at most one, the larger first. A function of ``n`` alone,
    so the verdict does not depend on where or on how many workers the chunks run."""
    if n <= 1:
        return [n]
    k = min(n, max(2, math.ceil(n / CHUNK_SIZE)))
    return [n // k + (1 if i < n % k else 0) for i in range(k)]


@dataclass(frozen=True)
class ChunkJob:
    """One chunk of an uncertain verdict, self-contained (picklable, no server state).

    Attributes:
        rover: the rover description (geometry, mass, drive).
        world: the map as served.
        draws: the chunk's twins.
        steps: the plan as ``(command, speed, distance)``.
        dt_s: the twin's step.
        safety_margin_m: the collision margin.
        start: the start pose (map frame, degrees).
        nominal: the nominal twin's ground, whose :func:`step_error` the draws'
            ``step_error`` shares move the final poses by (``None``: no step error).
    """

    rover: RoverDescription
    world: WorldMap
    draws: tuple[BatchDraw, ...]
    steps: tuple[tuple[int, int, int], ...]
    dt_s: float
    safety_margin_m: float
    start: Pose
    nominal: Ground | None = None


def chunk_jobs(
    rover: RoverDescription,
    world: WorldMap,
    plan: Plan,
    draws: Sequence[BatchDraw],
    *,
    dt_s: float,
    safety_margin_m: float,
    start: Pose,
    nominal: Ground | None = None,
) -> list[ChunkJob]:
    """The request's chunks, in order (:func:`chunk_sizes`); ``nominal`` as in
    :class:`ChunkJob`."""
    jobs: list[ChunkJob] = []
    at = 0
    for size in chunk_sizes(len(draws)):
        jobs.append(
            ChunkJob(
                rover,
                world,
                tuple(draws[at : at + size]),
                tuple(plan.to_wire()),
                dt_s,
                safety_margin_m,
                start,
                nominal,
            )
        )
        at += size
    return jobs


def run_chunk(job: ChunkJob) -> BatchResult:
    """Play one chunk (in a worker process or on a cluster's worker). With a
    ``nominal`` ground and draws that take a share of the step error, each twin that
    ended the plan (no collision, no stall) has its final pose moved by its share of
    the plan's :func:`step_error` (the map frame). The schedule's per-tick wheel speeds
    are dropped from the result (every chunk has them)."""
    start = Pose2D.from_deg(job.start.x, job.start.y, job.start.yaw_deg)
    result = play_batch(
        job.rover,
        job.world,
        job.draws,
        job.steps,
        dt_s=job.dt_s,
        safety_margin_m=job.safety_margin_m,
        start=start,
        record_every_s=ENVELOPE_PERIOD_S,
    )
    shares = np.array([d.step_error for d in job.draws])
    if job.nominal is not None and np.any(shares != 0.0):
        error = np.array(
            step_error(
                job.rover,
                job.world,
                job.nominal,
                job.steps,
                dt_s=job.dt_s,
                safety_margin_m=job.safety_margin_m,
                start=start,
            )
        )
        ended = (result.collision_tick < 0) & (result.schedule.stall is None)
        final = result.final + np.where(ended, shares, 0.0)[:, None] * error
        final[:, 2] = np.mod(final[:, 2] + math.pi, 2.0 * math.pi) - math.pi
        result = replace(result, final=final)
    empty = np.empty((0, 2))
    return replace(result, schedule=replace(result.schedule, surface_mps=empty))


def _ellipse(xs: np.ndarray, ys: np.ndarray) -> tuple[float, float, float]:
    """Semi-axes (m) and angle (deg) of the :data:`ENVELOPE_LEVEL` ellipse of points."""
    if len(xs) < 2:
        return 0.0, 0.0, 0.0
    dx, dy = xs - xs.mean(), ys - ys.mean()
    sxx, syy, sxy = float(np.mean(dx * dx)), float(np.mean(dy * dy)), float(np.mean(dx * dy))
    half = (sxx + syy) / 2.0
    root = math.hypot((sxx - syy) / 2.0, sxy)
    k = -2.0 * math.log(1.0 - ENVELOPE_LEVEL)  # chi-square quantile, 2 degrees of freedom
    major = math.sqrt(max(0.0, k * (half + root)))
    minor = math.sqrt(max(0.0, k * (half - root)))
    angle = math.degrees(0.5 * math.atan2(2.0 * sxy, sxx - syy)) if root > 0.0 else 0.0
    return major, minor, angle


def _yaw_stats(yaws_rad: np.ndarray) -> tuple[float, float]:
    """Circular mean and standard deviation about it, degrees."""
    mean = math.atan2(float(np.mean(np.sin(yaws_rad))), float(np.mean(np.cos(yaws_rad))))
    dev = np.mod(yaws_rad - mean + math.pi, 2.0 * math.pi) - math.pi
    return math.degrees(mean), math.degrees(math.sqrt(float(np.mean(dev * dev))))


def _envelope(results: Sequence[BatchResult], dt_s: float) -> list[EnvelopePoint]:
    first = results[0]
    poses = np.concatenate([r.poses for r in results], axis=1)
    points: list[EnvelopePoint] = []
    for index, (a, b) in enumerate(first.schedule.step_ticks):
        for row, tick in enumerate(first.record_ticks):
            if not a < tick <= b:
                continue
            at = poses[row]
            live = at[~np.isnan(at[:, 0])]
            if not len(live):
                continue
            major, minor, angle = _ellipse(live[:, 0], live[:, 1])
            yaw, yaw_sd = _yaw_stats(live[:, 2])
            points.append(
                EnvelopePoint(
                    step=index,
                    step_t_s=_r((tick - a) * dt_s),
                    samples=len(live),
                    pose=Pose(_r(live[:, 0].mean()), _r(live[:, 1].mean()), _r(yaw)),
                    major_m=_r(major),
                    minor_m=_r(minor),
                    angle_deg=_r(angle),
                    yaw_sd_deg=_r(yaw_sd),
                )
            )
    return points


def _hits(results: Sequence[BatchResult]) -> list[ObstacleHits]:
    obstacles = [o for r in results for o in r.collision_obstacle]
    steps = np.concatenate([r.collision_step for r in results])
    contacts = np.concatenate([r.collision_contact for r in results])
    out: list[ObstacleHits] = []
    counts = Counter(o for o in obstacles if o is not None)
    for oid, count in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])):
        mine = [i for i, o in enumerate(obstacles) if o == oid]
        by_step = Counter(int(steps[i]) for i in mine)
        step = min(by_step, key=lambda s: (-by_step[s], s))
        at = contacts[[i for i in mine if steps[i] == step]]
        contact = Point(_r(at[:, 0].mean()), _r(at[:, 1].mean()))
        out.append(ObstacleHits(oid, count, step, contact))
    return out


def summarise(
    results: Sequence[BatchResult],
    plan: Plan,
    *,
    start: Pose,
    seed: int,
    spread: str,
    slip_sigma: float,
    position_tolerance_m: float,
    yaw_tolerance_deg: float,
) -> Uncertainty:
    """The uncertainty block of a verdict from its chunks' results (in chunk order).

    Args:
        results: :func:`run_chunk` of each chunk, in order.
        plan: the plan played.
        start: its start pose.
        seed, spread, slip_sigma: how the twins were drawn (reported).
        position_tolerance_m, yaw_tolerance_deg: the verdict's tolerances, to judge
            each twin.
    """
    first = results[0]
    dt = first.dt_s
    sched = first.schedule
    n = sum(r.size for r in results)
    final = np.concatenate([r.final for r in results])
    hit = np.concatenate([r.collision_tick for r in results]) >= 0
    poses = np.concatenate([r.poses for r in results], axis=1)
    row_of = {tick: row for row, tick in enumerate(first.record_ticks)}
    stalled = ~hit if sched.stall is not None else np.zeros(n, dtype=bool)
    played = [c for c, _, _ in plan.to_wire()][: len(sched.step_ticks)]
    last_drive = max(
        (i for i, c in enumerate(played) if c in (Command.FWD, Command.REV)), default=None
    )
    goal = plan.goal
    errors: list[tuple[float, float, float, float]] = []
    approved = 0
    for i in range(n):
        if hit[i] or stalled[i]:
            continue
        if last_drive is None:
            heading = approach_heading_rad([], [], (start.x, start.y, start.yaw_rad), goal.xy)
        else:
            a = sched.step_ticks[last_drive][0]
            yaw0 = start.yaw_rad if a == 0 else float(poses[row_of[a], i, 2])
            heading = approach_heading_rad(
                [played[last_drive]], [yaw0], (start.x, start.y, start.yaw_rad), goal.xy
            )
        x, y, yaw = (float(v) for v in final[i])
        err = goal_error((x, y, math.degrees(yaw)), (goal.x, goal.y, goal.yaw_deg), heading)
        errors.append((err.distance_m, err.longitudinal_m, err.lateral_m, err.yaw_deg))
        if err.distance_m <= position_tolerance_m and abs(err.yaw_deg) <= yaw_tolerance_deg:
            approved += 1
    table = np.array(errors, dtype=np.float64).reshape(-1, 4)

    def pct(column: int) -> tuple[float, ...]:
        if not len(table):
            return ()
        return tuple(_r(v) for v in np.percentile(table[:, column], PERCENTILES))

    return Uncertainty(
        samples=n,
        seed=seed,
        spread=spread,
        slip_sigma=_r(slip_sigma),
        collision_probability=_r(hit.sum() / n),
        stall_probability=_r(stalled.sum() / n),
        approved_probability=_r(approved / n),
        collisions=tuple(_hits(results)),
        goal_error=GoalErrorPercentiles(
            samples=len(table),
            percentiles=PERCENTILES,
            distance_m=pct(0),
            position_m=pct(1),
            lateral_m=pct(2),
            yaw_deg=pct(3),
        ),
        level=ENVELOPE_LEVEL,
        envelope=tuple(_envelope(results, dt)),
    )
