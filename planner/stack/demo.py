"""The end-to-end demo: every part of the stack, on one machine, driving a mission.

:class:`Demo` starts the parts as ``rover stack up`` does
(:class:`planner.stack.processes.Stack`: gate, emulator on a pty, bridge, link relay,
real ROS 2 kept on this host) and runs the ground station in this process. The mission
(docs/ground.md): a plan around the lab's table, slip after a chosen step, a drift STOP,
a re-plan from the reported pose, the goal; then a summary and a picture.

:meth:`Demo.cancel` (SIGINT, SIGTERM) ends the mission through the executor's cancel
path (STOP; ``cancelled``); before the mission runs the caller interrupts the start-up
instead, and :meth:`Demo.close` stops what was started.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import math
import os
import socket
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

from bridge.ros.rosport import DEFAULT_BACKEND, TAP_RECEIVED, RosPort, open_port
from bridge.ros.rosport.msgs import DiagnosticArray, stamp_s
from bridge.ros.rosport.qos import DIAGNOSTICS
from bridge.ros.rosport.rclpy_backend import middleware
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import WorldMap
from firmware_proto.runtime.stall import STALL_LOG_ENV
from planner.ground.executor import ExecutionProgress, ExecutionResult, ExecutorConfig, PlanExecutor
from planner.ground.mission import MissionReport, MissionRunner
from planner.ground.onboard import OnboardExecutor, UplinkOptions
from planner.ground.overshoot import Overshoot, overshoot
from planner.plan.gate_client import GateClient, GateOptions
from planner.plan.orchestrator import MissionResult, PlannerOrchestrator
from planner.plan.planner import HeuristicLowLevelPlanner
from planner.record.foxlive import FoxgloveLive
from planner.record.mcaprec import McapRecorder
from planner.record.picture import picture_of, save
from planner.stack.domains import claim
from planner.stack.processes import Stack, StackConfig
from planner.stack.stackenv import DOMAIN_ENV
from planner.view.live import LiveView
from planner.view.server import ViewConfig

__all__ = ["LOCALHOST_ENV", "Demo", "DemoConfig", "DemoResult", "LinkTiming"]

logger = logging.getLogger(__name__)

LOCALHOST_ENV = "ROS_AUTOMATIC_DISCOVERY_RANGE"
"""ROS 2 Jazzy's discovery range variable; the demo sets it to ``LOCALHOST``."""


@dataclass(frozen=True)
class DemoConfig:
    """What the demo runs.

    ``rtt_s``, ``jitter_s``, ``loss``, ``speed``, ``seed``, ``firmware``,
    ``controller``, ``realtime``, ``ground``, ``twin`` and ``startup_timeout_s`` are
    :class:`~planner.stack.processes.StackConfig`'s (the planner also turns by ``twin``).

    Attributes:
        map_name, goal_name: the lab map and its goal behind the table.
        slip: the fault injected once step ``slip_after_step`` (0-based) has completed;
            ``None`` drives without slip.
        picture: where to write the PNG.
        progress_every_s: most frequent progress line while a step runs, mission s.
        record: the MCAP file to record the mission in (``None``: none).
        view: serve the live view so (``None``: no view); prints ``VIEW <url>``.
        foxglove_port: serve Foxglove live on this loopback port (0: a free one;
            ``None``: not); prints ``FOXGLOVE <url>``.
        replans: drift STOPs after which the mission is re-planned.
        step_by_step: the thesis's step-by-step executor instead of on board.
        samples, max_collision_p: approve a plan only if at most ``max_collision_p`` of
            ``samples`` twins from the gate's uncertainty collide (``None``: the nominal
            verdict decides).
    """

    rtt_s: float = 3.0
    jitter_s: float = 0.0
    loss: float = 0.0
    speed: float = 1.0
    map_name: str = "lab"
    goal_name: str = "behind_table"
    slip: str | None = "slip:left=0.05"
    slip_after_step: int = 0
    seed: int = 1
    picture: Path = Path("demo.png")
    startup_timeout_s: float = 60.0
    progress_every_s: float = 4.0
    record: Path | None = Path("demo.mcap")
    view: ViewConfig | None = None
    foxglove_port: int | None = None
    firmware: str = "python"
    controller: str = "emulator"
    realtime: bool = True
    ground: str | None = None
    twin: Path | None = None
    replans: int = 1
    step_by_step: bool = False
    samples: int | None = None
    max_collision_p: float | None = None


