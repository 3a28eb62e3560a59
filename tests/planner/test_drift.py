"""Drift monitor: per-step time alignment, thresholds, persistence (pure logic)."""

from __future__ import annotations

import pytest

from firmware_proto.model.pose import Pose
from firmware_proto.model.verdict import (
    Replay,
    StepPrediction,
    Tolerances,
    Trajectory,
    TrajectorySample,
    Verdict,
)
from planner.ground.drift import DriftMonitor, predicted_pose


def verdict_of(steps: list[list[tuple[float, Pose]]]) -> Verdict:
    """A verdict as the gate would send it, from per-step ``(step_t_s, pose)`` samples."""
    samples, predictions, t0 = [], [], 0.0
    for index, step in enumerate(steps):
        samples += [TrajectorySample(t0 + t, index, t, pose) for t, pose in step]
        duration = step[-1][0]
        predictions.append(
            StepPrediction(
                index,
                "FWD",
                60,
                0,
                t0,
                t0 + duration,
                duration,
                duration,
                step[0][1],
                step[-1][1],
                True,
                0.0,
                0.0,
            )
        )
        t0 += duration
    first, last = steps[0][0][1], steps[-1][-1][1]
    return Verdict(
        approved=True,
        failure_type=None,
        failure_reason="",
        failed_step=None,
        goal=last,
        start_pose=first,
        final_pose=last,
        position_error_m=0.0,
        lateral_error_m=0.0,
        distance_error_m=0.0,
        yaw_error_deg=0.0,
        approach_heading_deg=0.0,
        collision=None,
        stall=None,
        tolerances=Tolerances(0.1, 3.0, 0.1),
        steps=tuple(predictions),
        trajectory=Trajectory(0.1, tuple(samples)),
        sim_time_s=t0,
        replay=Replay(0, "test", "", "", "", "", first, 0.01, 10.0, False, "", "", ""),
    )


def straight_then_turn() -> Verdict:
    """Step 0: 1 m along +x in 4 s; step 1: spin to 90 deg in 2 s."""
    return verdict_of(
        [
            [(t / 10, Pose(t / 40, 0.0, 0.0)) for t in range(41)],
            [(t / 10, Pose(1.0, 0.0, 4.5 * t)) for t in range(21)],
        ]
    )


def test_prediction_interpolates_and_holds_at_the_ends() -> None:
    v = straight_then_turn()
    assert predicted_pose(v, 0, 2.05).x == pytest.approx(0.5125)
    assert predicted_pose(v, 0, 99.0) == Pose(1.0, 0.0, 0.0)
    assert predicted_pose(v, 1, -1.0) == Pose(1.0, 0.0, 0.0)  # before step 1: its start
    assert predicted_pose(v, 1, 1.0).yaw_deg == pytest.approx(45.0)
    assert predicted_pose(v, -1, 0.0) == v.start_pose


def test_on_track_poses_never_trigger_and_errors_are_measured() -> None:
    mon = DriftMonitor(straight_then_turn(), one_way_delay_s=1.5)
    mon.step_published(0, 100.0)
    mon.step_accepted(0, 100.0, 103.0)  # round trip 3 s: the rover started at 101.5
    for i in range(40):
        t = 101.5 + i * 0.1
        assert mon.update(i / 40 + 0.02, 0.01, 1.0, t) is None
    linear, angular = mon.worst
    assert linear == pytest.approx(0.0224, abs=1e-3) and angular == pytest.approx(1.0)


def test_a_persistent_violation_fires_once_a_single_outlier_does_not() -> None:
    mon = DriftMonitor(straight_then_turn(), persistence=3, one_way_delay_s=0.0)
    mon.step_published(0, 0.0)
    assert mon.update(0.0, 0.5, 0.0, 0.0) is None  # one bad fix
    assert mon.update(0.0, 0.0, 0.0, 0.1) is None  # back on track: count resets
    events = [mon.update(0.0, 0.3, 0.0, 0.2 + i * 0.1) for i in range(5)]
    fired = [e for e in events if e is not None]
    assert len(fired) == 1 and fired[0].samples_over == 3
    assert fired[0].linear_m > 0.25 and fired[0].step == 0


def test_heading_error_alone_triggers() -> None:
    mon = DriftMonitor(straight_then_turn(), persistence=2, one_way_delay_s=0.0)
    mon.step_published(0, 0.0)
    mon.update(0.0, 0.0, 13.0, 0.0)
    event = mon.update(0.0, 0.0, -13.0, 0.1)
    assert event is not None and event.angular_deg == pytest.approx(13.0)


def test_slip_shows_as_lag_behind_the_time_aligned_prediction() -> None:
    mon = DriftMonitor(straight_then_turn(), persistence=3, one_way_delay_s=0.0)
    mon.step_published(0, 0.0)
    fired = None
    for i in range(41):
        t = i * 0.1
        fired = fired or mon.update(0.8 * t / 4, 0.0, 0.0, t)  # 20 % slip: 0.8 m in 4 s
    assert fired is None  # 0.2 m behind at the end: under 0.25 m
    mon = DriftMonitor(straight_then_turn(), persistence=3, one_way_delay_s=0.0)
    mon.step_published(0, 0.0)
    for i in range(41):
        t = i * 0.1
        fired = fired or mon.update(0.6 * t / 4, 0.0, 0.0, t)  # 40 % slip
    assert fired is not None and fired.t_s < 4.0


def test_poses_measured_before_a_step_started_compare_with_the_previous_end() -> None:
    mon = DriftMonitor(straight_then_turn(), one_way_delay_s=1.5)
    mon.step_published(0, 0.0)
    mon.step_accepted(0, 0.0, 3.0)
    mon.step_published(1, 10.0)  # rover starts step 1 at ~11.5
    step, predicted = mon.predicted_at(10.5)
    assert (step, predicted) == (0, Pose(1.0, 0.0, 0.0))
    step, predicted = mon.predicted_at(12.5)
    assert step == 1 and predicted.yaw_deg == pytest.approx(45.0)


def test_time_scale_maps_wall_to_twin_time() -> None:
    mon = DriftMonitor(straight_then_turn(), one_way_delay_s=0.0, time_scale=4.0)
    mon.step_published(0, 0.0)
    assert mon.predicted_at(0.5)[1].x == pytest.approx(0.5)  # 0.5 s wall = 2 s twin


def test_bad_limits_are_refused() -> None:
    with pytest.raises(ValueError, match="positive"):
        DriftMonitor(straight_then_turn(), persistence=0)
