"""``rover calibrate --drive`` on grounds nobody has seen: prediction error before and
after, against the floor, and whether the gate's uncertainty bands hold the outcomes.

For each of three grounds generated from seeds the tests never use (one each from a
loose, a packed and an anisotropic range: :func:`generated_ground`):

1. a designed calibration (:func:`emulator.campaign.run_campaign`, what ``rover calibrate
   --drive`` runs) drives the rover in lockstep (:class:`sim.calibration_runs.
   LockstepRover`: the controller model at 1 ms with its sensor noise, the bridge's
   odometry code, a 3 s round trip, the same MCAP writer as a real run), on the lab map
   (its traction region left out) from the lab's start, within 60 s of driving, every
   plan validated by the gate's own validator (the description's twin) before it runs;
   its wall time is the time to calibrate (designing, fitting; the lockstep driving
   itself is counted apart);
2. held-out 12-step missions (seeded random steps, never used to fit) are driven on the
   same ground on an open field, back to back as a plan runs on board (each step queued
   in the controller while the one before runs: what the gate's playback plays), and
   recorded (each after :data:`REST_S` at rest, ``--rest``); each one's final pose is
   predicted as the gate predicts it (the whole plan from the start pose measured at
   rest, at the gate's 10 ms step) by the rover
   description's twin (before), the calibrated one (after) and one given the ground's
   true parameters (the floor: what sensor noise, the step size and timing leave), and
   compared with where the rover truly came to rest (the lockstep twin's pose). The
   first missions are also driven by the step-by-step executor (a round trip of rest
   between steps), which the gate's back-to-back playback does not model;
3. the gate's uncertainty for the calibrated twin (:func:`gate.ensemble.draw`: the fit's
   covariance, its slip spread, the start's own noise as its rest measured it, given
   with the plan as ``start_sigma_m`` and ``start_sigma_deg`` are, its step error,
   antithetic pairs;
   200 twins in one :func:`gate.ensemble.run_chunk`) gives 90 % bands of the final pose's longitudinal and lateral offset (in the
   frame of the predicted final pose) and of its yaw; coverage is the share of outcomes
   inside their band, width the band's, centring how far the band's middle is from the
   point prediction (in half-widths). Beside the width over the median error, the width
   over the median error the bands themselves expect (:func:`width_over_error`): bands
   that hold their outcomes exactly give about that ratio on these plans, so a ratio far
   above 3 with the bands' own near it is the plans' geometry (errors more across the
   path than along it), not bands too wide.

The issue's bars: after within 1.5x of the floor on every ground with at most 60 s of
driving; 90 % bands holding 85-95 % of outcomes; median lateral width at most 3x the
median final-position error. Deterministic: every ground, mission and noise draw is
seeded (the wall times are not).

    python -m benchmarks.bench_calibration [--quick] [--missions N] [--budget S]
        [--ground KIND] [--seed KIND=SEED] [--rest S] [--keep DIR]

The held-out grounds (:data:`GROUND_SEEDS`) are for the final run of a method fixed
beforehand; development runs name their own grounds (``--seed``), and ``--quick`` is a
development ground.
"""

from __future__ import annotations

import argparse
import math
import random
import statistics
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from emulator.calibration import Calibration
from emulator.campaign import run_campaign
from emulator.ground import Ground
from emulator.observations import HEADING_SIGMA_FLOOR_RAD, MAX_REST_S, SETTLE_S, START_GUARD_S
from emulator.playback import measure_turn_efficiency, play
from emulator.recording import Recording, read_recording
from emulator.twin import GATE_DT_S, Pose2D, Twin
from emulator.twinfile import write_twin
from firmware_proto.model.geometry import wrap_rad
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import WorldMap, load_map
from gate.config import PlaybackSettings
from gate.ensemble import ChunkJob, draw, run_chunk
from gate.validator import Validator
from planner.record.mcaprec import record_messages
from sim.calibration_runs import (
    LockstepMission,
    LockstepRover,
    field_map,
    random_mission,
    validate_with_gate,
)

