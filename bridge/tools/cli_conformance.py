"""``rover conformance``: play every rule of docs/protocol.md against a controller."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from bridge.tools.cli_bench import can_spec
from firmware_proto.cli import values
from firmware_proto.cli.runtimeargs import add_runtime_arguments, runtime_options
from firmware_proto.runtime import ProcessRuntime
from firmware_proto.runtime.realtime import BRIDGE_PRIORITY

__all__ = ["PACE_WINDOW_S", "PROBE_S", "main", "probe", "register"]

_DESCRIPTION = (
    "The protocol conformance suite (docs/protocol.md, 'Conformance suite'). A wire-level "
    "host plays the host side of every rule against the controller at --device (a serial "
    "device or any pyserial URL) or on --can INTERFACE:CHANNEL, and reports pass, fail or "
    "not run per rule with the frames exchanged. Rules that need the controller to do "
    "something a host cannot cause (a reboot, a fault) run only with --control HOST:PORT "
    "(the emulator's control port, or a lab's own); otherwise they are reported 'not run', "
    "never passed. Exit status: 0 when every selected rule passed, 1 when any failed, 3 "
    "when none failed but some were not run, 2 on a usage error or when no controller "
    "answers (one line: nothing arrives, or only bytes that are no frames: wrong baud "
    "suspected). A controller whose heartbeats arrive far slower than it sends them (a "
    "link slower than its telemetry) is named before the table: its rules time out. "
    "THE ROVER MOVES (a few centimetres per rule): put it on blocks."
)


PROBE_S = 2.0
"""How long to listen for any frame before the suite, s (scaled by --timeout-scale)."""
PACE_WINDOW_S = 1.0
"""How long the controller's heartbeats are counted before the suite, s (scaled)."""


def probe(host: Any, url: str) -> tuple[str | None, str | None]:
    """Listen to the controller before playing any rule: nothing is sent until a frame
    has come (a host must not talk to a device it has not heard). Then HELLO opens a
    session, so that the controller's telemetry flows, and its heartbeats are counted.

    Args:
        host: the open :class:`~bridge.tools.conformance.WireHost`.
        url: the device, for the message.

    Returns:
        ``(error, warning)``: the one line to exit 2 with when no frame arrives within
        :data:`PROBE_S` (nothing at all, or bytes that are no frames); a line to print
        before the table when its heartbeats arrive at under half their rate.
    """
    from firmware_proto.wire.message import Message
    from firmware_proto.wire.messages import (
        CONTROLLER_HEARTBEAT_PERIOD_MS,
        PROTOCOL_VERSION,
        SCHEMA_HASH,
        Heartbeat,
        Hello,
    )

    mark = host.mark()
    if host.find(Message, since=mark, timeout_s=PROBE_S) is None:
        counts = host.endpoint.counters.as_dict()
        waited = PROBE_S * host.timeout_scale
        garbage = {k: v for k, v in counts.items() if v and k not in ("frames", "bytes", "lost")}
        if counts.get("bytes", 0) and garbage:
            return (
                f"no controller answers at {url}: {counts['bytes']} bytes in {waited:g} s "
                f"but no frame ({', '.join(f'{k} {v}' for k, v in sorted(garbage.items()))}): "
                "wrong baud suspected",
                None,
            )
        return (
            f"no controller answers at {url}: nothing arrived in {waited:g} s (is it powered, "
            "is this its device, its baud, its node?)",
            None,
        )
    window = PACE_WINDOW_S * host.timeout_scale
    host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    mark = host.mark()
    host.settle(PACE_WINDOW_S)
    beats = sum(1 for m in host.received(mark) if isinstance(m, Heartbeat))
    expected = window / (CONTROLLER_HEARTBEAT_PERIOD_MS / 1000.0)
    if beats < expected / 2:
        return None, (
            f"warning: the controller's heartbeats arrive {beats} in {window:g} s instead of "
            f"about {expected:.0f}: the link is slower than its telemetry (wrong baud "
            "suspected); its rules will time out"
        )
    return None, None


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value >= 1.0:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``rover conformance``."""
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--device", metavar="URL", help="serial device or pyserial URL (/dev/rover-motor)"
    )
    where.add_argument(
        "--can", type=can_spec, metavar="IFACE:CH", help="python-can bus (socketcan:can0)"
    )
    p.add_argument(
        "--node", type=values.can_node, default=1, help="with --can: controller node 1..15"
    )
    p.add_argument(
        "--control", metavar="HOST:PORT", help="the device's control port (reboot, faults)"
    )
    p.add_argument(
        "--rover",
        metavar="TOML",
        help="the rover description the controller drives (acceleration limit, units; "
        "default: the packaged one)",
    )
    p.add_argument(
        "--rule",
        action="append",
        default=[],
        metavar="ID",
        help="run only these rules (repeatable, or comma-separated); see --list",
    )
    p.add_argument("--list", action="store_true", help="list the rules and exit")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument(
        "--frames", action="store_true", help="print every rule's frames, not only failures'"
    )
    p.add_argument(
        "--timeout-scale",
        type=_positive,
        default=1.0,
        metavar="K",
        help="multiply every wait by K >= 1 (a slow controller or a loaded machine)",
    )


def register(subparsers: Any) -> None:
    """Add ``rover conformance``."""
    p = subparsers.add_parser(
        "conformance",
        help="protocol conformance suite against a controller (--device URL / --can)",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "examples:\n"
            "  rover conformance --list\n"
            "  rover conformance --device /dev/rover-motor\n"
            "  rover conformance --can socketcan:rovercan0 --node 1 --json > verdict.json\n"
            "  rover emulate --serial --link /tmp/rover-motor --control-port 7700 &\n"
            "  rover conformance --device /tmp/rover-motor --control 127.0.0.1:7700\n"
        ),
    )
    add_arguments(p)
    add_runtime_arguments(p, BRIDGE_PRIORITY)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the suite as the options say; the exit status (see the description). The
    suite's host keeps time as the bridge does (its heartbeats feed the controller's
    watchdog): real-time scheduling where permitted (docs/realtime.md)."""
    runtime = ProcessRuntime(runtime_options(args, "conformance", BRIDGE_PRIORITY))
    with runtime:
        if runtime.realtime is not None and not runtime.realtime.granted:
            print(runtime.line(), file=sys.stderr, flush=True)
        return _suite(args)


