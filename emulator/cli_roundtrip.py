"""``rover roundtrip``: the codec over a real pty, end to end, with corrupted frames."""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["register"]


def register(subparsers: Any) -> None:
    """Add ``rover roundtrip``."""
    p = subparsers.add_parser(
        "roundtrip",
        help="send frames through a real pty with pyserial and decode them back",
        description=(
            "Open a pty pair, write COUNT mixed protocol frames (a share of them, 1% by "
            "default, with a flipped bit) through pyserial into one end, decode the other "
            "end incrementally, and report throughput and what the decoder dropped. Exit 1 "
            "unless every intact frame came back unaltered."
        ),
    )
    p.add_argument("--count", type=int, default=20000, help="frames to send (default 20000)")
    p.add_argument("--seed", type=int, default=1, help="seed of values and corruption (default 1)")
    p.add_argument(
        "--corrupt", type=float, default=0.01, help="share of frames corrupted, 0..1 (default 0.01)"
    )
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from emulator.roundtrip import pty_roundtrip

    if args.count <= 0 or not 0.0 <= args.corrupt <= 1.0:
        raise ValueError("--count must be > 0 and --corrupt in 0..1")
    result = pty_roundtrip(args.count, seed=args.seed, corrupt_ratio=args.corrupt)
    print(result.report())
    return 0 if result.ok else 1