BUDGET_S = 60.0
FLOOR_BAR = 1.5
COVERAGE = (0.85, 0.95)
WIDTH_BAR = 3.0
BAND_SAMPLES = 200
REST_S = 3.0
"""Rest before each held-out plan (``--rest``), s: a round trip, what the executor
leaves between plans; the start is averaged over all of it but its first
:data:`~emulator.observations.SETTLE_S` (the body settling): 2.5 s by default, what a
calibration's rests average (:data:`~emulator.observations.MAX_REST_S`)."""
STEP_BY_STEP_MISSIONS = 2
"""Held-out missions also driven by the step-by-step executor (rests between steps)."""

HELD_OUT_MISSIONS = 30
"""Held-out missions per ground (``--missions``). One mission's error is mostly its start
pose's noise (1-16 mm on one ground), so the mean of ten scatters: the second held-out
loose ground gave 1.54x the floor over its first ten and 1.09x over thirty (0.90x over
the twenty after the ten)."""
GROUND_SEEDS = {"loose": 878799, "packed": 196230, "anisotropic": 281156}
"""Seeds of the benchmark's held-out grounds: used nowhere else (``--quick`` and the tests
use :data:`QUICK_SEED`; development uses its own, ``--seed``)."""
SEEN_SEEDS = {
    "loose": (90417, 923476, 579788),
    "packed": (90533, 625244, 195140),
    "anisotropic": (90671, 869543, 997701),
}
"""The held-out seeds before :data:`GROUND_SEEDS`, oldest first: the first looked at twice
while the bands were developed, the second run once with ten missions a ground (and its
loose ground again with thirty, to see why it missed the floor's bar), the third run once
with thirty (2026-11-29). No longer held out: ``--seed loose=923476`` runs one."""
QUICK_SEED = 1000
"""The loose ground of ``--quick`` (a development seed, not a held-out one)."""

RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "loose": {
        "mu_longitudinal": (0.35, 0.5),
        "lateral_ratio": (0.9, 1.3),
        "slip_saturation_mps": (0.002, 0.006),
        "slip_saturation_ratio": (0.03, 0.06),
        "rolling_resistance": (0.06, 0.1),
    },
    "packed": {
        "mu_longitudinal": (0.65, 0.85),
        "lateral_ratio": (1.1, 1.4),
        "slip_saturation_mps": (0.001, 0.003),
        "slip_saturation_ratio": (0.01, 0.02),
        "rolling_resistance": (0.02, 0.04),
    },
    "anisotropic": {
        "mu_longitudinal": (0.5, 0.7),
        "lateral_ratio": (0.35, 0.55),
        "slip_saturation_mps": (0.002, 0.004),
        "slip_saturation_ratio": (0.02, 0.04),
        "rolling_resistance": (0.04, 0.07),
    },
}
"""Each kind's ranges (uniform in log): ``lateral_ratio`` is ``mu_lateral /
mu_longitudinal`` (anisotropic: much less grip across the wheels than along)."""


def generated_ground(kind: str, seed: int, rover: RoverDescription) -> Ground:
    """A ground of ``kind``'s ranges drawn with ``seed`` (log-uniform)."""
    rng = random.Random(seed)
    ranges = RANGES[kind]

    def pick(key: str) -> float:
        lo, hi = ranges[key]
        return math.exp(rng.uniform(math.log(lo), math.log(hi)))

    mu = pick("mu_longitudinal")
    values = {
        "mu_longitudinal": mu,
        "mu_lateral": mu * pick("lateral_ratio"),
        "slip_saturation_mps": pick("slip_saturation_mps"),
        "slip_saturation_ratio": pick("slip_saturation_ratio"),
        "rolling_resistance": pick("rolling_resistance"),
    }
    base = replace(Ground.of_rover(rover), name=f"{kind}-{seed}", description=f"{kind} range")
    return base.with_values(**values)


