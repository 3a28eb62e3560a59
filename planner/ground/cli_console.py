"""``rover status``, ``rover stop``, ``rover clear-stop`` and ``rover echo``: the
operator's console, no ros2cli needed (docs/commands.md, "The stack's console").

Through a stack's console socket where one is known (``--console URL``, or
``$ROVER_STACK_CONSOLE``; its token ``$ROVER_CONSOLE_TOKEN``, else the stacks' registry):
the running stack answers from its own ROS port on the bridge's topics (not through the
emulated link), with no rclpy and no discovery (:mod:`planner.ground.console_client`).
Otherwise, with ``--ros`` or ``--namespace``, or when the console does not answer (said
on stderr; for ``rover stop`` also when refused): ROS 2 (:mod:`planner.ground.console`)
on the bridge's topics in ``--namespace`` (default ``ground``, through the link relay;
``/`` for the bridge's own) on ``--domain`` or ``$ROS_DOMAIN_ID``.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
import time
from typing import Any

from firmware_proto.cli import values
from planner.ground.console_client import CONSOLE_ENV, TOKEN_ENV
from planner.stack.stackenv import add_domain_argument

__all__ = [
    "ECHO_TOPICS",
    "describe",
    "namespace_hint",
    "register_clear_stop",
    "register_echo",
    "register_status",
    "register_stop",
]

ECHO_TOPICS = (
    "command_status",
    "diagnostics",
    "odom",
    "odom_ground",
    "wheel_instructions",
    "emergency_stop",
    "clear_emergency_stop",
)
"""The product's topics ``rover echo`` knows (docs/bridge.md, ROS contract)."""

ECHO_TYPES = {
    "command_status": "std_msgs/String",
    "diagnostics": "diagnostic_msgs/DiagnosticArray",
    "odom": "nav_msgs/Odometry",
    "odom_ground": "nav_msgs/Odometry",
    "wheel_instructions": "std_msgs/Int16MultiArray",
    "emergency_stop": "std_msgs/Bool",
    "clear_emergency_stop": "std_msgs/Empty",
}
"""Each of :data:`ECHO_TOPICS`' message type (the header ``rover echo`` prints)."""

EXIT_HELD = 3
"""``rover status``: the bridge answered, and the rover refuses steps now."""


def _paths(p: argparse.ArgumentParser) -> None:
    """``--console URL``, ``--ros``, ``--namespace NS`` and ``--domain N``."""
    p.add_argument(
        "--console",
        metavar="URL",
        default=None,
        help=f"a stack's console socket (default ${CONSOLE_ENV}, which 'rover stack env' "
        "exports): the stack answers at once, rover side, no ROS 2 discovery",
    )
    p.add_argument(
        "--ros",
        action="store_true",
        help="over ROS 2 even where a stack's console is known (what a bridge started "
        "alone answers to)",
    )
    p.add_argument(
        "--namespace",
        default=None,
        help="over ROS 2, the namespace of the topics: ground (the default: through the "
        "link relay, as rover go) or / (the bridge's own); implies --ros",
    )
    add_domain_argument(p)


def _common(p: argparse.ArgumentParser, timeout_s: float) -> None:
    _paths(p)
    p.add_argument(
        "--timeout",
        type=values.positive,
        default=timeout_s,
        metavar="S",
        help=f"how long to wait for the bridge's answer, s (default {timeout_s:g})",
    )


def register_status(subparsers: Any) -> None:
    """Add ``rover status``."""
    p = subparsers.add_parser(
        "status",
        help="the rover's link, controller, latch, faults, last statuses and counters",
        description=(
            "Read the bridge's /diagnostics (and listen to command_status) and print the "
            "link state, the controller state, what holds the STOP latch, the fault "
            "conditions active now, the last statuses and the counters, and why the rover "
            "refuses steps, if it does, with the way out. Exit status: 0 the rover takes "
            f"steps, {EXIT_HELD} it refuses them (latched, a stopping fault, no link), 1 no "
            "answer from a bridge within --timeout, 2 usage; with --watch 0 (130 on Ctrl-C)."
        ),
    )
    _common(p, 10.0)
    p.add_argument("--json", action="store_true", help="print one JSON object per report")
    p.add_argument(
        "--watch", action="store_true", help="print every report as it comes, until Ctrl-C"
    )
    p.add_argument(
        "--count",
        type=values.positive_int,
        default=None,
        metavar="N",
        help="with --watch: stop after N reports",
    )
    p.set_defaults(func=_status)


