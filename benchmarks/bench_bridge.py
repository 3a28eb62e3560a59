"""STOP latency through the bridge, beside the pty round trip; sustained steps/s.

Run: ``.venv/bin/python -m benchmarks.bench_bridge [--trials N] [--quick] [--ros2]``

The emulator serves the controller on a real pty in real time, in a process of its own
as ``rover emulate`` does on a bench (in one process its control thread and the bridge
would share the interpreter lock, whose 5 ms switch interval adds tails that a real
controller never sees). The bridge's ControllerLink (and its ROS node) drives it. For
every trial the rover is moving, then a STOP is requested, and two latencies are taken
on CLOCK_MONOTONIC, which every process of the machine shares (``time.monotonic()``):

- (a) request -> the STOP frame's last byte written to the device by the bridge;
- (b) request -> the emulator's wheel targets at zero (its control thread handled it;
  the emulator process reports when).

The request is an API call (``ControllerLink.emergency_stop``) or a ROS message on
``emergency_stop`` published by another node: on the in-process port (same process), or
over real ROS 2 from another process's plain rclpy node (``--ros2``: the bridge node on
the ``rclpy-process`` backend, its default, and on ``rclpy`` in this process, Fast DDS
between the two; it needs the private loopback network namespace of the tests; the publisher stamps its request on the same clock). Idle means
one long step running; load means the motion queue full and telemetry at 100 Hz (over
ROS 2 also published as ``/odom`` to a subscriber in the observer node). The pty round
trip (15 bytes there and back through pyserial) is measured in the same run: it is the
floor for (b). The thesis reports 8.4 +/- 1.2 ms; the target is p99 < 1 ms.

Run the ROS 2 case inside the namespace::

    unshare -n -- bash -c 'ip link set lo up && ip link set lo multicast on &&
        exec .venv/bin/python -m benchmarks.bench_bridge --ros2'
"""

from __future__ import annotations

import argparse
import functools
import random
import select
import subprocess
import sys
import time
from collections.abc import Callable
from functools import partial
from typing import IO

from benchmarks.common import pty_round_trip, summary, table
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
from firmware_proto.runtime.realtime import RealtimeConfig, apply_realtime
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

    def mark(self) -> int:
        return self.log.mark()


HOPS: list[float] = []
#: The bridge's backends in the ROS 2 case: the default (the node in a child process)
#: beside the node in the bridge's process, so the table shows what the extra hop costs.
ROS2_BACKENDS = ("rclpy-process", "rclpy")
"""Request -> the bridge node's STOP callback, per trial of the last ROS case, s."""

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


def _readline(stream: IO[str], timeout_s: float, what: str) -> str:
    """One line from a child process's stdout (each of our children answers one line per
    request, so nothing waits in the reader's buffer), or TimeoutError."""
    ready, _, _ = select.select([stream], [], [], timeout_s)
    if not ready:
        raise TimeoutError(f"no answer from {what} within {timeout_s} s")
    return stream.readline()


class EmulatorProcess:
    """The emulator serving a pty in a child process (``--emulator-child``), driven over
    its stdin and stdout: one command line, one answer line."""

    def __init__(self, seed: int, rt_priority: int = 0) -> None:
        self._child = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "benchmarks.bench_bridge",
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
            first = _readline(self._stdout, 30.0, "the emulator process")
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
        answer = _readline(self._stdout, 30.0, "the emulator process").strip()
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
) -> tuple[list[float], list[float]]:
    """STOP trials; the two latencies of each (see the module docstring). With ``node``,
    ``HOPS`` also gets, per trial, request -> the node's STOP callback."""
    written, zeroed = [], []
    HOPS.clear()
    emu.telemetry(100 if load else 50)
    for _ in range(trials):
        mark = statuses.mark()
        for _ in range(8 if load else 1):
            link.submit_step(StepRequest(Command.FWD, 60, 30000))
        statuses.wait("accepted", mark)
        time.sleep(rng.uniform(0.05, 0.25))  # STOP at a random moment of the motion
        before, previous = emu.stops(), link.last_stop_written
        t0 = request()
        handled = emu.stop_handled(before)
        # The emulator may handle the STOP a moment before the writing thread stamps it.
        deadline = time.monotonic() + 1.0
        while link.last_stop_written == previous and time.monotonic() < deadline:
            time.sleep(0.0005)
        written_at = link.last_stop_written
        if written_at is not None and written_at != previous and handled is not None:
            written.append(written_at - t0)
            zeroed.append(handled - t0)
            if node is not None and node.last_estop_received is not None:
                HOPS.append(node.last_estop_received - t0)
        mark = statuses.mark()
        link.clear_stop()
        statuses.wait("cleared", mark)
    return written, zeroed


def _completed_at_least(n: int, statuses: list[str]) -> bool:
    return statuses.count("completed") >= n


