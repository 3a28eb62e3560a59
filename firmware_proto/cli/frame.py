"""``rover frame``: protocol tools (list, encode, decode, generate, dbc).

A number that parses but is out of range (a field value, ``--seq``, a node id, a CAN
identifier) fails the command with one line on stderr and exit status 1, as the codec's
own errors do; text that is not a number is a usage error (exit 2, from argparse).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from firmware_proto.cli import values

__all__ = ["register"]

_MAX_SEQ = 0xFF
"""The serial frame counter is one byte."""
_MAX_CAN_ID = 0x1FFFFFFF
"""Largest CAN identifier (29-bit extended); classic frames stop at 0x7FF."""


def _integer(text: str) -> int:
    """An integer in any base Python writes (``19``, ``0x13``, ``0b10011``)."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an integer such as 19 or 0x013, got {text!r}"
        ) from None


def register(subparsers: Any) -> None:
    """Add ``rover frame`` and its sub-subcommands."""
    parser = subparsers.add_parser(
        "frame",
        help="wire protocol tools: list, encode, decode, generate, dbc",
        description="Tools for the rover motor-controller wire protocol (docs/protocol.md).",
    )
    sub = parser.add_subparsers(dest="frame_command", metavar="ACTION")
    sub.required = True

    p = sub.add_parser("list", help="print the message table")
    p.set_defaults(func=_cmd_list)

    p = sub.add_parser(
        "encode",
        help="encode one message to wire bytes",
        description="Encode one message; prints serial frame bytes (or CAN id and data) in hex.",
        epilog="example: rover frame encode MOTION seq=1 command=FWD speed=30 distance=23000",
    )
    p.add_argument("name", help="message name, e.g. MOTION (see 'rover frame list')")
    p.add_argument(
        "fields",
        nargs="*",
        metavar="FIELD=VALUE",
        help="field values; enum fields take names or numbers",
    )
    p.add_argument(
        "--seq",
        type=int,
        default=None,
        help=f"serial frame counter, 0..{_MAX_SEQ} (default 0); serial frames only",
    )
    p.add_argument(
        "--can",
        type=values.can_node_or_broadcast,
        metavar="NODE",
        help="encode as a CAN frame for this node id (0..15, 0: broadcast), not a serial frame",
    )
    p.add_argument(
        "--loose",
        action="store_true",
        help="only enforce wire ranges, not semantic limits (to test NACKs)",
    )
    p.set_defaults(func=_cmd_encode, intermixed="fields")

    p = sub.add_parser(
        "decode",
        help="decode serial bytes or a CAN frame",
        description="Decode hex serial stream bytes, or the data of one CAN frame with --can-id.",
    )
    p.add_argument("hex", nargs="+", help="hex bytes; spaces and ':' are ignored")
    p.add_argument(
        "--can-id",
        type=_integer,
        metavar="ID",
        help="decode the bytes as the data of one CAN frame with this identifier (0..0x7FF)",
    )
    p.set_defaults(func=_cmd_decode)

    p = sub.add_parser("generate", help="regenerate the files derived from protocol.toml")
    p.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 if any generated file is stale"
    )
    p.set_defaults(func=_cmd_generate)

    p = sub.add_parser("dbc", help="print the CAN database for one node id")
    p.add_argument(
        "--node", type=values.can_node, default=None, help="controller node id, 1..15 (default 1)"
    )
    p.set_defaults(func=_cmd_dbc)


def _cmd_list(args: argparse.Namespace) -> int:
    from firmware_proto.wire.messages import MESSAGE_TYPES, PROTOCOL_VERSION, SCHEMA_HASH

    print(f"protocol version {PROTOCOL_VERSION}, schema hash 0x{SCHEMA_HASH:04X}")
    for msg_id, cls in sorted(MESSAGE_TYPES.items()):
        arrow = "host->ctrl" if cls.DIRECTION == "host_to_controller" else "ctrl->host"
        print(
            f"{msg_id:4d}  {cls.NAME:<15} {arrow}  {cls.PRIORITY:<9} {cls.LENGTH} B  "
            f"{' '.join(cls.FIELDS)}"
        )
    return 0


