"""Missions driven in lockstep and heard as a real mission is, for calibration runs.

A real recording (``rover go --record``) is made by the ground station's port: it hears
the steps it publishes and, after the link's one-way delay, what the bridge publishes
from the controller's telemetry. :func:`drive_lockstep` produces the same messages
without real time: the controller model (:class:`emulator.controller.ControllerModel`) drives its
twin tick by tick on a ground of its own; the host's side of the bridge runs in process
(the bridge's own :class:`~bridge.link.odometry.OdometryEstimator` and
:func:`~bridge.link.odometry.ground_pose`, the ``odom`` and ``odom_ground`` messages built as
``bridge/ros/node.py`` builds them); the executor's pacing is kept (a step is sent when the
previous one's ``completed`` has crossed the link, so the rover rests a round trip
between steps); and every message gets the log time at which the ground station would
have heard it (downlink: the rover's time plus the one-way delay; uplink: the time the
rover received it minus the delay). :func:`planner.record.mcaprec.record_messages`
writes them as a recording (the calibration's tests and benchmark do; ``sim`` sits
below the planner and does not import it). :class:`LockstepRover` keeps one rover from
plan to plan, drives a plan back to back as it runs on board too, and is the driver of
a designed calibration (``rover calibrate --drive``) in virtual time: each plan validated
by the gate's own :class:`gate.validator.Validator` in process
(:func:`validate_with_gate`), each recording written by the caller's recorder.

What is left out of a real run: the serial link and its framing, ROS 2 transport, and
wall-clock jitter. ``tests/emulator/test_calibrate_e2e.py`` calibrates from a real run.
"""

from __future__ import annotations

import math
import random
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bridge.link.odometry import OdometryEstimator, ground_pose
from bridge.ros.odommsg import ground_odometry, wheel_odometry
from bridge.ros.rosport.msgs import (
    Int16MultiArray,
    String,
    stamp,
)
from emulator.campaign import Driven
from emulator.controller import ControllerConfig, ControllerModel
from emulator.ground import Ground
from emulator.twin import Pose2D, Twin
from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Pose as PlanPose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    AbortReason,
    Ack,
    AckResult,
    Command,
    Encoders,
    Hello,
    HostHeartbeat,
    Imu,
    Motion,
    PoseMsg,
    StepState,
    WheelSpeeds,
)
from firmware_proto.wire.messages import Status as StatusMsg
from gate.options import ValidateOptions
from gate.validator import Validator

__all__ = [
    "EPOCH_S",
    "LockstepMission",
    "LockstepRover",
    "drive_lockstep",
    "field_map",
    "random_mission",
    "validate_with_gate",
]

EPOCH_S = 1_800_000_000.0
"""Wall time of twin time 0 in the recordings (any fixed value will do)."""

HOST_HEARTBEAT_S = 0.1
"""The host's heartbeat period (the controller's watchdog is 250 ms)."""


def field_map(size_m: float = 40.0) -> WorldMap:
    """An open field, ``size_m`` square, no obstacles, start at its centre facing east:
    room for any 12-step mission of :func:`random_mission`."""
    half = size_m / 2.0
    return WorldMap.from_dict(
        {
            "name": "field",
            "description": "an open field for calibration runs",
            "bounds": {"min_x": 0.0, "min_y": 0.0, "max_x": size_m, "max_y": size_m},
            "obstacles": [],
            "traction_regions": [],
            "start": {"x": half, "y": half, "yaw_deg": 0.0},
        },
        "field",
    )


def random_mission(
    rover: RoverDescription,
    rng: random.Random,
    steps: int = 12,
    *,
    max_driving_s: float | None = None,
) -> list[tuple[int, int, int]]:
    """Seeded steps alternating straight lines (FWD mostly, some REV; 0.3-1.6 m at
    speed 15-60) and turns on the spot (LEFT or RIGHT, 20-150 degrees by the rover
    description's turn model, speed 15-45). With ``max_driving_s``, steps stop being
    added before their nominal durations would pass it."""
    out: list[tuple[int, int, int]] = []
    total = 0.0
    turn_next = rng.random() < 0.5
    while len(out) < steps:
        if turn_next:
            command = Command.LEFT if rng.random() < 0.5 else Command.RIGHT
            speed = rng.randint(15, 45)
            distance = rover.turn_units_for_yaw(math.radians(rng.uniform(20.0, 150.0)))
        else:
            command = Command.FWD if rng.random() < 0.75 else Command.REV
            speed = rng.randint(15, 60)
            distance = rover.m_to_units(rng.uniform(0.3, 1.6))
        turn_next = not turn_next
        duration = rover.step_duration_s(speed, distance)
        if max_driving_s is not None and total + duration > max_driving_s:
            break
        total += duration
        out.append((int(command), speed, min(distance, rover.drive.max_distance)))
    return out


