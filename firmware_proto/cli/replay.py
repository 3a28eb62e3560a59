"""``rover replay``: replay a recorded traffic log for regression tests.

The replay targets are plugged in by entry point (group :data:`REPLAY_GROUP`), as the
``rover`` subcommands are: a function ``run(args: argparse.Namespace) -> int`` that reads
the options below. This module never imports the targets.

Exit status: 0 the replay matched the recording, 1 it differed (or failed), 2 usage.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any

from firmware_proto.cli import values
from firmware_proto.cli.runtimeargs import add_runtime_arguments, runtime_options
from firmware_proto.runtime.realtime import EMULATOR_PRIORITY

__all__ = ["DEFAULT_TARGET", "REPLAY_GROUP", "register"]

REPLAY_GROUP = "rover.replay"
DEFAULT_TARGET = "emulator"

_TARGET_HELP = {
    "emulator": "re-send the host's frames to a fresh emulator and compare its answers "
    "(the default)",
    "bridge": "play the controller's side to a fresh bridge link and compare the bridge's requests",
}


def _targets() -> list[str]:
    return sorted({ep.name for ep in entry_points(group=REPLAY_GROUP)})


def register(subparsers: Any) -> None:
    """Add ``rover replay``."""
    p = subparsers.add_parser(
        "replay",
        help="replay a recorded traffic log into a fresh emulator (or bridge) and compare",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Replay a traffic log recorded with --record (rover emulate, rover bridge, "
            "rover bench stop) and report where the behaviour differs from the recording. "
            "With --emulator (the default) the host's frames are re-sent with their "
            "recorded timing to a fresh, seeded emulator on a new pty (serial logs) or a "
            "python-can bus (CAN logs); its answers (acks, statuses, stops, faults, idents) "
            "are compared type by type with the recorded ones, leaving out measured fields "
            "(travel, stopping distance and time, boot nonce) unless --strict. The emulator "
            "must run as when the log was recorded: an emulator-recorded serial log names "
            "its seed, speed factor and map, which become the defaults here. With --bridge "
            "the controller's frames are played to a fresh bridge link (ControllerLink) "
            "that is given the recorded operator inputs (steps, stops, clears), and the "
            "requests it sends are compared with the recorded ones; the /command_status it "
            "reports is printed. See docs/traffic-logs.md."
        ),
        epilog=(
            "examples:\n"
            "  rover emulate --serial --seed 3 --record session.rlog   (drive it, stop it)\n"
            "  rover replay session.rlog\n"
            "  rover replay bus.log --can virtual:replay --strict\n"
            "  rover replay bridge.rlog --bridge"
        ),
    )
    p.add_argument("log", metavar="LOG", help="serial frame log or CAN log (.log candump)")
    into = p.add_mutually_exclusive_group()
    for name in _targets():
        into.add_argument(
            f"--{name}",
            dest="into",
            action="store_const",
            const=name,
            help=_TARGET_HELP.get(name, f"replay into the {name}"),
        )
    p.add_argument(
        "--can",
        metavar="INTERFACE:CHANNEL",
        help="bus for a CAN log (default virtual:rover-replay, in-process)",
    )
    p.add_argument(
        "--node", type=values.can_node, help="CAN node id (default: the node the log addressed)"
    )
    p.add_argument("--seed", type=int, help="emulator seed (default: the log's, else 0)")
    p.add_argument(
        "--speed-factor",
        type=float,
        help="twin seconds per wall second (default: the log's, else 1)",
    )
    p.add_argument("--map", help="map name or JSON file (default: the log's, else lab)")
    p.add_argument("--rover", metavar="TOML", help="rover description (default: the log's)")
    p.add_argument(
        "--strict", action="store_true", help="also compare measured fields (travel, ...)"
    )
    p.add_argument(
        "--edge",
        type=float,
        default=0.05,
        metavar="SECONDS",
        help=(
            "answers this close to the end of the recording may fall on either side of it "
            "(default 0.05)"
        ),
    )
    p.add_argument("--record", metavar="FILE", help="record the replay session too")
    # It plays one side of the link on its recorded clock: it keeps time like the emulator.
    add_runtime_arguments(p, EMULATOR_PRIORITY, lock_memory=False)
    p.set_defaults(func=_run, into=None)


def _run(args: argparse.Namespace) -> int:
    from firmware_proto.runtime import ProcessRuntime

    name = args.into or DEFAULT_TARGET
    for ep in entry_points(group=REPLAY_GROUP):
        if ep.name == name:
            run: Callable[[argparse.Namespace], int] = ep.load()
            options = runtime_options(args, "replay", EMULATOR_PRIORITY, lock_memory=False)
            with ProcessRuntime(options) as runtime:
                print(runtime.line(), file=sys.stderr, flush=True)
                return int(run(args))
    known = ", ".join(_targets()) or "none installed"
    raise ValueError(f"unknown replay target {name!r}; known: {known}")
