"""The scheduling options every long-running ``rover`` program takes (docs/realtime.md):
``--rt-priority N`` and ``--no-realtime`` on the programs that keep time, ``--nice N`` on
those that need not, and ``--stall-ms MS`` on all; values checked by
:mod:`firmware_proto.cli.values`.
"""

from __future__ import annotations

import argparse

from firmware_proto.cli import values
from firmware_proto.runtime.process import RuntimeOptions
from firmware_proto.runtime.stall import DEFAULT_STALL_THRESHOLD_S, stall_log_path

__all__ = ["add_runtime_arguments", "runtime_options"]


def add_runtime_arguments(
    parser: argparse.ArgumentParser, default_priority: int, *, lock_memory: bool = True
) -> None:
    """``--rt-priority N`` / ``--no-realtime`` where ``default_priority`` > 0 (a program
    that keeps time; ``lock_memory``: it also locks its memory), else ``--nice N``; and
    ``--stall-ms MS``."""
    group = parser.add_argument_group("scheduling (docs/realtime.md)")
    if default_priority > 0:
        policy = "SCHED_RR, memory locked" if lock_memory else "SCHED_RR"
        group.add_argument(
            "--rt-priority",
            type=values.rt_priority,
            default=None,
            metavar="N",
            help=f"real-time priority 1..99 ({policy}) where permitted "
            f"(default {default_priority}; 0 = off); without permission the program says "
            "so once and runs at normal priority",
        )
        group.add_argument(
            "--no-realtime",
            dest="rt_priority",
            action="store_const",
            const=0,
            help="normal scheduling (the same as --rt-priority 0)",
        )
    else:
        group.add_argument(
            "--nice",
            type=values.yielding_nice,
            default=0,
            metavar="N",
            help="run at nice N, 0..19 (default 0), yielding the CPU to the programs that "
            "keep time",
        )
    group.add_argument(
        "--stall-ms",
        type=values.positive,
        default=DEFAULT_STALL_THRESHOLD_S * 1e3,
        metavar="MS",
        help="log a stall of this program or its loops longer than MS: one line, its stacks "
        f"in the stall log ($ROVER_STALL_LOG), on the console too with -v (default "
        f"{DEFAULT_STALL_THRESHOLD_S * 1e3:.0f})",
    )


def runtime_options(
    args: argparse.Namespace, name: str, default_priority: int = 0, *, lock_memory: bool = True
) -> RuntimeOptions:
    """The options :func:`add_runtime_arguments` parsed; a program with a default priority
    keeps time (short switch interval too; memory locked with ``lock_memory``). The ``rover``
    command's ``-v`` brings stalls' stacks back to the console."""
    priority = getattr(args, "rt_priority", None)
    if priority is None:
        priority = default_priority
    return RuntimeOptions(
        name=name,
        priority=priority,
        stall_threshold_s=getattr(args, "stall_ms", DEFAULT_STALL_THRESHOLD_S * 1e3) / 1e3,
        stall_log=stall_log_path(),
        short_switch=default_priority > 0,
        nice=getattr(args, "nice", 0),
        lock_memory=lock_memory,
        stall_stacks_on_console=getattr(args, "verbose", 0) >= 1,
    )
