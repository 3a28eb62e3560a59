"""``rover bridge``: run the rover-side ROS 2 bridge node.

Also the ``rover_bridge`` console script that ``ros2 run`` and launch files start
(:func:`main`), which accepts ``--ros-args ...``. Every bridge parameter
(:class:`~bridge.ros.params.BridgeParams`) can be set by a named option, by ``--param
NAME=VALUE``, and as a ROS parameter from the ROS arguments (:class:`RosLayer`).
Precedence and validation are those of :func:`bridge.ros.params.load_params`: an unknown
parameter, a bad value or a malformed ROS argument is a usage error (exit status 2),
never ignored. The node then declares every parameter with its resolved value.

At the default verbosity it says, on stdout, one line per event of its link that an
operator must know (:mod:`bridge.link.linklines`).

SIGINT and SIGTERM (or ``--duration``) end it cleanly: the node, the link and the ROS
context are closed (the exit statuses: :func:`run`).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from firmware_proto.cli import values

if TYPE_CHECKING:
    from bridge.ros.params import BridgeParams

__all__ = [
    "EXIT_NEVER_REACHED",
    "RosLayer",
    "add_arguments",
    "main",
    "register",
    "resolve_params",
    "ros_layer",
    "run",
]

NODE_NAME = "rover_bridge"
"""The node's name, unless the ROS arguments remap ``__node``."""

_ROS_NODE_PARAMETERS = {"use_sim_time"}
"""Parameters every ROS node has (launch files set them for all nodes, ``/**``)."""
#: How often the running bridge checks that its ROS port still works and looks at its link, s.
_FAILURE_POLL_S = 0.5
#: Exit status of a bridge stopped without ever having reached a controller.
EXIT_NEVER_REACHED = 3

_OPTIONS: list[tuple[str, str, Any, str]] = [
    ("--baud", "baud", values.baud, "serial baud rate (default 115200; a pty ignores it)"),
    ("--node", "node_id", values.can_node, "CAN node id of the controller, 1..15 (default 1)"),
    ("--namespace", "namespace", str, "ROS namespace of the node and its relative topics"),
    ("--heartbeat-hz", "heartbeat_hz", float, "host heartbeat rate (default 10)"),
    ("--ack-timeout", "ack_timeout_s", float, "MOTION ack timeout, s (default 0.05)"),
    ("--retries", "motion_retries", int, "MOTION retransmissions before fault:no_ack (default 3)"),
    ("--reconnect-min", "reconnect_min_s", float, "first reconnect delay, s (default 0.1)"),
    ("--reconnect-max", "reconnect_max_s", float, "longest reconnect delay, s (default 2)"),
    ("--rover", "rover_description", str, "rover description TOML (default: the packaged one)"),
    (
        "--rt-priority",
        "rt_priority",
        int,
        "real-time priority of the bridge's process, which holds the controller link: "
        "SCHED_RR with memory locked where permitted (default 20; 0 = normal scheduling); "
        "without permission the bridge says so once and runs on (docs/realtime.md)",
    ),
    (
        "--stall-ms",
        "stall_ms",
        float,
        "log a stall of the bridge or a link thread longer than MS: one line, its stack in "
        "the stall log ($ROVER_STALL_LOG), on the console too with -v (default 100)",
    ),
    (
        "--record",
        "record",
        str,
        "record the link traffic to FILE: a serial frame log on serial, a python-can log "
        "chosen by suffix on CAN (.log: candump); see docs/traffic-logs.md",
    ),
]