@dataclass(frozen=True)
class LockstepMission:
    """A lockstep mission and what the ground station would have heard of it.

    Attributes:
        messages: ``(log time ns, topic, ROS message)`` in time order (what
            :func:`planner.record.mcaprec.record_messages` writes).
        steps: the steps driven.
        start, final: the twin's true pose before the first step and at the end.
        driving_s: twin time spent executing steps (rests excluded).
        completed: steps that completed.
    """

    messages: tuple[tuple[int, str, Any], ...]
    steps: tuple[tuple[int, int, int], ...]
    start: Pose2D
    final: Pose2D
    driving_s: float
    completed: int


class _Host:
    """The bridge's telemetry side and the link's delay, in process."""

    def __init__(self, rover: RoverDescription, one_way_delay_s: float) -> None:
        self.odometry = OdometryEstimator(rover)
        self.delay_s = one_way_delay_s
        self.events: list[tuple[int, str, Any]] = []
        self.completed_at: float | None = None
        self.ended = ""

    def _down(self, t_s: float, topic: str, msg: Any) -> None:
        self.events.append((round((EPOCH_S + t_s + self.delay_s) * 1e9), topic, msg))

    def up(self, t_s: float, topic: str, msg: Any) -> None:
        """A message the ground published, received by the rover at ``t_s``."""
        self.events.append((round((EPOCH_S + t_s - self.delay_s) * 1e9), topic, msg))

    def status(self, t_s: float, text: str) -> None:
        self._down(t_s, "/command_status", String(data=text))

    def feed(self, t_s: float, messages: list[Any]) -> None:
        """The controller's messages at twin time ``t_s``, as the bridge handles them."""
        for msg in messages:
            if isinstance(msg, Encoders):
                est = self.odometry.update_encoders(msg)
                when = stamp(EPOCH_S + t_s)
                self._down(t_s, "/odom", wheel_odometry(est, when, "odom", "base_link"))
            elif isinstance(msg, Imu):
                self.odometry.update_imu(msg)
            elif isinstance(msg, WheelSpeeds):
                self.odometry.update_speeds(msg)
            elif isinstance(msg, PoseMsg):
                pose = ground_pose(msg)
                if pose is None:
                    continue
                when = stamp(EPOCH_S + t_s - pose.age_s)
                self._down(t_s, "/odom_ground", ground_odometry(pose, when, "map", "base_link"))
            elif isinstance(msg, Ack):
                if msg.result == AckResult.ACCEPTED:
                    self.status(t_s, "accepted")
                else:
                    self.status(t_s, f"rejected:{AckResult(msg.result).name.lower()}")
                    self.ended = "rejected"
            elif isinstance(msg, StatusMsg):
                if msg.state == StepState.COMPLETED:
                    self.status(t_s, "completed")
                    self.completed_at = t_s
                    self.ended = "completed"
                elif msg.state == StepState.ABORTED:
                    self.status(t_s, f"aborted:{AbortReason(msg.reason).name.lower()}")
                    self.ended = "aborted"


