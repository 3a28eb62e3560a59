"""Calibration against grounds the gate does not know: prediction error before and after.

For each shipped ground (``emulator/grounds/``: loose, compacted, dusty), on an open
field:

1. a calibration mission of at most 60 s of driving (seeded random steps, turns and
   straight lines) is driven in lockstep on that ground and recorded as a real mission
   is (:mod:`sim.calibration_runs`: the controller model at 1 ms, sensor noise, the
   bridge's odometry, a 3 s round trip, the same MCAP writer);
2. ``rover calibrate``'s path fits the twin to that recording (read the MCAP, measure
   the steps at rest, least squares); its wall time is the time to calibrate;
3. other 12-step missions (other seeds, never used to fit) are driven and recorded on
   the same ground; each one's final pose is predicted as the gate predicts it (the
   whole plan played from the recorded start pose at the gate's 10 ms step) by three
   twins: the rover description's (what the gate knows without calibration), the
   calibrated one, and one given the ground's true parameters (the floor: what sensor
   noise, the step size and timing leave), and compared with the final pose the
   recording measured (POSE averaged at rest).

The issue's bar: calibration cuts the mean final-position error by at least 5x, or
brings it within 1.5x of the floor; ``pass`` says which holds. Deterministic: every
mission and every noise draw is seeded.

    python -m benchmarks.bench_calibration [--quick] [--missions N]
"""

from __future__ import annotations

import argparse
import math
import random
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from emulator.fit import fit_ground
from emulator.ground import Ground, list_grounds, load_ground
from emulator.observations import MAX_REST_S, SETTLE_S, START_GUARD_S, observe_steps
from emulator.playback import play
from emulator.recording import Recording, read_recording
from emulator.twin import GATE_DT_S, Pose2D, Twin
from firmware_proto.model.geometry import wrap_rad
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import WorldMap
from planner.record.mcaprec import record_messages
from sim.calibration_runs import drive_lockstep, field_map, random_mission

FIT_DRIVING_S = 60.0
CUT_BAR = 5.0
FLOOR_BAR = 1.5


@dataclass
class GroundResult:
    name: str
    fit_steps: int
    fit_driving_s: float
    calibrate_s: float
    errors_m: dict[str, list[float]]
    errors_deg: dict[str, list[float]]
    fitted: dict[str, tuple[float, float]]
    true: dict[str, float]
    turn_efficiency: tuple[float, float, float]


def _rest_pose(rec: Recording, lo: float, hi: float) -> Pose2D:
    sel = (rec.pose_t_s >= lo) & (rec.pose_t_s <= hi)
    xy = rec.pose_xy_m[sel].mean(axis=0)
    yaw = float(np.angle(np.exp(1j * rec.pose_yaw_rad[sel]).mean()))
    return Pose2D(float(xy[0]), float(xy[1]), yaw)


def mission_ends(rec: Recording) -> tuple[Pose2D, Pose2D]:
    """The recorded pose at rest before the first step and after the last."""
    first = rec.to_rover_clock(rec.steps[0].accepted_s or 0.0)
    last = rec.to_rover_clock(rec.steps[-1].ended_s or 0.0)
    start = _rest_pose(rec, first - START_GUARD_S - MAX_REST_S, first - START_GUARD_S)
    end = _rest_pose(rec, last + SETTLE_S, last + SETTLE_S + MAX_REST_S)
    return start, end


def predict_final(
    rover: RoverDescription,
    world: WorldMap,
    ground: Ground,
    start: Pose2D,
    steps: list[tuple[int, int, int]],
) -> Pose2D:
    twin = Twin(ground.rover(rover), ground.world(world), dt_s=GATE_DT_S, start=start)
    return play(twin, steps).final_pose


