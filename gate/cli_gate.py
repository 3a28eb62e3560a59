"""``rover gate``: serve the simulation gate, or ``rover gate check`` one plan offline."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

from firmware_proto.cli import values
from firmware_proto.cli.runtimeargs import add_runtime_arguments, runtime_options
from firmware_proto.runtime import ProcessRuntime, ShutdownSignals

__all__ = ["add_arguments", "main", "register"]

EXIT_APPROVED = 0
EXIT_REJECTED = 1
EXIT_USAGE = 2


def _add_playback_options(p: argparse.ArgumentParser, prefix: str = "") -> None:
    p.add_argument(
        "--margin",
        dest=prefix + "safety_margin_m",
        type=float,
        metavar="M",
        help="safety margin: footprint inflation for collisions, m (default 0.10)",
    )
    p.add_argument(
        "--pos-tol",
        dest=prefix + "position_tolerance_m",
        type=float,
        metavar="M",
        help="accepted final distance to the goal, m (default 0.10)",
    )
    p.add_argument(
        "--yaw-tol",
        dest=prefix + "yaw_tolerance_deg",
        type=float,
        metavar="DEG",
        help="accepted final yaw error, degrees (default 3)",
    )
    p.add_argument(
        "--sample-hz",
        dest=prefix + "sample_hz",
        type=float,
        metavar="HZ",
        help="predicted trajectory rate, Hz (default 10)",
    )
    p.add_argument("--rover", dest=prefix + "rover_path", metavar="TOML", help="rover description")
    p.add_argument(
        "--twin",
        dest=prefix + "twin_path",
        metavar="FILE",
        help="play plans on a calibrated twin (written by rover calibrate) instead of the "
        "rover description; not with --rover",
    )


_DESCRIPTION = (
    "Serve the simulation gate over HTTP: plans posted to /validate_plan are played on the "
    "pymunk twin and answered with a verdict (docs/gate.md). Prints 'GATE http://HOST:PORT' "
    "as its first line once it accepts requests (use --port 0 for a free port). Stops "
    "gracefully on Ctrl-C or SIGTERM. Settings also come from ROVER_GATE_<SETTING> "
    "variables and a TOML file (--config)."
)


def register(subparsers: Any) -> None:
    """Add ``rover gate`` (serve) and ``rover gate check`` (one plan, offline)."""
    p = subparsers.add_parser(
        "gate",
        help="serve the simulation gate (POST /validate_plan), or check one plan",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_DESCRIPTION,
        epilog=(
            "examples:\n"
            "  rover gate --map lab --port 8080\n"
            "  rover gate --host 0.0.0.0 --token-file /etc/rover/gate.token --workers 2\n"
            "  rover gate check plan.json --map scn02 --start 1,4,0 --png verdict.png"
        ),
    )
    add_arguments(p)
    p.set_defaults(func=_serve)
    _add_check(p)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of the server (``rover gate`` and ``rover_gate``)."""
    p.add_argument(
        "--map",
        dest="default_map",
        metavar="NAME|FILE",
        help="default map: name or JSON file (lab)",
    )
    p.add_argument("--host", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=values.tcp_port, help="port (default 8080; 0 picks a free one)")
    p.add_argument(
        "--token-file",
        metavar="PATH",
        help="bearer token required on every request, read from this file (or set "
        "ROVER_GATE_TOKEN); a non-loopback --host needs one",
    )
    p.add_argument("--token", help=argparse.SUPPRESS)  # refused: see _serve
    p.add_argument(
        "--allowed-host",
        dest="allowed_hosts",
        action="append",
        metavar="NAME",
        help="a further name clients reach the gate by (the Host header; repeatable)",
    )
    p.add_argument(
        "--workers", type=int, metavar="N", help="validations in parallel (default: CPU count)"
    )
    p.add_argument("--pool", choices=("process", "thread"), help="worker kind (process)")
    p.add_argument(
        "--queue", dest="queue_depth", type=int, metavar="N", help="queued beyond workers (16)"
    )
    p.add_argument(
        "--max-body", dest="max_body_bytes", type=int, metavar="BYTES", help="body limit (65536)"
    )
    p.add_argument("--config", metavar="TOML", help="settings file with a [gate] table")
    p.add_argument(
        "--cluster",
        metavar="ADDRESS",
        help="play the samples of verdicts with uncertainty on this Dask scheduler "
        "(tcp://HOST:PORT; needs the cluster extra) instead of the local workers",
    )
    _add_playback_options(p)
    add_runtime_arguments(p, 0)


