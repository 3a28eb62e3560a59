"""``rover replay --emulator``: the emulator's replay target (see
:mod:`firmware_proto.cli.replay` for the options and :mod:`emulator.replay` for what it
does)."""

from __future__ import annotations

import argparse
import os

__all__ = ["run"]


def run(args: argparse.Namespace) -> int:
    """Replay ``args.log`` into a fresh emulator; print the report; 0 if the answers
    match, 1 if they differ."""
    from emulator.replay import ReplayOptions, replay_into_emulator
    from firmware_proto.linkio.trafficio import open_recorder, read_log

    log = read_log(args.log)
    meta = log.metadata
    interface, channel = "virtual", f"rover-replay-{os.getpid()}"
    if args.can:
        interface, sep, channel = args.can.partition(":")
        if not sep or not interface or not channel:
            raise ValueError(f"--can needs INTERFACE:CHANNEL, got {args.can!r}")
    options = ReplayOptions(
        seed=args.seed if args.seed is not None else int(meta.get("seed", "0")),
        speed_factor=(
            args.speed_factor
            if args.speed_factor is not None
            else float(meta.get("speed_factor", "1"))
        ),
        dt_s=float(meta["dt_s"]) if meta.get("dt_s") else None,
        map_name=args.map or meta.get("map") or "lab",
        rover_path=args.rover or meta.get("rover", ""),
        node=args.node,
        can_interface=interface,
        can_channel=channel,
        strict=args.strict,
        edge_s=args.edge,
    )
    if options.speed_factor <= 0 or args.edge < 0:
        raise ValueError("--speed-factor must be > 0 and --edge >= 0")
    recorder = (
        open_recorder(args.record, log.kind, channel=channel, metadata={"role": "replay"})
        if args.record
        else None
    )
    try:
        result = replay_into_emulator(log, options, recorder=recorder)
    finally:
        if recorder is not None:
            recorder.close()
    print(
        f"{log.path}: {log.kind} log, {len(log.records)} frames; emulator seed "
        f"{options.seed}, speed factor {options.speed_factor:g}, map {options.map_name}"
    )
    print(result.report())
    return 0 if result.ok else 1
