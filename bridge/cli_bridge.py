"""``rover bridge``: run the rover-side ROS 2 bridge node.

Also the ``rover_bridge`` console script that ``ros2 run`` starts (:func:`main`), which
accepts ``--ros-args ...`` and then reads ROS parameters through the rclpy backend.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any

__all__ = ["add_arguments", "main", "register", "run"]

_OPTIONS: list[tuple[str, str, type, str]] = [
    ("--baud", "baud", int, "serial baud rate (default 115200; a pty ignores it)"),
    ("--node", "node_id", int, "CAN node id of the controller, 1..15 (default 1)"),
    ("--namespace", "namespace", str, "ROS namespace of the node and its relative topics"),
    ("--heartbeat-hz", "heartbeat_hz", float, "host heartbeat rate (default 10)"),
    ("--ack-timeout", "ack_timeout_s", float, "MOTION ack timeout, s (default 0.05)"),
    ("--retries", "motion_retries", int, "MOTION retransmissions before fault:no_ack (default 3)"),
    ("--reconnect-min", "reconnect_min_s", float, "first reconnect delay, s (default 0.1)"),
    ("--reconnect-max", "reconnect_max_s", float, "longest reconnect delay, s (default 2)"),
    ("--rover", "rover_description", str, "rover description TOML (default: the packaged one)"),
    (
        "--record",
        "record",
        str,
        "record the link traffic to FILE: a serial frame log on serial, a python-can log "
        "chosen by suffix on CAN (.log: candump); see docs/traffic-logs.md",
    ),
]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The bridge's options (shared by ``rover bridge`` and ``rover_bridge``)."""
    where = p.add_mutually_exclusive_group()
    where.add_argument("--device", help="serial device or pyserial URL (default /dev/rover-motor)")
    where.add_argument(
        "--can", metavar="INTERFACE:CHANNEL", help="python-can bus, e.g. socketcan:rovercan0"
    )
    for flag, dest, kind, text in _OPTIONS:
        p.add_argument(flag, dest=dest, type=kind, help=text)
    p.add_argument(
        "--ros-backend",
        choices=("dds", "rclpy", "inprocess"),
        help="ROS port backend (default dds; rclpy on a ROS 2 machine)",
    )
    p.add_argument(
        "--dds-config",
        metavar="loopback|FILE|XML",
        help="Cyclone DDS config: 'loopback' keeps traffic on 127.0.0.1 (default: $CYCLONEDDS_URI)",
    )
    p.add_argument(
        "--params-file", metavar="FILE", help="parameters file (TOML or JSON; see docs/bridge.md)"
    )
    p.add_argument(
        "--duration",
        type=float,
        default=0.0,
        help="exit after SECONDS (wall); 0 runs until stopped",
    )


def register(subparsers: Any) -> None:
    """Add ``rover bridge``."""
    p = subparsers.add_parser(
        "bridge",
        help="run the rover-side ROS 2 bridge to the motor controller",
        description=(
            "Bridge /wheel_instructions, /emergency_stop and /clear_emergency_stop to the motor "
            "controller over USB-serial or CAN, and publish /command_status, /odom, /odom_ground "
            "and /diagnostics. Parameters: command line > ROVER_BRIDGE_* environment > "
            "--params-file > defaults (docs/bridge.md). Prints 'BRIDGE <url> <backend>' when up."
        ),
        epilog=(
            "examples:\n"
            "  rover bridge --device /dev/rover-motor\n"
            "  rover bridge --can socketcan:rovercan0 --node 1 --ros-backend rclpy\n"
            "  rover bridge --device /tmp/rover-motor --dds-config loopback"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(p)
    p.set_defaults(func=run)


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    values: dict[str, Any] = {name: getattr(args, name) for _, name, _, _ in _OPTIONS}
    values["device"] = args.device
    values["ros_backend"] = args.ros_backend
    if args.can:
        interface, sep, channel = args.can.partition(":")
        if not sep or not interface or not channel:
            raise ValueError(
                f"--can needs INTERFACE:CHANNEL, e.g. socketcan:vcan0, got {args.can!r}"
            )
        values["can_interface"], values["can_channel"] = interface, channel
    return values


def run(args: argparse.Namespace, ros_args: Sequence[str] = ()) -> int:
    """Run the bridge until SIGINT/SIGTERM (or ``--duration``); returns the exit status."""
    from bridge.node import BridgeNode
    from bridge.params import load_params, ros_parameters
    from bridge.rosport import loopback_config, open_port

    params = load_params(_overrides(args), file=args.params_file)
    options: dict[str, Any] = {}
    if params.ros_backend == "dds" and args.dds_config:
        options["config"] = loopback_config() if args.dds_config == "loopback" else args.dds_config
    if params.ros_backend == "rclpy" and ros_args:
        options["args"] = list(ros_args)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    with open_port(
        params.ros_backend, namespace=params.namespace, node_name="rover_bridge", **options
    ) as port:
        if params.ros_backend == "rclpy":
            # ROS parameters sit between the command line and the environment.
            params = load_params(
                {**ros_parameters(port, params), **_overrides(args)}, file=args.params_file
            )
        with BridgeNode(params, port):
            print(f"BRIDGE {params.url} {params.ros_backend}", flush=True)
            done.wait(args.duration if args.duration > 0 else None)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``rover_bridge`` (for ``ros2 run``): bridge options, then optional ``--ros-args``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if "--ros-args" in argv:
        cut = argv.index("--ros-args")
        argv, ros_args = argv[:cut], argv[cut:]
    parser = argparse.ArgumentParser(
        prog="rover_bridge", description="Rover-side ROS 2 bridge node."
    )
    add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)-7s %(name)s: %(message)s"
    )
    try:
        return run(args, ros_args)
    except Exception as exc:  # one clean line for the operator, whatever the package
        print(f"rover_bridge: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