def calibration_map() -> WorldMap:
    """The lab map without its traction region: room to find around the start."""
    return replace(load_map("lab"), traction_regions=())


@dataclass
class HeldOutResult:
    """One held-out mission: errors (m, deg) of each twin, and the band check."""

    errors_m: dict[str, float]
    errors_deg: dict[str, float]
    inside: tuple[bool, bool, bool]
    widths: tuple[float, float, float]
    centring: tuple[float, float, float]
    band_errors_m: tuple[float, ...] = ()
    """How far each of the band's samples ends from the point prediction (m): the errors
    the band itself expects."""


@dataclass
class GroundResult:
    name: str
    truth: Ground
    driving_s: float
    steps: int
    rounds: int
    stopped: str
    calibrate_wall_s: float
    calibrate_cpu_s: float
    fit_wall_s: float
    lockstep_wall_s: float
    fitted: dict[str, tuple[float, float, float]]
    turn_efficiency: tuple[float, float, float]
    slip_sigma: float
    outcomes: list[HeldOutResult] = field(default_factory=list)
    refusal: str = ""
    rested_m: dict[str, list[float]] = field(default_factory=dict)


def _rest_pose(rec: Recording, lo: float, hi: float) -> Pose2D:
    return _rest_measured(rec, lo, hi)[0]


def _rest_measured(rec: Recording, lo: float, hi: float) -> tuple[Pose2D, float, float]:
    """The POSE averaged over ``[lo, hi]`` (rover clock) and its own 1-sigma errors:
    position per axis (the samples' stated noise over the root of their number, m) and
    heading (their spread over the root of their number, at least
    :data:`~emulator.observations.HEADING_SIGMA_FLOOR_RAD`), as a calibration's rests."""
    sel = (rec.pose_t_s >= lo) & (rec.pose_t_s <= hi)
    n = int(np.count_nonzero(sel))
    xy = rec.pose_xy_m[sel].mean(axis=0)
    unit = np.exp(1j * rec.pose_yaw_rad[sel])
    yaw = float(np.angle(unit.mean()))
    spread = np.angle(unit * np.exp(-1j * yaw))
    position = float(np.mean(rec.pose_sigma_m[sel])) / math.sqrt(n)
    heading = max(HEADING_SIGMA_FLOOR_RAD, float(np.std(spread, ddof=1)) / math.sqrt(n))
    return Pose2D(float(xy[0]), float(xy[1]), yaw), position, heading


def mission_start(rec: Recording, rest_s: float = MAX_REST_S) -> tuple[Pose2D, float, float]:
    """The recorded pose at rest before the first step (the POSE averaged over the last
    ``rest_s`` s before it) and its own 1-sigma errors (m per axis, rad): what the
    ground station gives the gate with the plan (``start``, ``start_sigma_m``,
    ``start_sigma_deg``)."""
    first = rec.to_rover_clock(rec.steps[0].accepted_s or 0.0)
    return _rest_measured(rec, first - START_GUARD_S - rest_s, first - START_GUARD_S)


def mission_end(rec: Recording) -> Pose2D:
    """The recorded pose at rest after the last step."""
    last = rec.to_rover_clock(rec.steps[-1].ended_s or 0.0)
    return _rest_pose(rec, last + SETTLE_S, last + SETTLE_S + MAX_REST_S)


def predict_final(
    rover: RoverDescription,
    world: WorldMap,
    ground: Ground,
    start: Pose2D,
    steps: list[tuple[int, int, int]],
) -> Pose2D:
    twin = Twin(ground.rover(rover), ground.world(world), dt_s=GATE_DT_S, start=start)
    return play(twin, steps).final_pose


def _in_frame(pose: Pose2D, origin: Pose2D) -> tuple[float, float, float]:
    """``pose`` in the frame of ``origin``: along, across (m), yaw difference (rad)."""
    dx, dy = pose.x_m - origin.x_m, pose.y_m - origin.y_m
    c, s = math.cos(origin.yaw_rad), math.sin(origin.yaw_rad)
    return c * dx + s * dy, -s * dx + c * dy, wrap_rad(pose.yaw_rad - origin.yaw_rad)