class LockstepRover:
    """A rover in lockstep that keeps its state from plan to plan: the controller model
    on its own ground, the bridge's telemetry side and the link's delay in process. Each
    :meth:`drive_steps` drives one plan as ``rover go --record`` hears it (a rest before
    the first step, a round trip of rest between steps or none when back to back, a rest
    after the last); it is the driver (:class:`emulator.campaign.Driver`) of a designed
    calibration in virtual time when it has a ``validator`` (the gate's, in process) to
    validate each plan with and a ``recorder`` to write each plan's recording with.

    Args:
        rover: the rover description (the controller's, and the twin's but for the
            traction ``ground`` replaces).
        world: the map (``None``: an open plane).
        ground: the ground the rover really drives on (``None``: the description's).
        start: the true start pose (default: the map's start).
        seed: the controller's seed (sensor noise).
        rtt_s: the link's round trip: a step is sent this long after the previous one
            completed (and the recording's log times are shifted by half of it).
        dt_s: the controller's tick (the emulator's default 1 ms).
        rest_s: rest before the first step of a plan and after its last.
        namespace: prefix of the topics (``"/ground"``, as ``rover demo`` records).
        validator: ``(pose, steps, goal) -> (approved, reason, failed step)``, the
            gate's judgement of a plan from the rover's pose (:func:`validate_with_gate`);
            ``None``: every plan is driven.
        recorder: ``(path, messages)`` writes a plan's messages as a recording (the
            caller's: :func:`planner.record.mcaprec.record_messages`); needed by
            :meth:`drive` only.

    Single-threaded; virtual time only (no wall clock in what it simulates).
    """

    speed_factor = 1.0

    def __init__(
        self,
        rover: RoverDescription,
        world: WorldMap | None,
        ground: Ground | None,
        *,
        start: Pose2D | None = None,
        seed: int = 0,
        rtt_s: float = 3.0,
        dt_s: float = 0.001,
        rest_s: float = 3.0,
        namespace: str = "",
        validator: Callable[
            [Pose2D, list[tuple[int, int, int]], Pose2D], tuple[bool, str, int | None]
        ]
        | None = None,
        recorder: Callable[[Path, Sequence[tuple[int, str, Any]]], None] | None = None,
    ) -> None:
        twin_rover = ground.rover(rover) if ground is not None else rover
        twin_world = ground.world(world) if ground is not None else world
        self.rover = rover
        self.twin = Twin(twin_rover, twin_world, dt_s=dt_s, start=start)
        self.model = ControllerModel(rover, self.twin, ControllerConfig(), seed=seed)
        self.host = _Host(rover, rtt_s / 2.0)
        self.rtt_s = rtt_s
        self.rest_s = rest_s
        self.namespace = namespace
        self.validator = validator
        self.recorder = recorder
        self.driving_s = 0.0
        """Twin seconds spent executing steps, over every plan."""
        self.lockstep_wall_s = 0.0
        """Wall seconds spent simulating and recording the plans (a benchmark's figure)."""
        self.lockstep_cpu_s = 0.0
        """CPU seconds (this process's) spent simulating and recording the plans."""
        self._beats = 0
        self._next_beat = 0.0
        self._seq = 0
        self.host.feed(0.0, self.model.boot())
        self.host.feed(0.0, self.model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH)))

    def _run(self, duration_s: float, until_ended: bool = False) -> None:
        model, host = self.model, self.host
        end = model.now_s + duration_s
        while model.now_s < end - 1e-9:
            now = model.now_s
            if now >= self._next_beat - 1e-9:
                host.feed(now, model.handle(HostHeartbeat(self._beats & 0xFFFF)))
                self._beats += 1
                self._next_beat = now + HOST_HEARTBEAT_S
            host.feed(model.now_s, model.tick())
            if until_ended and host.ended:
                return

    def pose(self) -> Pose2D:
        """The rover's true pose (for where there is room to drive: the lab's tracking)."""
        return self.twin.pose

    def drive_steps(
        self, steps: list[tuple[int, int, int]], *, back_to_back: bool = False
    ) -> LockstepMission:
        """Drive ``steps`` from where the rover is: one at a time with a round trip of
        rest between them (the step-by-step executor), or ``back_to_back`` as a plan run
        on board goes (each next step queued in the controller while the one before
        runs, so it starts the tick that one ends)."""
        wall0, cpu0 = time.perf_counter(), time.process_time()
        host = self.host
        host.events = []
        self._run(self.rest_s)
        true_start = self.twin.pose
        if back_to_back:
            driving, completed = self._back_to_back(steps)
        else:
            driving, completed = self._one_at_a_time(steps)
        self._run(self.rest_s)
        self.driving_s += driving
        messages = tuple(
            (t_ns, self.namespace + topic, msg)
            for t_ns, topic, msg in sorted(host.events, key=lambda e: e[0])
        )
        self.lockstep_wall_s += time.perf_counter() - wall0
        self.lockstep_cpu_s += time.process_time() - cpu0
        return LockstepMission(
            messages, tuple(steps), true_start, self.twin.pose, driving, completed
        )

    def _send(self, step: tuple[int, int, int]) -> None:
        self.host.up(self.model.now_s, "/wheel_instructions", Int16MultiArray(data=list(step)))
        self.host.feed(self.model.now_s, self.model.handle(Motion(self._seq & 0xFFFF, *step)))
        self._seq += 1

    def _back_to_back(self, steps: list[tuple[int, int, int]]) -> tuple[float, int]:
        host = self.host
        t0 = self.model.now_s
        limit = sum(1.5 * self.rover.step_duration_s(s, d) + 5.0 for _c, s, d in steps)
        queued = list(steps)
        depth = self.model.config.queue_depth
        running = 0
        completed = ended = 0
        while queued and running < depth:
            self._send(queued.pop(0))
            running += 1
        while ended < len(steps) and self.model.now_s < t0 + limit:
            host.ended = ""
            self._run(limit, until_ended=True)
            if not host.ended:
                break
            ended += 1
            completed += host.ended == "completed"
            running -= 1
            if host.ended != "completed":
                break
            if queued:
                self._send(queued.pop(0))
                running += 1
        return self.model.now_s - t0, completed

    def _one_at_a_time(self, steps: list[tuple[int, int, int]]) -> tuple[float, int]:
        host = self.host
        driving = 0.0
        completed = 0
        for k, step in enumerate(steps):
            host.ended = ""
            t0 = self.model.now_s
            self._send(step)
            if not host.ended:
                limit = 1.5 * self.rover.step_duration_s(step[1], step[2]) + 5.0
                self._run(limit, until_ended=True)
            driving += self.model.now_s - t0
            completed += host.ended == "completed"
            if k < len(steps) - 1:
                self._run(self.rtt_s)
        return driving, completed

    def drive(self, steps: Sequence[tuple[int, int, int]], *, goal: Pose2D, path: Path) -> Driven:
        """:class:`emulator.campaign.Driver`: the plan validated (``validator``), then
        driven step by step and written to ``path`` (``recorder``)."""
        if self.recorder is None:
            raise ValueError("LockstepRover.drive needs a recorder to write recordings with")
        if self.validator is not None:
            approved, reason, failed = self.validator(self.twin.pose, list(steps), goal)
            if not approved:
                return Driven(False, None, reason, failed)
        mission = self.drive_steps(list(steps))
        wall0, cpu0 = time.perf_counter(), time.process_time()
        self.recorder(path, mission.messages)
        self.lockstep_wall_s += time.perf_counter() - wall0
        self.lockstep_cpu_s += time.process_time() - cpu0
        reason = (
            ""
            if mission.completed == len(steps)
            else f"{len(steps) - mission.completed} step(s) did not complete"
        )
        return Driven(True, path, reason)


