"""``rover onboard``: the rover's onboard sequencer and drift guard, beside the bridge
(docs/onboard.md, "The program").

Also the ``rover_onboard`` console script (:func:`main`), which accepts ``--ros-args ...``
(its ``-p name:=value`` stand for the long options: ``time_scale`` -> ``--time-scale``).

The uplink token comes from the environment only (``ROVER_UPLINK_TOKEN``; a command line
is readable by every user in ``/proc``): without it the program refuses to start unless
told ``--insecure`` (then any publisher on the rover's ROS domain can drive it).

It prints ``ONBOARD <namespace> <backend> (uplinks must be signed)`` once its node is up
and the bridge subscribes to its steps and its STOP, and one line per plan. SIGINT and
SIGTERM (or ``--duration``) stop a running plan first, then close the node and the ROS
context. Exit status 0, 2 on a usage error, 1 when ROS 2 is missing or no bridge came
within ``--bridge-timeout``.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from typing import Any

from firmware_proto.cli.runtimeargs import add_runtime_arguments, runtime_options

__all__ = ["add_arguments", "main", "register", "run"]

DEFAULT_PRIORITY = 20
"""Real-time priority, as the bridge's: the guard's STOP must not wait for the CPU."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The program's options."""
    p.add_argument("--namespace", default="", help="ROS namespace: the bridge's (default '')")
    p.add_argument(
        "--ros-backend",
        choices=("rclpy", "inprocess"),
        default="rclpy",
        help="ROS port backend: rclpy (ROS 2, the default) or inprocess (tests only)",
    )
    p.add_argument(
        "--insecure",
        action="store_true",
        help="run without an uplink token (tags not checked: anyone on the ROS domain can "
        "drive the rover); without it the token must be in $ROVER_UPLINK_TOKEN",
    )
    p.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        help="twin seconds per rover second: the emulator's --speed-factor (default 1)",
    )
    p.add_argument("--rover", default=None, help="rover description TOML (default: packaged)")
    p.add_argument(
        "--persistence",
        type=int,
        default=3,
        help="consecutive estimates past a limit before the guard stops (default 3)",
    )
    p.add_argument(
        "--bridge-timeout",
        type=float,
        default=30.0,
        help="wait this long, s, for the bridge to subscribe to wheel_instructions and "
        "emergency_stop before saying ONBOARD; exit 1 if it does not (0: do not wait; "
        "default 30)",
    )
    p.add_argument(
        "--duration", type=float, default=0.0, help="exit after SECONDS; 0 runs until stopped"
    )
    add_runtime_arguments(p, DEFAULT_PRIORITY)


def register(subparsers: Any) -> None:
    """Add ``rover onboard``."""
    p = subparsers.add_parser(
        "onboard",
        help="run the rover's onboard sequencer and drift guard beside the bridge",
        description=(
            "Take approved plans from plan_uplink (checked: format, ranges, the tag under "
            "$ROVER_UPLINK_TOKEN, this run's boot id, the prediction against the steps, ids "
            "never run twice), run their steps "
            "back to back on wheel_instructions, estimate the pose (EKF of odom and "
            "odom_ground) and stop the rover on emergency_stop when it drifts 0.25 m or 12 "
            "deg off the prediction. Answers on plan_ack, reports on onboard_report, the "
            "estimate on onboard_pose (docs/onboard.md). Prints 'ONBOARD <namespace> "
            "<backend>' when up."
        ),
    )
    add_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run until SIGINT/SIGTERM (or ``--duration``)."""
    from bridge.errors import RosPortError
    from bridge.onboard.core import OnboardConfig
    from bridge.onboard.node import OnboardNode
    from bridge.ros.rosport import open_port
    from firmware_proto.model.rover import load_rover
    from firmware_proto.model.uplink import TOKEN_ENV, token_from_env
    from firmware_proto.runtime import ProcessRuntime, ShutdownSignals
    from firmware_proto.runtime.realtime import (
        RealtimeConfig,
        apply_realtime_to_process,
        leave_realtime_for_process,
    )

    if not args.time_scale > 0 or args.persistence < 1 or not args.bridge_timeout >= 0:
        print(
            "rover onboard: error: --time-scale must be > 0, --persistence >= 1, "
            "--bridge-timeout >= 0",
            file=sys.stderr,
        )
        return 2
    token = token_from_env(os.environ)
    if token is None and not args.insecure:
        print(
            f"rover onboard: error: no uplink token: set ${TOKEN_ENV} (rover stack up and "
            "rover demo make one), or run --insecure to take unsigned plans from anyone",
            file=sys.stderr,
        )
        return 2
    rover = load_rover(args.rover)
    config = OnboardConfig(
        token=token,
        time_scale=args.time_scale,
        persistence=args.persistence,
    )
    options = runtime_options(args, "onboard", DEFAULT_PRIORITY)
    priority = options.priority
    # Start at normal priority (the heavy start must not hold a core above the kernel's
    # workers), then every thread is promoted.
    with ShutdownSignals() as done, ProcessRuntime(_normal(options)) as runtime:
        try:
            port = open_port(args.ros_backend, namespace=args.namespace, node_name="rover_onboard")
        except RosPortError as exc:
            print(f"rover onboard: error: {exc}", file=sys.stderr)
            return 1
        with port, OnboardNode(port, rover, config) as node:
            if args.bridge_timeout > 0 and not node.wait_for_bridge(args.bridge_timeout):
                print(
                    f"rover onboard: error: no bridge subscribed to wheel_instructions and "
                    f"emergency_stop in namespace '{port.namespace}' within "
                    f"{args.bridge_timeout:g} s: its STOP would reach nobody",
                    file=sys.stderr,
                )
                return 1
            status = apply_realtime_to_process(RealtimeConfig(priority))
            print(f"onboard: {status.line()}", file=sys.stderr)
            print(f"onboard: boot {node.core.boot}", file=sys.stderr)
            auth = (
                "uplinks must be signed" if config.token else "INSECURE: no token, tags not checked"
            )
            print(f"ONBOARD {port.namespace} {args.ros_backend} ({auth})", flush=True)
            done.wait(args.duration if args.duration > 0 else None)
            leave_realtime_for_process()
            runtime.wind_down()
            if node.core.active:
                node.stop_now("the onboard program is ending")
        counts = ", ".join(f"{k} {v}" for k, v in node.core.counts.items())
        print(f"onboard: {counts}", file=sys.stderr)
        ekf = node.ekf
        print(
            f"onboard: estimate: POSE applied {ekf.corrections}, slips {ekf.inflations}, "
            f"too old {ekf.too_old}, refused {ekf.rejected}, odometry re-based {ekf.rebased}",
            file=sys.stderr,
        )
    return 0


def _normal(options: Any) -> Any:
    from dataclasses import replace

    return replace(options, priority=0)


def main(argv: Sequence[str] | None = None) -> int:
    """``rover_onboard`` for ``ros2 run`` and launch files: the options of ``rover
    onboard``, then optionally ``--ros-args``."""
    from firmware_proto.cli.program import ros_main

    parser = argparse.ArgumentParser(
        prog="rover_onboard", description="The rover's onboard sequencer and drift guard."
    )
    add_arguments(parser)
    return ros_main(parser, run, argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
