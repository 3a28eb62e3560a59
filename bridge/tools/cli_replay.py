"""``rover replay --bridge``: the bridge's replay target (the options:
:mod:`firmware_proto.cli.replay`; what it does: :mod:`bridge.tools.bridge_replay`)."""

from __future__ import annotations

import argparse
import os

__all__ = ["run"]


def run(args: argparse.Namespace) -> int:
    """Replay ``args.log``'s controller side into a fresh bridge link; print the report;
    0 if the bridge sent the recorded requests, 1 if not."""
    from bridge.tools.bridge_replay import BridgeReplayOptions, replay_into_bridge
    from firmware_proto.linkio.trafficio import read_log

    log = read_log(args.log)
    interface, channel = "virtual", f"rover-bridge-replay-{os.getpid()}"
    if args.can:
        interface, sep, channel = args.can.partition(":")
        if not sep or not interface or not channel:
            raise ValueError(f"--can needs INTERFACE:CHANNEL, got {args.can!r}")
    ignored = [
        flag
        for flag, value in (
            ("--seed", args.seed),
            ("--speed-factor", args.speed_factor),
            ("--map", args.map),
            ("--rover", args.rover),
            ("--record", args.record),
        )
        if value is not None
    ]
    if args.strict:
        ignored.append("--strict")
    if ignored:
        raise ValueError(f"{', '.join(ignored)}: emulator options; not used with --bridge")
    result = replay_into_bridge(
        log, BridgeReplayOptions(node=args.node, can_interface=interface, can_channel=channel)
    )
    print(f"{log.path}: {log.kind} log, {len(log.records)} frames")
    print(result.report())
    return 0 if result.ok else 1