def validate_with_gate(
    validator: Validator, *, margin_m: float = 0.1
) -> Callable[[Pose2D, list[tuple[int, int, int]], Pose2D], tuple[bool, str, int | None]]:
    """A :class:`LockstepRover` ``validator`` that asks the gate's own
    :class:`gate.validator.Validator` (in process), as ``rover go --plan`` asks the gate
    (the plan's goal the fit's prediction, its tolerances wide: the gate judges the
    collisions and stalls)."""

    def check(
        at: Pose2D, steps: list[tuple[int, int, int]], goal: Pose2D
    ) -> tuple[bool, str, int | None]:
        names = {1: "FWD", 2: "REV", 3: "LEFT", 4: "RIGHT"}
        plan = Plan.from_dict(
            {
                "goal": {"x": goal.x_m, "y": goal.y_m, "yaw_deg": math.degrees(goal.yaw_rad)},
                "commands": [
                    {"command": names[c], "speed": sp, "distance": d} for c, sp, d in steps
                ],
            }
        )
        options = ValidateOptions(
            start=PlanPose(at.x_m, at.y_m, math.degrees(at.yaw_rad)),
            safety_margin_m=margin_m,
            position_tolerance_m=1.0,
            yaw_tolerance_deg=180.0,
        )
        resolved = options.resolve(validator.settings, validator.default_map)
        verdict = validator.validate(plan, resolved)
        return bool(verdict.approved), verdict.failure_reason or "", verdict.failed_step

    return check


def drive_lockstep(
    rover: RoverDescription,
    world: WorldMap | None,
    ground: Ground | None,
    steps: list[tuple[int, int, int]],
    *,
    start: Pose2D | None = None,
    seed: int = 0,
    rtt_s: float = 3.0,
    dt_s: float = 0.001,
    rest_s: float = 3.0,
    namespace: str = "",
) -> LockstepMission:
    """Drive ``steps`` on ``ground`` in lockstep, one at a time, hearing the mission as
    the ground station would (module docstring): one plan of a fresh
    :class:`LockstepRover` (its arguments)."""
    lockstep = LockstepRover(
        rover,
        world,
        ground,
        start=start,
        seed=seed,
        rtt_s=rtt_s,
        dt_s=dt_s,
        rest_s=rest_s,
        namespace=namespace,
    )
    return lockstep.drive_steps(steps)
