"""``rover decode``: print the messages of a traffic log (serial frame log or CAN log)."""

from __future__ import annotations

import argparse
import json
from collections import Counter
from typing import Any

from firmware_proto.cli import values

__all__ = ["register_decode"]


def register_decode(subparsers: Any) -> None:
    """Add ``rover decode``."""
    p = subparsers.add_parser(
        "decode",
        help="print the decoded messages of a traffic log (serial or CAN, auto-detected)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Decode a traffic log recorded with --record (rover bridge, rover emulate, "
            "rover bench stop) or by candump -L: one line per frame with its time (s from "
            "the first frame, or --absolute), direction (H>C host to controller, C>H "
            "controller to host, ? for a frame of no protocol message), serial frame "
            "counter or CAN node, and the message with enum values by name. Frames that "
            "do not decode are shown with the reason. The format is told by content: a "
            "serial frame log starts with '# rover-hil serial frame log v1'; anything else "
            "is read by python-can by its suffix (.log candump, .asc, .blf, .csv). "
            "A .mcap file (a mission recorded by rover go --record or rover demo) is "
            "summarised instead: topics, counts, first and last poses (docs/view.md). "
            "See docs/traffic-logs.md."
        ),
        epilog=(
            "examples:\n"
            "  rover decode session.rlog\n"
            "  rover decode bus.log --only STOP,STOP_ACK,STOPPED --absolute\n"
            "  rover decode bus.log --no-telemetry --node 1"
        ),
    )
    p.add_argument("log", metavar="LOG", help="the traffic log")
    p.add_argument(
        "--absolute", action="store_true", help="print epoch times instead of relative ones"
    )
    p.add_argument(
        "--only", metavar="NAMES", help="only these messages, comma-separated (STOP,STOP_ACK)"
    )
    p.add_argument(
        "--no-telemetry",
        action="store_true",
        help="leave out periodic telemetry (HEARTBEAT, ENCODERS, WHEEL_SPEEDS, IMU, ...)",
    )
    p.add_argument("--node", type=values.can_node, help="CAN: only frames of this node")
    p.add_argument("--raw", action="store_true", help="also print each frame's bytes")
    p.add_argument("--json", action="store_true", help="one JSON object per frame")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    if str(args.log).endswith(".mcap"):  # a recorded mission: its reader plugs in (rover.decode)
        from importlib.metadata import entry_points

        for ep in entry_points(group="rover.decode", name="mcap"):
            status: int = ep.load()(args)
            return status
        raise ValueError(f"{args.log}: no reader of .mcap files is installed")
    from firmware_proto.linkio.trafficio import read_log
    from firmware_proto.linkio.trafficlog import decode_records
    from firmware_proto.wire.messages import BY_NAME

    only: set[str] | None = None
    if args.only:
        only = {name.strip().upper() for name in args.only.split(",") if name.strip()}
        unknown = sorted(only - set(BY_NAME))
        if unknown:
            raise ValueError(
                f"--only: unknown message(s) {', '.join(unknown)}; known: {', '.join(BY_NAME)}"
            )
    log = read_log(args.log)
    decoded = decode_records(log.records)
    t0 = decoded[0].time_s if decoded else 0.0
    counts: Counter[str] = Counter()
    bad = 0
    header = f"{log.path}: {log.kind} log, {len(log.records)} frames"
    if log.metadata:
        header += " (" + ", ".join(f"{k} {v}" for k, v in log.metadata.items() if v) + ")"
    if not args.json:
        print(header)
    for rec in decoded:
        msg = rec.message
        if msg is None:
            bad += 1
        else:
            counts[msg.NAME] += 1
        if args.node is not None and rec.node != args.node:
            continue
        if only is not None and (msg is None or msg.NAME not in only):
            continue
        if args.no_telemetry and msg is not None and msg.PRIORITY == "telemetry":
            continue
        t = rec.time_s if args.absolute else rec.time_s - t0
        if args.json:
            print(
                json.dumps(
                    {
                        "time_s": round(t, 6),
                        "direction": rec.direction,
                        "node": rec.node,
                        "seq": rec.seq,
                        "name": msg.NAME if msg else None,
                        "fields": msg.to_dict() if msg else None,
                        "raw": rec.raw,
                        "error": rec.error or None,
                    }
                )
            )
            continue
        where = f"seq {rec.seq:3d}" if rec.seq is not None else ""
        if log.kind == "can":
            where = f"node {rec.node:2d}" if rec.node is not None else "node  ?"
        text = msg.describe() if msg else f"undecodable ({rec.error})"
        width = 17 if args.absolute else 11
        line = f"{t:{width}.6f}  {rec.direction or '?':3}  {where:8} {text}"
        if args.raw or msg is None:
            line += f"  [{rec.raw}]"
        print(line)
    if not args.json:
        summary = ", ".join(f"{name} {n}" for name, n in sorted(counts.items()))
        print(f"-- {len(decoded)} frames: {summary or 'none'}; undecodable {bad}")
    return 0
