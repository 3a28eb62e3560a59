"""``rover calibrate``: fit the twin's ground to recorded missions, write a twin file."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from typing import Any

__all__ = ["EXIT_OK", "EXIT_UNIDENTIFIABLE", "EXIT_USAGE", "register"]

EXIT_OK = 0
EXIT_USAGE = 2
EXIT_UNIDENTIFIABLE = 3

_DESCRIPTION = (
    "Fit the twin's ground (every traction parameter of the force model, and the friction "
    "of each map region driven on) to steps measured at rest: every completed step is "
    "replayed on the twin from the pose recorded at rest before it and compared with the "
    "pose (POSE) and the yaw change (IMU) recorded at rest after it, the encoders checking "
    "that the step was whole; scipy's least squares; the noise the twin cannot predict "
    "estimated from the residuals, the posterior drawn, each step and each plan checked "
    "against its 90 % band. The steps come from missions recorded with --record by "
    "'rover go' or 'rover demo', or, with --drive, from steps it designs and drives itself "
    "on the running stack (through the ground station: 'rover go --plan', each plan "
    "validated on the stack's gate first) within --budget seconds of driving, until every "
    "parameter is under its target. Writes a twin description (a rover description with "
    "the fitted traction and a [calibration] table) for 'rover gate --twin FILE' and "
    "'rover stack up --twin FILE' (docs/twin.md)."
)

_EPILOG = (
    "exit status:\n"
    f"  {EXIT_OK}  the twin file was written\n"
    f"  {EXIT_USAGE}  bad usage, a recording that cannot be read or has no step measured at\n"
    "     rest before and after it, or (--drive) a stack that cannot be driven\n"
    f"  {EXIT_UNIDENTIFIABLE}  the steps cannot identify a parameter: one line says which, and\n"
    "     which steps would; nothing is written\n\n"
    "examples:\n"
    "  rover stack up --ground loose            # then, in another shell:\n"
    '  eval "$(rover stack env)"\n'
    "  rover calibrate --drive --map lab -o twin.toml\n"
    "  rover demo --ground loose --record day1.mcap\n"
    "  rover calibrate day1.mcap --map lab -o twin.toml\n"
    "  rover gate --map lab --twin twin.toml"
)


def register(subparsers: Any) -> None:
    """Add ``rover calibrate``."""
    p = subparsers.add_parser(
        "calibrate",
        help="fit the twin's ground to recorded missions (MCAP) and write a twin file",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_DESCRIPTION,
        epilog=_EPILOG,
    )
    p.add_argument(
        "missions",
        nargs="*",
        metavar="MISSION.mcap",
        help="recorded missions (with --drive: fitted first, their driving not counted)",
    )
    drive = p.add_argument_group(
        "a designed calibration (--drive): drives a running stack through the ground station"
    )
    drive.add_argument(
        "--drive",
        action="store_true",
        help="design and drive the identifying steps (rover go --plan on the stack that "
        "rover stack up exports), until every parameter is under its target or the budget "
        "is spent",
    )
    drive.add_argument(
        "--budget",
        type=_positive,
        default=60.0,
        metavar="S",
        help="seconds of driving it may use (nominal step durations; default 60)",
    )
    drive.add_argument(
        "--keep",
        metavar="DIR",
        help="where each round's plan and recording go (default OUTPUT's name + .rounds)",
    )
    drive.add_argument("--gate", metavar="URL", help="the stack's gate (default $ROVER_GATE_URL)")
    drive.add_argument(
        "--domain", type=int, metavar="N", help="the stack's ROS 2 domain (default $ROS_DOMAIN_ID)"
    )
    drive.add_argument(
        "--rtt", type=_positive, metavar="S", help="the link's round trip, wall s ($ROVER_LINK_RTT)"
    )
    drive.add_argument(
        "--time-scale",
        type=_positive,
        metavar="S",
        help="mission seconds per wall second of the stack ($ROVER_TIME_SCALE, else 1)",
    )
    p.add_argument(
        "--map", default="lab", metavar="NAME|FILE", help="the map driven on (default lab)"
    )
    p.add_argument("--rover", metavar="TOML", help="rover description (default: the packaged one)")
    p.add_argument(
        "-o", "--output", default="twin.toml", metavar="FILE", help="twin file (twin.toml)"
    )
    p.add_argument("--namespace", metavar="NS", help="the recordings' topic namespace (if several)")
    p.add_argument(
        "--speed-factor",
        type=float,
        default=1.0,
        metavar="S",
        help="mission seconds per wall second the missions ran at (rover demo --speed)",
    )
    p.add_argument(
        "--dt", type=float, default=None, metavar="S", help="twin step, s (default the gate's 0.01)"
    )
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(func=_run)


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0.0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def _run(args: argparse.Namespace) -> int:
    if args.drive:
        return _drive(args)
    if not args.missions:
        print("rover calibrate: give recorded missions, or --drive", file=sys.stderr)
        return EXIT_USAGE
    from emulator.errors import (
        CalibrationError,
        EmulatorError,
        RecordingError,
        UnidentifiableError,
    )
    from emulator.fit import fit_ground
    from emulator.observations import observe_steps
    from emulator.recording import read_recording
    from emulator.twin import GATE_DT_S
    from emulator.twinfile import write_twin
    from firmware_proto.errors import DescriptionError
    from firmware_proto.model.rover import load_rover
    from firmware_proto.model.worldmap import load_map

    try:
        rover = load_rover(args.rover)
        world = load_map(args.map)
        recordings = [read_recording(path, args.namespace) for path in args.missions]
        observed = observe_steps(recordings, rover, speed_factor=args.speed_factor)
        calibration, report = fit_ground(
            observed,
            rover,
            world,
            dt_s=args.dt if args.dt is not None else GATE_DT_S,
            sources=tuple(args.missions),
        )
    except UnidentifiableError as exc:
        print(f"rover calibrate: {exc}", file=sys.stderr)
        return EXIT_UNIDENTIFIABLE
    except (RecordingError, DescriptionError, ValueError) as exc:
        print(f"rover calibrate: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (CalibrationError, EmulatorError) as exc:  # pragma: no cover - scipy missing
        print(f"rover calibrate: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        write_twin(args.output, rover, calibration)
    except OSError as exc:
        print(f"rover calibrate: cannot write {args.output}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    cal = calibration
    if args.json:
        print(
            json.dumps(
                {
                    "output": args.output,
                    "parameters": {
                        p: {
                            "value": cal.value(p),
                            "relative_sigma": cal.relative_sigma(p),
                            "interval_95": list(cal.interval(p)),
                            "target_sigma": t,
                        }
                        for p, t in zip(cal.parameters, cal.targets, strict=True)
                    },
                    "noise": dataclasses.asdict(cal.noise) if cal.noise else None,
                    "checks": [
                        {**dataclasses.asdict(c), "inside": list(c.inside)} for c in cal.checks
                    ],
                    "turn_efficiency": cal.turn_efficiency,
                    "steps": cal.after.steps,
                    "skipped": len(observed.skipped) + len(report.outliers),
                    "driving_s": cal.driving_s,
                    "residuals_before": cal.before.__dict__,
                    "residuals_after": cal.after.__dict__,
                    "reduced_chi2": cal.reduced_chi2,
                    "wall_s": report.wall_s,
                }
            )
        )
        return EXIT_OK
    print(
        f"{cal.after.steps} steps fitted ({cal.driving_s:.1f} s of driving), "
        f"{len(observed.skipped) + len(report.outliers)} left out; {report.evaluations} "
        f"replay batches in {report.wall_s:.1f} s"
    )
    for source, index, why in observed.skipped + report.outliers:
        print(f"  left out: {source} step {index}: {why}")
    print_calibration(cal, rover, world)
    print(f"twin written to {args.output} (rover gate --twin {args.output})")
    return EXIT_OK


def print_calibration(cal: Any, rover: Any, world: Any) -> None:
    """Each parameter with its 95 % interval and target, the noise, the residuals and
    the held-out checks against their bands: the calibration's report."""
    import math

    print(
        f"{'parameter':<24} {'description':>11} {'fitted':>9} {'95 % interval':>19} "
        f"{'1 sigma':>8} {'target':>7}"
    )
    for p, target in zip(
        cal.parameters, cal.targets or [math.nan] * len(cal.parameters), strict=True
    ):
        if p.startswith("region."):
            before = next(
                (r.mu_scale for r in world.traction_regions if r.id == p[len("region.") :]), 1.0
            )
        else:
            before = float(getattr(rover.traction, p))
        lo, hi = cal.interval(p)
        sigma = cal.relative_sigma(p)
        mark = "" if sigma <= target else "  (above its target)"
        print(
            f"{p:<24} {before:>11.4g} {cal.value(p):>9.4g} {f'{lo:.4g}..{hi:.4g}':>19} "
            f"{sigma:>7.1%} {target:>7.1%}{mark}"
        )
    print(
        f"{'turn_efficiency':<24} {rover.traction.turn_efficiency:>11.4g} "
        f"{cal.turn_efficiency:>9.4g}"
    )
    if cal.noise is not None:
        n = cal.noise
        print(
            f"noise: slip spread {n.slip_sigma:.3g} (1 sigma of each side's log friction), a "
            f"pose at rest to {n.pose_sigma_m * 1e3:.1f} mm and "
            f"{math.degrees(n.heading_sigma_rad):.3f} deg"
        )
    if cal.step_error_scale > 0.0:
        print(
            f"model discrepancy: {cal.step_error_scale:g} x each plan's step error at 1 sigma "
            "(its final pose at 2 ms less at the gate's 10 ms; the gate draws it)"
        )
    print(f"residuals before: {cal.before.line()}")
    print(f"residuals after:  {cal.after.line()}")
    if cal.checks:
        inside = [sum(c.inside[a] for c in cal.checks) for a in range(3)]
        k = len(cal.checks)
        print(
            "held-out checks (each step left out of the fit, and each plan as the gate plays "
            f"it, predicted with its 90 % band): inside {inside[0]}/{k} forward, "
            f"{inside[1]}/{k} lateral, {inside[2]}/{k} yaw"
        )
        for check in cal.checks:
            print(f"  {check.line()}")