def _assignment(text: str) -> tuple[str, str]:
    """``--param`` argument: ``NAME=VALUE`` -> (name, value text)."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(
            f"--param needs NAME=VALUE (a bridge parameter, docs/bridge.md), got {text!r}"
        )
    return name.strip(), value


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
        "--no-realtime",
        dest="rt_priority",
        action="store_const",
        const=0,
        help="normal scheduling (the same as --rt-priority 0)",
    )
    p.add_argument(
        "--ros-backend",
        choices=("rclpy-process", "rclpy", "inprocess"),
        help="ROS port backend: rclpy-process (the default: the ROS 2 nodes in child "
        "processes, so that no middleware call can stall the controller link), rclpy (the "
        "node in this process) or inprocess (tests only)",
    )
    p.add_argument(
        "--params-file", metavar="FILE", help="parameters file (TOML or JSON; see docs/bridge.md)"
    )
    p.add_argument(
        "--param",
        dest="param",
        metavar="NAME=VALUE",
        type=_assignment,
        action="append",
        default=[],
        help="set any bridge parameter by name, e.g. --param topic_odom=wheel_odom or "
        "--param auto_clear_watchdog=false (repeatable; a named option for the same "
        "parameter wins; names, types and ranges in docs/bridge.md)",
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
            "and /diagnostics. Parameters: command line (options, --param NAME=VALUE) > ROS "
            "parameters > ROVER_BRIDGE_* environment > --params-file > defaults "
            "(docs/bridge.md). Prints 'BRIDGE <url> <backend>' when up, then one line per "
            "link event: the device cannot be opened, no controller answers, wrong baud "
            "suspected, handshake done, link lost and back. Exit status: 0 stopped (Ctrl-C, "
            f"SIGTERM, --duration) after it had reached a controller, {EXIT_NEVER_REACHED} "
            "stopped without ever reaching one, 2 usage (bad option, parameter, device URL), "
            "1 device held by another process, ROS 2 missing or its node died."
        ),
        epilog=(
            "examples:\n"
            "  rover bridge --device /dev/rover-motor\n"
            "  rover bridge --can socketcan:rovercan0 --node 1\n"
            "  rover bridge --device /tmp/rover-motor --ros-args -r __ns:=/rover1 "
            "-p heartbeat_hz:=20.0"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(p)
    p.set_defaults(func=run)


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The command line's parameters: ``--param`` values, then the named options."""
    from firmware_proto.linkio.errors import LinkUrlError
    from firmware_proto.linkio.urls import parse_can_spec

    values: dict[str, Any] = dict(getattr(args, "param", None) or [])
    for _, name, _, _ in _OPTIONS:
        if getattr(args, name) is not None:
            values[name] = getattr(args, name)
    if args.device is not None:
        values["device"] = args.device
    if args.ros_backend is not None:
        values["ros_backend"] = args.ros_backend
    if args.can:
        try:
            interface, channel = parse_can_spec(args.can)
        except LinkUrlError as exc:
            raise ValueError(f"--can: {exc}") from None
        values["can_interface"], values["can_channel"] = interface, channel
    return values


@dataclass(frozen=True)
class RosLayer:
    """What the ROS arguments of a command line say about the bridge node.

    Attributes:
        params: its parameters: its sections of each ``--params-file`` in order, then
            every ``-p``, later ones winning; ``namespace`` from ``-r __ns:=`` unless a
            parameter sets it.
        node_name: from ``-r __node:=``, else :data:`NODE_NAME`.
    """

    params: dict[str, Any] = field(default_factory=dict)
    node_name: str = NODE_NAME


def ros_layer(ros_args: Sequence[str]) -> RosLayer:
    """Parse the ROS arguments (without ``--ros-args``) into the node's parameters: by
    rcl's own parser where rclpy is installed (:mod:`firmware_proto.cli.rclargs`, as
    for any ROS 2 node), else by :mod:`firmware_proto.cli.rosargs`.

    Raises:
        ValueError: a malformed ROS argument or parameters file, or PyYAML missing.
        OSError: a parameters file cannot be read.
    """
    from firmware_proto.cli.rclargs import rclpy_available, rclpy_node_parameters
    from firmware_proto.cli.rosargs import parse_ros_args, ros_node_parameters
    from firmware_proto.cli.rosparams import load_parameters_file

    if rclpy_available():
        read = rclpy_node_parameters(ros_args, NODE_NAME)
        params = dict(read.params)
        if read.namespace.strip("/") and "namespace" not in params:
            params["namespace"] = read.namespace
        return RosLayer(params, read.node_name)
    parsed = parse_ros_args(ros_args)
    node = parsed.node_name or NODE_NAME
    params = ros_node_parameters(parsed, NODE_NAME, load_parameters_file)
    if parsed.namespace is not None and "namespace" not in params:
        params["namespace"] = "" if not parsed.namespace.strip("/") else parsed.namespace
    return RosLayer(params, node)


def _bridge_parameters(values: Mapping[str, Any]) -> dict[str, Any]:
    """The ROS parameters that are the bridge's: those every ROS node has are accepted
    when they ask for nothing the bridge does not do (``use_sim_time: false``)."""
    from bridge.errors import ParameterError

    out = dict(values)
    for name in _ROS_NODE_PARAMETERS & set(out):
        if out.pop(name) not in (False, "false", "False"):
            raise ParameterError(f"parameter {name} (ROS parameter): the bridge runs on wall time")
    return out


def resolve_params(
    args: argparse.Namespace,
    ros_args: Sequence[str] = (),
    *,
    env: Mapping[str, str] | None = None,
) -> tuple[BridgeParams, RosLayer]:
    """The bridge's parameters from the command line, the ROS arguments, the environment
    and the parameters file (:func:`bridge.ros.params.load_params`), on every backend.

    Raises:
        ParameterError: an unknown parameter or a bad value; names it and its source.
        ValueError: malformed ROS arguments.
        OSError: a parameters file cannot be read.
    """
    from bridge.ros.params import load_params

    layer = ros_layer(ros_args) if ros_args else RosLayer()
    ros = _bridge_parameters(layer.params)
    params = load_params(_overrides(args), ros=ros, env=env, file=args.params_file)
    return params, layer


