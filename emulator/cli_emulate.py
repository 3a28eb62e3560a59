"""``rover emulate``: serve the controller emulator over a pty or a CAN bus.

Also :func:`main`, the ``rover_emulator`` console script of ``ros2 run`` and launch
files: the same options, then optionally ``--ros-args`` (``--params-file`` section and
``-p`` values stand for long options; docs/ros2.md).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from firmware_proto.cli import values
from firmware_proto.cli.runtimeargs import add_runtime_arguments, runtime_options
from firmware_proto.runtime import ProcessRuntime, ShutdownSignals
from firmware_proto.runtime.realtime import EMULATOR_PRIORITY

if TYPE_CHECKING:
    from emulator.controller import ControllerConfig, ControllerModel
    from emulator.frontend import FrontEnd
    from emulator.ground import Ground
    from emulator.injection import FaultSpec, InjectionRecord
    from firmware_proto.model.rover import RoverDescription

__all__ = ["add_arguments", "controller_config", "ground_of", "main", "register"]

NODE_NAME = "rover_emulator"
"""Node name whose section of a ROS parameters file configures ``rover_emulator``."""

_DESCRIPTION = (
    "Run the motor-controller emulator: the firmware behaviour of docs/protocol.md "
    "over the pymunk twin, served on a pty (--serial) or a python-can bus (--can). "
    "Prints 'DEVICE <path>' (or 'CAN <interface:channel> node <n>') and, with "
    "--control-port, 'CONTROL 127.0.0.1:<port>' as its first lines. Stops cleanly "
    "on Ctrl-C or SIGTERM. Every fault is checked before serving: one that cannot apply "
    "(a value out of range, link-corrupt on CAN, an unknown region) is an error, exit 1. "
    "Each injection prints 'INJECT t=<twin s> <fault> (<source>)' to stderr when it applies."
)


def _epilog() -> str:
    from emulator.injection import FAULT_KINDS  # light: no pymunk

    kinds = "\n".join(f"  {k:<16} {v}" for k, v in FAULT_KINDS.items())
    return (
        "fault injection (--inject, repeatable; also on the control interface):\n"
        f"{kinds}\n"
        "  triggers: @t=SECONDS (twin time), @d=METRES (ground travel), @region=ID\n"
        "  ranges: slip scale (0, 1]; encoder-noise 0..100000 units; |imu-bias| <= 32.767 "
        "rad/s;\n  link ratios 0..1; link-delay 0..10 s; link-corrupt on serial only\n\n"
        "examples:\n"
        "  rover emulate --serial --link /tmp/rover-motor --map lab\n"
        "  rover emulate --can virtual:rover --node 2 --inject slip:left=0.3@t=5\n"
        "  rover emulate --can socketcan:vcan0 --control-port 7700\n"
        "  rover emulate --serial --record session.rlog   (then: rover decode session.rlog)"
    )


def register(subparsers: Any) -> None:
    """Add ``rover emulate``."""
    p = subparsers.add_parser(
        "emulate",
        help="impersonate the motor controller over a pty or a CAN bus",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_DESCRIPTION,
        epilog=_epilog(),
    )
    add_arguments(p)
    p.set_defaults(func=_run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The emulator's options (shared by ``rover emulate`` and ``rover_emulator``)."""
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--serial", action="store_true", help="serve on a new pty")
    where.add_argument(
        "--can", metavar="INTERFACE:CHANNEL", help="serve on a python-can bus, e.g. socketcan:vcan0"
    )
    p.add_argument("--link", metavar="PATH", help="with --serial: stable symlink to the pty device")
    p.add_argument(
        "--baud", type=values.baud, help="with --serial: pace frames to the host at this bit rate"
    )
    p.add_argument(
        "--node", type=values.can_node, default=1, help="with --can: node id 1..15 (default 1)"
    )
    p.add_argument("--map", default="lab", help="map name or JSON file (default: lab)")
    p.add_argument("--rover", metavar="TOML", help="rover description (default: the packaged one)")
    p.add_argument(
        "--ground",
        metavar="NAME|FILE",
        help=(
            "drive on a ground of its own, unknown to the gate: a shipped ground "
            f"({', '.join(_shipped_grounds())}) or a ground TOML file (docs/twin.md); "
            "default: the rover description's traction and the map's regions"
        ),
    )
    p.add_argument(
        "--ground-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=(
            "set one ground parameter (repeatable, after --ground): mu_longitudinal, "
            "mu_lateral, slip_saturation_mps, slip_saturation_ratio, rolling_resistance, "
            "turn_efficiency (solves mu_lateral), region.ID (a region's friction scale)"
        ),
    )
    p.add_argument(
        "--seed", type=int, default=0, help="seed of sensor noise, boot nonces, link faults"
    )
    p.add_argument(
        "--dt",
        type=float,
        default=None,
        help=(
            "physics and control step, s (default: 1 ms of wall time, 0.001 times the "
            "speed factor, at most 0.01)"
        ),
    )
    p.add_argument(
        "--speed-factor",
        type=float,
        default=1.0,
        help="twin seconds per wall second; timeouts scale with it (default 1)",
    )
    p.add_argument(
        "--watchdog-ms",
        type=int,
        metavar="MS",
        help="controller watchdog, host ms, 50..10000 (default: the protocol's 250)",
    )
    p.add_argument(
        "--telemetry-hz",
        type=int,
        metavar="HZ",
        help="ENCODERS, WHEEL_SPEEDS and IMU rate, 1..200 (default: the protocol's 50)",
    )
    p.add_argument(
        "--inject",
        action="append",
        default=[],
        metavar="FAULT",
        help="schedule a fault (see below)",
    )
    p.add_argument(
        "--control-port",
        type=values.tcp_port,
        metavar="PORT",
        help="serve the control interface on 127.0.0.1:PORT (0 picks one)",
    )
    p.add_argument(
        "--status",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="print a status line to stderr every SECONDS",
    )
    p.add_argument(
        "--duration", type=float, default=0.0, metavar="SECONDS", help="exit after SECONDS (wall)"
    )
    p.add_argument(
        "--schema-hash",
        type=lambda s: int(s, 0),
        metavar="HASH",
        help="claim this schema hash in IDENT (to test a host's mismatch handling)",
    )
    p.add_argument(
        "--firmware",
        choices=("python", "c"),
        default="python",
        help=(
            "the controller: the Python model, or the C firmware core of "
            "firmware_proto/wire/c/fw built for this host and run in the loop (needs a C "
            "compiler; docs/firmware.md) (default: python)"
        ),
    )
    p.add_argument(
        "--mutant",
        metavar="NAME",
        help=(
            "TEST AID: serve a mutant controller, the Python model with one rule of "
            "docs/protocol.md broken (emulator/mutants.py; the conformance suite must fail "
            "it); an unknown NAME lists the known ones. Never drive a rover with one"
        ),
    )
    p.add_argument(
        "--record",
        metavar="FILE",
        help=(
            "record the link traffic: a serial frame log with --serial, a python-can log "
            "chosen by suffix with --can (.log: candump); see docs/traffic-logs.md"
        ),
    )
    add_runtime_arguments(p, EMULATOR_PRIORITY)