def register_stop(subparsers: Any) -> None:
    """Add ``rover stop``."""
    p = subparsers.add_parser(
        "stop",
        help="emergency stop: the rover stops and latches",
        description=(
            "Publish true on emergency_stop (repeated every 0.5 s) until the bridge says "
            "'stopped': the controller acknowledged the STOP, the rover stops and its latch "
            "holds until 'rover clear-stop'. Exit status: 0 stopped, 1 no acknowledgement "
            "within --timeout, 2 usage."
        ),
    )
    _common(p, 10.0)
    p.set_defaults(func=_stop)


def register_clear_stop(subparsers: Any) -> None:
    """Add ``rover clear-stop``."""
    p = subparsers.add_parser(
        "clear-stop",
        help="release the STOP latch, and say whether it released and why not",
        description=(
            "Publish on clear_emergency_stop and wait for the controller's answer through "
            "the bridge: 'released' (and what held it), 'not latched' (nothing to release), "
            "or why the latch stays (a stopping fault's condition still active, no link, no "
            "bridge). Exit status: 0 released or not latched, 1 the latch stays or no "
            "answer, 2 usage."
        ),
    )
    _common(p, 15.0)
    p.add_argument("--json", action="store_true", help="print the outcome as JSON")
    p.set_defaults(func=_clear_stop)


def register_echo(subparsers: Any) -> None:
    """Add ``rover echo``."""
    p = subparsers.add_parser(
        "echo",
        help="print the messages on one of the product's topics",
        description=(
            "Subscribe to TOPIC (one of: " + ", ".join(ECHO_TOPICS) + ") and print each "
            "message on one line (--json: as JSON). Exit status: 0 after --count messages or "
            "Ctrl-C, 1 when --timeout passes without a message, 2 usage."
        ),
    )
    p.add_argument("topic", choices=ECHO_TOPICS, metavar="TOPIC", help=", ".join(ECHO_TOPICS))
    _paths(p)
    p.add_argument("--count", type=values.positive_int, default=None, metavar="N")
    p.add_argument(
        "--timeout",
        type=values.positive,
        default=None,
        metavar="S",
        help="give up after S s without a message (default: wait until Ctrl-C)",
    )
    p.add_argument("--json", action="store_true", help="one JSON object per message")
    p.set_defaults(func=_echo)


# -- handlers -------------------------------------------------------------------------------
def _where(port: Any, domain: int | None) -> str:
    ns = port.namespace
    return f"{ns}, ROS domain {domain if domain is not None else 0}"


def _open(args: argparse.Namespace, node: str) -> tuple[Any, int | None]:
    from bridge.ros.rosport import open_port
    from planner.stack.stackenv import apply_domain

    domain = apply_domain(args)
    namespace = args.namespace if args.namespace is not None else "ground"
    return open_port("rclpy", namespace=namespace, node_name=node), domain


def namespace_hint(namespace: str | None) -> str:
    """What to add to "nothing from a bridge" over ROS 2: with the default namespace
    (``namespace`` ``None``: ``ground``, the ground side of a stack's link), a bridge
    started alone is not there but at the root; ``""`` when ``--namespace`` was given."""
    if namespace is not None:
        return ""
    return (
        "; a bridge started alone (no stack, no link relay) has its topics at the root: "
        "add --namespace /"
    )


def _console(args: argparse.Namespace) -> Any:
    """The stack's console client, or ``None`` for ROS 2 (``--ros``, ``--namespace``,
    or no console known)."""
    import os

    if args.ros or args.namespace is not None:
        return None
    url = args.console or os.environ.get(CONSOLE_ENV, "").strip()
    if not url:
        return None
    from planner.ground.console_client import ConsoleClient

    return ConsoleClient(url, _console_token(url))


