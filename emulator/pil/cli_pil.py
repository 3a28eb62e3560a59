"""``rover pil``: the firmware image in an emulated MCU, served as ``rover emulate``
serves a controller (docs/firmware.md, "Processor in the loop").

It builds the image (or takes ``--image``), starts the emulator (real-time priority
where permitted), prints ``DEVICE <pty> [LINK path]`` and, with ``--control-port``,
``CONTROL 127.0.0.1:<port>`` first on stdout, serves ``rover emulate``'s control port
(``reboot`` is a real reset), and on Ctrl-C or SIGTERM ends everything it started.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from firmware_proto.cli.runtimeargs import add_runtime_arguments, runtime_options
from firmware_proto.runtime import ProcessRuntime, ShutdownSignals
from firmware_proto.runtime.realtime import EMULATOR_PRIORITY

__all__ = ["add_arguments", "register", "run"]

_DESCRIPTION = (
    "Run the controller's firmware image in an emulated MCU: the nRF51 (micro:bit) under "
    "qemu-system-arm with its plant inside the image, or the ATmega2560 under simavr with "
    "the pymunk twin as its plant. Prints 'DEVICE <path>' and, with --control-port, "
    "'CONTROL 127.0.0.1:<port>' as its first lines, like rover emulate; the control port "
    "takes status, inject reboot|stall:SIDE|encoder-dropout:SIDE|slip:SIDE=SCALE|clear:KIND "
    "and injections. Stops cleanly on Ctrl-C or SIGTERM."
)


def register(subparsers: Any) -> None:
    """Add ``rover pil``."""
    p = subparsers.add_parser(
        "pil",
        help="the firmware image in an emulated MCU (qemu micro:bit, simavr ATmega2560)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_DESCRIPTION,
        epilog=(
            "examples:\n"
            "  rover pil --target microbit --link /tmp/rover-motor --control-port 7700\n"
            "  rover pil --target atmega2560 --map lab --inject slip:left=0.3\n"
            "  rover conformance --device /tmp/rover-motor --control 127.0.0.1:7700"
        ),
    )
    add_arguments(p)
    p.set_defaults(func=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The runner's options."""
    from emulator.pil.registry import TARGETS

    p.add_argument("--target", required=True, choices=sorted(TARGETS), help="the MCU")
    p.add_argument(
        "--link", type=Path, help="a stable symlink to the device (e.g. /tmp/rover-motor)"
    )
    p.add_argument(
        "--control-port",
        type=int,
        default=None,
        metavar="PORT",
        help="serve the control interface on 127.0.0.1:PORT (0: a free port)",
    )
    p.add_argument(
        "--image", type=Path, help="an image already built (ELF) instead of building one"
    )
    p.add_argument(
        "--map",
        default="lab",
        help="the plant's world: the twin's map (atmega2560), the start pose (microbit)",
    )
    p.add_argument("--seed", type=int, default=1, help="seeds the plant's sensor noise")
    p.add_argument(
        "--inject",
        action="append",
        default=[],
        metavar="FAULT",
        help="apply a fault at the start (stall:right, slip:left=0.3, ...; repeatable)",
    )
    p.add_argument(
        "--duration",
        type=float,
        default=0.0,
        help="stop after this many seconds (0: run until stopped)",
    )
    add_runtime_arguments(p, EMULATOR_PRIORITY)


def _target(args: argparse.Namespace, priority: int) -> Any:
    from emulator.pil.images import IMAGES, Image, build_image
    from emulator.pil.registry import target_class

    if args.image is not None:
        built = build_image(args.target)  # for its symbols' addresses and sizes
        image = Image(
            built.spec, args.image, True, built.text, built.data, built.bss, built.symbols
        )
    else:
        image = build_image(args.target)
    print(image.line(), file=sys.stderr, flush=True)
    del IMAGES
    cls = target_class(args.target)
    kwargs: dict[str, Any] = {
        "link": args.link,
        "realtime_priority": priority,
        "seed": args.seed,
        "say": lambda line: print(line, file=sys.stderr, flush=True),
    }
    kwargs["map_name"] = args.map
    return cls(image, **kwargs)


def run(args: argparse.Namespace) -> int:
    """Serve until a signal or ``--duration``; exit 0, or 1 with one line on an error."""
    from emulator.control import ControlServer
    from emulator.errors import EmulatorError
    from emulator.injection import parse_fault
    from firmware_proto.runtime.realtime import leave_realtime_for_process

    options = runtime_options(args, "pil", EMULATOR_PRIORITY)
    try:
        faults = [parse_fault(f) for f in args.inject]
        target = _target(args, options.priority)
    except EmulatorError as exc:
        print(f"rover pil: error: {exc}", file=sys.stderr)
        return 1
    runtime = ProcessRuntime(options)
    with ShutdownSignals() as done, runtime:
        print(runtime.line(), file=sys.stderr, flush=True)
        control: ControlServer | None = None
        try:
            target.start()
            for fault in faults:
                target.inject(fault, source="cli")
            print(f"PLANT {target.plant_name}", file=sys.stderr, flush=True)
            print(f"SCHEDULING emulator: {target.realtime_note}", file=sys.stderr, flush=True)
            print(
                f"DEVICE {target.device}" + (f" LINK {args.link}" if args.link else ""),
                flush=True,
            )
            if args.control_port is not None:
                control = ControlServer(target, args.control_port).start()
                print(f"CONTROL 127.0.0.1:{control.port}", flush=True)
            waited = 0.0
            while not done.received:
                if done.wait(0.5):
                    break
                waited += 0.5
                if not target.alive():
                    print("rover pil: error: the emulator exited", file=sys.stderr)
                    return 1
                if args.duration > 0 and waited >= args.duration:
                    break
        except EmulatorError as exc:
            print(f"rover pil: error: {exc}", file=sys.stderr)
            return 1
        finally:
            leave_realtime_for_process()
            if control is not None:
                control.close()
            target.close()
    return 0
