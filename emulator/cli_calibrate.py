"""``rover calibrate``: fit the twin's ground to recorded missions, write a twin file."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

__all__ = ["EXIT_OK", "EXIT_UNIDENTIFIABLE", "EXIT_USAGE", "register"]

EXIT_OK = 0
EXIT_USAGE = 2
EXIT_UNIDENTIFIABLE = 3

_DESCRIPTION = (
    "Fit the twin's ground (friction along and across the wheels, slip ratio, rolling "
    "resistance, and the friction of each map region driven on) to missions recorded "
    "with --record by 'rover go' or 'rover demo': every completed step is replayed on "
    "the twin from the pose recorded at rest before it and compared with the pose "
    "(POSE) and the yaw change (IMU) recorded at rest after it, the encoders checking "
    "that the step was whole; scipy's least squares. Writes a twin description (a rover "
    "description with the fitted traction and a [calibration] table: each parameter's "
    "value and uncertainty, the residuals) for 'rover gate --twin FILE' (docs/twin.md)."
)

_EPILOG = (
    "exit status:\n"
    f"  {EXIT_OK}  the twin file was written\n"
    f"  {EXIT_USAGE}  bad usage, or a recording that cannot be read or has no step\n"
    "     measured at rest before and after it\n"
    f"  {EXIT_UNIDENTIFIABLE}  the recordings cannot identify a parameter (no turns, too short, a\n"
    "     region barely driven on): one line says which; nothing is written\n\n"
    "examples:\n"
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
    p.add_argument("missions", nargs="+", metavar="MISSION.mcap", help="recorded missions")
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


def _run(args: argparse.Namespace) -> int:
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
                        p: {"value": cal.value(p), "relative_sigma": cal.relative_sigma(p)}
                        for p in cal.parameters
                    },
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
        f"replays of them in {report.wall_s:.1f} s"
    )
    for source, index, why in observed.skipped + report.outliers:
        print(f"  left out: {source} step {index}: {why}")
    print(f"{'parameter':<24} {'description':>11} {'fitted':>9} {'1 sigma':>8}")
    for p in cal.parameters:
        if p.startswith("region."):
            before = next(
                (r.mu_scale for r in world.traction_regions if r.id == p[len("region.") :]), 1.0
            )
        else:
            before = float(getattr(rover.traction, p))
        print(f"{p:<24} {before:>11.4g} {cal.value(p):>9.4g} {cal.relative_sigma(p):>7.0%}")
    print(
        f"{'turn_efficiency':<24} {rover.traction.turn_efficiency:>11.4g} "
        f"{cal.turn_efficiency:>9.4g}"
    )
    print(f"residuals before: {cal.before.line()}")
    print(f"residuals after:  {cal.after.line()}")
    print(f"twin written to {args.output} (rover gate --twin {args.output})")
    return EXIT_OK