def _console_token(url: str) -> str | None:
    """The console's token: ``$ROVER_CONSOLE_TOKEN``, else its stack's in the registry
    (never an argument: ``ps`` shows those to every user)."""
    import os

    from planner.errors import StackRegistryError
    from planner.stack.domains import console_token

    given = os.environ.get(TOKEN_ENV, "").strip()
    if given:
        return given
    try:
        return console_token(url)
    except (StackRegistryError, OSError) as exc:
        print(f"warning: the stacks' registry: {exc}", file=sys.stderr, flush=True)
        return None


def _unavailable(prog: str, exc: Exception | str) -> None:
    print(f"{prog}: {exc}; over ROS 2 instead (--ros)", file=sys.stderr, flush=True)


def _on_console(client: Any) -> str:
    return f"the stack's console {client.url}, rover side"


def _terminate_as_interrupt() -> None:
    """SIGTERM ends a watch as Ctrl-C does (the port closes on the way out)."""
    if threading.current_thread() is threading.main_thread():

        def _raise(signum: int, frame: Any) -> None:
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, _raise)


def _status(args: argparse.Namespace) -> int:
    from planner.ground.console import RoverConsole
    from planner.ground.console_client import ConsoleUnavailableError

    client = _console(args)
    if client is not None:
        try:
            return _status_on_console(args, client)
        except ConsoleUnavailableError as exc:
            _unavailable("rover status", exc)
    port, domain = _open(args, "rover_status")
    with port, RoverConsole(port) as console:
        where = _where(port, domain)
        if not args.watch:
            status = console.status(args.timeout)
            if status is None:
                print(
                    f"rover status: error: no /diagnostics from a bridge on "
                    f"{console.topic('diagnostics')} (ROS domain {domain or 0}) within "
                    f"{args.timeout:g} s: is the stack up, and this the domain it printed?"
                    f"{namespace_hint(args.namespace)}",
                    file=sys.stderr,
                )
                return 1
            plan = console.onboard
            if args.json:
                on_board = json.loads(plan.to_json()) if plan is not None else None
                print(
                    json.dumps({"where": where, **status.as_dict(), "plan": on_board}), flush=True
                )
            else:
                print(status.text(where), flush=True)
                print(
                    f"plan on board: {plan.line()}"
                    if plan is not None
                    else "plan on board: none reported (no plan run, or no rover onboard)",
                    flush=True,
                )
            return 0 if status.ready else EXIT_HELD
        _terminate_as_interrupt()
        shown = 0
        seen = 0
        try:
            while args.count is None or shown < args.count:
                status = console.status(args.timeout, newer_than=seen)
                if status is None:
                    print(f"(no /diagnostics for {args.timeout:g} s)", flush=True)
                    continue
                seen = console.diagnostics_seen
                if args.json:
                    print(json.dumps({"where": where, **status.as_dict()}), flush=True)
                else:
                    print(time.strftime("%H:%M:%S ") + status.text(where) + "\n", flush=True)
                shown += 1
        except KeyboardInterrupt:
            return 130
    return 0


def _status_on_console(args: argparse.Namespace, client: Any) -> int:
    from planner.ground.console_client import ConsoleRefusedError

    where = _on_console(client)
    _terminate_as_interrupt()
    shown, stamp = 0, None
    try:
        while True:
            try:
                status, doc = client.status(args.timeout)
            except ConsoleRefusedError as exc:
                print(f"rover status: error: {exc}", file=sys.stderr)
                return 1
            if not args.watch:
                _print_status(args, status, where, doc["age_s"], plan=doc.get("plan"))
                return 0 if status.ready else EXIT_HELD
            if doc["stamp_s"] != stamp:
                stamp = doc["stamp_s"]
                _print_status(args, status, where, doc["age_s"], stamped=True)
                shown += 1
                if args.count is not None and shown >= args.count:
                    return 0
            time.sleep(0.25)
    except KeyboardInterrupt:
        return 130