def steps_per_second(link: ControllerLink, statuses: Statuses, count: int) -> float:
    """Sustained rate of tiny steps (1 distance unit) completed through the bridge, fed in
    batches that fit the bridge's lane (more would be refused ``queue_full``)."""
    batch = min(count, link.config.lane_limit)
    t0 = time.monotonic()
    done = 0
    while done < count:
        mark = statuses.mark()
        n = min(batch, count - done)
        for _ in range(n):
            link.submit_step(StepRequest(Command.FWD, 60, 1))
        if not statuses.log.until(
            functools.partial(_completed_at_least, n), since=mark, timeout_s=30.0
        ):
            got = statuses.log.items(mark).count("completed")
            raise TimeoutError(f"only {got}/{n} steps completed")
        done += n
    return count / (time.monotonic() - t0)


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
    use_short_switch_interval()  # as rover bridge does (firmware_proto/runtime/interpreter.py)
    rng = random.Random(args.seed)
    rover = load_rover()
    rows = [
        ("pty round trip (15 B there and back, pyserial)", summary(pty_round_trip(rtt_samples)))
    ]

    with EmulatorProcess(args.seed) as emu:
        statuses = Statuses()
        link = ControllerLink(LinkConfig(emu.device), on_status=statuses)
        with link:
            statuses.wait("ready", 0)
            for load in (False, True):
                written, zeroed = _trials(emu, link, statuses, _api(link), trials, load, rng)
                label = "load: queue full, telemetry 100 Hz" if load else "idle"
                rows.append((f"API call -> STOP written ({label})", summary(written)))
                rows.append((f"API call -> wheel targets zero ({label})", summary(zeroed)))
            rate = steps_per_second(link, statuses, steps)

    # The ROS path: another node publishes on emergency_stop; the bridge node relays.
    with EmulatorProcess(args.seed) as emu:
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
                statuses.wait("ready", 0)
                for load in (False, True):
                    written, zeroed = _trials(
                        emu,
                        node.link,
                        statuses,
                        _published(estop.publish),
                        ros_trials,
                        load,
                        rng,
                    )
                    label = "load" if load else "idle"
                    rows.append(
                        (f"ROS message (in-process) -> STOP written ({label})", summary(written))
                    )
                    rows.append(
                        (
                            f"ROS message (in-process) -> wheel targets zero ({label})",
                            summary(zeroed),
                        )
                    )

    ros2_note = ""
    if args.ros2:
        from benchmarks.bench_rosport import in_private_loopback_namespace

        private, why = in_private_loopback_namespace()
        if private:
            for backend in ROS2_BACKENDS:
                rows += _ros2_rows(rover, args.seed, ros_trials, rng, backend)
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
                "over a pty. ROS 2 message latency alone: benchmarks/bench_rosport.py." + ros2_note
            ),
        )
    )
    print(
        f"\nSustained steps through the bridge: {rate:,.0f} steps/s (tiny FWD steps, ack + completion each)"
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
    rover: RoverDescription, seed: int, trials: int, rng: random.Random, backend: str
) -> list[tuple[str, dict[str, float]]]:
    """The bridge on ``backend`` (its STOP lane included); the STOP from a plain rclpy
    node in another process; an observer subscribing to /odom."""
    rows: list[tuple[str, dict[str, float]]] = []
    with EmulatorProcess(seed) as emu:
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
                [sys.executable, "-m", "benchmarks.bench_bridge", "--stop-publisher"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
            )
            try:
                assert child.stdin is not None
                assert child.stdout is not None
                stdin, stdout = child.stdin, child.stdout
                if _readline(stdout, 60.0, "the ROS 2 STOP publisher").strip() != "READY":
                    raise RuntimeError("the ROS 2 STOP publisher did not match the bridge")
                deadline = time.monotonic() + 10.0
                while not node.link.ready and time.monotonic() < deadline:
                    time.sleep(0.01)

                def request() -> float:
                    stdin.write("go\n")
                    stdin.flush()
                    return float(_readline(stdout, 10.0, "the ROS 2 STOP publisher"))

                for load in (False, True):
                    written, zeroed = _trials(
                        emu, node.link, statuses, request, trials, load, rng, node
                    )
                    label = "load" if load else "idle"
                    rows.append(
                        (
                            f"ROS 2 STOP -> bridge on {backend}: STOP callback ({label})",
                            summary(list(HOPS)),
                        )
                    )
                    rows.append(
                        (
                            f"ROS 2 STOP -> bridge on {backend}: STOP written ({label})",
                            summary(written),
                        )
                    )
                    rows.append(
                        (
                            f"ROS 2 STOP -> bridge on {backend}: wheel targets zero ({label})",
                            summary(zeroed),
                        )
                    )
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
