"""The ``rover`` command line: one entry point, subcommands plugged in by each package.

Each package registers its subcommands under the entry-point group ``rover.commands``
(``pyproject.toml``): a function ``register(subparsers)`` adds one ``argparse``
subparser and sets ``func`` on it; ``func(args)`` returns the exit status. Register
functions import nothing heavy at module level, so ``rover --help`` stays fast. A
subcommand whose positionals may follow its options sets ``intermixed`` to their
destination (``rover frame encode MOTION --can 1 seq=1``).

This sub-package is the one place below every other part: it discovers them by entry
point and never imports them, and nothing else in ``firmware_proto`` imports it
(docs/architecture.md, Parts and layers).

Exit status: 0 success, 1 the command failed (one line on stderr; ``-vv`` adds the
traceback), 2 usage error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points
from typing import Any

from firmware_proto.cli.program import configure_logging, error_text
from firmware_proto.runtime.parentwatch import watch_parent
from firmware_proto.runtime.procname import set_process_name

__all__ = ["ENTRY_POINT_GROUP", "build_parser", "main"]

logger = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "rover.commands"

RegisterFn = Callable[[Any], None]


def _load_registrations(only: str | None = None) -> list[tuple[str, RegisterFn]]:
    found = []
    points = sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name)
    if only is not None and any(ep.name == only for ep in points):
        # One command named: load its entry point alone (the others import their packages).
        points = [ep for ep in points if ep.name == only]
    for ep in points:
        try:
            found.append((ep.name, ep.load()))
        except Exception as exc:  # a broken plugin must not take the whole CLI down
            logger.warning("rover: subcommand %r unavailable: %s", ep.name, exc)
    return found


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``rover`` parser with every installed subcommand, or only ``command`` if given."""
    parser = argparse.ArgumentParser(
        prog="rover",
        description=(
            "Hardware-in-the-loop stack of a RASSOR-class rover: wire protocol tools, "
            "controller emulator, ROS 2 bridge, simulation gate and ground station."
        ),
        epilog="Run 'rover COMMAND --help' for the options of one command.",
    )
    parser.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=0,
        help="more log output (-v info, -vv debug with per-frame traffic)",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for _name, register in _load_registrations(command):
        register(sub)
    return parser


def _command_named(argv: Sequence[str]) -> str | None:
    """The subcommand ``argv`` names: its first word after the global options (``-v``
    and ``--verbose`` only; ``None`` with ``-h`` or any other option first)."""
    for word in argv:
        if word in ("-v", "--verbose") or (word.startswith("-v") and set(word[1:]) == {"v"}):
            continue
        return None if word.startswith("-") else word
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``rover`` command line; returns the process exit status. Run as the
    program (``argv`` ``None``: ``sys.argv``), it names its process ``rover-COMMAND``
    (docs/realtime.md, "Which process is which"); a caller's in-process run keeps its
    name."""
    given = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(_command_named(given))
    args, extra = parser.parse_known_args(given)
    # ``intermixed`` (module docstring); anything else left over is a usage error.
    into = getattr(args, "intermixed", None)
    if extra and into is not None and not any(x.startswith("-") for x in extra):
        getattr(args, into).extend(extra)
    elif extra:
        parser.parse_args(given)  # reports the unrecognised arguments; exit status 2
    verbosity: int = args.verbose
    configure_logging(
        logging.WARNING if verbosity <= 0 else logging.INFO if verbosity == 1 else logging.DEBUG
    )
    func: Callable[[argparse.Namespace], int] = args.func
    if argv is None:  # the program (not a caller's in-process run): named for top and
        set_process_name(f"rover-{args.command}")  # pgrep (runtime/procname.py)
    # A part of a stack ends with the process that started it (runtime/parentwatch.py).
    watch_parent()
    try:
        return int(func(args) or 0)
    except KeyboardInterrupt:
        print("rover: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (e.g. `rover devices | head`): not an error of ours.
        # Point stdout at devnull so the interpreter's final flush stays quiet.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    except Exception as exc:
        # Whatever the package's error tree: one clean line, the traceback with -vv.
        if args.verbose >= 2:
            logger.exception("rover %s failed", args.command)
        hint = "" if args.verbose >= 2 else " (run with -vv for details)"
        print(f"rover {args.command}: error: {error_text(exc)}{hint}", file=sys.stderr)
        return 1