def _print_status(
    args: argparse.Namespace,
    status: Any,
    where: str,
    age_s: float,
    *,
    stamped: bool = False,
    plan: dict[str, Any] | None = None,
) -> None:
    if args.json:
        answer = {"where": where, "age_s": age_s, **status.as_dict(), "plan": plan}
        print(json.dumps(answer), flush=True)
    elif stamped:
        print(time.strftime("%H:%M:%S ") + status.text(where) + "\n", flush=True)
    else:
        print(status.text(f"{where}, {age_s:.1f} s old"), flush=True)
        print(_plan_line(plan), flush=True)


def _plan_line(plan: dict[str, Any] | None) -> str:
    """The plan on board, as the console's ``/status`` carries it (docs/onboard.md)."""
    from firmware_proto.model.downlink import decode_report

    if plan is None:
        return "plan on board: none reported (no plan run, or no rover onboard)"
    try:
        return f"plan on board: {decode_report(json.dumps(plan)).line()}"
    except ValueError:
        return "plan on board: (a report this console cannot read)"


def _stop(args: argparse.Namespace) -> int:
    from planner.ground.console import RoverConsole
    from planner.ground.console_client import ConsoleRefusedError, ConsoleUnavailableError

    client = _console(args)
    if client is not None:
        try:
            if client.stop(args.timeout):
                print(
                    f"stopped: the controller acknowledged the STOP ({_on_console(client)}); "
                    "the latch holds until 'rover clear-stop'",
                    flush=True,
                )
                return 0
            print(
                f"rover stop: error: no 'stopped' within {args.timeout:g} s "
                f"({_on_console(client)}): is the bridge linked to its controller?",
                file=sys.stderr,
            )
            return 1
        except ConsoleRefusedError as exc:
            # Refused before anything was published (a wrong token, ...): a STOP must
            # still get through, so over ROS 2.
            _unavailable("rover stop", f"the stack's console {client.url} refused: {exc}")
        except ConsoleUnavailableError as exc:
            _unavailable("rover stop", exc)
    port, domain = _open(args, "rover_stop")
    with port, RoverConsole(port) as console:
        console.wait_matched(min(args.timeout, 5.0))
        if console.stop(args.timeout):
            print(
                f"stopped: the controller acknowledged the STOP ({_where(port, domain)}); "
                "the latch holds until 'rover clear-stop'",
                flush=True,
            )
            return 0
    print(
        f"rover stop: error: no 'stopped' on {port.resolve('command_status')} within "
        f"{args.timeout:g} s (is the stack up on ROS domain {domain or 0}?)",
        file=sys.stderr,
    )
    return 1


def _clear_stop(args: argparse.Namespace) -> int:
    from planner.ground.console import ClearOutcome, RoverConsole
    from planner.ground.console_client import ConsoleRefusedError, ConsoleUnavailableError

    client = _console(args)
    if client is not None:
        try:
            doc = client.clear_stop(args.timeout)
        except ConsoleRefusedError as exc:
            print(f"rover clear-stop: error: {exc}", file=sys.stderr)
            return 1
        except ConsoleUnavailableError as exc:
            _unavailable("rover clear-stop", exc)
        else:
            return _say_cleared(args, doc)
    port, _domain = _open(args, "rover_clear_stop")
    with port, RoverConsole(port) as console:
        console.wait_matched(min(args.timeout / 3.0, 5.0))
        report = console.clear_stop(args.timeout)
    before = report.before
    if args.json:
        print(
            json.dumps(
                {
                    "outcome": report.outcome.value,
                    "released": report.released,
                    "why": report.why,
                    "held_by": list(before.latch) if before is not None else None,
                    "after": report.after.as_dict() if report.after is not None else None,
                    "armed": report.armed,
                }
            )
        )
    elif report.outcome is ClearOutcome.RELEASED:
        held = ", ".join(before.latch) if before is not None and before.latch else "the latch"
        print(f"released: the latch is off (it was held by {held}); the rover takes steps again")
    elif report.outcome is ClearOutcome.NOT_LATCHED:
        print("not latched: there was nothing to release; the rover takes steps")
    else:
        unheard = report.outcome is ClearOutcome.NO_ANSWER and report.before is None
        hint = namespace_hint(args.namespace) if unheard and report.after is None else ""
        print(f"rover clear-stop: NOT released: {report.why}{hint}", file=sys.stderr)
    if report.armed and not args.json:
        print(f"note: {report.armed}")
    if report.after is not None and report.released and report.after.stopping_faults:
        print(
            "note: fault condition(s) "
            + ", ".join(report.after.stopping_faults)
            + " active again: the rover stops at once",
            file=sys.stderr,
        )
    return 0 if report.released else 1