def run(args: argparse.Namespace, ros_args: Sequence[str] = (), prog: str = "rover bridge") -> int:
    """Run the bridge until SIGINT/SIGTERM (or ``--duration``); returns the exit status:
    0, or :data:`EXIT_NEVER_REACHED` when no controller was ever reached (one line on
    stderr says so), 2 for a bad parameter, a malformed device URL or a bad ROS argument
    (reported on stderr as ``prog: error:``), 1 when ROS 2 is not installed or the ROS 2
    node's process died (for its supervisor to restart it).

    ``ros_args`` are the ROS arguments without the ``--ros-args`` marker
    (:func:`firmware_proto.cli.rosargs.split_ros_args`).
    """
    from bridge.errors import DeviceBusyError
    from bridge.link.linklines import LinkNarrator
    from bridge.link.serial_transport import refuse_if_in_use
    from bridge.link.transport import open_transport
    from bridge.ros.node import BridgeNode
    from bridge.ros.rosport import BackendUnavailableError, open_port, preload
    from firmware_proto.runtime import (
        ProcessRuntime,
        RuntimeOptions,
        ShutdownSignals,
        stall_log_path,
    )

    try:
        params, layer = resolve_params(args, ros_args)
        open_transport(params.url)  # a malformed device URL is a usage error too
    except (OSError, ValueError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    try:
        if not params.can_interface:
            refuse_if_in_use(params.url)
    except DeviceBusyError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    options: dict[str, Any] = {}
    if params.ros_backend in ("rclpy", "rclpy-process") and ros_args:
        options["args"] = ["--ros-args", *ros_args]
    try:
        # Its modules (rclpy and its messages: 100-300 ms of CPU) are imported here, at
        # normal priority: at real-time priority they held a core from everything else.
        preload(params.ros_backend)
    except BackendUnavailableError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    # First, before any thread starts: every thread of the link inherits the policy.
    runtime = ProcessRuntime(
        RuntimeOptions(
            name="bridge",
            priority=params.rt_priority,
            stall_threshold_s=params.stall_ms / 1e3,
            stall_log=stall_log_path(),
            short_switch=True,  # a STOP must not wait 5 ms for the interpreter lock
            stall_stacks_on_console=getattr(args, "verbose", 0) >= 1,
        )
    )
    with ShutdownSignals() as done, runtime:
        print(runtime.line(), file=sys.stderr, flush=True)
        try:
            port = open_port(
                params.ros_backend, namespace=params.namespace, node_name=layer.node_name, **options
            )
        except BackendUnavailableError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 1
        end = time.monotonic() + args.duration if args.duration > 0 else math.inf
        if getattr(args, "verbose", 1) == 0:
            # The narrator below says the link's warnings once, in words; -v brings them.
            for name in ("bridge.link.controllerlink", "bridge.link.linkcore"):
                logging.getLogger(name).setLevel(logging.ERROR)
        narrator = LinkNarrator(
            params.url if params.can_interface else (args.device or params.device),
            None if params.can_interface else params.baud,
        )
        with port, BridgeNode(params, port) as node:
            print(f"BRIDGE {params.url} {params.ros_backend}", flush=True)
            try:
                while not done.wait(min(_FAILURE_POLL_S, max(0.0, end - time.monotonic()))):
                    for line in narrator.update(node.diagnostics(), time.monotonic()):
                        print(f"bridge: {line}", flush=True)
                    if port.failure is not None:
                        print(
                            f"{prog}: error: the ROS 2 node failed: {port.failure}",
                            file=sys.stderr,
                        )
                        return 1
                    if time.monotonic() >= end:
                        break
            finally:
                # Closing the link and the node is no work that must keep time.
                runtime.wind_down()
            for line in narrator.update(node.diagnostics(), time.monotonic()):
                print(f"bridge: {line}", flush=True)
    if not narrator.reached:
        print(
            f"{prog}: error: stopped without ever reaching a controller at {narrator.device}",
            file=sys.stderr,
        )
        return EXIT_NEVER_REACHED
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``rover_bridge`` (for ``ros2 run`` and launch files): the options of ``rover
    bridge``, then optionally ``--ros-args`` (see the module docstring). Exit status 2
    for a usage error (bad option, unknown or bad parameter, malformed ROS argument), 1
    when the bridge fails."""
    from firmware_proto.cli.program import ros_main

    parser = argparse.ArgumentParser(
        prog="rover_bridge",
        description="Rover-side ROS 2 bridge node. Accepts --ros-args: -p name:=value and "
        "the node's --params-file section set bridge parameters (docs/bridge.md).",
    )
    add_arguments(parser)
    return ros_main(
        parser, lambda args: run(args, args.ros_args, prog="rover_bridge"), argv, node=True
    )


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