def _parse_fields(cls: Any, items: list[str]) -> dict[str, int]:
    values: dict[str, int] = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or name not in cls.FIELDS:
            raise ValueError(
                f"{item!r}: expected FIELD=VALUE with FIELD in {', '.join(cls.FIELDS)}"
            )
        enum = cls.ENUMS.get(name)
        if enum is not None and text in enum.__members__:
            values[name] = int(enum[text])
        else:
            try:
                values[name] = int(text, 0)
            except ValueError:
                raise ValueError(
                    f"{name}: {text!r} is not an integer"
                    + (f" or one of {', '.join(enum.__members__)}" if enum else "")
                ) from None
    missing = [f for f in cls.FIELDS if f not in values]
    if missing:
        raise ValueError(f"{cls.NAME} needs {', '.join(f + '=' for f in missing)}")
    return values


def _cmd_encode(args: argparse.Namespace) -> int:
    from firmware_proto.wire.canmap import encode_can
    from firmware_proto.wire.framing import encode_frame
    from firmware_proto.wire.messages import BY_NAME

    cls = BY_NAME.get(args.name.upper())
    if cls is None:
        raise ValueError(f"unknown message {args.name!r}; known: {', '.join(sorted(BY_NAME))}")
    msg = cls(**_parse_fields(cls, args.fields))
    if args.can is not None:
        if args.seq is not None:
            raise ValueError("--seq is the serial frame counter; CAN frames have none")
        arb, data = encode_can(msg, args.can, strict=not args.loose)
        print(f"{arb:03X}#{data.hex().upper()}")
        return 0
    seq = 0 if args.seq is None else args.seq
    if not 0 <= seq <= _MAX_SEQ:
        # encode_frame would send the low 8 bits: say so rather than print another number
        raise ValueError(f"--seq {seq} outside 0..{_MAX_SEQ} (the frame counter is one byte)")
    print(encode_frame(msg, seq, strict=not args.loose).hex(" "))
    return 0


def _cmd_decode(args: argparse.Namespace) -> int:
    from firmware_proto.wire.canmap import CanDecoder
    from firmware_proto.wire.framing import FrameDecoder

    text = "".join(args.hex).replace(" ", "").replace(":", "")
    try:
        data = bytes.fromhex(text)
    except ValueError as exc:
        raise ValueError(f"not hex: {exc}") from None
    if args.can_id is not None:
        if not 0 <= args.can_id <= _MAX_CAN_ID:
            raise ValueError(
                f"--can-id {args.can_id} is not a CAN identifier "
                f"(0..0x7FF, or up to 0x{_MAX_CAN_ID:X} extended)"
            )
        can = CanDecoder()
        can_frame = can.decode(args.can_id, data)
        if can_frame is None:
            bad = {k: v for k, v in can.counters.as_dict().items() if v}
            print(f"dropped: {bad}")
            return 1
        print(f"node {can_frame.node}: {can_frame.message.describe()}")
        return 0
    decoder = FrameDecoder()
    for frame in decoder.feed(data):
        print(f"seq {frame.seq:3d}: {frame.message.describe()}")
    dropped = {
        k: v for k, v in decoder.counters.as_dict().items() if v and k not in ("frames", "bytes")
    }
    if dropped:
        print(f"dropped: {dropped}")
    if decoder.counters.frames:
        return 0
    # Say why nothing came out: the bytes were dropped, or await a frame's end.
    held = len(data) - sum(v for k, v in dropped.items() if k == "dropped_bytes")
    why = (
        f"{held} byte(s) without a frame delimiter (0x00): a truncated frame, or not a frame"
        if held > 0 and not dropped
        else "every byte was dropped (above)"
    )
    print(f"rover frame: error: no frame decoded from {len(data)} byte(s): {why}", file=sys.stderr)
    return 1


def _cmd_generate(args: argparse.Namespace) -> int:
    from firmware_proto.wire import codegen

    if args.check:
        stale = codegen.stale()
        for path in stale:
            print(f"stale: {path.relative_to(codegen.REPO_ROOT)}")
        return 1 if stale else 0
    for path in codegen.generate():
        print(f"wrote {path.relative_to(codegen.REPO_ROOT)}")
    return 0


def _cmd_dbc(args: argparse.Namespace) -> int:
    from firmware_proto.wire.codegen.dbc import render_dbc
    from firmware_proto.wire.spec import load_spec

    sys.stdout.write(render_dbc(load_spec(), args.node))
    return 0