def band_check(
    rover: RoverDescription,
    world: WorldMap,
    calibration: Calibration,
    start: Pose2D,
    steps: list[tuple[int, int, int]],
    nominal: Pose2D,
    truth: Pose2D,
    seed: int,
    start_sigma: tuple[float | None, float | None] = (None, None),
) -> tuple[
    tuple[bool, bool, bool], tuple[float, float, float], tuple[float, float, float], np.ndarray
]:
    """The gate's 90 % bands of the final pose (see the module docstring): whether the
    true outcome is inside each, each width (m, m, rad), each centring, and each
    sample's distance from the point prediction (m). ``start_sigma``: the start's own
    1-sigma errors (m, rad) given with the plan (``None``: the calibration's)."""
    noise = calibration.noise
    slip = noise.slip_sigma if noise is not None else 0.1
    draws = draw(calibration, BAND_SAMPLES, seed, slip, start_sigma)
    # The gate's own chunk (its step error too), all the twins in one.
    job = ChunkJob(
        rover,
        world,
        tuple(draws),
        tuple(steps),
        GATE_DT_S,
        0.0,
        Pose(start.x_m, start.y_m, math.degrees(start.yaw_rad)),
        calibration.ground if calibration.step_error_scale > 0.0 else None,
    )
    result = run_chunk(job)
    samples = np.array([_in_frame(Pose2D(*row), nominal) for row in result.final])
    outcome = _in_frame(truth, nominal)
    inside, widths, centring = [], [], []
    for axis in range(3):
        lo, hi = np.percentile(samples[:, axis], [5.0, 95.0])
        inside.append(bool(lo <= outcome[axis] <= hi))
        widths.append(float(hi - lo))
        half = max((hi - lo) / 2.0, 1e-12)
        centring.append(float(abs((hi + lo) / 2.0) / half))
    distances = np.hypot(samples[:, 0], samples[:, 1])
    return tuple(inside), tuple(widths), tuple(centring), distances  # type: ignore[return-value]


def width_over_error(outcomes: list[HeldOutResult]) -> tuple[float, float]:
    """The issue's width statistic: the median lateral width of the outcomes' bands over
    their median final-position error; and the same over the median error the bands
    themselves expect (every outcome's samples pooled, each outcome weighing the same:
    what the statistic would be if each outcome were a draw from its band). The second
    is what bands that hold their outcomes exactly give on these plans: a first far
    above 3 with a second near it is the plans' geometry, not bands too wide."""
    width = statistics.median(o.widths[1] for o in outcomes)
    error = statistics.median(o.errors_m["after"] for o in outcomes)
    own = float(np.median(np.concatenate([o.band_errors_m for o in outcomes])))
    return width / error, width / own


def _recorded(mission: LockstepMission, path: Path) -> Recording:
    """``mission`` written as a recording to ``path`` (as ``rover go --record`` does)
    and read back."""
    record_messages(path, mission.messages)
    return read_recording(path)