def _drive(args: argparse.Namespace) -> int:
    """``rover calibrate --drive``: a designed calibration on the running stack."""
    import time
    from pathlib import Path

    from emulator.campaign import run_campaign
    from emulator.errors import CalibrationError, EmulatorError
    from emulator.stackdriver import StackDriver
    from emulator.twin import GATE_DT_S
    from emulator.twinfile import write_twin
    from firmware_proto.errors import DescriptionError
    from firmware_proto.model.rover import load_rover
    from firmware_proto.model.worldmap import load_map

    t0 = time.monotonic()

    def say(line: str) -> None:
        print(f"[{time.monotonic() - t0:6.1f} s] {line}", flush=True)

    try:
        rover = load_rover(args.rover)
        world = load_map(args.map)
        keep = Path(args.keep) if args.keep else Path(args.output).with_suffix(".rounds")
        driver = StackDriver(
            rover,
            world.name,
            gate=args.gate,
            domain=args.domain,
            time_scale=args.time_scale,
            rtt_s=args.rtt,
        )
        campaign = run_campaign(
            driver,
            rover,
            world,
            keep,
            budget_s=args.budget,
            recordings=[Path(m) for m in args.missions],
            dt_s=args.dt if args.dt is not None else GATE_DT_S,
            on_event=say,
        )
    except (DescriptionError, ValueError) as exc:
        print(f"rover calibrate: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (CalibrationError, EmulatorError) as exc:
        print(f"rover calibrate: {exc}", file=sys.stderr)
        return EXIT_USAGE
    say(
        f"{campaign.driving_s:.1f} s of driving of {args.budget:g} in {len(campaign.rounds)} "
        f"plan(s); stopped: {campaign.stopped}; recordings in {keep}"
    )
    if campaign.refusal is not None or campaign.calibration is None:
        print(f"rover calibrate: {campaign.refusal}", file=sys.stderr)
        return EXIT_UNIDENTIFIABLE
    try:
        write_twin(args.output, rover, campaign.calibration)
    except OSError as exc:
        print(f"rover calibrate: cannot write {args.output}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    print_calibration(campaign.calibration, rover, world)
    scale = f" --speed-factor {driver.speed_factor:g}" if driver.speed_factor != 1.0 else ""
    print(
        f"calibrated in {campaign.wall_s:.1f} s of wall time (fits {campaign.fit_wall_s:.1f} s); "
        f"twin written to {args.output} (rover gate --twin {args.output}; rover calibrate "
        f"{keep}/round-*.mcap --map {args.map}{scale} fits the same recordings again)"
    )
    return EXIT_OK
