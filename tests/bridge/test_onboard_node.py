"""The onboard program's ROS shell (bridge/onboard/node.py) on the in-process port in
lockstep: virtual time, no thread; the system clock is stepped as NTP would step it.
The program on real DDS beside a real bridge is tests/bridge/test_onboard_mission.py."""

from __future__ import annotations

import contextlib
import itertools
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest

from bridge.onboard.core import OnboardConfig, decode_screened
from bridge.onboard.node import BACKLOG_GRACE_S, ONBOARD_POSE_PERIOD_S, OnboardNode
from bridge.ros.rosport import RosPort, open_port, qos
from bridge.ros.rosport.contract import (
    EMERGENCY_STOP,
    ONBOARD_POSE,
    ONBOARD_REPORT,
    PLAN_UPLINK,
    WHEEL_INSTRUCTIONS,
)
from bridge.ros.rosport.msgs import (
    Bool,
    Header,
    Int16MultiArray,
    Odometry,
    Point,
    Pose,
    PoseWithCovariance,
    String,
    Twist,
    TwistWithCovariance,
    Vector3,
    quaternion_from_yaw,
    stamp,
    stamp_s,
)
from firmware_proto.linkio.clock import LockstepClock
from firmware_proto.model.downlink import OnboardReport, decode_report
from firmware_proto.model.rover import load_rover
from firmware_proto.model.uplink import PlanUplink
from firmware_proto.runtime import stall
from sim.mission import predict

ROVER = load_rover(None)
TOKEN = "node-t0ken"
COV = [0.0] * 36
for _i in (0, 7, 35):
    COV[_i] = 1e-4


@dataclass
class Bench:
    """The node on lockstep time; a ground and a bridge of plain subscriptions."""

    clock: LockstepClock
    node: OnboardNode
    ground: RosPort
    jump_s: list[float] = field(default_factory=lambda: [0.0])
    stops: list[float] = field(default_factory=list)
    steps: list[list[int]] = field(default_factory=list)
    reports: list[OnboardReport] = field(default_factory=list)
    x_m: float = 0.0

    def wall(self) -> float:
        return self.clock.time() + self.jump_s[0]

    def odometry(
        self, topic: str, v_mps: float, *, at: float | None = None, x_m: float | None = None
    ) -> None:
        """Publish an ``odom`` or ``odom_ground`` sample stamped ``at`` (now) and at
        ``x_m`` (the bench's)."""
        x = self.x_m if x_m is None else x_m
        msg = Odometry(
            header=Header(stamp=stamp(self.wall() if at is None else at), frame_id="odom"),
            child_frame_id="base_link",
            pose=PoseWithCovariance(
                pose=Pose(position=Point(x=x, y=0.0, z=0.0), orientation=quaternion_from_yaw(0.0)),
                covariance=COV,
            ),
            twist=TwistWithCovariance(twist=Twist(linear=Vector3(x=v_mps), angular=Vector3(z=0.0))),
        )
        self.ground_pub[topic].publish(msg)

    ground_pub: dict[str, Any] = field(default_factory=dict)

    def run(self, seconds: float, *, sensors: bool) -> None:
        """Advance; with ``sensors``, odom at 50 Hz and POSE at 10 Hz from the rover
        standing at the origin (a plan's step is accepted, nothing moves)."""
        ticks = round(seconds / self.clock.dt_s)
        for k in range(ticks):
            if sensors and k % 2 == 0:
                self.odometry("odom", 0.0)
                if k % 10 == 0:
                    self.odometry("odom_ground", 0.0)
            self.clock.advance()


@pytest.fixture
def bench() -> Iterator[Bench]:
    with _bench() as b:
        yield b


