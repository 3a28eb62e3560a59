"""A calibration that designs and drives its own steps: ``rover calibrate --drive``.

Within a budget of driving seconds (nominal step durations, rests not counted), a
campaign repeats: **design** a round (:mod:`emulator.design`: steps chosen one at a
time, each cutting the worst probe's spread most per second of driving, among those with
room around the rover, :func:`room_for`, and in the budget); **drive** it as one plan (a
:class:`Driver`: validated on the gate, executed and recorded with rests between steps;
a rejected plan's faulty step is ruled out where it would have started and the round
designed again); **fit** every step measured so far (:func:`emulator.fit.fit_ground`).

It stops when every probe is under its bar and has stood still for :data:`STILL_FITS`
fits, when the budget cannot hold another step, or when no candidate has room; the last
fit is then made with its refusals. Drivers: :class:`~emulator.stackdriver.StackDriver`
(a real stack) and ``sim.calibration_runs.LockstepRover`` (virtual time). More in
docs/twin.md, "A designed calibration".
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from emulator import design
from emulator.calibration import FIT_PARAMETERS, Calibration
from emulator.errors import UnidentifiableError
from emulator.fit import MIN_DRIVING_S, PRIOR_SIGMA, FitReport, fit_ground
from emulator.ground import Ground
from emulator.observations import ObservedSteps, StepObservation, observe_steps
from emulator.recording import read_recording
from emulator.twin import GATE_DT_S, Pose2D
from firmware_proto.model.geometry import point_in_polygon, segment_polygon_distance, wrap_rad
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap
from firmware_proto.wire.messages import Command

__all__ = [
    "DEFAULT_BUDGET_S",
    "FIRST_ROUND",
    "GROUND_NAMES",
    "ROUND_STEPS",
    "Campaign",
    "Driven",
    "Driver",
    "Round",
    "room_for",
    "run_campaign",
]

logger = logging.getLogger(__name__)

DEFAULT_BUDGET_S = 60.0
"""Driving seconds a campaign may use (nominal step durations)."""
FIRST_ROUND = 6
"""Steps of the first round: a first fit needs six (:data:`emulator.fit.MIN_STEPS`)."""
ROUND_STEPS = 3
"""Steps of each later round: few enough that the design follows the fit, enough that a
round's fixed costs (a plan through the gate and the link, a fit) are shared."""
MARGIN_M = 0.15
"""Clearance kept around a step's swept footprint beyond the gate's, m."""
UNKNOWN_TURN = 0.5
"""Before the first fit, a turn may end this far (as a fraction of itself) from where
the description's model puts it: what the next straight step's room allows for."""
MAX_ROUND_STEPS = 12
"""A plan's limit (the plan schema's)."""
GATE_RETRIES = 5
"""Plans the gate may reject in a row before the campaign stops; each rules out its faulty step."""
IDLE_ROUNDS = 3
"""Approved plans in a row of which no step ran before the campaign stops: nothing changed
for the design, which would ask for the same plan again, round after round."""
STILL_FITS = 2
"""Fits in a row that must leave every probe's spread under its bar, and move it less than
its bar, for the campaign to stop early (one is not enough: the covariance is linearised)."""

GROUND_NAMES = FIT_PARAMETERS
"""What the design identifies: the ground's parameters (a region's friction is fitted
where the steps drove on it, not designed for)."""

_DEFAULT_XY_M = 0.003
_DEFAULT_YAW_RAD = 0.002
_DEFAULT_HEADING_RAD = 0.002


@dataclass(frozen=True)
class Driven:
    """What a driver did with one plan.

    Attributes:
        approved: the gate approved it (else nothing was driven).
        recording: the plan's recording (MCAP), when something was driven.
        reason: the gate's or the execution's reason when not all of it ran.
        failed_step: the step the gate found at fault, when it rejected the plan.
    """

    approved: bool
    recording: Path | None
    reason: str = ""
    failed_step: int | None = None
    """The step the gate found at fault (a rejection), if it said."""


