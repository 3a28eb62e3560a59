"""``rover link``: relay ground and rover topics with the Earth-Moon link's delay.

Also the ``rover_link`` console script for ``ros2 run`` (:func:`main`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from firmware_proto.cli.runtimeargs import add_runtime_arguments, runtime_options
from firmware_proto.runtime import ProcessRuntime, ShutdownSignals

__all__ = ["add_arguments", "main", "register", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The relay's options."""
    p.add_argument("--rtt", type=float, default=3.0, help="round trip, s (default 3.0: Earth-Moon)")
    p.add_argument("--jitter", type=float, default=0.0, help="extra one-way delay, uniform 0..J s")
    p.add_argument(
        "--loss", type=float, default=0.0, help="share of messages lost, 0..1 (default 0)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of jitter and loss (default 0)")
    p.add_argument(
        "--ground-namespace", default="ground", help="namespace of the operator's topics"
    )
    p.add_argument(
        "--rover-namespace", default="", help="namespace of the rover's topics (the bridge's)"
    )
    p.add_argument(
        "--ros-backend",
        choices=("rclpy", "inprocess"),
        default="rclpy",
        help="ROS port backend: rclpy (ROS 2, the default) or inprocess (tests only)",
    )
    p.add_argument(
        "--duration", type=float, default=0.0, help="exit after SECONDS; 0 runs until stopped"
    )
    add_runtime_arguments(p, 0)


def register(subparsers: Any) -> None:
    """Add ``rover link``."""
    p = subparsers.add_parser(
        "link",
        help="relay ground <-> rover topics with a delayed, lossy link",
        description=(
            "Emulate the Earth-Moon link: relay wheel_instructions, emergency_stop and "
            "clear_emergency_stop from the ground namespace to the rover's, and command_status, "
            "odom, odom_ground and diagnostics back, each after half the round trip plus jitter, "
            "minus the lost ones. Deterministic for a seed. Prints 'LINK rtt=...' when up."
        ),
    )
    add_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Relay until SIGINT/SIGTERM (or ``--duration``)."""
    from bridge.ros.rosport import open_port
    from planner.ground.relay import LinkProfile, LinkRelay

    profile = LinkProfile(
        one_way_delay_s=args.rtt / 2.0, jitter_s=args.jitter, loss=args.loss, seed=args.seed
    )
    with (
        ShutdownSignals() as done,
        ProcessRuntime(runtime_options(args, "link")),
        open_port(
            args.ros_backend, namespace=args.ground_namespace, node_name="rover_link"
        ) as ground,
        open_port(
            args.ros_backend,
            namespace=args.rover_namespace,
            node_name="rover_link_rover",
        ) as rover,
        LinkRelay(ground, rover, profile) as relay,
    ):
        print(
            f"LINK rtt={profile.rtt_s:g}s jitter={profile.jitter_s:g}s loss={profile.loss:g}",
            flush=True,
        )
        done.wait(args.duration if args.duration > 0 else None)
        print(
            f"link relayed {sum(relay.forwarded.values())}, dropped {sum(relay.dropped.values())}",
            file=sys.stderr,
        )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``rover_link`` for ``ros2 run`` and launch files: the options of ``rover link``,
    then optionally ``--ros-args`` (its ``--params-file`` section for the node and
    ``-p name:=value`` stand for the long options: ``rtt`` -> ``--rtt``)."""
    from firmware_proto.cli.program import ros_main

    parser = argparse.ArgumentParser(prog="rover_link", description="Earth-Moon link relay.")
    add_arguments(parser)
    return ros_main(parser, run, argv, with_rclpy=True)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