@contextlib.contextmanager
def _bench(time_scale: float = 1.0) -> Iterator[Bench]:
    clock = LockstepClock(0.01)
    port = open_port("inprocess", node_name="rover_onboard", bus="node-clock", clock=clock)
    ground = open_port("inprocess", node_name="ground", bus="node-clock", clock=clock)
    holder: list[Bench] = []
    node = OnboardNode(
        port,
        ROVER,
        OnboardConfig(
            token=TOKEN,
            blind_s=0.5,
            step_margin_s=60.0,
            report_period_s=0.5,
            time_scale=time_scale,
        ),
        wall=lambda: holder[0].wall(),  # noqa: PLW0108 - the bench is made below
        monotonic=clock.now,
    )
    b = Bench(clock, node, ground)
    holder.append(b)
    ground.subscribe(EMERGENCY_STOP, Bool, lambda m: b.stops.append(clock.now()), qos.STOP)
    ground.subscribe(
        WHEEL_INSTRUCTIONS, Int16MultiArray, lambda m: b.steps.append(list(m.data)), qos.COMMAND
    )
    ground.subscribe(
        ONBOARD_REPORT, String, lambda m: b.reports.append(decode_report(m.data)), qos.STATUS
    )
    b.ground_pub = {
        "odom": ground.publisher("odom", Odometry, qos.SENSOR),
        "odom_ground": ground.publisher("odom_ground", Odometry, qos.SENSOR),
        "uplink": ground.publisher(PLAN_UPLINK, String, qos.COMMAND),
        "status": ground.publisher("command_status", String, qos.STATUS),
    }
    clock.add(node.step)
    try:
        yield b
    finally:
        node.close()
        ground.close()
        port.close()


def _uplink_and_accept(b: Bench) -> PlanUplink:
    """After 0.5 s of sensors, uplink a one-step plan and, 0.05 s later, the bridge's
    ``accepted`` for its step; returns the plan."""
    b.run(0.5, sensors=True)
    plan = predict(ROVER, 7, ((1, 30, 23000),), boot=b.node.core.boot)
    b.ground_pub["uplink"].publish(String(data=plan.envelope(TOKEN)))
    b.run(0.05, sensors=True)
    b.ground_pub["status"].publish(String(data="accepted"))
    return plan


def _start_a_plan(b: Bench) -> None:
    _uplink_and_accept(b)
    b.run(0.05, sensors=True)
    assert b.steps == [[1, 30, 23000]] and b.node.core.running is not None


def test_a_step_of_the_system_clock_backwards_does_not_blind_the_blind_check(
    bench: Bench,
) -> None:
    """Review A10: every deadline ran on the wall clock; an NTP step backwards put the
    blind check and the step timeout an hour away."""
    _start_a_plan(bench)
    bench.jump_s[0] = -3600.0
    stepped = bench.clock.now()
    bench.run(1.0, sensors=False)  # the sensors fall silent
    assert bench.stops and bench.stops[0] - stepped == pytest.approx(0.5, abs=0.05)
    assert bench.reports[-1].outcome == "blind"


def test_a_step_forwards_fires_nothing_and_reports_keep_ros_time(bench: Bench) -> None:
    _start_a_plan(bench)
    bench.jump_s[0] = 3600.0
    bench.run(1.0, sensors=True)  # stamps jump with the clock: the same offset
    assert bench.stops == [] and bench.node.core.running is not None
    last = bench.reports[-1]
    assert last.t_s == pytest.approx(bench.wall(), abs=0.6)  # ROS time, stepped