@dataclass(frozen=True)
class DemoResult:
    """The mission report, the picture, whether drift control fired, the MCAP recording
    (``None`` when not recorded) and how the link kept time (:class:`LinkTiming`)."""

    report: MissionReport
    picture: Path
    drift_fired: bool
    recording: Path | None = None
    timing: LinkTiming | None = None
    physical: tuple[tuple[Overshoot, Overshoot], ...] = ()
    """Per drift stop, how far and long the rover went on past the limit, as drift control saw
    it and from its own ``odom_ground`` off the approved path (:mod:`planner.ground.overshoot`)."""


@dataclass(frozen=True)
class LinkTiming:
    """How regularly the two ends of the controller link heard each other, wall ms
    (``None``: not measured), read at the end of the mission: the bridge's from its last
    ``/diagnostics``, the emulator's from its control port.

    Attributes:
        bridge_rx_max_ms, bridge_rx_p99_ms: gaps between controller heartbeats the
            bridge received.
        bridge_tx_max_ms, bridge_tx_p99_ms: gaps between host heartbeats it sent.
        emulator_rx_max_ms, emulator_rx_p99_ms: gaps between host heartbeats the
            emulator received.
        emulator_catchups, emulator_late_max_ms: times the emulator's control loop woke
            late, and the latest.
        bridge_stall_max_ms: the bridge's longest stall.
    """

    bridge_rx_max_ms: float | None = None
    bridge_rx_p99_ms: float | None = None
    bridge_tx_max_ms: float | None = None
    bridge_tx_p99_ms: float | None = None
    emulator_rx_max_ms: float | None = None
    emulator_rx_p99_ms: float | None = None
    emulator_catchups: int | None = None
    emulator_late_max_ms: float | None = None
    bridge_stall_max_ms: float | None = None

    def line(self) -> str:
        """One line for the summary."""

        def ms(value: float | None) -> str:
            return "n/a" if value is None else f"{value:.0f}"

        return (
            "link timing (heartbeat gaps, max/p99 ms): bridge rx "
            f"{ms(self.bridge_rx_max_ms)}/{ms(self.bridge_rx_p99_ms)}, bridge tx "
            f"{ms(self.bridge_tx_max_ms)}/{ms(self.bridge_tx_p99_ms)}, emulator rx "
            f"{ms(self.emulator_rx_max_ms)}/{ms(self.emulator_rx_p99_ms)}; emulator "
            f"catch-ups {self.emulator_catchups if self.emulator_catchups is not None else 'n/a'}"
            f" (latest {ms(self.emulator_late_max_ms)} ms); bridge's longest stall "
            f"{ms(self.bridge_stall_max_ms)} ms"
        )