def run_ground(
    name: str, rover: RoverDescription, world: WorldMap, missions: int, work: Path
) -> GroundResult:
    truth = load_ground(name, rover)
    seed = 10 + list_grounds().index(name)
    fit_steps = random_mission(rover, random.Random(seed), 40, max_driving_s=FIT_DRIVING_S)
    fit_path = work / f"{name}-fit.mcap"
    fit = drive_lockstep(rover, world, truth, fit_steps, seed=seed)
    record_messages(fit_path, fit.messages)
    t0 = time.perf_counter()
    observed = observe_steps([read_recording(fit_path)], rover)
    calibration, _report = fit_ground(observed, rover, world, sources=(str(fit_path),))
    calibrate_s = time.perf_counter() - t0
    twins = {"before": Ground.of_rover(rover, world), "after": calibration.ground, "floor": truth}
    errors_m: dict[str, list[float]] = {k: [] for k in twins}
    errors_deg: dict[str, list[float]] = {k: [] for k in twins}
    for k in range(missions):
        steps = random_mission(rover, random.Random(1000 + 100 * seed + k), 12)
        test_path = work / f"{name}-test{k}.mcap"
        test = drive_lockstep(rover, world, truth, steps, seed=500 + seed * 10 + k)
        record_messages(test_path, test.messages)
        start, end = mission_ends(read_recording(test_path))
        for key, ground in twins.items():
            final = predict_final(rover, world, ground, start, steps)
            errors_m[key].append(math.dist((final.x_m, final.y_m), (end.x_m, end.y_m)))
            errors_deg[key].append(abs(math.degrees(wrap_rad(final.yaw_rad - end.yaw_rad))))
    return GroundResult(
        name=name,
        fit_steps=len(fit_steps),
        fit_driving_s=fit.driving_s,
        calibrate_s=calibrate_s,
        errors_m=errors_m,
        errors_deg=errors_deg,
        fitted={
            p: (calibration.value(p), calibration.relative_sigma(p)) for p in calibration.parameters
        },
        true=truth.values(),
        turn_efficiency=(
            rover.traction.turn_efficiency,
            calibration.turn_efficiency,
            _true_turn_efficiency(rover, truth),
        ),
    )


def _true_turn_efficiency(rover: RoverDescription, ground: Ground) -> float:
    from emulator.playback import measure_turn_efficiency

    return measure_turn_efficiency(
        ground.rover(rover), distance=rover.turn_units_for_yaw(math.pi / 2.0)
    )


def verdict(result: GroundResult) -> tuple[float, float, str]:
    """(cut, after/floor, pass) on the mean final-position error."""
    before = float(np.mean(result.errors_m["before"]))
    after = float(np.mean(result.errors_m["after"]))
    floor = float(np.mean(result.errors_m["floor"]))
    cut = before / after if after > 0 else math.inf
    ratio = after / floor if floor > 0 else math.inf
    ok = []
    if cut >= CUT_BAR:
        ok.append(f"cut >= {CUT_BAR:g}x")
    if ratio <= FLOOR_BAR:
        ok.append(f"<= {FLOOR_BAR:g}x floor")
    return cut, ratio, ("yes (" + ", ".join(ok) + ")") if ok else "NO"


def report(results: list[GroundResult], missions: int) -> str:
    lines = [
        f"Final-pose prediction error of 12-step missions not used to fit ({missions} per "
        "ground), mean (max); twins at the gate's 10 ms step",
        "",
        "| ground | fit steps | fit driving s | before m | after m | floor m | before deg "
        "| after deg | floor deg | cut | after/floor | pass | calibrate s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for r in results:
        cut, ratio, ok = verdict(r)

        def cell(values: list[float], digits: int) -> str:
            return f"{np.mean(values):.{digits}f} ({max(values):.{digits}f})"

        lines.append(
            f"| {r.name} | {r.fit_steps} | {r.fit_driving_s:.1f} | "
            f"{cell(r.errors_m['before'], 3)} | {cell(r.errors_m['after'], 4)} | "
            f"{cell(r.errors_m['floor'], 4)} | {cell(r.errors_deg['before'], 1)} | "
            f"{cell(r.errors_deg['after'], 2)} | {cell(r.errors_deg['floor'], 2)} | "
            f"{cut:.0f}x | {ratio:.2f} | {ok} | {r.calibrate_s:.1f} |"
        )
    lines += [
        "",
        "Fitted parameters (relative 1-sigma) against the ground's true values; turn "
        "efficiency: description / fitted / true",
        "",
        "| ground | parameter | true | fitted | 1 sigma |",
        "|---|---|---:|---:|---:|",
    ]
    for r in results:
        for p, (value, sigma) in r.fitted.items():
            lines.append(f"| {r.name} | {p} | {r.true[p]:.4g} | {value:.4g} | {sigma:.0%} |")
        d, f, t = r.turn_efficiency
        lines.append(f"| {r.name} | turn_efficiency | {t:.3f} | {f:.3f} | (description {d:.2f}) |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="1 test mission per ground")
    parser.add_argument("--missions", type=int, help="test missions per ground (default 6)")
    args = parser.parse_args()
    missions = args.missions or (1 if args.quick else 6)
    rover = load_rover()
    world = field_map()
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-calibration-") as tmp:
        for name in list_grounds():
            results.append(run_ground(name, rover, world, missions, Path(tmp)))
    print(report(results, missions))


if __name__ == "__main__":
    main()