def test_the_timer_survives_a_failing_turn_and_stops_the_rover_after_three(
    bench: Bench, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review A12: the timer thread died on any exception, silently (the stall monitor
    forgot it): no more blind checks, step timeouts or reports."""
    _start_a_plan(bench)
    node = bench.node
    bench.clock.remove(node.step)  # the turns below are the timer's
    beat = stall.Beat("onboard-timer", lambda: 1.0)
    assert node._timer_turn(beat, 0) == 0 and beat.last == 1.0  # a healthy turn

    def broken(now: float) -> float:
        raise RuntimeError("a bug in the core")

    monkeypatch.setattr(node.core, "next_deadline", broken)
    failures = 0
    for expected in (1, 2):
        failures = node._timer_turn(beat, failures)
        assert failures == expected
    bench.clock.advance()
    assert bench.stops == []  # two failures: logged, the plan goes on
    failures = node._timer_turn(beat, failures)
    bench.clock.advance()
    assert failures == 3 and bench.stops  # the third: STOP
    assert bench.reports[-1].outcome == "failed" and node.core.running is None
    monkeypatch.undo()
    assert node._timer_turn(beat, failures) == 0  # and it goes on when the fault is gone


def test_copies_and_forgeries_are_answered_without_a_full_decode(
    bench: Bench, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review A11: every uplink was decoded in full (tens of milliseconds for a large
    plan) under the lock the estimates, the timer and STOP wait for, before the check
    for a copy; the ground resends until it hears an answer, and junk costs the same.
    Now the tag and the id are checked first, and only a new, authentic plan is
    decoded, outside the lock."""
    import bridge.onboard.node as node_module

    decoded: list[int] = []
    real = decode_screened

    def counting(screened: Any, rover: Any) -> Any:
        assert not bench.node._lock.locked()  # outside the lock
        decoded.append(screened.plan_id)
        return real(screened, rover)

    monkeypatch.setattr(node_module, "decode_screened", counting)
    acks: list[str] = []
    bench.ground.subscribe("plan_ack", String, lambda m: acks.append(m.data), qos.STATUS)
    bench.run(0.5, sensors=True)
    plan = predict(ROVER, 7, ((1, 30, 23000),), boot=bench.node.core.boot)
    for text in (plan.envelope(TOKEN), plan.envelope(TOKEN), plan.envelope("forged")):
        bench.ground_pub["uplink"].publish(String(data=text))
        bench.run(0.05, sensors=True)
    assert decoded == [7]  # the copy and the forgery were answered from the first look
    results = [(a["result"], a["reason"]) for a in map(json.loads, acks)]
    assert results == [("accepted", ""), ("duplicate", ""), ("refused", "bad_tag")]


def _drive_through_a_stall(b: Bench, *, poses_kept: bool) -> None:
    """The plan's step at 8x (1.2 m/s on the rover's clock), odom at 50 Hz and POSE at
    10 Hz on the prediction, then a 0.4 s stall of the program (the clock runs, nothing is
    read), then its queues' backlog as rclpy's executor hands it over (one message per
    queue per turn, ``odom_ground`` first; only the last five ``odom`` kept), then 0.3 s
    more. Without ``poses_kept`` the POSE falls silent as the stall begins."""
    plan = _uplink_and_accept(b)
    t_start = b.wall()

    def x_at(t: float) -> float:
        return plan.pose_at(0, 8.0 * max(0.0, t - t_start)).x

    def drive(seconds: float, *, poses: bool = True) -> None:
        for k in range(round(seconds / b.clock.dt_s)):
            now = b.wall()
            b.x_m = x_at(now)
            if k % 2 == 0:
                b.odometry("odom", 1.2)
                if k % 10 == 0 and poses:
                    b.odometry("odom_ground", 0.0)
            b.clock.advance()

    drive(0.6)
    t0 = b.wall()
    for _ in range(40):  # the stall
        b.clock.advance()
    poses = [t0 + 0.1 * k for k in range(1, 5)] if poses_kept else []
    odoms = [t0 + 0.02 * k for k in range(16, 21)]
    for i, at in enumerate(odoms):
        if i < len(poses):
            b.odometry("odom_ground", 0.0, at=poses[i], x_m=x_at(poses[i]))
        b.odometry("odom", 1.2, at=at, x_m=x_at(at))
    drive(0.3, poses=poses_kept)


def test_a_backlog_after_a_stall_reads_late_and_sees_no_blindness() -> None:
    """CI (the walkthrough at --speed 4): a 0.37 s stall of the onboard program, and the
    plan ended ``blind`` ("0.39 m driven since the last POSE fix") with the POSE samples
    that covered the motion read in the same backlog. The driven distance is now the
    filter's by stamps, a POSE ahead of the odometry waits for it, and the verdict has a
    grace; with the POSEs lost in the stall, the plan still stops blind."""
    with _bench(time_scale=8.0) as b:
        _drive_through_a_stall(b, poses_kept=True)
        assert b.stops == [] and b.node.core.running is not None
        assert all(r.outcome != "blind" for r in b.reports)
    with _bench(time_scale=8.0) as b:
        _drive_through_a_stall(b, poses_kept=False)
        assert b.stops and b.reports[-1].outcome == "blind"
        assert "driven since the last POSE fix" in b.reports[-1].reason


def _stall_whole_program(b: Bench, seconds: float, *, backlog: bool) -> float:
    """The program stalls as a whole for ``seconds`` while a plan's step runs (the rover
    standing on the prediction's first instants): neither its timer nor its callbacks
    run. Then its timer's turn comes before the queues are read (the race it may lose),
    and the backlog (the last five ``odom``, a POSE) is read on the next tick. Returns
    when the stall ended (the monotonic clock)."""
    _uplink_and_accept(b)
    b.run(0.1, sensors=True)
    b.clock.remove(b.node.step)
    for _ in range(round(seconds / b.clock.dt_s)):
        b.clock.advance()  # the timer does not run, and nothing is published
    end, wall = b.clock.now(), b.wall()
    b.node.step()  # the timer first
    if backlog:
        for k in range(1, 6):
            b.odometry("odom", 0.0, at=wall - 0.02 * (5 - k))
        b.odometry("odom_ground", 0.0, at=wall - 0.05)
    b.clock.add(b.node.step)
    return end


def test_a_stall_of_the_whole_program_waits_for_its_backlog_before_the_blind_check() -> None:
    """A stall of the onboard program longer than blind_s (0.5 s): its timer may run
    before the samples queued in the stall are read, and the blind check judged their
    absence. A late turn holds the deadlines for BACKLOG_GRACE_S; the backlog is read,
    and the plan runs on. With nothing queued, the plan stops blind after the grace."""
    with _bench() as b:
        _stall_whole_program(b, 0.6, backlog=True)
        b.run(0.2, sensors=True)
        assert b.stops == [] and b.node.core.running is not None
        assert all(r.outcome != "blind" for r in b.reports)
        assert b.node.late_turns == 1
    with _bench() as b:
        end = _stall_whole_program(b, 0.6, backlog=False)
        b.run(0.2, sensors=False)
        assert b.node.late_turns == 1
        assert b.reports[-1].outcome == "blind" and b.stops
        assert b.stops[0] - end == pytest.approx(BACKLOG_GRACE_S, abs=0.015)


def test_onboard_pose_goes_out_for_each_fix_and_at_10_hz_between_fixes(bench: Bench) -> None:
    """``onboard_pose`` carries every estimate that took a POSE fix, and odometry-only
    estimates at most every ``ONBOARD_POSE_PERIOD_S`` of their stamps (the guard acts on
    all of them): 10 Hz for the link, not the odometry's 50."""
    got: list[float] = []
    bench.ground.subscribe(
        ONBOARD_POSE, Odometry, lambda m: got.append(stamp_s(m.header.stamp)), qos.SENSOR
    )
    bench.odometry("odom_ground", 0.0)  # the first fix: the filter starts
    bench.clock.advance()
    assert len(got) == 1
    t0 = bench.wall()
    for k in range(1, 51):  # 1 s of odometry at 50 Hz, moving, no fix
        bench.clock.advance()
        bench.clock.advance()
        bench.x_m = 0.01 * k
        bench.odometry("odom", 0.5)
    odometry_only = [t for t in got[1:] if t > t0]
    assert len(odometry_only) == pytest.approx(1.0 / ONBOARD_POSE_PERIOD_S, abs=1)
    gaps = [b - a for a, b in itertools.pairwise(odometry_only)]
    assert min(gaps) >= ONBOARD_POSE_PERIOD_S - 1e-6
    before = len(got)
    bench.clock.advance()
    bench.odometry("odom_ground", 0.0, x_m=0.5)  # a fix 0.01 s after the last odometry
    bench.clock.advance()
    assert len(got) == before + 1
    assert bench.node.poses_published == len(got)