class Driver(Protocol):
    """How a campaign reaches the rover; ``speed_factor``: mission seconds per second of
    the recordings' clock (1 in lockstep)."""

    speed_factor: float

    def pose(self) -> Pose2D:
        """The rover's pose now, map frame (it is at rest)."""
        ...

    def drive(self, steps: Sequence[tuple[int, int, int]], *, goal: Pose2D, path: Path) -> Driven:
        """Validate ``steps`` on the gate as one plan ending at ``goal``; if approved,
        execute it with rests between steps, recorded to ``path`` until at rest."""
        ...


@dataclass(frozen=True)
class Round:
    """One plan of a campaign.

    Attributes:
        steps: what was asked.
        driven: what the driver did.
        measured: how many of its steps were measured at rest.
        excess: the worst probe's spread over its bar after the next fit (``nan``: none).
        fit_wall_s: wall time of that fit, s.
    """

    steps: tuple[tuple[int, int, int], ...]
    driven: Driven
    measured: int
    excess: float
    fit_wall_s: float


@dataclass
class Campaign:
    """A campaign's outcome (see :func:`run_campaign`).

    Attributes:
        calibration: the last fit (with its refusals), ``None`` when it refused.
        refusal: why the last fit refused, if it did.
        rounds: each plan, in order.
        driving_s: nominal driving seconds of the steps driven.
        stopped: why it stopped.
        recordings: every recording made (and the ones given).
        wall_s: wall time of the whole campaign, s; ``fit_wall_s`` of its fits.
    """

    calibration: Calibration | None = None
    refusal: UnidentifiableError | None = None
    rounds: list[Round] = field(default_factory=list)
    driving_s: float = 0.0
    stopped: str = ""
    recordings: list[Path] = field(default_factory=list)
    wall_s: float = 0.0
    fit_wall_s: float = 0.0
    report: FitReport | None = None


def room_for(
    world: WorldMap | None,
    rover: RoverDescription,
    pose: Pose2D,
    step: tuple[int, int, int],
    move: tuple[float, float, float],
    *,
    heading_unknown_rad: float = 0.0,
    margin_m: float = MARGIN_M,
) -> bool:
    """Whether ``step`` from ``pose`` keeps the footprint's circle ``margin_m`` clear of
    every obstacle, wall and traction region it is not in: where it turns, or along its
    swept segment (10 % past ``move``, +-``heading_unknown_rad``) where it drives."""
    if world is None:
        return True
    radius = rover.footprint_radius_m + margin_m
    here = (pose.x_m, pose.y_m)
    regions = [r.polygon for r in world.traction_regions if not point_in_polygon(here, r.polygon)]
    if step[0] in (Command.LEFT, Command.RIGHT):
        ends = [(here, here)]
    else:
        forward = move[0] * 1.1
        ends = []
        for spread in (0.0, -heading_unknown_rad, heading_unknown_rad):
            yaw = pose.yaw_rad + spread
            ends.append(
                (here, (here[0] + forward * math.cos(yaw), here[1] + forward * math.sin(yaw)))
            )
    for a, b in ends:
        if world.segment_clearance(a, b)[0] < radius:
            return False
        if any(segment_polygon_distance(a, b, polygon) < radius for polygon in regions):
            return False
    return True


def _after(pose: Pose2D, move: np.ndarray) -> Pose2D:
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    return Pose2D(
        pose.x_m + c * move[0] - s * move[1],
        pose.y_m + s * move[0] + c * move[1],
        wrap_rad(pose.yaw_rad + move[2]),
    )


def _key(pose: Pose2D) -> tuple[float, float]:
    return round(pose.x_m, 2), round(pose.y_m, 2)


def _kind(command: int) -> int:
    """0 for a turn on the spot (any turn there sweeps the same disc), else the command."""
    return 0 if command in (Command.LEFT, Command.RIGHT) else command


def _ruled_out(
    ruled_out: set[tuple[tuple[float, float], int, int]],
    where: tuple[float, float],
    step: tuple[int, int, int],
) -> bool:
    """Whether the gate rejected a step like this here: a turn (any turn), or a straight
    step the same way at least as long."""
    kind = _kind(step[0])
    return any(
        at == where and k == kind and (kind == 0 or step[2] >= distance)
        for at, k, distance in ruled_out
    )