def _add_check(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="gate_command", metavar="check")
    c = sub.add_parser(
        "check",
        help="validate one plan file offline and print the verdict",
        description=(
            "Play one plan (Listing 1 JSON) on the twin, exactly as the server would, and "
            "print the verdict. Exit status: 0 approved, 1 rejected, 2 bad plan or usage (or "
            "the picture could not be written)."
        ),
    )
    c.add_argument("plan", help="plan JSON file ('-' for stdin)")
    c.add_argument(
        "--map", dest="check_map", metavar="NAME|FILE", help="map name or JSON file (lab)"
    )
    c.add_argument("--start", dest="check_start", metavar="X,Y,YAW", help="start pose")
    c.add_argument("--png", dest="check_png", metavar="PATH", help="write the picture here")
    c.add_argument("--json", dest="check_json", action="store_true", help="print the JSON")
    c.add_argument(
        "--samples",
        dest="check_samples",
        metavar="N",
        help="also play N twins drawn from the twin's uncertainty (docs/gate.md)",
    )
    c.add_argument("--seed", dest="check_seed", metavar="S", help="seed of those draws (0)")
    c.add_argument("--slip-sigma", dest="check_slip_sigma", metavar="X", help="slip spread (0.1)")
    c.add_argument(
        "--start-sigma-m",
        dest="check_start_sigma_m",
        metavar="M",
        help="the start's own position error as measured, 1 sigma per axis, m (the twin's)",
    )
    c.add_argument(
        "--start-sigma-deg",
        dest="check_start_sigma_deg",
        metavar="D",
        help="the start's own heading error as measured, 1 sigma, deg (the twin's)",
    )
    _add_playback_options(c, "check_")
    c.set_defaults(func=_check)


def _playback_args(args: argparse.Namespace, prefix: str = "") -> dict[str, Any]:
    keys = ("safety_margin_m", "position_tolerance_m", "yaw_tolerance_deg", "sample_hz", "dt_s")
    out = {k: getattr(args, prefix + k, None) for k in keys}
    out["rover_path"] = getattr(args, prefix + "rover_path", None)
    out["twin_path"] = getattr(args, prefix + "twin_path", None)
    return out


def _serve(args: argparse.Namespace) -> int:
    from firmware_proto.errors import BindPolicyError
    from firmware_proto.http.tokenfile import read_token_file, refuse_token_argument
    from gate.config import load_config
    from gate.errors import GateConfigError
    from gate.server import GateServer

    try:
        if args.token is not None:
            raise refuse_token_argument("--token", "--token-file", "ROVER_GATE_TOKEN")
        token = read_token_file(args.token_file) if args.token_file else None
    except BindPolicyError as exc:
        raise GateConfigError(str(exc)) from exc
    config = load_config(
        {
            "default_map": args.default_map,
            "host": args.host,
            "port": args.port,
            "token": token,
            "workers": args.workers,
            "pool": args.pool,
            "queue_depth": args.queue_depth,
            "max_body_bytes": args.max_body_bytes,
            "cluster": args.cluster,
            "allowed_hosts": tuple(args.allowed_hosts) if args.allowed_hosts else None,
            **{k: v for k, v in _playback_args(args).items() if k != "twin_path"},
        },
        config_path=args.config,
    )
    validator = (
        _twin_validator(args.twin_path, config.default_map, config.playback, config.rover_path)
        if args.twin_path
        else None
    )
    with (
        ShutdownSignals() as signals,
        ProcessRuntime(runtime_options(args, "gate")),
        GateServer(config, validator=validator) as gate,
    ):
        print(f"GATE {gate.url}", flush=True)
        signals.wait(None)
        print("gate: shutting down", file=sys.stderr, flush=True)
    return 0


def _twin_validator(twin_path: str, default_map: str, settings: Any, rover_path: str | None) -> Any:
    """A validator (:class:`gate.validator.Validator`) that plays every plan on the
    calibrated twin ``twin_path``: its rover description, and its region scales on the
    map it was calibrated on.

    Raises:
        GateConfigError: ``--rover`` given too, or the twin file cannot be used.
    """
    from emulator.errors import EmulatorError
    from emulator.twinfile import load_twin
    from gate.errors import GateConfigError
    from gate.validator import Validator, load_maps

    if rover_path:
        raise GateConfigError("give --twin or --rover, not both (a twin holds its rover)")
    try:
        twin = load_twin(twin_path)
    except EmulatorError as exc:
        raise GateConfigError(str(exc)) from exc
    maps, default = load_maps(default_map)
    served = {name: twin.world(world) or world for name, world in maps.items()}
    cal = twin.calibration
    noise = ""
    if cal.noise is not None:
        settings = replace(settings, slip_sigma=cal.noise.slip_sigma)
        noise = f"; slip spread {cal.noise.slip_sigma:.3g} (the calibration's estimate)"
    if cal.step_error_scale > 0.0:
        noise += f"; step error {cal.step_error_scale:g} sigma"
    print(
        f"gate: twin {twin_path}: calibrated on {cal.map_name or 'an open plane'} from "
        f"{cal.after.steps} steps; turn efficiency {cal.turn_efficiency:.3f}{noise}",
        file=sys.stderr,
        flush=True,
    )
    return Validator(twin.rover, served, settings, default, spread=cal, spread_map=cal.map_name)


