"""STOP latency through the bridge, beside the pty round trip; sustained steps/s.

Run: ``.venv/bin/python -m benchmarks.bench_bridge [--trials N] [--quick]``; the ROS 2
case in the tests' private loopback network namespace::

    unshare -n -- bash -c 'ip link set lo up && ip link set lo multicast on &&
        exec .venv/bin/python -m benchmarks.bench_bridge --ros2'

The emulator serves the controller on a real pty in real time, in a process of its own
as ``rover emulate`` does (in one process it would share the interpreter lock with the
bridge); the bridge's ControllerLink (and its ROS node) drives it. Both take the
real-time priority their programs ask for where the system permits it
(docs/realtime.md; the table's note says what was granted). For every trial the rover
is moving, then a STOP is requested, and two latencies are taken on CLOCK_MONOTONIC,
which every process shares:

- (a) request -> the STOP frame's last byte written to the device by the bridge;
- (b) request -> the emulator's wheel targets at zero (its control thread handled it).

The request is an API call (``ControllerLink.emergency_stop``) or a ROS message on
``emergency_stop`` from another node: on the in-process port, or over real ROS 2 from
another process's plain rclpy node (``--ros2``: the bridge node on ``rclpy-process``
and on ``rclpy``). Idle means one long step running; load means the motion queue full
and telemetry at 100 Hz.
The pty round trip (15 bytes there and back through pyserial), measured in the same run,
is the floor for (b). The thesis reports 8.4 +/- 1.2 ms; the target is p99 < 1 ms.

A trial whose step is refused or whose link is lost before its STOP is measured counts
as lost: the bench waits for the new session, clears any latch left and goes on (lost
trials and the link's counts are printed under the table).
"""

from __future__ import annotations

import argparse
import random
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

from benchmarks.common import pty_round_trip, readline_within, summary, table
from bridge.link.controllerlink import ControllerLink, LinkConfig, StepRequest
from bridge.ros.node import BridgeNode
from bridge.ros.params import load_params
from bridge.ros.rosport import open_port, qos
from bridge.ros.rosport.msgs import Bool, Int16MultiArray, Odometry, String
from emulator.controller import ControllerConfig, ControllerModel
from emulator.engine import Emulator
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin
from firmware_proto.linkio.inbox import Inbox
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.runtime.interpreter import use_short_switch_interval
from firmware_proto.runtime.realtime import (
    BRIDGE_PRIORITY,
    EMULATOR_PRIORITY,
    RealtimeConfig,
    apply_realtime,
    module_command_at_normal_priority,
)
from firmware_proto.wire.messages import Command


class Statuses:
    """Collects /command_status strings (a waitable
    :class:`~firmware_proto.linkio.inbox.Inbox`) and lets the benchmark wait for one."""

    def __init__(self) -> None:
        self.log: Inbox[str] = Inbox()

    def __call__(self, text: str) -> None:
        self.log.append(text)

    def wait(self, text: str, since: int, timeout: float = 10.0) -> None:
        if self.log.wait(lambda s: s == text, since=since, timeout_s=timeout) is None:
            raise TimeoutError(f"no {text!r} within {timeout} s")

    def first(self, words: tuple[str, ...], since: int, timeout: float = 10.0) -> str:
        """The first status from ``since`` on that starts with one of ``words`` ('' when
        none came within ``timeout`` s)."""
        found = self.log.wait(lambda s: s.startswith(words), since=since, timeout_s=timeout)
        return found[1] if found is not None else ""

    def mark(self) -> int:
        return self.log.mark()


SETTLED = ("accepted", "rejected", "aborted", "fault")
"""The first answer to a step: accepted, or why not (a lost link answers ``aborted``, ``fault``)."""

SESSION_TIMEOUT_S = 30.0
"""How long the bench waits for the link's (new) session, s."""


def recover(link: ControllerLink, statuses: Statuses) -> None:
    """Wait for the link's session (a lost one handshakes again by itself) and clear any
    latch left behind (an operator STOP of a trial cut short; the watchdog's the link
    clears itself), so the next trial starts moving.

    Raises:
        TimeoutError: no session, or the latch would not clear, within
            :data:`SESSION_TIMEOUT_S` (the bench cannot go on).
    """
    deadline = time.monotonic() + SESSION_TIMEOUT_S
    while time.monotonic() < deadline:
        if link.ready and not link.stop_latched:
            return
        if link.ready:
            mark = statuses.mark()
            link.clear_stop()
            statuses.first(("cleared", "fault", "rejected"), mark, timeout=5.0)
        else:
            time.sleep(0.01)
    raise TimeoutError(f"the link had no session, unlatched, within {SESSION_TIMEOUT_S} s")