def _preference(
    world: WorldMap | None,
    rover: RoverDescription,
    at: Pose2D,
    home: Pose2D,
    candidates: Sequence[tuple[int, int, int]],
    moves: np.ndarray,
) -> np.ndarray:
    """Tie-breaker among equally informative steps: near ``home``, facing as it did."""
    out = np.empty(len(candidates))
    for i, step in enumerate(candidates):
        end = _after(at, moves[i])
        if step[0] in (Command.LEFT, Command.RIGHT):
            out[i] = -abs(wrap_rad(end.yaw_rad - home.yaw_rad))
        else:
            room = world.clearance((end.x_m, end.y_m), 2.0)[0] if world is not None else 2.0
            out[i] = min(room, 2.0) - math.dist((end.x_m, end.y_m), (home.x_m, home.y_m))
    return out


def _structure_met(steps: Sequence[tuple[int, int, int]], rover: RoverDescription) -> bool:
    """Whether a first fit can be made: enough steps and driving, turns and straights."""
    turns = sum(c in (Command.LEFT, Command.RIGHT) for c, _, _ in steps)
    driving = sum(rover.step_duration_s(s, d) for _, s, d in steps)
    return len(steps) >= FIRST_ROUND and 0 < turns < len(steps) and driving >= 15.0


@dataclass(frozen=True)
class _Design:
    """What a round is chosen from: sensitivities, noise and precision at the current fit."""

    moves: np.ndarray
    jac: np.ndarray
    noise: np.ndarray
    probe_jac: np.ndarray
    precision: np.ndarray
    probe_moves: np.ndarray


def _design(
    rover: RoverDescription,
    ground: Ground,
    covariance: np.ndarray,
    observations: Sequence[StepObservation],
    calibration: Calibration | None,
    dt_s: float,
) -> _Design:
    names = list(GROUND_NAMES)
    candidates = design.candidates(rover)
    moves, jac, side = design.sensitivities(rover, ground, names, candidates, dt_s=dt_s, sides=True)
    probe_moves, probe_jac, _ = design.sensitivities(
        rover, ground, names, design.probes(rover), dt_s=dt_s
    )
    assert side is not None
    noise = calibration.noise if calibration is not None else None

    def median(key: str, default: float) -> float:
        if not observations:
            return default
        return float(np.median([getattr(o, key) for o in observations]))

    cand_noise = design.step_noise(
        moves,
        side,
        sigma_xy_m=median("sigma_xy_m", _DEFAULT_XY_M),
        sigma_yaw_rad=median("sigma_yaw_rad", _DEFAULT_YAW_RAD),
        sigma_heading_rad=noise.heading_sigma_rad if noise else _DEFAULT_HEADING_RAD,
        slip_sigma=noise.slip_sigma if noise else 0.0,
    )
    return _Design(moves, jac, cand_noise, probe_jac, np.linalg.inv(covariance), probe_moves)


def _choose(
    d: _Design,
    rover: RoverDescription,
    world: WorldMap | None,
    pose: Pose2D,
    *,
    count: int,
    first: bool,
    left_s: float,
    ruled_out: set[tuple[tuple[float, float], int, int]],
    home: Pose2D,
) -> tuple[list[int], list[Pose2D]]:
    """Up to ``count`` candidates, and the fit's predicted poses before each and after."""
    candidates = design.candidates(rover)
    durations = np.array([rover.step_duration_s(s, dist) for _c, s, dist in candidates])
    shortest = float(durations.min())
    is_turn = np.array([c in (Command.LEFT, Command.RIGHT) for c, _, _ in candidates])
    inv_noise = np.linalg.inv(d.noise)
    precision = d.precision.copy()
    chosen: list[int] = []
    at = pose
    poses = [pose]
    turned = False

    def more() -> bool:
        if len(chosen) >= MAX_ROUND_STEPS:
            return False
        if not first:
            return len(chosen) < count
        kinds = {bool(is_turn[i]) for i in chosen}
        driving = float(sum(durations[i] for i in chosen))
        return len(chosen) < count or driving < MIN_DRIVING_S or len(kinds) < 2

    while more():
        spent = float(sum(durations[i] for i in chosen))
        unknown = UNKNOWN_TURN * math.pi if (first and turned) else 0.0
        where = (round(at.x_m, 2), round(at.y_m, 2))
        allowed = np.array(
            [
                durations[i] <= left_s - spent + 1e-9
                and not _ruled_out(ruled_out, where, candidates[i])
                and room_for(
                    world, rover, at, candidates[i], tuple(d.moves[i]), heading_unknown_rad=unknown
                )
                for i in range(len(candidates))
            ]
        )
        if first and len(chosen) >= count - 1 and len({bool(is_turn[i]) for i in chosen}) == 1:
            allowed &= is_turn != is_turn[chosen[0]]  # a first fit needs both kinds
        if first and left_s >= MIN_DRIVING_S:
            # A step either reaches a first fit's driving or leaves budget for another.
            total = spent + durations
            allowed &= (total >= MIN_DRIVING_S) | (left_s - total >= shortest - 1e-9)
        index, _after_excess = design.best_step(
            precision,
            d.probe_jac,
            d.jac,
            d.noise,
            durations,
            allowed=allowed,
            preference=_preference(world, rover, at, home, candidates, d.moves),
        )
        if index < 0:
            break
        chosen.append(index)
        precision = precision + d.jac[index].T @ inv_noise[index] @ d.jac[index]
        turned = turned or bool(is_turn[index])
        at = _after(at, d.moves[index])
        poses.append(at)
    return chosen, poses