def _shipped_grounds() -> tuple[str, ...]:
    from emulator.ground import list_grounds  # light: no pymunk

    return list_grounds()


def ground_of(args: argparse.Namespace, rover: RoverDescription) -> Ground | None:
    """The ground ``--ground`` and ``--ground-set`` ask for; ``None`` for neither.

    Raises:
        GroundError: an unknown ground, an invalid file or setting.
    """
    from dataclasses import replace

    from emulator.ground import Ground, load_ground, parse_ground_setting, solve_mu_lateral

    settings = [parse_ground_setting(text) for text in getattr(args, "ground_set", [])]
    name = getattr(args, "ground", None)
    if name is None and not settings:
        return None
    ground = load_ground(name, rover) if name is not None else Ground.of_rover(rover)
    if name is None:
        ground = replace(ground, name="custom")
    values = {k: v for k, v in settings if k != "turn_efficiency"}
    ground = ground.with_values(**values)
    for key, value in settings:
        if key == "turn_efficiency":
            ground = replace(ground, mu_lateral=solve_mu_lateral(rover, ground, value))
    return ground


def controller_config(args: argparse.Namespace) -> ControllerConfig:
    """The firmware settings the options ask for.

    Raises:
        ValueError: speed factor not positive, or a watchdog or telemetry rate outside
            what SET_PARAM accepts (``emulator.controller.PARAM_RANGES``).
    """
    from emulator.controller import PARAM_RANGES, ControllerConfig
    from firmware_proto.wire.messages import Param

    if not args.speed_factor > 0:
        raise ValueError("--speed-factor must be > 0")
    settings: dict[str, Any] = {"timeout_scale": args.speed_factor}
    for option, param, name in (
        ("--watchdog-ms", Param.WATCHDOG_MS, "watchdog_ms"),
        ("--telemetry-hz", Param.TELEMETRY_HZ, "telemetry_hz"),
    ):
        value = getattr(args, name)
        if value is None:
            continue
        low, high = PARAM_RANGES[param]
        if not low <= value <= high:
            raise ValueError(f"{option} must be in {low}..{high}, got {value}")
        settings[name] = value
    return ControllerConfig(**settings)


