"""How a program of ours starts and ends: the ``main()`` that ``ros2 run`` and the launch
files start (docs/ros2.md), its logging, and the one line an error gets.

Exit status: what ``run`` returns; 1 when it raised (``PROG: error: ...``); 2 for a
usage error (a bad option or ROS argument, an unreadable ``--params-file``); 130 when
interrupted.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable, Sequence

from firmware_proto.cli.rosargs import split_ros_args
from firmware_proto.cli.rosparams import parse_args_with_ros_args

__all__ = ["LOG_FORMAT", "configure_logging", "error_text", "ros_main"]

LOG_FORMAT = "%(asctime)s %(levelname)-7s %(name)s: %(message)s"
"""The log line of every program of ours (on stderr)."""


def configure_logging(level: int = logging.INFO) -> None:
    """Log at ``level`` and above to stderr as :data:`LOG_FORMAT` (entry points only)."""
    logging.basicConfig(level=level, format=LOG_FORMAT, stream=sys.stderr)


def error_text(exc: BaseException) -> str:
    """What an operator reads of ``exc``: its message, after its type's name unless it is
    an ``OSError``, ``ValueError`` or ``RuntimeError`` (whose messages say what they
    are; every package's error tree derives from one of them or names itself)."""
    if isinstance(exc, (OSError, ValueError, RuntimeError)):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


def ros_main(
    parser: argparse.ArgumentParser,
    run: Callable[[argparse.Namespace], int],
    argv: Sequence[str] | None = None,
    *,
    node: bool = False,
    with_rclpy: bool = False,
) -> int:
    """Run a program that ``ros2 run`` starts: its own options, then optionally
    ``--ros-args``; returns the exit status (module docstring); a usage error exits through
    ``parser.error``.

    Args:
        parser: the program's parser; its ``prog`` names the program in messages and is the
            node name that ``--params-file`` sections and ``-p`` address.
        run: the program; its return value is the exit status.
        argv: the arguments (default ``sys.argv[1:]``).
        node: the program runs a ROS node of its own: the ``--ros-args`` tail goes to it
            whole, as ``args.ros_args``. Otherwise the node's parameters become long
            options placed before the program's own, which therefore win.
        with_rclpy: read the ROS arguments with rcl's parser where rclpy is installed.
    """
    given = list(sys.argv[1:] if argv is None else argv)
    prog = parser.prog
    if node:
        own, ros_args = split_ros_args(given)
        args = parser.parse_args(own)
        args.ros_args = ros_args
    else:
        args = parse_args_with_ros_args(parser, given, prog, with_rclpy=with_rclpy)
    configure_logging()
    try:
        return run(args)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one clean line for the operator, whatever the package
        print(f"{prog}: error: {error_text(exc)}", file=sys.stderr)
        return 1