def run_campaign(
    driver: Driver,
    rover: RoverDescription,
    world: WorldMap | None,
    workdir: Path,
    *,
    budget_s: float = DEFAULT_BUDGET_S,
    recordings: Sequence[Path] = (),
    dt_s: float = GATE_DT_S,
    on_event: Callable[[str], None] = lambda line: None,
) -> Campaign:
    """Design, drive and fit until done (module docstring).

    Args:
        driver: reaches the rover.
        rover: the rover description (the priors, the units).
        world: the map driven on (free space, regions).
        workdir: where each round's recording is written.
        budget_s: driving seconds allowed (nominal step durations), > 0.
        recordings: missions already recorded, fitted first (not counted in the budget).
        dt_s: the twin's step (the gate's).
        on_event: one line per plan, rejection and fit.

    Raises:
        RecordingError: a given recording cannot be read.
        ValueError: ``budget_s`` not > 0.
    """
    if not (math.isfinite(budget_s) and budget_s > 0.0):
        raise ValueError(f"budget_s must be > 0, got {budget_s}")
    t0 = time.perf_counter()
    workdir.mkdir(parents=True, exist_ok=True)
    out = Campaign(recordings=list(recordings))
    given = [read_recording(p) for p in recordings]
    seen = observe_steps(given, rover, speed_factor=driver.speed_factor)
    observations = list(seen.observations)
    skipped = list(seen.skipped)
    candidates = design.candidates(rover)
    shortest = min(rover.step_duration_s(s, d) for _c, s, d in candidates)
    calibration: Calibration | None = None
    pose = home = driver.pose()
    ruled_out: set[tuple[tuple[float, float], int, int]] = set()
    rejections = 0
    idle = 0  # approved plans in a row that ran no step (IDLE_ROUNDS)
    previous: np.ndarray | None = None
    still = 0

    def fit(refuse: bool) -> tuple[Calibration, FitReport]:
        driving = sum(rover.step_duration_s(o.speed, o.distance) for o in observations)
        observed = ObservedSteps(tuple(observations), tuple(skipped), driving)
        sources = tuple(str(p) for p in out.recordings)
        start = calibration.ground if calibration is not None else None
        tf = time.perf_counter()
        try:
            return fit_ground(
                observed,
                rover,
                world,
                start=start,
                dt_s=dt_s,
                sources=sources,
                refuse=refuse,
                posterior=refuse,
            )
        finally:
            out.fit_wall_s += time.perf_counter() - tf

    while True:
        if _structure_met([o.step for o in observations], rover):
            calibration, out.report = fit(refuse=False)
            cov = _ground_covariance(calibration)
            d = _design(rover, calibration.ground, cov, observations, calibration, dt_s)
            excess = float(np.max(design.excess(design.probe_spread(d.probe_jac, cov))))
            # Trusted once the probes stand still between fits (STILL_FITS).
            shift = math.inf
            if previous is not None:
                shift = float(np.max(design.excess(np.abs(d.probe_moves - previous))))
            previous = d.probe_moves
            if out.rounds:
                last = out.rounds[-1]
                out.rounds[-1] = Round(
                    last.steps, last.driven, last.measured, excess, out.report.wall_s
                )
            moved = f", moved {shift:.2f} of it since the last fit" if math.isfinite(shift) else ""
            on_event(
                f"fit of {len(observations)} steps: the worst probe's spread is {excess:.2f} "
                f"of its bar{moved} (fit {out.report.wall_s:.1f} s)"
            )
            still = still + 1 if excess <= 1.0 and shift <= 1.0 else 0
            if still >= STILL_FITS:
                out.stopped = (
                    f"every probe under its bar, and still, at {STILL_FITS} fits in a row: every "
                    "parameter under its target"
                )
                break
        else:
            cov = np.eye(len(GROUND_NAMES)) * PRIOR_SIGMA**2
            d = _design(rover, Ground.of_rover(rover, world), cov, observations, None, dt_s)
        left = budget_s - out.driving_s
        first = calibration is None
        count = max(ROUND_STEPS, FIRST_ROUND - len(observations)) if first else ROUND_STEPS
        chosen, poses = _choose(
            d,
            rover,
            world,
            pose,
            count=count,
            first=first,
            left_s=left,
            ruled_out=ruled_out,
            home=home,
        )
        if not chosen:
            out.stopped = (
                "the budget cannot hold another step"
                if left < shortest
                else "no candidate step fits in the room left around the rover"
            )
            break
        steps = tuple(candidates[i] for i in chosen)
        n = len(out.rounds) + 1
        driving = sum(rover.step_duration_s(s, dist) for _c, s, dist in steps)
        on_event(
            f"round {n}: "
            + "; ".join(design.describe_step(rover, s) for s in steps)
            + f" ({driving:.1f} s of driving, {left:.1f} s left)"
        )
        driven = driver.drive(steps, goal=poses[-1], path=workdir / f"round-{n:02d}.mcap")
        if not driven.approved:
            on_event(f"round {n}: the gate rejected it: {driven.reason}")
            k = driven.failed_step if driven.failed_step is not None else 0
            k = min(max(k, 0), len(steps) - 1)
            command, _speed, distance = steps[k]
            at = _key(poses[k])
            ruled_out.add((at, _kind(command), 0 if _kind(command) == 0 else distance))
            rejections += 1
            out.rounds.append(Round(steps, driven, 0, math.nan, 0.0))
            if rejections >= GATE_RETRIES:
                out.stopped = f"the gate rejected {rejections} plans in a row"
                break
            continue
        rejections = 0
        measured = 0
        ran_none = True
        moved_to: Pose2D | None = None
        if driven.recording is not None:
            out.recordings.append(driven.recording)
            rec = read_recording(driven.recording)
            round_seen = observe_steps([rec], rover, speed_factor=driver.speed_factor)
            observations += round_seen.observations
            skipped += round_seen.skipped
            measured = len(round_seen.observations)
            ran = [s for s in rec.steps if s.accepted_s is not None]
            ran_none = not ran
            out.driving_s += sum(rover.step_duration_s(s.speed, s.distance) for s in ran)
            final = round_seen.observations[-1] if round_seen.observations else None
            if final is not None and final.index == len(rec.steps) - 1:
                moved_to = final.end
        pose = moved_to if moved_to is not None else driver.pose()
        out.rounds.append(Round(steps, driven, measured, math.nan, 0.0))
        if driven.reason:
            on_event(f"round {n}: {driven.reason}")
        idle = idle + 1 if ran_none else 0
        if idle >= IDLE_ROUNDS:
            out.stopped = f"{idle} approved plans in a row ran no step" + (
                f" (the last: {driven.reason})" if driven.reason else ""
            )
            break
    try:
        if len(observations) == 0:
            raise UnidentifiableError("nothing could be driven and measured")
        out.calibration, out.report = fit(refuse=True)
    except UnidentifiableError as exc:
        out.refusal = exc
    out.wall_s = time.perf_counter() - t0
    return out


def _ground_covariance(calibration: Calibration) -> np.ndarray:
    """The covariance of the ground parameters' logarithms (regions left out)."""
    index = [calibration.parameters.index(n) for n in GROUND_NAMES]
    full = np.array(calibration.covariance)
    return np.asarray(full[np.ix_(index, index)])