def _say_cleared(args: argparse.Namespace, doc: dict[str, Any]) -> int:
    """What ``rover clear-stop`` says of a console's answer."""
    if args.json:
        keys = ("outcome", "released", "why", "held_by", "armed")
        print(json.dumps({k: doc.get(k) for k in keys}))
    elif doc["outcome"] == "released":
        held = ", ".join(doc.get("held_by") or []) or "the latch"
        print(f"released: the latch is off (it was held by {held}); the rover takes steps again")
    elif doc["outcome"] == "not_latched":
        print("not latched: there was nothing to release; the rover takes steps")
    else:
        print(f"rover clear-stop: NOT released: {doc['why']}", file=sys.stderr)
    if doc.get("armed"):
        print(f"note: {doc['armed']}")
    return 0 if doc["released"] else 1


def _yaw_deg(q: Any) -> float:
    return math.degrees(2.0 * math.atan2(q.z, q.w))


def describe(topic: str, msg: Any) -> str:
    """One line for one message of one of :data:`ECHO_TOPICS` (relative name)."""
    if topic in ("odom", "odom_ground"):
        p = msg.pose.pose
        return (
            f"x={p.position.x:.3f} y={p.position.y:.3f} yaw={_yaw_deg(p.orientation):.1f} deg "
            f"v={msg.twist.twist.linear.x:.3f} m/s frame={msg.header.frame_id}"
        )
    if topic == "diagnostics":
        from planner.ground.roverstatus import LEVELS

        parts = []
        for s in msg.status:
            level = s.level[0] if isinstance(s.level, (bytes, bytearray)) else int(s.level)
            parts.append(f"{s.name}: {LEVELS.get(level, level)} {s.message}")
        return " | ".join(parts)
    if topic == "wheel_instructions":
        return "[" + ", ".join(str(int(v)) for v in msg.data) + "]"
    if topic == "emergency_stop":
        return str(bool(msg.data)).lower()
    if topic == "clear_emergency_stop":
        return "{}"
    return str(msg.data)


_LAST_WAIT_S = 3.0
"""How long ``rover echo command_status`` waits for ``/diagnostics``' last status, s."""
_LAST_NOTE = "(the last before this echo, from /diagnostics)"


class _LastStatus:
    """The bridge's last ``command_status`` as its ``/diagnostics`` carries it
    (``last_statuses``), for ``rover echo command_status`` on an idle rover."""

    def __init__(self, port: Any) -> None:
        from bridge.ros.rosport import qos
        from bridge.ros.rosport.msgs import DiagnosticArray

        self._came = threading.Event()
        self.value: tuple[float, str] | None = None
        self._sub = port.subscribe(
            "diagnostics", DiagnosticArray, self._on_diagnostics, qos.DIAGNOSTICS
        )

    def _on_diagnostics(self, msg: Any) -> None:
        from planner.ground.roverstatus import from_diagnostics

        if self._came.is_set():
            return
        try:
            status = from_diagnostics(msg)
        except ValueError:
            return  # another node's diagnostics
        if status.statuses:
            self.value = (status.stamp_s, status.statuses[-1])
        self._came.set()

    def wait(self, timeout_s: float) -> tuple[float, str] | None:
        """The last status, once the first ``/diagnostics`` came (``None``: none came
        within ``timeout_s``, or the bridge has said nothing yet)."""
        self._came.wait(timeout_s)
        self._sub.close()
        return self.value


