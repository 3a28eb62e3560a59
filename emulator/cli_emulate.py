"""``rover emulate``: serve the controller emulator over a pty or a CAN bus."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Any

__all__ = ["register"]


def register(subparsers: Any) -> None:
    """Add ``rover emulate``."""
    from emulator.injection import FAULT_KINDS  # light: no pymunk

    kinds = "\n".join(f"  {k:<16} {v}" for k, v in FAULT_KINDS.items())
    p = subparsers.add_parser(
        "emulate",
        help="impersonate the motor controller over a pty or a CAN bus",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Run the motor-controller emulator: the firmware behaviour of docs/protocol.md "
            "over the pymunk twin, served on a pty (--serial) or a python-can bus (--can). "
            "Prints 'DEVICE <path>' (or 'CAN <interface:channel> node <n>') and, with "
            "--control-port, 'CONTROL 127.0.0.1:<port>' as its first lines. Stops cleanly "
            "on Ctrl-C or SIGTERM."
        ),
        epilog=(
            "fault injection (--inject, repeatable; also on the control interface):\n"
            f"{kinds}\n"
            "  triggers: @t=SECONDS (twin time), @d=METRES (ground travel), @region=ID\n\n"
            "examples:\n"
            "  rover emulate --serial --link /tmp/rover-motor --map lab\n"
            "  rover emulate --can virtual:rover --node 2 --inject slip:left=0.3@t=5\n"
            "  rover emulate --can socketcan:vcan0 --control-port 7700"
        ),
    )
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--serial", action="store_true", help="serve on a new pty")
    where.add_argument(
        "--can", metavar="INTERFACE:CHANNEL", help="serve on a python-can bus, e.g. socketcan:vcan0"
    )
    p.add_argument("--link", metavar="PATH", help="with --serial: stable symlink to the pty device")
    p.add_argument(
        "--baud", type=int, help="with --serial: pace frames to the host at this bit rate"
    )
    p.add_argument("--node", type=int, default=1, help="with --can: node id 1..15 (default 1)")
    p.add_argument("--map", default="lab", help="map name or JSON file (default: lab)")
    p.add_argument("--rover", metavar="TOML", help="rover description (default: the packaged one)")
    p.add_argument(
        "--seed", type=int, default=0, help="seed of sensor noise, boot nonces, link faults"
    )
    p.add_argument(
        "--dt", type=float, default=0.001, help="physics and control step, s (default 0.001)"
    )
    p.add_argument(
        "--speed-factor",
        type=float,
        default=1.0,
        help="twin seconds per wall second; timeouts scale with it (default 1)",
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
        type=int,
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
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from emulator.can_frontend import CanFrontEnd
    from emulator.control import ControlServer
    from emulator.controller import ControllerConfig, ControllerModel
    from emulator.engine import Emulator
    from emulator.frontend import FrontEnd
    from emulator.injection import parse_fault
    from emulator.serial_frontend import SerialFrontEnd
    from emulator.twin import Twin
    from emulator.worldmap import load_map
    from firmware_proto.messages import SCHEMA_HASH
    from firmware_proto.rover import load_rover

    if args.speed_factor <= 0:
        raise ValueError("--speed-factor must be > 0")
    rover = load_rover(args.rover)
    world = load_map(args.map)
    faults = [parse_fault(text) for text in args.inject]
    twin = Twin(rover, world, dt_s=args.dt)
    model = ControllerModel(
        rover,
        twin,
        ControllerConfig(timeout_scale=args.speed_factor),
        seed=args.seed,
        schema_hash=SCHEMA_HASH if args.schema_hash is None else args.schema_hash,
    )
    frontend: FrontEnd
    if args.serial:
        frontend = SerialFrontEnd(link=args.link, baud=args.baud, seed=args.seed)
    else:
        interface, sep, channel = args.can.partition(":")
        if not sep or not interface or not channel:
            raise ValueError(
                f"--can needs INTERFACE:CHANNEL, e.g. socketcan:vcan0, got {args.can!r}"
            )
        frontend = CanFrontEnd(interface=interface, channel=channel, node=args.node, seed=args.seed)

    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    emulator = Emulator(model, frontend, speed_factor=args.speed_factor, faults=faults)
    control: ControlServer | None = None
    with emulator:
        if isinstance(frontend, SerialFrontEnd):
            print(
                f"DEVICE {frontend.device}" + (f" LINK {frontend.link}" if frontend.link else ""),
                flush=True,
            )
        else:
            print(f"CAN {frontend.device} node {args.node}", flush=True)
        try:
            if args.control_port is not None:
                control = ControlServer(emulator, args.control_port).start()
                print(f"CONTROL 127.0.0.1:{control.port}", flush=True)
            deadline = args.duration if args.duration > 0 else None
            interval = args.status if args.status > 0 else None
            waited = 0.0
            while not done.is_set():
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
            if control is not None:
                control.close()
    final = emulator.last_status
    if final is not None:
        print(f"emulator stopped: {final.line()}", file=sys.stderr)
    return 0