def _suite(args: argparse.Namespace) -> int:
    from bridge.errors import BridgeError
    from bridge.tools.conformance import (
        Context,
        ControlClient,
        WireHost,
        exit_status,
        render_json,
        render_list,
        render_table,
        run_suite,
        select_rules,
    )
    from firmware_proto.errors import DescriptionError
    from firmware_proto.linkio.endpoint import HOST
    from firmware_proto.linkio.media import open_endpoint
    from firmware_proto.model.rover import load_rover

    try:
        rules = select_rules(args.rule)
    except BridgeError as exc:
        print(f"rover conformance: error: {exc}", file=sys.stderr)
        return 2
    if args.list:
        sys.stdout.write(render_list(rules))
        return 0
    if args.device:
        url = args.device
    elif args.can:
        url = f"can://{args.can[0]}/{args.can[1]}?node={args.node}"
    else:
        print("rover conformance: error: give --device URL or --can IFACE:CH", file=sys.stderr)
        return 2
    control = None
    try:
        rover = load_rover(args.rover)
        endpoint = open_endpoint(url, HOST)
        if args.control:
            control = ControlClient(args.control)
        host = WireHost(endpoint, timeout_scale=args.timeout_scale)
        try:
            host.open()
        except OSError as exc:
            raise OSError(f"cannot open {url}: {exc}") from exc
        with host:
            error, warning = probe(host, url)
            if error is not None:
                print(f"rover conformance: error: {error}", file=sys.stderr)
                return 2
            if warning is not None:
                print(f"rover conformance: {warning}", file=sys.stderr, flush=True)
            results = run_suite(Context(host, control, rover), rules)
    except (BridgeError, OSError, DescriptionError) as exc:
        print(f"rover conformance: error: {exc}", file=sys.stderr)
        return 2
    finally:
        if control is not None:
            control.close()
    if args.json:
        sys.stdout.write(render_json(results, url=url))
    else:
        sys.stdout.write(render_table(results, url=url, frames=args.frames))
    return exit_status(results)


def main(argv: list[str] | None = None) -> int:
    """``python -m bridge.tools.cli_conformance``: the same as ``rover conformance``."""
    parser = argparse.ArgumentParser(prog="rover conformance", description=_DESCRIPTION)
    add_arguments(parser)
    return run(parser.parse_args(argv))