def run_ground(
    kind: str,
    rover: RoverDescription,
    missions: int,
    budget_s: float,
    work: Path,
    seed: int | None = None,
    rest_s: float = REST_S,
) -> GroundResult:
    """Calibrate on ``kind``'s ground of ``seed`` (default :data:`GROUND_SEEDS`'s) and
    check ``missions`` held-out plans (module docstring), each after ``rest_s`` s at
    rest, its start averaged over that rest but its first
    :data:`~emulator.observations.SETTLE_S` and given to the gate with its own noise."""
    name = kind if seed is None else f"{kind}-{seed}"
    seed = GROUND_SEEDS[kind] if seed is None else seed
    truth = generated_ground(kind, seed, rover)
    lab = calibration_map()
    validator = Validator(rover, {lab.name: lab}, PlaybackSettings(), lab.name)
    driver = LockstepRover(
        rover,
        lab,
        truth,
        seed=seed,
        validator=validate_with_gate(validator),
        recorder=record_messages,
    )
    t0, c0 = time.perf_counter(), time.process_time()
    campaign = run_campaign(driver, rover, lab, work / name, budget_s=budget_s)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    cal = campaign.calibration
    result = GroundResult(
        name=name,
        truth=truth,
        driving_s=driver.driving_s,
        steps=cal.after.steps if cal is not None else 0,
        rounds=len(campaign.rounds),
        stopped=campaign.stopped,
        calibrate_wall_s=wall - driver.lockstep_wall_s,
        calibrate_cpu_s=cpu - driver.lockstep_cpu_s,
        fit_wall_s=campaign.fit_wall_s,
        lockstep_wall_s=driver.lockstep_wall_s,
        fitted={},
        turn_efficiency=(math.nan, math.nan, math.nan),
        slip_sigma=math.nan,
    )
    if cal is None:
        result.refusal = str(campaign.refusal)
        return result
    write_twin(work / f"{name}-twin.toml", rover, cal)
    quarter = rover.turn_units_for_yaw(math.pi / 2.0)
    result.fitted = {
        p: (cal.value(p), cal.relative_sigma(p), t)
        for p, t in zip(cal.parameters, cal.targets, strict=True)
    }
    result.turn_efficiency = (
        rover.traction.turn_efficiency,
        cal.turn_efficiency,
        measure_turn_efficiency(truth.rover(rover), distance=quarter),
    )
    result.slip_sigma = cal.noise.slip_sigma if cal.noise is not None else math.nan
    field_world = field_map()
    twins = {"before": Ground.of_rover(rover), "after": cal.ground, "floor": truth}
    for k in range(missions):
        steps = random_mission(rover, random.Random(seed * 10 + k), 12)
        lockstep = LockstepRover(rover, field_world, truth, seed=seed + 1000 + k, rest_s=rest_s)
        mission = lockstep.drive_steps(steps, back_to_back=True)
        if k < STEP_BY_STEP_MISSIONS:
            # The same mission by the step-by-step executor (a round trip of rest
            # between steps), against the same back-to-back prediction.
            rested = LockstepRover(rover, field_world, truth, seed=seed + 1000 + k).drive_steps(
                steps
            )
            start = mission_start(_recorded(rested, work / f"{name}-rested{k}.mcap"))[0]
            for key in ("after", "floor"):
                final = predict_final(rover, field_world, twins[key], start, steps)
                gap = math.dist((final.x_m, final.y_m), (rested.final.x_m, rested.final.y_m))
                result.rested_m.setdefault(key, []).append(gap)
        start, sigma_m, sigma_rad = mission_start(
            _recorded(mission, work / f"{name}-test{k}.mcap"), rest_s - SETTLE_S
        )
        errors_m, errors_deg = {}, {}
        finals = {}
        for key, ground in twins.items():
            final = predict_final(rover, field_world, ground, start, steps)
            finals[key] = final
            errors_m[key] = math.dist(
                (final.x_m, final.y_m), (mission.final.x_m, mission.final.y_m)
            )
            errors_deg[key] = abs(math.degrees(wrap_rad(final.yaw_rad - mission.final.yaw_rad)))
        inside, widths, centring, distances = band_check(
            rover,
            field_world,
            cal,
            start,
            steps,
            finals["after"],
            mission.final,
            seed + k,
            (sigma_m, sigma_rad),
        )
        result.outcomes.append(
            HeldOutResult(
                errors_m, errors_deg, inside, widths, centring, tuple(float(d) for d in distances)
            )
        )
    return result


