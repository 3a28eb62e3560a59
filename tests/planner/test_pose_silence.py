"""When drift control falls back from ``odom_ground`` to ``odom``: silence is judged by
the two topics' stamps (the rover's clock), not by when the ground station reads them.

A ground station that fell behind (its process not scheduled for half a second beside
other work) reads both topics' waiting messages late; judged by the wall clock at
reading, the first ``odom`` of that backlog looked like half a second of ``odom_ground``
silence (a false "fell back to odom" seen in the stack walkthrough under load). The
executor's callbacks are called here as its port calls them, with its clock (given as
an argument) moved on between them (a silence must also last
:data:`~planner.ground.executor.SILENCE_CONFIRM_S` of it); the real fall-back, a POSE
dropout on the emulated rover, is ``tests/planner/test_executor.py``."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator

import pytest

from bridge.ros.rosport import open_port
from bridge.ros.rosport.msgs import Odometry, stamp
from firmware_proto.model.rover import load_rover
from planner.ground.executor import SILENCE_CONFIRM_S, ExecutorConfig, PlanExecutor

T0 = 1_800_000_000.0  # the rover's clock, s


def _odometry(stamp_s: float) -> Odometry:
    msg = Odometry()
    msg.header.stamp = stamp(stamp_s)
    msg.pose.pose.position.x = 1.0
    msg.pose.pose.orientation.w = 1.0
    return msg


class _Clock:
    """The executor's clock (``clock=``): it stands still but when the test moves it on,
    so that no pause of this process beside load moves it."""

    def __init__(self) -> None:
        self.offset_s = 0.0

    def now(self) -> float:
        return 1000.0 + self.offset_s

    def time(self) -> float:
        return T0 + self.offset_s

    def wait_for(
        self, cond: threading.Condition, ready: Callable[[], bool], timeout_s: float
    ) -> bool:
        return ready()

    def sleep(self, seconds: float) -> None:
        self.offset_s += max(0.0, seconds)


@pytest.fixture
def clock() -> _Clock:
    return _Clock()


@pytest.fixture
def executor(clock: _Clock) -> Iterator[PlanExecutor]:
    with open_port("inprocess", node_name="ground", bus="pose-silence") as port:
        ex = PlanExecutor(port, load_rover(), ExecutorConfig(pose_stale_s=0.5), clock=clock)
        try:
            yield ex
        finally:
            ex.close()


def test_a_backlog_read_late_is_no_silence(
    executor: PlanExecutor, clock: _Clock, caplog: pytest.LogCaptureFixture
) -> None:
    executor._on_ground(_odometry(T0))
    clock.offset_s = 10.0  # the rest of the backlog is read 10 s after it came
    with caplog.at_level(logging.WARNING, logger="planner.ground.executor"):
        for k in range(1, 6):  # odom of the same backlog, stamped up to 0.5 s after
            executor._on_odom(_odometry(T0 + 0.1 * k))
        # The reader kept only the newest odom: 0.8 s after the last POSE it has read,
        # in one burst with the POSE still queued behind it.
        executor._on_odom(_odometry(T0 + 0.8))
        executor._on_odom(_odometry(T0 + 0.81))
        assert executor.pose_source_in_use == "odom_ground"
        executor._on_ground(_odometry(T0 + 0.75))
        clock.offset_s = 20.0
        executor._on_odom(_odometry(T0 + 0.9))
    assert executor.pose_source_in_use == "odom_ground"
    assert "fell back" not in caplog.text


def test_a_silence_in_the_stamps_that_lasts_falls_back_and_pose_returns(
    executor: PlanExecutor, clock: _Clock, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING, logger="planner.ground.executor"):
        executor._on_ground(_odometry(T0))
        executor._on_odom(_odometry(T0 + 0.5))  # exactly stale: not yet
        executor._on_odom(_odometry(T0 + 0.51))  # stale: seen ...
        clock.offset_s = SILENCE_CONFIRM_S / 2
        executor._on_odom(_odometry(T0 + 0.56))
        assert executor.pose_source_in_use == "odom_ground"
        clock.offset_s = 1.5 * SILENCE_CONFIRM_S  # ... and still there, read later
        executor._on_odom(_odometry(T0 + 0.61))
        assert executor.pose_source_in_use == "odom"
        assert "odom_ground silent for more than 0.5 s" in caplog.text
        executor._on_ground(_odometry(T0 + 0.6))
        assert executor.pose_source_in_use == "odom_ground"
        assert "odom_ground came back" in caplog.text


def test_a_pose_read_between_resets_the_confirmation(executor: PlanExecutor, clock: _Clock) -> None:
    executor._on_ground(_odometry(T0))
    executor._on_odom(_odometry(T0 + 0.6))  # silent: seen at wall 0
    executor._on_ground(_odometry(T0 + 0.05))  # an old POSE, late: a silence begun anew
    clock.offset_s = 1.5 * SILENCE_CONFIRM_S
    executor._on_odom(_odometry(T0 + 0.6))  # seen again, now
    assert executor.pose_source_in_use == "odom_ground"
    clock.offset_s = 3 * SILENCE_CONFIRM_S
    executor._on_odom(_odometry(T0 + 0.7))
    assert executor.pose_source_in_use == "odom"


def test_before_the_first_pose_and_any_plan_odom_is_no_silence(
    executor: PlanExecutor, clock: _Clock
) -> None:
    # The bridge publishes odom first; through the link it may come well ahead.
    clock.offset_s = 10.0
    executor._on_odom(_odometry(T0))
    assert executor.pose_source_in_use == "odom_ground"