def _check(args: argparse.Namespace) -> int:
    import base64

    from emulator.errors import EmulatorError
    from firmware_proto.errors import PlanError
    from firmware_proto.model.plan import Plan
    from firmware_proto.model.rover import load_rover
    from gate.config import PlaybackSettings
    from gate.errors import GateError
    from gate.options import ValidateOptions
    from gate.validator import Validator, load_maps

    try:
        text = sys.stdin.read() if args.plan == "-" else Path(args.plan).read_text(encoding="utf-8")
        plan = Plan.from_json(text)
        query = {"start": args.check_start} if args.check_start else {}
        for key in ("samples", "seed", "slip_sigma", "start_sigma_m", "start_sigma_deg"):
            value = getattr(args, "check_" + key)
            if value is not None:
                query[key] = value
        if args.check_png:
            query["render"] = "1"
        options = ValidateOptions.from_query(urlencode(query))
        given = _playback_args(args, "check_")
        rover_path = given.pop("rover_path")
        twin_path = given.pop("twin_path")
        settings = PlaybackSettings(**{k: v for k, v in given.items() if v is not None})
        if twin_path:
            validator = _twin_validator(twin_path, args.check_map or "lab", settings, rover_path)
            default = validator.default_map
        else:
            maps, default = load_maps(args.check_map or "lab")
            validator = Validator(load_rover(rover_path), maps, settings, default)
        job = validator.prepare(plan, options.resolve(validator.settings, default))
        verdict = validator.validate_uncertain(job)
    except OSError as exc:
        print(f"rover gate check: cannot read {args.plan}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (PlanError, GateError, EmulatorError, ValueError) as exc:
        print(f"rover gate check: {exc}", file=sys.stderr)
        return EXIT_USAGE
    png_error: OSError | None = None
    if args.check_png and verdict.image_png_base64 is not None:
        try:
            Path(args.check_png).write_bytes(base64.b64decode(verdict.image_png_base64))
        except OSError as exc:
            png_error = exc
    if args.check_json:
        print(verdict.to_json())
    else:
        _print_summary(verdict, None if png_error else args.check_png)
    if png_error is not None:  # the verdict is printed; the picture is what failed
        print(f"rover gate check: cannot write {args.check_png}: {png_error}", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_APPROVED if verdict.approved else EXIT_REJECTED


def _print_summary(verdict: Any, png: str | None) -> None:
    v = verdict
    f = v.final_pose
    status = "APPROVED" if v.approved else f"REJECTED {v.failure_type} at step {v.failed_step}"
    print(status)
    if v.failure_reason:
        print(f"  {v.failure_reason}")
    print(f"  final pose     x={f.x:.3f} y={f.y:.3f} yaw={f.yaw_deg:.2f} deg")
    print(
        f"  goal error     {v.position_error_m:+.3f} m along, {v.lateral_error_m:+.3f} m "
        f"across, {v.yaw_error_deg:+.2f} deg (tolerances {v.tolerances.position_m:g} m, "
        f"{v.tolerances.yaw_deg:g} deg)"
    )
    print(f"  steps played   {len(v.steps)}, twin time {v.sim_time_s:.2f} s")
    u = v.uncertainty
    if u is not None:
        g = u.goal_error
        spread = ", ".join(
            f"p{p:g} {d:.3f} m" for p, d in zip(g.percentiles, g.distance_m, strict=False)
        )
        print(
            f"  {u.samples} samples  collision probability {u.collision_probability:.3f}, "
            f"approved {u.approved_probability:.3f}; goal distance {spread or 'n/a'}"
        )
    r = v.replay
    print(f"  map            {r.map} sha256 {r.map_sha256[:16]}, rover {r.rover_sha256[:16]}")
    if png:
        print(f"  picture        {png}")


def main(argv: list[str] | None = None) -> int:
    """``rover_gate`` for ``ros2 run`` and launch files: the server's options of ``rover
    gate``, then optionally ``--ros-args`` (its ``--params-file`` section for the node and
    ``-p name:=value`` stand for the long options: ``map`` -> ``--map``)."""
    from firmware_proto.cli.program import ros_main

    parser = argparse.ArgumentParser(
        prog="rover_gate",
        description=_DESCRIPTION + " Accepts --ros-args (see docs/ros2.md).",
    )
    add_arguments(parser)
    return ros_main(parser, _serve, argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