@dataclass
class Trials:
    """The STOP trials of one case: latencies (s), and trials lost to the link."""

    written: list[float] = field(default_factory=list)
    zeroed: list[float] = field(default_factory=list)
    hops: list[float] = field(default_factory=list)
    """Request -> the bridge node's STOP callback (with a node), s."""
    lost: int = 0
    """Trials not measured: the step was refused or the link lost before the STOP."""


#: The bridge's backends in the ROS 2 case: the default (the node in a child process)
#: beside the node in the bridge's process, so the table shows what the extra hop costs.
ROS2_BACKENDS = ("rclpy-process", "rclpy")

Request = Callable[[], float]
"""Asks for a STOP; returns when it was asked (``time.monotonic()``)."""


def _api(link: ControllerLink) -> Request:
    def request() -> float:
        t0 = time.monotonic()
        link.emergency_stop()
        return t0

    return request


def _published(publish: Callable[[Bool], None]) -> Request:
    def request() -> float:
        t0 = time.monotonic()
        publish(Bool(data=True))
        return t0

    return request


class EmulatorProcess:
    """The emulator serving a pty in a child process (``--emulator-child``), driven over
    its stdin and stdout: one command line, one answer line."""

    def __init__(self, seed: int, rt_priority: int = EMULATOR_PRIORITY) -> None:
        """Start the child: at normal priority until imported, then at ``rt_priority``
        (0: none) where permitted, as ``rover emulate --rt-priority``."""
        self._child = subprocess.Popen(
            [
                *module_command_at_normal_priority("benchmarks.bench_bridge"),
                "--emulator-child",
                f"--seed={seed}",
                f"--rt-priority={rt_priority}",
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self._child.stdin is not None
        assert self._child.stdout is not None
        self._stdin, self._stdout = self._child.stdin, self._child.stdout
        try:
            first = readline_within(self._stdout, 30.0, "the emulator process")
        except TimeoutError:
            self.close()
            raise
        word, _, device = first.strip().partition(" ")
        if word != "DEVICE":
            self.close()
            raise RuntimeError("the emulator process did not start")
        self.device = device

    def _ask(self, line: str) -> str:
        self._stdin.write(line + "\n")
        self._stdin.flush()
        answer = readline_within(self._stdout, 30.0, "the emulator process").strip()
        if not answer:
            raise RuntimeError(f"the emulator process ended (asked {line!r})")
        return answer

    def telemetry(self, hz: float) -> None:
        """Set the controller's telemetry rate, Hz."""
        self._ask(f"hz {hz}")

    def stops(self) -> int:
        """How many STOP frames the emulator has handled so far."""
        return int(self._ask("count"))

    def stop_handled(self, index: int, timeout_s: float = 5.0) -> float | None:
        """``time.monotonic()`` when the emulator's STOP number ``index`` (from 0) had
        zeroed the wheel targets; None if it did not come within ``timeout_s``."""
        answer = self._ask(f"wait {index} {timeout_s}")
        return None if answer == "none" else float(answer)

    def close(self) -> None:
        self._stdin.close()
        try:
            self._child.wait(10)
        except subprocess.TimeoutExpired:
            self._child.kill()
            self._child.wait(10)
        self._stdout.close()

    def __enter__(self) -> EmulatorProcess:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def emulator_child(seed: int, rt_priority: int = 0) -> int:
    """Child process: the emulator on a pty (at this real-time priority, 0: none, as
    ``rover emulate --rt-priority``); prints ``DEVICE <path>``, then answers ``hz N``,
    ``count`` and ``wait INDEX TIMEOUT`` lines from stdin until it closes."""
    apply_realtime(RealtimeConfig(rt_priority))
    rover = load_rover()
    model = ControllerModel(rover, Twin(rover), ControllerConfig(), seed=seed)
    with Emulator(model, SerialFrontEnd(seed=seed)) as emu:
        assert isinstance(emu.frontend, SerialFrontEnd)
        print("DEVICE", emu.frontend.device, flush=True)
        for line in sys.stdin:
            verb, *args = line.split()
            if verb == "hz":
                emu.call(partial(setattr, emu.model, "telemetry_hz", float(args[0])))
                print("ok", flush=True)
            elif verb == "count":
                print(len(emu.stop_handled), flush=True)
            elif verb == "wait":
                index, deadline = int(args[0]), time.monotonic() + float(args[1])
                while len(emu.stop_handled) <= index and time.monotonic() < deadline:
                    time.sleep(0.002)
                handled = emu.stop_handled[index] if len(emu.stop_handled) > index else None
                print("none" if handled is None else repr(handled), flush=True)
            else:
                print(f"error: unknown command {verb!r}", flush=True)
    return 0


def _trials(
    emu: EmulatorProcess,
    link: ControllerLink,
    statuses: Statuses,
    request: Request,
    trials: int,
    load: bool,
    rng: random.Random,
    node: BridgeNode | None = None,
) -> Trials:
    """STOP trials; the two latencies of each (see the module docstring), and with
    ``node`` request -> the node's STOP callback. A trial the link loses is counted, not
    measured, and the next one waits for the link's new session (:func:`recover`)."""
    out = Trials()
    emu.telemetry(100 if load else 50)
    for _ in range(trials):
        recover(link, statuses)
        mark = statuses.mark()
        for _ in range(8 if load else 1):
            link.submit_step(StepRequest(Command.FWD, 60, 30000))
        if statuses.first(SETTLED, mark) != "accepted":
            out.lost += 1
            continue
        time.sleep(rng.uniform(0.05, 0.25))  # STOP at a random moment of the motion
        before, previous = emu.stops(), link.last_stop_written
        t0 = request()
        handled = emu.stop_handled(before)
        # The emulator may handle the STOP a moment before the writing thread stamps it.
        deadline = time.monotonic() + 1.0
        while link.last_stop_written == previous and time.monotonic() < deadline:
            time.sleep(0.0005)
        written_at = link.last_stop_written
        # A trial the link lost measures the outage, not the STOP path.
        cut = any(s.startswith("fault:") for s in statuses.log.items(mark))
        if written_at is not None and written_at != previous and handled is not None and not cut:
            out.written.append(written_at - t0)
            out.zeroed.append(handled - t0)
            if node is not None and node.last_estop_received is not None:
                out.hops.append(node.last_estop_received - t0)
        else:
            out.lost += 1
        mark = statuses.mark()
        link.clear_stop()
        statuses.first(("cleared", "fault", "rejected"), mark)
    recover(link, statuses)
    return out


def _cut_or_done(n: int, statuses: list[str]) -> bool:
    """All ``n`` steps completed, or one did not."""
    return statuses.count("completed") >= n or any(s.startswith(SETTLED[1:]) for s in statuses)


def _all_settled(n: int, statuses: list[str]) -> bool:
    """Each of ``n`` steps has its fate (completed, aborted or rejected)."""
    return sum(s == "completed" or s.startswith(("aborted", "rejected")) for s in statuses) >= n


@dataclass
class Rate:
    """Sustained steps: how many completed in how long, and batches cut short."""

    completed: int
    seconds: float
    lost_batches: int

    @property
    def per_second(self) -> float:
        return self.completed / self.seconds


def steps_per_second(link: ControllerLink, statuses: Statuses, count: int) -> Rate:
    """Sustained rate of tiny steps (1 distance unit) completed through the bridge, fed in
    batches that fit the bridge's lane (more would be refused ``queue_full``). A batch
    the link cuts short (a step aborted or refused) counts what completed; the next
    batch waits for the link's new session.

    Raises:
        TimeoutError: no step completed within 30 s, or more batches lost than kept.
    """
    batch = min(count, link.config.lane_limit)
    recover(link, statuses)
    t0 = time.monotonic()
    done = lost = 0
    while done < count:
        mark = statuses.mark()
        n = min(batch, count - done)
        for _ in range(n):
            link.submit_step(StepRequest(Command.FWD, 60, 1))
        statuses.log.until(partial(_cut_or_done, n), since=mark, timeout_s=30.0)
        completed = statuses.log.items(mark).count("completed")
        if completed < n:
            lost += 1
            # Every step of the batch has its fate before the next batch (a lost link
            # aborts them all at once; a refused one leaves the rest to complete).
            statuses.log.until(partial(_all_settled, n), since=mark, timeout_s=10.0)
            completed = statuses.log.items(mark).count("completed")
            done += completed
            if lost >= max(5, count // 10):
                break
            recover(link, statuses)
            continue
        done += completed
    return Rate(done, time.monotonic() - t0, lost)


def _link_line(label: str, link: ControllerLink, lost: int, trials: int) -> str:
    """One line of what the link went through in a case."""
    d = link.diagnostics()
    return (
        f"- {label}: {lost} of {trials} trials lost to the link; heartbeat losses "
        f"{d.heartbeat_losses}, watchdog trips {d.watchdog_trips}, reconnects {d.reconnects}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--trials", type=int, default=200, help="STOP trials per case (default 200)"
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--quick", action="store_true", help="3 trials per case, fewer samples (smoke test)"
    )
    parser.add_argument(
        "--ros2",
        action="store_true",
        help="add the ROS 2 case: the bridge on rclpy here, the STOP published by a plain "
        "rclpy node in another process (needs the private loopback network namespace)",
    )
    parser.add_argument("--stop-publisher", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--emulator-child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--rt-priority", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.stop_publisher:
        return stop_publisher()
    if args.emulator_child:
        return emulator_child(args.seed, args.rt_priority)
    if args.trials < 1:
        parser.error("--trials must be >= 1")
    trials, ros_trials = (3, 3) if args.quick else (args.trials, max(20, args.trials // 2))
    rtt_samples, steps = (200, 30) if args.quick else (2000, 300)
    # As rover bridge: the link's threads (started from here) keep time where permitted.
    realtime = apply_realtime(RealtimeConfig(BRIDGE_PRIORITY, lock_memory=False))
    use_short_switch_interval()  # as rover bridge does (firmware_proto/runtime/interpreter.py)
    rng = random.Random(args.seed)
    rover = load_rover()
    rows = [
        ("pty round trip (15 B there and back, pyserial)", summary(pty_round_trip(rtt_samples)))
    ]
    events: list[str] = []

    with EmulatorProcess(args.seed, EMULATOR_PRIORITY) as emu:
        statuses = Statuses()
        link = ControllerLink(LinkConfig(emu.device), on_status=statuses)
        with link:
            statuses.wait("ready", 0, timeout=SESSION_TIMEOUT_S)
            lost = 0
            for load in (False, True):
                got = _trials(emu, link, statuses, _api(link), trials, load, rng)
                lost += got.lost
                label = "load: queue full, telemetry 100 Hz" if load else "idle"
                rows.append((f"API call -> STOP written ({label})", summary(got.written)))
                rows.append((f"API call -> wheel targets zero ({label})", summary(got.zeroed)))
            rate = steps_per_second(link, statuses, steps)
            events.append(_link_line("API call", link, lost, 2 * trials))

    # The ROS path: another node publishes on emergency_stop; the bridge node relays.
    with EmulatorProcess(args.seed, EMULATOR_PRIORITY) as emu:
        params = load_params({"device": emu.device, "ros_backend": "inprocess"}, env={})
        with (
            open_port("inprocess", node_name="bridge", bus="bench") as bport,
            open_port("inprocess", node_name="operator", bus="bench") as oport,
        ):
            node = BridgeNode(params, bport)
            with node:
                statuses = Statuses()
                oport.subscribe("command_status", String, lambda m: statuses(m.data), qos.STATUS)
                estop = oport.publisher("emergency_stop", Bool, qos.STOP)
                oport.publisher("wheel_instructions", Int16MultiArray)
                statuses.wait("ready", 0, timeout=SESSION_TIMEOUT_S)
                lost = 0
                for load in (False, True):
                    got = _trials(
                        emu,
                        node.link,
                        statuses,
                        _published(estop.publish),
                        ros_trials,
                        load,
                        rng,
                    )
                    lost += got.lost
                    label = "load" if load else "idle"
                    rows.append(
                        (
                            f"ROS message (in-process) -> STOP written ({label})",
                            summary(got.written),
                        )
                    )
                    rows.append(
                        (
                            f"ROS message (in-process) -> wheel targets zero ({label})",
                            summary(got.zeroed),
                        )
                    )
                events.append(
                    _link_line("ROS message (in-process)", node.link, lost, 2 * ros_trials)
                )

    ros2_note = ""
    if args.ros2:
        from benchmarks.bench_rosport import in_private_loopback_namespace

        private, why = in_private_loopback_namespace()
        if private:
            for backend in ROS2_BACKENDS:
                rows += _ros2_rows(rover, args.seed, ros_trials, rng, backend, events)
        else:
            ros2_note = f" ROS 2 case not run: not in a private loopback namespace ({why})."
    else:
        ros2_note = " ROS 2 case: run with --ros2 in the private network namespace (see --help)."

    print(
        table(
            "STOP latency through the bridge (real pty, emulator in real time in its own process)",
            rows,
            note=(
                "Thesis figure: 8.4 +/- 1.2 ms detection to activation. Target: p99 < 1 ms end to end "
                "over a pty. ROS 2 message latency alone: benchmarks/bench_rosport.py."
                + ros2_note
                + f" This process: {realtime.line()}; the emulator's process asks for "
                f"priority {EMULATOR_PRIORITY}."
            ),
        )
    )
    print("\nThe link during the run (a lost trial is counted, not measured):")
    print("\n".join(events))
    print(
        f"\nSustained steps through the bridge: {rate.per_second:,.0f} steps/s (tiny FWD steps, "
        f"ack + completion each; {rate.completed} completed, {rate.lost_batches} batches cut "
        "short by the link)"
    )
    return 0


def stop_publisher() -> int:
    """Child process of the ROS 2 case: a plain rclpy node (none of our code) that
    publishes ``emergency_stop`` once per ``go`` line on stdin and answers with the
    ``time.monotonic()`` it published at."""
    import rclpy
    import rclpy.utilities
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Bool as RosBool

    rclpy.init()
    try:
        node = rclpy.create_node("operator")
        estop = node.create_publisher(
            RosBool, "emergency_stop", QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        )
        deadline = time.monotonic() + 30.0
        while estop.get_subscription_count() < 1:
            if time.monotonic() > deadline:
                print("NOSUB", flush=True)
                return 1
            time.sleep(0.01)
        print("READY", flush=True)
        for line in sys.stdin:
            if line.strip() != "go":
                break
            t0 = time.monotonic()
            estop.publish(RosBool(data=True))
            print(repr(t0), flush=True)
        node.destroy_node()
    finally:
        rclpy.utilities.try_shutdown()
    return 0


def _ros2_rows(
    rover: RoverDescription,
    seed: int,
    trials: int,
    rng: random.Random,
    backend: str,
    events: list[str],
) -> list[tuple[str, dict[str, float]]]:
    """The bridge on ``backend`` (its STOP lane included); the STOP from a plain rclpy
    node in another process (at normal priority: an operator's); an observer subscribing
    to /odom. What the link went through is added to ``events``."""
    rows: list[tuple[str, dict[str, float]]] = []
    with EmulatorProcess(seed, EMULATOR_PRIORITY) as emu:
        params = load_params({"device": emu.device, "ros_backend": backend}, env={})
        with (
            open_port(backend, node_name="rover_bridge") as bport,
            open_port("rclpy", node_name="observer") as oport,
            BridgeNode(params, bport) as node,
        ):
            statuses = Statuses()
            oport.subscribe("command_status", String, lambda m: statuses(m.data), qos.STATUS)
            oport.subscribe("odom", Odometry, lambda _m: None, qos.SENSOR)
            child = subprocess.Popen(
                [*module_command_at_normal_priority("benchmarks.bench_bridge"), "--stop-publisher"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
            )
            try:
                assert child.stdin is not None
                assert child.stdout is not None
                stdin, stdout = child.stdin, child.stdout
                if readline_within(stdout, 60.0, "the ROS 2 STOP publisher").strip() != "READY":
                    raise RuntimeError("the ROS 2 STOP publisher did not match the bridge")
                deadline = time.monotonic() + 10.0
                while not node.link.ready and time.monotonic() < deadline:
                    time.sleep(0.01)

                def request() -> float:
                    stdin.write("go\n")
                    stdin.flush()
                    return float(readline_within(stdout, 10.0, "the ROS 2 STOP publisher"))

                lost = 0
                for load in (False, True):
                    got = _trials(emu, node.link, statuses, request, trials, load, rng, node)
                    lost += got.lost
                    label = "load" if load else "idle"
                    rows.append(
                        (
                            f"ROS 2 STOP -> bridge on {backend}: STOP callback ({label})",
                            summary(got.hops),
                        )
                    )
                    rows.append(
                        (
                            f"ROS 2 STOP -> bridge on {backend}: STOP written ({label})",
                            summary(got.written),
                        )
                    )
                    rows.append(
                        (
                            f"ROS 2 STOP -> bridge on {backend}: wheel targets zero ({label})",
                            summary(got.zeroed),
                        )
                    )
                events.append(_link_line(f"ROS 2 on {backend}", node.link, lost, 2 * trials))
            finally:
                if child.stdin is not None:
                    child.stdin.close()
                try:
                    child.wait(30)
                except subprocess.TimeoutExpired:
                    child.kill()
                    child.wait(10)
    return rows


if __name__ == "__main__":
    raise SystemExit(main())