def report(
    results: list[GroundResult], missions: int, budget_s: float, *, held_out: bool = True
) -> str:
    """The tables (``held_out``: the grounds are :data:`GROUND_SEEDS`', else named)."""
    grounds = "grounds from held-out seeds" if held_out else "grounds from the seeds named"
    lines = [
        f"Designed calibration (budget {budget_s:g} s of driving) on {grounds}; "
        f"{missions} held-out 12-step missions per ground; final-pose error against "
        "where the rover truly came to rest, mean (max); twins at the gate's 10 ms step",
        "",
        "| ground | driving s | steps | rounds | before m | after m | floor m | cut "
        "| after/floor | within 1.5x | after deg | floor deg | calibrate wall s | of which "
        "fits s | calibrate CPU s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        if not r.outcomes:
            lines.append(f"| {r.name} | {r.driving_s:.1f} | refused: {r.refusal} |")
            continue

        outcomes = r.outcomes

        def mean(key: str, metric: str = "m", of: list[HeldOutResult] = outcomes) -> float:
            return float(np.mean([getattr(o, f"errors_{metric}")[key] for o in of]))

        def cell(
            key: str, digits: int, metric: str = "m", of: list[HeldOutResult] = outcomes
        ) -> str:
            values = [getattr(o, f"errors_{metric}")[key] for o in of]
            return f"{np.mean(values):.{digits}f} ({max(values):.{digits}f})"

        ratio = mean("after") / mean("floor")
        lines.append(
            f"| {r.name} | {r.driving_s:.1f} | {r.steps} | {r.rounds} | {cell('before', 3)} "
            f"| {cell('after', 4)} | {cell('floor', 4)} | {mean('before') / mean('after'):.0f}x "
            f"| {ratio:.2f} | {'yes' if ratio <= FLOOR_BAR and r.driving_s <= BUDGET_S else 'NO'} "
            f"| {cell('after', 2, 'deg')} | {cell('floor', 2, 'deg')} "
            f"| {r.calibrate_wall_s:.1f} | {r.fit_wall_s:.1f} | {r.calibrate_cpu_s:.1f} |"
        )
    lines += [
        "",
        "90 % bands of the gate's uncertainty for the calibrated twin (200 samples): share of "
        "outcomes inside; median width; centring (the band's middle off the point "
        "prediction, in half-widths, median); the bands' own error: the median error they "
        "expect (width_over_error)",
        "",
        "| ground | outcomes | inside longitudinal | inside lateral | inside yaw "
        "| median lateral width m | median error m | width / error | width / the bands' "
        "own error | centring |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    every: list[HeldOutResult] = []
    for r in results:
        if r.outcomes:
            lines.append(_band_row(r.name, r.outcomes))
            every += r.outcomes
    if every:
        lines.append(_band_row("all", every))
        inside = sum(sum(o.inside) for o in every) / (3 * len(every))
        ratio, own = width_over_error(every)
        lines += [
            "",
            f"coverage {inside:.1%} of {3 * len(every)} outcomes (bar "
            f"{COVERAGE[0]:.0%}-{COVERAGE[1]:.0%}: "
            f"{'holds' if COVERAGE[0] <= inside <= COVERAGE[1] else 'does NOT hold'}); "
            f"median lateral width {ratio:.2f}x the median error (bar {WIDTH_BAR:g}x: "
            f"{'holds' if ratio <= WIDTH_BAR else 'does NOT hold'}); {own:.2f}x the median "
            "error the bands themselves expect",
        ]
    rested = [r for r in results if r.rested_m]
    if rested:
        lines += [
            "",
            "The same missions by the step-by-step executor (a 3 s round trip of rest between "
            "steps; the first ones of each ground), against the gate's back-to-back "
            "prediction: mean final-position error",
            "",
            "| ground | missions | after m | floor m |",
            "|---|---:|---:|---:|",
        ]
        for r in rested:
            lines.append(
                f"| {r.name} | {len(r.rested_m['after'])} | {np.mean(r.rested_m['after']):.4f} "
                f"| {np.mean(r.rested_m['floor']):.4f} |"
            )
    lines += [
        "",
        "Fitted parameters (relative 1-sigma, target) against the ground's true values; "
        "turn efficiency description / fitted / true; the slip spread estimated",
        "",
        "| ground | parameter | true | fitted | 1 sigma | target |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for r in results:
        for p, (value, sigma, target) in r.fitted.items():
            true = r.truth.values()[p]
            lines.append(
                f"| {r.name} | {p} | {true:.4g} | {value:.4g} | {sigma:.0%} | {target:.0%} |"
            )
        d, f, t = r.turn_efficiency
        lines.append(
            f"| {r.name} | turn_efficiency | {t:.3f} | {f:.3f} | (description {d:.2f}) | |"
        )
        lines.append(f"| {r.name} | slip_sigma | | {r.slip_sigma:.3g} | | |")
        lines.append(f"| {r.name} | stopped | {r.stopped} | | | |")
    return "\n".join(lines)


def _band_row(name: str, outcomes: list[HeldOutResult]) -> str:
    n = len(outcomes)
    inside = [sum(o.inside[a] for o in outcomes) / n for a in range(3)]
    width = statistics.median(o.widths[1] for o in outcomes)
    error = statistics.median(o.errors_m["after"] for o in outcomes)
    ratio, own = width_over_error(outcomes)
    centring = statistics.median(max(o.centring) for o in outcomes)
    return (
        f"| {name} | {3 * n} | {inside[0]:.0%} | {inside[1]:.0%} | {inside[2]:.0%} "
        f"| {width:.4f} | {error:.4f} | {ratio:.2f} | {own:.2f} | {centring:.2f} |"
    )


def parse_seed(text: str) -> tuple[str, int]:
    """``KIND=SEED`` (``--seed``): a ground kind of :data:`RANGES` and a seed.

    Raises:
        argparse.ArgumentTypeError: not of that form.
    """
    kind, sep, seed = text.partition("=")
    if not sep or kind not in RANGES or not seed.strip().isdigit():
        raise argparse.ArgumentTypeError(
            f"expected KIND=SEED with KIND one of {', '.join(RANGES)}, got {text!r}"
        )
    return kind, int(seed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--quick", action="store_true", help="the loose ground only, 1 mission, 30 s budget"
    )
    parser.add_argument(
        "--missions", type=int, help=f"held-out missions per ground (default {HELD_OUT_MISSIONS})"
    )
    parser.add_argument("--budget", type=float, help=f"driving seconds (default {BUDGET_S:g})")
    parser.add_argument("--ground", choices=list(GROUND_SEEDS), action="append", help="only these")
    parser.add_argument(
        "--seed",
        type=parse_seed,
        action="append",
        metavar="KIND=SEED",
        help="a ground of KIND's range from SEED instead of the held-out ones (repeatable; "
        "development, or the seen-before SEEN_SEEDS)",
    )
    parser.add_argument(
        "--rest",
        type=float,
        default=REST_S,
        help=f"seconds at rest before each held-out plan, its start averaged over it "
        f"(default {REST_S:g}: a round trip)",
    )
    parser.add_argument("--keep", type=Path, help="keep the recordings and twins here")
    args = parser.parse_args()
    missions = args.missions or (1 if args.quick else HELD_OUT_MISSIONS)
    budget = args.budget or (30.0 if args.quick else BUDGET_S)
    grounds: list[tuple[str, int | None]]
    if args.seed:
        grounds = list(args.seed)
    elif args.quick:
        grounds = [("loose", QUICK_SEED)]
    else:
        grounds = [(kind, None) for kind in args.ground or GROUND_SEEDS]
    rover = load_rover()
    with tempfile.TemporaryDirectory(prefix="bench-calibration-") as tmp:
        work = args.keep or Path(tmp)
        results = [
            run_ground(kind, rover, missions, budget, work, seed, args.rest)
            for kind, seed in grounds
        ]
    print(report(results, missions, budget, held_out=all(seed is None for _k, seed in grounds)))


if __name__ == "__main__":
    main()