def _run(args: argparse.Namespace) -> int:
    from emulator.errors import InjectionError
    from emulator.firmware import make_controller
    from emulator.injection import Injector, parse_fault
    from emulator.twin import Twin, served_dt_s
    from firmware_proto.linkio.errors import LinkUrlError
    from firmware_proto.linkio.trafficio import LogWriter, open_recorder
    from firmware_proto.linkio.urls import parse_can_spec
    from firmware_proto.model.rover import load_rover
    from firmware_proto.model.worldmap import load_map
    from firmware_proto.wire.messages import SCHEMA_HASH

    config = controller_config(args)
    faults: list[FaultSpec] = []
    for text in args.inject:
        try:
            faults.append(parse_fault(text))
        except InjectionError as exc:
            raise InjectionError(f"--inject {text}: {exc}") from None
    interface = channel = ""
    if not args.serial:
        try:
            interface, channel = parse_can_spec(args.can)
        except LinkUrlError as exc:
            raise ValueError(f"--can: {exc}") from None
    rover = load_rover(args.rover)
    world = load_map(args.map)
    ground = ground_of(args, rover)
    dt_s = served_dt_s(args.speed_factor) if args.dt is None else args.dt
    if ground is not None:
        # Only the plant drives on this ground: firmware knows nothing of it.
        twin = Twin(ground.rover(rover), ground.world(world), dt_s=dt_s)
        values = ", ".join(f"{k}={v:g}" for k, v in ground.values().items())
        regions = ", ".join(f"{k}={v:g}" for k, v in ground.regions)
        print(
            f"GROUND {ground.name}: {values}" + (f"; regions {regions}" if regions else ""),
            file=sys.stderr,
            flush=True,
        )
    else:
        twin = Twin(rover, world, dt_s=dt_s)
    schema_hash = SCHEMA_HASH if args.schema_hash is None else args.schema_hash
    mutant = None
    if getattr(args, "mutant", None):
        from emulator.mutants import mutant as find_mutant

        if getattr(args, "firmware", "python") != "python":
            raise ValueError("--mutant: mutants are of the Python model (--firmware python)")
        mutant = find_mutant(args.mutant)
        print(f"MUTANT {mutant.name}: breaks: {mutant.breaks}", file=sys.stderr, flush=True)
        model = mutant.model(rover, twin, config, seed=args.seed, schema_hash=schema_hash)
    else:
        model = make_controller(
            getattr(args, "firmware", "python"),
            rover,
            twin,
            config,
            seed=args.seed,
            schema_hash=schema_hash,
        )
    frontend = _frontend(args, interface, channel)
    if mutant is not None and mutant.link is not None:
        mutant.link(frontend.endpoint)
    # Refuse what cannot apply before anything is served or written.
    checker = Injector(model, frontend)
    for text, spec in zip(args.inject, faults, strict=True):
        try:
            checker.check(spec)
        except InjectionError as exc:
            raise InjectionError(f"--inject {text}: {exc}") from None
    recorder: LogWriter | None = None
    if args.record:
        recorder = open_recorder(
            args.record,
            "serial" if args.serial else "can",
            channel=channel,
            metadata={
                "role": "emulator",
                "seed": str(args.seed),
                "speed_factor": str(args.speed_factor),
                "dt_s": str(dt_s),
                "map": str(args.map),
                "rover": str(args.rover or ""),
                "ground": ground.to_toml() if ground is not None else "",
                "firmware": getattr(args, "firmware", "python"),
            },
        )
        frontend.recorder = recorder
    try:
        return _serve(args, model, frontend, faults)
    finally:
        if recorder is not None:
            recorder.close()