def _control(port: int, command: str) -> str:
    """One command to the emulator's control interface (as the lab's bench would)."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        sock.sendall(command.encode() + b"\n")
        return sock.makefile().readline().strip()


class Demo:
    """Starts the parts, runs the mission, stops everything (a context manager)."""

    def __init__(
        self, config: DemoConfig | None = None, say: Callable[[str], None] = print
    ) -> None:
        self.config = config or DemoConfig()
        self._say = say
        self._t0 = time.monotonic()
        # Every process of the demo discovers ROS 2 peers on this host only.
        self.logs = Path(tempfile.mkdtemp(prefix="rover-demo-logs-"))
        """Where each process's stderr and the stack's stall log are kept (not removed)."""
        self.stall_log = self.logs / "stalls.jsonl"
        """The stall log every process of this demo writes to (docs/realtime.md)."""
        self._env = {
            **os.environ,
            LOCALHOST_ENV: "LOCALHOST",
            STALL_LOG_ENV: str(self.stall_log),
        }
        self._diagnostics: DiagnosticArray | None = None
        self._cancel = threading.Event()
        self._mission_running = False
        self._view: LiveView | None = None
        self._hold = threading.Event()
        self._holding = False
        self._stack: Stack | None = None
        self._domains = contextlib.ExitStack()

    @property
    def mission_running(self) -> bool:
        """The mission has started: :meth:`cancel` now stops the rover."""
        return self._mission_running

    def cancel(self) -> None:
        """End the mission (from a signal handler or another thread): the running plan
        ends with STOP, nothing more is sent, the report says ``cancelled``."""
        self._cancel.set()

    @property
    def view_url(self) -> str | None:
        """The live view's address, once it serves."""
        return self._view.url if self._view is not None else None

    @property
    def holding(self) -> bool:
        """:meth:`hold` is waiting (:meth:`end_hold` ends it)."""
        return self._holding

    def hold(self, seconds: float) -> None:
        """Keep everything up (the view serving, the parts running) for ``seconds`` or
        until :meth:`end_hold`."""
        self._holding = True
        try:
            self._hold.wait(seconds)
        finally:
            self._holding = False

    def end_hold(self) -> None:
        """End :meth:`hold` (from a signal handler or another thread)."""
        self._hold.set()

    def say(self, line: str) -> None:
        """Print one line with the mission time (and show it in the view)."""
        self._say(f"[{(time.monotonic() - self._t0) * self.config.speed:6.1f} s] {line}")
        if self._view is not None:
            self._view.hub.event(line)

    def _uplink_token(self) -> str | None:
        """The stack's uplink token (its onboard program checks plans with it)."""
        return self._stack.uplink_token if self._stack is not None else None

    def _view_clear(self, executor: PlanExecutor) -> bool:
        """The view's clear-STOP (the hub allowed it): only while the mission runs."""
        if not self._mission_running:
            raise RuntimeError("the mission has ended")
        self.say("clear-STOP from the view: releasing the latch")
        return executor.clear_stop()

    def _view_stop(self) -> str:
        """The view's STOP button: what Ctrl-C does."""
        if self._mission_running:
            self.cancel()
            self.say("STOP from the view: cancelling the mission; sending STOP")
            return "sent: the running step ends with STOP, the mission is cancelled"
        if self._holding:
            return "the mission has ended: no plan is running, nothing was sent"
        self.cancel()
        self.say("STOP from the view before the mission: nothing will be sent to the rover")
        return "the mission is cancelled before it starts: nothing will be sent"

    def run(self) -> DemoResult:
        """Start everything, drive the mission, return the result."""
        cfg = self.config
        if cfg.speed <= 0 or cfg.rtt_s < 0:
            raise ValueError("speed must be > 0 and rtt_s >= 0")
        stack = StackConfig(
            map_name=cfg.map_name,
            firmware=cfg.firmware,
            controller=cfg.controller,
            rtt_s=cfg.rtt_s,
            jitter_s=cfg.jitter_s,
            loss=cfg.loss,
            speed=cfg.speed,
            seed=cfg.seed,
            startup_timeout_s=cfg.startup_timeout_s,
            realtime=cfg.realtime,
            ground=cfg.ground,
            twin=cfg.twin,
        )
        if not os.environ.get(DOMAIN_ENV, "").strip():
            # No domain chosen: one of its own, so two demos or stacks never hear each other.
            domain = self._domains.enter_context(claim()).domain
            self._domains.callback(os.environ.pop, DOMAIN_ENV, None)
            os.environ[DOMAIN_ENV] = self._env[DOMAIN_ENV] = str(domain)
            self.say(f"ROS 2 domain {domain} (of its own)")
        self.say(stack.link_line())
        self._stack = Stack(stack, self._env, say=self.say, logs=self.logs)
        endpoints = self._stack.start()
        url = endpoints.gate_url
        control_port = int(endpoints.control.rsplit(":", 1)[1])
        self.say(f"emulator control port: 127.0.0.1:{control_port}")
        rover = load_rover(cfg.twin)
        os.environ[LOCALHOST_ENV] = "LOCALHOST"  # read when the port's context starts
        self.say(f"ROS 2 middleware: {middleware()}")
        recorder = McapRecorder(cfg.record) if cfg.record is not None else None
        try:
            return self._drive(url, control_port, rover, recorder)
        finally:
            if recorder is not None:
                recorder.close()

    def _drive(
        self, url: str, control_port: int, rover: RoverDescription, recorder: McapRecorder | None
    ) -> DemoResult:
        cfg = self.config
        with (
            GateClient(url) as client,
            open_port(DEFAULT_BACKEND, namespace="ground", node_name="rover_executor") as port,
        ):
            if recorder is not None:
                recorder.attach(port)
            port.subscribe("diagnostics", DiagnosticArray, self._on_diagnostics, DIAGNOSTICS)
            foxglove = (
                FoxgloveLive(port=cfg.foxglove_port) if cfg.foxglove_port is not None else None
            )
            try:
                return self._mission(client, port, rover, control_port, recorder, foxglove)
            finally:
                if foxglove is not None:
                    foxglove.close()

    def _mission(
        self,
        client: GateClient,
        port: RosPort,
        rover: RoverDescription,
        control_port: int,
        recorder: McapRecorder | None,
        foxglove: FoxgloveLive | None,
    ) -> DemoResult:
        cfg = self.config
        if foxglove is not None:
            port.add_tap(foxglove.tap)
            self._say(f"FOXGLOVE {foxglove.url}")
        world = client.get_map(cfg.map_name)
        goal = _goal(world, cfg.goal_name)
        if recorder is not None:
            recorder.set_map(world, goal)
        start = world.start
        orchestrator = PlannerOrchestrator(
            HeuristicLowLevelPlanner(rover, world=world),
            client,
            map_name=cfg.map_name,
            world=world,
            options=GateOptions(samples=cfg.samples),
            max_collision_p=cfg.max_collision_p,
        )
        exec_config = ExecutorConfig(link_rtt_s=cfg.rtt_s / cfg.speed, time_scale=cfg.speed)
        executor = (
            PlanExecutor(port, rover, exec_config)
            if cfg.step_by_step
            else OnboardExecutor(
                port, rover, exec_config, UplinkOptions(token=self._uplink_token())
            )
        )
        ground_poses: list[tuple[float, float, float]] = []

        def keep_pose(direction: str, topic: str, msg: Any) -> None:
            # What the recording keeps too: the rover's stamped ground-seeing POSE.
            if direction == TAP_RECEIVED and topic.endswith("/odom_ground"):
                p = msg.pose.pose.position
                ground_poses.append((stamp_s(msg.header.stamp), p.x, p.y))

        port.add_tap(keep_pose)
        if cfg.view is not None:
            self._view = LiveView(
                world,
                cfg.view,
                rtt_s=cfg.rtt_s / cfg.speed,
                time_scale=cfg.speed,
                on_stop=self._view_stop,
                on_clear=lambda: self._view_clear(executor),
                drift_source=lambda: executor.latest_drift,
            )
            port.add_tap(self._view.hub.tap)
            self._say(f"VIEW {self._view.url}")
            if cfg.view.wait_s > 0:
                self.say(f"waiting up to {cfg.view.wait_s:g} s for a browser to open the view")
                if self._view.hub.wait_for_client(cfg.view.wait_s):
                    self.say("view: a browser is watching")
        view = self._view

        def planned(mission: MissionResult) -> None:
            if cfg.slip and mission.approved and not slipped.is_set():
                # The slip starts by distance travelled (the emulator's trigger), however
                # the steps reach it (step by step, on board).
                slipped.set()
                at_m = slip_distance_m(mission.verdicts[0], cfg.slip_after_step)
                answer = _control(control_port, f"inject {cfg.slip}@d={at_m:.3f}")
                self.say(f"SCHEDULING {cfg.slip} on the rover after {at_m:.2f} m: {answer}")
            if recorder is not None:
                recorder.planned(mission)
            if foxglove is not None:
                foxglove.planned(mission)
            if view is not None:
                view.hub.planned(mission)

        slipped = threading.Event()
        try:
            self.say(f"waiting for the rover to report (round trip {cfg.rtt_s:g} s)")
            if executor.settled_pose(cfg.startup_timeout_s) is None:
                raise RuntimeError("the rover never reported its pose through the link")
            self.say(
                f"mission: ({start.x:.1f}, {start.y:.1f}) -> goal '{cfg.goal_name}' "
                f"({goal.x:.1f}, {goal.y:.1f}, {goal.yaw_deg:.0f} deg), behind the table"
            )
            last_line = [-math.inf]

            def progress(p: ExecutionProgress) -> None:
                if view is not None:
                    view.hub.progress(p)
                now = time.monotonic() * cfg.speed
                if p.final or now - last_line[0] >= cfg.progress_every_s:
                    last_line[0] = now
                    self.say(p.line(cfg.speed))

            def out_of_the_sand(result: ExecutionResult) -> None:
                if cfg.slip:
                    answer = _control(control_port, "inject clear:slip")
                    self.say(f"operator: traction back ({answer}); re-planning (still latched)")

            runner = MissionRunner(
                orchestrator,
                executor,
                replans=cfg.replans,
                on_progress=progress,
                on_drift=out_of_the_sand,
                on_event=self.say,
                cancel=self._cancel,
                on_planned=planned,
            )
            self._mission_running = True
            try:
                report = runner.run(goal, start=start)
            finally:
                self._mission_running = False
        finally:
            executor.close()
        if view is not None:
            view.hub.result(report.reached, report.summary(cfg.speed).splitlines()[0])
        outcome = (
            "goal reached"
            if report.reached
            else "cancelled"
            if report.cancelled
            else "goal not reached"
        )
        title = (
            f"rover demo: {outcome}; {len(report.drift_events)} drift STOP(s); RTT {cfg.rtt_s:g} s"
        )
        picture = picture_of(report, world, title)
        path = save(picture, cfg.picture)
        timing = self._timing(control_port)
        physical = tuple(
            figure
            for run in report.runs
            if run.execution.drift is not None and run.verdict is not None
            for figure in [
                _physical(run.verdict, run.execution, ground_poses, cfg.rtt_s, cfg.speed)
            ]
            if figure is not None
        )
        return DemoResult(report, path, bool(report.drift_events), cfg.record, timing, physical)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        if any(status.name == "rover_bridge: link" for status in msg.status):
            self._diagnostics = msg

    def _timing(self, control_port: int) -> LinkTiming:
        """The link's timing figures at the end of the mission (see :class:`LinkTiming`)."""
        values: dict[str, str] = {}
        if self._diagnostics is not None:
            for status in self._diagnostics.status:
                if status.name == "rover_bridge: link":
                    values = {kv.key: kv.value for kv in status.values}

        def number(key: str) -> float | None:
            try:
                return float(values[key])
            except (KeyError, ValueError):
                return None

        emulator: dict[str, Any] = {}
        try:
            answer = json.loads(_control(control_port, "status"))
            emulator = answer.get("status") or {}
        except (OSError, ValueError) as exc:
            logger.warning("emulator status unavailable: %s", exc)
        host_gaps = emulator.get("host_heartbeat_gaps") or {}
        return LinkTiming(
            bridge_rx_max_ms=number("heartbeat_rx_gap_max_ms"),
            bridge_rx_p99_ms=number("heartbeat_rx_gap_p99_ms"),
            bridge_tx_max_ms=number("heartbeat_tx_gap_max_ms"),
            bridge_tx_p99_ms=number("heartbeat_tx_gap_p99_ms"),
            emulator_rx_max_ms=host_gaps.get("max_ms"),
            emulator_rx_p99_ms=host_gaps.get("p99_ms"),
            emulator_catchups=emulator.get("catchups"),
            emulator_late_max_ms=emulator.get("late_max_ms"),
            bridge_stall_max_ms=number("stall_max_ms"),
        )

    def close(self) -> None:
        """Stop the view and every process, last started first (idempotent)."""
        if self._view is not None:
            self._view.close()
        if self._stack is not None:
            self._stack.close()
        self._domains.close()

    def __enter__(self) -> Demo:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def slip_distance_m(verdict: Verdict, step: int) -> float:
    """How far the rover's centre travels, predicted, to the end of ``step``, plus 5 cm:
    where the demo's slip starts (the emulator's ``@d=`` trigger)."""
    points = [(s.pose.x, s.pose.y) for s in verdict.trajectory.samples if s.step <= step]
    return sum(math.dist(a, b) for a, b in itertools.pairwise(points)) + 0.05


def _physical(
    verdict: Verdict,
    execution: ExecutionResult,
    poses: list[tuple[float, float, float]],
    rtt_s: float,
    speed: float,
) -> tuple[Overshoot, Overshoot] | None:
    """The drift stop's figures from the poses the rover stamped while it ran this plan
    and until the ground could have sent anything after the stop (a round trip later:
    the rover stood latched meanwhile)."""
    assert execution.drift is not None
    detected = execution.drift.t_s
    path = [(s.pose.x, s.pose.y) for s in verdict.trajectory.samples]
    during = [
        p for p in poses if detected - execution.elapsed_s <= p[0] <= detected + 0.9 * rtt_s / speed
    ]
    by_drift = overshoot(path, during, crossing_s=detected, time_scale=speed)
    by_path = overshoot(path, during, time_scale=speed)
    return None if by_drift is None or by_path is None else (by_drift, by_path)


def _goal(world: WorldMap, name: str) -> Pose:
    try:
        return world.goal(name).pose
    except KeyError as exc:
        raise ValueError(exc.args[0]) from exc
