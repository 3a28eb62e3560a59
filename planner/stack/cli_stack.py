"""``rover stack up``: the gate, the emulator (or a real device), the bridge and the link
relay as child processes that stay up, so that ``rover go`` runs mission after mission
against them; ``rover stack env`` and ``rover stack inject`` for the running stack.

Its ROS 2 domain and the ``export`` line that points the operator's commands at it:
:mod:`planner.stack.domains`, :mod:`planner.stack.stackenv`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from firmware_proto.cli import values
from planner.stack.controllers import CONTROLLERS
from planner.stack.linkargs import add_link_arguments
from planner.stack.stackenv import TWIN_ENV, add_domain_argument

__all__ = ["register"]

_UP_DESCRIPTION = (
    "Start the simulation gate, the motor-controller emulator on a pty (or, with --device, "
    "a real controller's serial device instead), the rover-side ROS 2 bridge and the "
    "Earth-Moon link relay as child processes; wait until the rover's state comes back "
    "through the link; print the health and the endpoints, and the export line that "
    "points rover go / status / stop / clear-stop / echo at this stack; then stay up until "
    "Ctrl-C or SIGTERM (or --duration), and end every child. Each stack gets a ROS 2 domain "
    "of its own (the first free of 101..232 unless --domain), with discovery kept on this "
    "host, so two stacks on one machine never hear each other. A child that exits ends "
    "the stack. Exit status: 0 stopped by Ctrl-C, SIGTERM or --duration; 1 a part did not "
    "come up or exited, or the domain is taken; 2 usage."
)


def register(subparsers: Any) -> None:
    """Add ``rover stack`` with ``up``, ``env`` and ``inject``."""
    stack = subparsers.add_parser(
        "stack",
        help="a whole stack that stays up (gate, emulator or device, bridge, link)",
        description="A whole HIL stack that stays up: rover stack up; then rover go, "
        "rover status, ... against it (docs/commands.md: 'Missions against a stack').",
    )
    sub = stack.add_subparsers(dest="stack_command", metavar="ACTION")
    sub.required = True
    up = sub.add_parser(
        "up",
        help="start the stack and keep it up until Ctrl-C",
        description=_UP_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "examples:\n"
            "  rover stack up                                   # lab map, emulator, 3 s link\n"
            "  rover stack up --map scn02 --firmware c --rtt 1\n"
            "  rover stack up --loss 0.3 --jitter 0.2        # a degraded link\n"
            "  rover stack up --device /dev/rover-motor --baud 1000000\n"
            "  rover stack up --ground loose --twin twin.toml   # a calibrated twin on it\n"
            "then, in another shell:\n"
            '  eval "$(rover stack env)"\n'
            "  rover go --goal behind_table && rover status"
        ),
    )
    up.add_argument("--map", default="lab", help="map name or JSON file (default lab)")
    up.add_argument(
        "--firmware",
        choices=("python", "c"),
        default="python",
        help="the emulator's controller: the Python model or the C firmware core",
    )
    up.add_argument(
        "--controller",
        choices=CONTROLLERS,
        default="emulator",
        help="the controller: the emulator (default; --firmware chooses its core), or the "
        "firmware image in an emulated MCU (rover pil: pil:microbit under qemu, "
        "pil:atmega2560 under simavr with the twin as its plant; real time only)",
    )
    up.add_argument(
        "--device",
        metavar="URL",
        help="a real controller's serial device or pyserial URL: no emulator is started",
    )
    up.add_argument("--baud", type=values.baud, help="with --device: its baud rate")
    add_link_arguments(up)
    up.add_argument(
        "--speed",
        type=values.positive,
        default=1.0,
        help="mission seconds per wall second: emulator and link this much faster (default 1)",
    )
    up.add_argument("--seed", type=int, default=1, help="seed of the emulator and the link")
    up.add_argument(
        "--ground",
        metavar="NAME|FILE",
        help="the emulator drives on this ground, which the gate does not know (rover "
        "emulate --ground: a shipped ground's name or a ground file); not with --device",
    )
    up.add_argument(
        "--twin",
        metavar="FILE",
        help="a calibrated twin (rover calibrate): the gate plays every plan on it, and "
        f"rover go plans by its turn efficiency (the export line's ${TWIN_ENV})",
    )
    up.add_argument(
        "--gate-port",
        type=values.tcp_port,
        default=0,
        metavar="PORT",
        help="the gate's port on 127.0.0.1 (default: a free one)",
    )
    up.add_argument(
        "--inject",
        action="append",
        default=[],
        metavar="FAULT",
        help="schedule a fault on the emulator (rover emulate --inject; repeatable)",
    )
    add_domain_argument(up)
    up.add_argument(
        "--console-host",
        default="127.0.0.1",
        metavar="HOST",
        help="address of the stack's console socket (default 127.0.0.1; any other needs "
        "a token, in $ROVER_CONSOLE_TOKEN)",
    )
    up.add_argument(
        "--console-port",
        type=values.tcp_port,
        default=0,
        metavar="PORT",
        help="its port (default: a free one)",
    )
    up.add_argument(
        "--console-token",
        default=None,
        metavar="TOKEN",
        help=argparse.SUPPRESS,  # refused, saying why (a token in argv is seen by all)
    )
    up.add_argument(
        "--duration",
        type=values.non_negative,
        default=0.0,
        metavar="S",
        help="stop after S s (wall); 0 (default) runs until Ctrl-C",
    )
    up.add_argument(
        "--startup-timeout",
        type=values.positive,
        default=60.0,
        metavar="S",
        help="how long each part may take to come up, and the rover to report (default 60)",
    )
    up.add_argument(
        "--link-timeout",
        type=values.positive,
        default=20.0,
        metavar="S",
        help="once the rover reports, how long its link to the controller may take to "
        "come up before the stack says why not and ends, exit 1 (default 20)",
    )
    up.set_defaults(func=_up)

    env = sub.add_parser(
        "env",
        help="print the export line of a running stack",
        description=(
            "Print the export line of the stack running on this machine (of --domain when "
            'several are): eval "$(rover stack env)" points rover go, rover status, ... at '
            "it. Exit status 0, 1 when no stack (or more than one, without --domain) runs."
        ),
    )
    add_domain_argument(env)
    env.set_defaults(func=_env)

    inject = sub.add_parser(
        "inject",
        help="inject a fault into the stack's emulator",
        description=(
            "Send 'inject FAULT' to the emulator's control interface of the stack "
            "($ROVER_STACK_CONTROL, else the running stack's): a stall, slip, a reboot, ... "
            "(rover emulate --help lists them). Exit status 0 applied or scheduled, 1 "
            "refused or no stack."
        ),
    )
    inject.add_argument("fault", help="e.g. stall:left, slip:right=0.2, reboot, clear:stall:left")
    add_domain_argument(inject)
    inject.set_defaults(func=_inject)


# -- rover stack up -------------------------------------------------------------------------
def _say(line: str) -> None:
    from planner.stack.lines import say

    say(line)


def _health(console: Any, timeout_s: float, link_timeout_s: float) -> Any:
    """The first state heard through the link in which the rover takes steps, else the
    last one heard (``None``: none at all): the first state within ``timeout_s``, and
    one that takes steps within ``link_timeout_s`` of it (both in s)."""
    deadline = time.monotonic() + timeout_s
    last = None
    seen = 0
    while time.monotonic() < deadline:
        status = console.status(max(0.0, deadline - time.monotonic()), newer_than=seen)
        if status is None:
            break
        if last is None:  # the rover reports: its link now has link_timeout_s to come up
            deadline = min(deadline, time.monotonic() + link_timeout_s)
        seen = console.diagnostics_seen
        last = status
        if status.ready:
            break
    return last


def _up(args: argparse.Namespace) -> int:
    from bridge.ros.rosport import open_port
    from firmware_proto.runtime import ShutdownSignals
    from planner.ground.console import RoverConsole
    from planner.ground.console_client import TOKEN_ENV
    from planner.stack.console_server import ConsoleConfig, ConsoleServer
    from planner.stack.domains import TOKEN_KEY, claim
    from planner.stack.processes import Stack, StackConfig
    from planner.stack.stackenv import UPLINK_TOKEN_ENV, export_line, stack_environment

    if args.ground is not None and args.device is not None:
        print(
            "rover stack up: error: --ground is the emulator's ground; with --device the "
            "rover drives on its own",
            file=sys.stderr,
        )
        return 2
    twin = Path(args.twin).resolve() if args.twin is not None else None
    if twin is not None and not twin.is_file():
        print(f"rover stack up: error: --twin {args.twin}: no such file", file=sys.stderr)
        return 2
    if args.console_token is not None:
        print(
            "rover stack up: error: --console-token is no longer accepted: a token on the "
            "command line is shown to every user of this machine (ps, /proc/PID/cmdline); "
            f"set {TOKEN_ENV} instead (without it the stack makes one, which the rover "
            "commands find in the stacks' registry)",
            file=sys.stderr,
        )
        return 2
    try:
        console_config = ConsoleConfig(
            args.console_host, args.console_port, os.environ.get(TOKEN_ENV, "").strip()
        )
    except ValueError as exc:
        print(f"rover stack up: error: {exc}", file=sys.stderr)
        return 2
    config = StackConfig(
        map_name=args.map,
        firmware=args.firmware,
        controller=args.controller,
        device=args.device,
        baud=args.baud,
        rtt_s=args.rtt,
        jitter_s=args.jitter,
        loss=args.loss,
        speed=args.speed,
        seed=args.seed,
        gate_port=args.gate_port,
        startup_timeout_s=args.startup_timeout,
        inject=tuple(args.inject),
        ground=args.ground,
        twin=twin,
    )
    up = threading.Event()
    # While the stack starts, a signal ends the start-up at once (KeyboardInterrupt).
    with ShutdownSignals(interrupt=True) as done, claim(args.domain) as held:
        domain = held.domain
        os.environ.update({"ROS_DOMAIN_ID": str(domain)})
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        _say(f"rover stack: ROS 2 domain {domain}, discovery on this host; starting the parts")

        def forward(name: str, line: str) -> None:
            if up.is_set() or name == "bridge":
                _say(f"[{name}] {line}")

        logs = Path(tempfile.mkdtemp(prefix="rover-stack-logs-"))
        _say(f"rover stack: each part's log and the stall log in {logs}")
        _say(f"rover stack: {config.link_line()}")
        # The parts never need the console's token.
        parts_env = {k: v for k, v in os.environ.items() if k != TOKEN_ENV}
        with (
            Stack(config, parts_env, say=_say, on_line=forward, logs=logs) as stack,
            contextlib.ExitStack() as stack_ports,  # closed before the parts stop
        ):
            try:
                endpoints = stack.start()
            except KeyboardInterrupt:
                _say("rover stack: interrupted while starting; stopping what started")
                return 0
            # The console: a port on the bridge's own topics, matched now, so the
            # commands need no discovery later.
            rover_port = stack_ports.enter_context(
                open_port("rclpy", namespace="", node_name="rover_stack_console")
            )
            console = stack_ports.enter_context(RoverConsole(rover_port))
            server = stack_ports.enter_context(ConsoleServer(console, console_config))
            variables = stack_environment(
                domain,
                endpoints.gate_url,
                endpoints.control,
                config.rtt_s,
                config.speed,
                logs / "stalls.jsonl",
                twin=config.twin,
                console=server.url,
                uplink_token=stack.uplink_token,
            )
            # The token goes to the registry (this user's alone), never to the output.
            held.publish(
                {"env": variables, "device": endpoints.device, TOKEN_KEY: console_config.token}
            )
            _say(f"GATE {endpoints.gate_url}")
            if endpoints.control:
                _say(f"CONTROL {endpoints.control} (the emulator: rover stack inject FAULT)")
            _say(f"DEVICE {endpoints.device}")
            _say(
                f"CONSOLE {server.url} (rover status / stop / clear-stop / echo answer here, "
                "rover side, at once)"
            )
            # Through the link each state comes late: a round trip more is allowed.
            wait_s = config.startup_timeout_s + config.rtt_s / config.speed
            link_wait_s = args.link_timeout + config.rtt_s / config.speed
            with (
                open_port("rclpy", namespace="ground", node_name="rover_stack") as port,
                RoverConsole(port) as through_link,
            ):
                health = _health(through_link, wait_s, link_wait_s)
            if not console.wait_matched(config.startup_timeout_s):
                _say("rover stack: the console has not matched the bridge's topics yet")
            if health is None:
                failed = stack.failed()
                why = (
                    f"the {failed.name} exited: {failed.stderr_tail()}"
                    if failed is not None
                    else "no /ground/diagnostics through the link"
                )
                print(
                    f"rover stack: error: the rover's state never came back within "
                    f"{wait_s:g} s ({why})",
                    file=sys.stderr,
                )
                return 1
            if health.link_state != "ready":
                # Up with no controller is no stack to drive: say why and end it.
                for line in health.text(f"domain {domain}, through the link").splitlines():
                    _say("health: " + line.strip())
                print(
                    f"rover stack: error: no link to the controller within {link_wait_s:g} s "
                    f"of the rover's first report: "
                    f"{health.why_held()[0]}",
                    file=sys.stderr,
                )
                _say(f"rover stack: stopping {_names(stack)}")
                return 1
            for line in health.text(f"domain {domain}, through the link").splitlines():
                _say("health: " + line.strip())
            _say(f"STACK UP domain {domain}")
            _say("point rover go / status / stop / clear-stop / echo at it, in any shell:")
            _say('  eval "$(rover stack env)"')
            shown = {k: v for k, v in variables.items() if k != UPLINK_TOKEN_ENV}
            _say(
                f"  (that is: {export_line(shown)} and {UPLINK_TOKEN_ENV}, the key rover go "
                "signs its plans with; it is not printed)"
            )
            _say("Ctrl-C stops the stack")
            up.set()
            done.interrupt = False
            end = time.monotonic() + args.duration if args.duration > 0 else None
            status = 0
            while not done.received:
                if end is not None and time.monotonic() >= end:
                    break
                failed = stack.failed()
                if failed is not None:
                    print(
                        f"rover stack: error: the {failed.name} exited with status "
                        f"{failed.exit_status}: {failed.stderr_tail() or 'no message'}; "
                        "stopping the stack",
                        file=sys.stderr,
                    )
                    status = 1
                    break
                done.wait(0.5)
            _say(f"rover stack: stopping {_names(stack)}")
        _say("rover stack: down")
        return status


def _names(stack: Any) -> str:
    """The parts started, last first, in words: ``the link, the bridge and the gate``."""
    words = {"onboard": "onboard program"}
    names = [f"the {words.get(part.name, part.name)}" for part in reversed(stack.parts)]
    if len(names) < 2:
        return "".join(names) or "nothing (no part started)"
    return ", ".join(names[:-1]) + " and " + names[-1]


# -- rover stack env / inject -------------------------------------------------------------
def _one_stack(args: argparse.Namespace, prog: str) -> dict[str, Any] | None:
    from planner.stack.domains import running

    stacks = running()
    if args.domain is not None:
        stacks = [s for s in stacks if str(s["domain"]) == str(args.domain)]
    if len(stacks) == 1:
        return stacks[0]
    if not stacks:
        where = f" on ROS domain {args.domain}" if args.domain is not None else ""
        print(
            f"{prog}: error: no rover stack runs{where} (start one: rover stack up)",
            file=sys.stderr,
        )
    else:
        domains = ", ".join(str(s["domain"]) for s in stacks)
        print(
            f"{prog}: error: {len(stacks)} stacks run (domains {domains}): give --domain N",
            file=sys.stderr,
        )
    return None


def _env(args: argparse.Namespace) -> int:
    from planner.stack.stackenv import export_line

    stack = _one_stack(args, "rover stack env")
    if stack is None:
        return 1
    print(export_line(stack["env"]))
    return 0


def _inject(args: argparse.Namespace) -> int:
    from planner.stack.stackenv import CONTROL_ENV

    control = os.environ.get(CONTROL_ENV, "") if args.domain is None else ""
    if not control:
        stack = _one_stack(args, "rover stack inject")
        if stack is None:
            return 1
        control = str(stack["env"].get(CONTROL_ENV, ""))
        if not control:
            print(
                "rover stack inject: error: this stack drives a real device: no emulator",
                file=sys.stderr,
            )
            return 1
    host, port = values.check(values.host_port, control, CONTROL_ENV)
    try:
        with socket.create_connection((host, port), timeout=5) as sock:
            sock.sendall(f"inject {args.fault}\n".encode())
            answer = json.loads(sock.makefile().readline() or "{}")
    except (OSError, ValueError) as exc:
        print(
            f"rover stack inject: error: the emulator at {control} does not answer: {exc}",
            file=sys.stderr,
        )
        return 1
    if not answer.get("ok"):
        print(f"rover stack inject: error: {answer.get('error', answer)}", file=sys.stderr)
        return 1
    when = answer.get("fires") or "now"
    print(f"injected {answer.get('fault', args.fault)} ({when})")
    return 0
