"""Drift monitor: per-step time alignment, thresholds, persistence (pure logic)."""

from __future__ import annotations

import pytest

from planner.drift import DriftMonitor, PoseXY, ReferenceTrajectory, angle_diff_deg


def straight_then_turn() -> ReferenceTrajectory:
    """Step 0: 1 m along +x in 4 s; step 1: spin to 90 deg in 2 s."""
    step0 = [(t / 10, PoseXY(t / 40, 0.0, 0.0)) for t in range(41)]
    step1 = [(t / 10, PoseXY(1.0, 0.0, 4.5 * t)) for t in range(21)]
    return ReferenceTrajectory(
        {0: step0, 1: step1},
        {0: 4.0, 1: 2.0},
        {0: PoseXY(1.0, 0.0, 0.0), 1: PoseXY(1.0, 0.0, 90.0)},
        PoseXY(0.0, 0.0, 0.0),
    )


def test_reference_interpolates_and_clamps() -> None:
    ref = straight_then_turn()
    assert ref.pose_at(0, 2.05) == PoseXY(pytest.approx(0.5125), 0.0, 0.0)  # type: ignore[arg-type]
    assert ref.pose_at(0, 99.0) == PoseXY(1.0, 0.0, 0.0)
    assert ref.pose_at(1, -1.0) == PoseXY(1.0, 0.0, 0.0)  # before step 1: end of step 0
    assert ref.pose_at(1, 1.0).yaw_deg == pytest.approx(45.0)


def test_reference_from_gate_verdict_json() -> None:
    verdict = {
        "trajectory": {
            "sample_period_s": 0.1,
            "samples": [
                {"t_s": 0.0, "step": 0, "step_t_s": 0.0, "x": 0.0, "y": 0.0, "yaw_deg": 0.0},
                {"t_s": 1.0, "step": 0, "step_t_s": 1.0, "x": 0.3, "y": 0.0, "yaw_deg": 0.0},
            ],
        },
        "steps": [
            {
                "index": 0,
                "expected_duration_s": 1.0,
                "start_pose": {"x": 0.0, "y": 0.0, "yaw_deg": 0.0},
                "end_pose": {"x": 0.3, "y": 0.0, "yaw_deg": 0.0},
            }
        ],
    }
    ref = ReferenceTrajectory.from_verdict(verdict)
    assert ref.step_count == 1 and ref.pose_at(0, 0.5).x == pytest.approx(0.15)
    with pytest.raises(ValueError, match="no predicted steps"):
        ReferenceTrajectory.from_verdict({"steps": []})


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
    assert (step, predicted) == (0, PoseXY(1.0, 0.0, 0.0))
    step, predicted = mon.predicted_at(12.5)
    assert step == 1 and predicted.yaw_deg == pytest.approx(45.0)


def test_time_scale_maps_wall_to_twin_time() -> None:
    mon = DriftMonitor(straight_then_turn(), one_way_delay_s=0.0, time_scale=4.0)
    mon.step_published(0, 0.0)
    assert mon.predicted_at(0.5)[1].x == pytest.approx(0.5)  # 0.5 s wall = 2 s twin


def test_angle_diff_wraps() -> None:
    assert angle_diff_deg(179.0, -179.0) == pytest.approx(-2.0)
    assert angle_diff_deg(-170.0, 170.0) == pytest.approx(20.0)


def test_bad_limits_are_refused() -> None:
    with pytest.raises(ValueError, match="positive"):
        DriftMonitor(straight_then_turn(), persistence=0)