def _echo_on_console(args: argparse.Namespace, client: Any) -> int:
    """``rover echo`` through a stack's console: its last value first where one is kept
    (marked so), then each message as it comes."""
    from planner.ground.console_client import ConsoleRefusedError

    _terminate_as_interrupt()
    idle = args.timeout if args.timeout is not None else 1e9
    try:
        for doc in client.echo(args.topic, args.count or 0, idle):
            if doc.get("listening"):
                print(
                    f"# /{args.topic} [{ECHO_TYPES[args.topic]}] ({_on_console(client)})",
                    flush=True,
                )
            elif args.json:
                data = dict(doc["data"]) if isinstance(doc["data"], dict) else {"data": doc}
                if doc.get("last_known"):
                    data["last_known"] = True
                print(json.dumps(data, default=str), flush=True)
            else:
                note = f" {_LAST_NOTE_CONSOLE}" if doc.get("last_known") else ""
                print(f"{doc['t']:.3f} {doc['text']}{note}", flush=True)
    except ConsoleRefusedError as exc:
        print(f"rover echo: error: {exc}", file=sys.stderr)
        return 1
    except TimeoutError as exc:
        print(f"rover echo: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 0
    return 0


_LAST_NOTE_CONSOLE = "(the last before this echo)"


def _echo(args: argparse.Namespace) -> int:
    import queue

    from planner.ground.console_client import ConsoleUnavailableError

    client = _console(args)
    if client is not None:
        try:
            return _echo_on_console(args, client)
        except ConsoleUnavailableError as exc:
            _unavailable("rover echo", exc)

    from bridge.ros.rosport import STOP_LANE, qos
    from bridge.ros.rosport.msgs import (
        Bool,
        DiagnosticArray,
        Empty,
        Int16MultiArray,
        Odometry,
        String,
    )
    from planner.record.mcaprec import plain_message

    kinds: dict[str, tuple[type[Any], Any]] = {
        "command_status": (String, qos.STATUS),
        "diagnostics": (DiagnosticArray, qos.DIAGNOSTICS),
        "odom": (Odometry, qos.SENSOR),
        "odom_ground": (Odometry, qos.SENSOR),
        "wheel_instructions": (Int16MultiArray, qos.COMMAND),
        "emergency_stop": (Bool, qos.STOP),
        "clear_emergency_stop": (Empty, qos.STOP),
    }
    msg_type, profile = kinds[args.topic]
    got: queue.SimpleQueue[Any] = queue.SimpleQueue()
    port, _domain = _open(args, "rover_echo")
    _terminate_as_interrupt()
    shown = 0
    with port:
        lane = STOP_LANE if profile is qos.STOP else "default"
        last = _LastStatus(port) if args.topic == "command_status" else None
        sub = port.subscribe(args.topic, msg_type, got.put, profile, lane=lane)
        full = port.resolve(args.topic)
        # The header means 'listening': a publisher that is there is matched first (a
        # volatile topic loses what is sent before), as far as discovery lets us wait.
        sub.wait_for_publishers(1, min(args.timeout or 5.0, 5.0))
        print(f"# {full} [{msg_type.__module__.split('.')[0]}/{msg_type.__name__}]", flush=True)
        if last is not None:
            # command_status is volatile: an idle rover says nothing. Its last value is
            # in the bridge's /diagnostics (1 Hz, then the link's delay).
            known = last.wait(min(args.timeout or _LAST_WAIT_S, _LAST_WAIT_S))
            if known is not None and got.empty():
                stamp, text = known
                if args.json:
                    print(json.dumps({"data": text, "last_known": True}), flush=True)
                else:
                    print(f"{stamp:.3f} {text} {_LAST_NOTE}", flush=True)
                shown += 1
        try:
            while args.count is None or shown < args.count:
                try:
                    msg = got.get(timeout=args.timeout if args.timeout is not None else 1.0)
                except queue.Empty:
                    if args.timeout is not None:
                        print(
                            f"rover echo: error: no message on {full} within {args.timeout:g} s",
                            file=sys.stderr,
                        )
                        return 1
                    continue
                if args.json:
                    print(json.dumps(plain_message(msg), default=str), flush=True)
                else:
                    print(f"{time.time():.3f} {describe(args.topic, msg)}", flush=True)
                shown += 1
        except KeyboardInterrupt:
            return 0
    return 0