def _frontend(args: argparse.Namespace, interface: str, channel: str) -> FrontEnd:
    """The front end the options ask for, not yet opened (nothing is served)."""
    from emulator.can_frontend import CanFrontEnd
    from emulator.serial_frontend import SerialFrontEnd

    if args.serial:
        return SerialFrontEnd(link=args.link, baud=args.baud, seed=args.seed)
    return CanFrontEnd(interface=interface, channel=channel, node=args.node, seed=args.seed)


def _print_injection(record: InjectionRecord) -> None:
    print(record.line(), file=sys.stderr, flush=True)


def _serve(
    args: argparse.Namespace,
    model: ControllerModel,
    frontend: FrontEnd,
    faults: list[FaultSpec],
) -> int:
    # Everything is checked; before any thread starts, so that all inherit the policy.
    runtime = ProcessRuntime(runtime_options(args, "emulator", EMULATOR_PRIORITY))
    with ShutdownSignals() as done, runtime:
        print(runtime.line(), file=sys.stderr, flush=True)
        return _serve_emulator(args, model, frontend, faults, done)


def _serve_emulator(
    args: argparse.Namespace,
    model: ControllerModel,
    frontend: FrontEnd,
    faults: list[FaultSpec],
    done: ShutdownSignals,
) -> int:
    from emulator.can_frontend import CanFrontEnd
    from emulator.control import ControlServer
    from emulator.engine import Emulator
    from emulator.serial_frontend import SerialFrontEnd
    from firmware_proto.runtime.realtime import leave_realtime_for_process

    emulator = Emulator(
        model,
        frontend,
        speed_factor=args.speed_factor,
        faults=faults,
        on_injection=_print_injection,
        fault_source="cli",
    )
    control: ControlServer | None = None
    with emulator:
        if isinstance(frontend, SerialFrontEnd):
            print(
                f"DEVICE {frontend.device}" + (f" LINK {frontend.link}" if frontend.link else ""),
                flush=True,
            )
        elif isinstance(frontend, CanFrontEnd):
            print(f"CAN {frontend.device} node {args.node}", flush=True)
        try:
            if args.control_port is not None:
                control = ControlServer(emulator, args.control_port).start()
                print(f"CONTROL 127.0.0.1:{control.port}", flush=True)
            deadline = args.duration if args.duration > 0 else None
            interval = args.status if args.status > 0 else None
            waited = 0.0
            while not done.received:
                step = min(x for x in (interval, 0.5) if x is not None)
                if deadline is not None:
                    step = min(step, max(0.0, deadline - waited))
                if done.wait(step):
                    break
                waited += step
                if interval is not None and emulator.last_status is not None:
                    print(emulator.last_status.line(), file=sys.stderr, flush=True)
                if deadline is not None and waited >= deadline:
                    break
        finally:
            # Shutting down need not keep time.
            leave_realtime_for_process()
            if control is not None:
                control.close()
    final = emulator.last_status
    if final is not None:
        print(f"emulator stopped: {final.line()}", file=sys.stderr)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``rover_emulator``: ``rover emulate``'s options, then ``--ros-args`` (module doc)."""
    from firmware_proto.cli.program import ros_main

    parser = argparse.ArgumentParser(
        prog=NODE_NAME,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_DESCRIPTION
        + " Accepts --ros-args: its --params-file section for the node and -p name:=value "
        "stand for the long options (speed_factor -> --speed-factor).",
        epilog=_epilog(),
    )
    add_arguments(parser)
    return ros_main(parser, _run, argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
