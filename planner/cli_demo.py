"""``rover demo``: the whole stack on one machine, driving a mission (the README's main job)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

__all__ = ["register"]


def register(subparsers: Any) -> None:
    """Add ``rover demo``."""
    p = subparsers.add_parser(
        "demo",
        help="the end-to-end demo: gate, emulator, bridge, 3 s link, planner and executor",
        description=(
            "Start the gate, the motor-controller emulator on a pty (lab map), the ROS 2 "
            "bridge and the Earth-Moon link relay (3 s round trip) as separate processes, "
            "talking ROS 2 over loopback-only Cyclone DDS; plan a mission behind the table (the "
            "direct plan collides, the orchestrator repairs it into a detour), drive it, inject "
            "slip on one leg so that drift control stops the rover, re-plan from the rover's "
            "reported pose and finish. Prints a summary and writes a picture of the predicted "
            "against the actual trajectory. About two minutes in real time (--speed 4: under one)."
        ),
    )
    p.add_argument("--rtt", type=float, default=3.0, help="link round trip, s (default 3)")
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="mission seconds per wall second: emulator and link run this much faster (default 1)",
    )
    p.add_argument("--no-slip", action="store_true", help="drive without injecting slip")
    p.add_argument(
        "--seed", type=int, default=1, help="seed of sensor noise and the link (default 1)"
    )
    p.add_argument(
        "--picture", type=Path, default=Path("demo.png"), help="PNG to write (default demo.png)"
    )
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from planner.demo import Demo, DemoConfig

    config = DemoConfig(
        rtt_s=args.rtt,
        speed=args.speed,
        slip=None if args.no_slip else DemoConfig.slip,
        seed=args.seed,
        picture=args.picture,
    )
    with Demo(config) as demo:
        result = demo.run()
    print()
    print(result.report.summary(config.speed))
    print(f"picture: {result.picture}")
    if config.slip and not result.drift_fired:
        print("note: the injected slip did not make drift control fire this time")
    return 0 if result.report.reached else 1
