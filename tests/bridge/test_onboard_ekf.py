"""The onboard estimate (bridge/onboard/ekf.py): odometry carried along, POSE applied at
its own stamp, a slip followed at once, the covariance honest about silence."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bridge.onboard.ekf import PoseEkf

R = np.diag([1e-4, 1e-4, 1e-4])


def _drive(ekf: PoseEkf, t0: float, n: int, *, dx: float, odom: list[float]) -> float:
    """``n`` odom samples 20 ms apart, each ``dx`` forward in the odometry frame."""
    t = t0
    for _ in range(n):
        t += 0.02
        odom[0] += dx
        ekf.predict(t, odom[0], 0.0, 0.0, dx / 0.02, 0.0)
    return t


def test_no_map_pose_until_the_first_pose_then_odometry_carries_it() -> None:
    ekf = PoseEkf()
    odom = [5.0]
    ekf.predict(0.0, 5.0, 0.0, 0.0)
    assert ekf.estimate() is None
    ekf.correct(0.0, 1.0, 2.0, math.pi / 2, R)  # facing +y in the map
    t = _drive(ekf, 0.0, 50, dx=0.01, odom=odom)
    est = ekf.estimate()
    assert est is not None and est.stamp_s == pytest.approx(t)
    # 0.5 m forward in the odometry frame is 0.5 m along +y in the map
    assert (est.x_m, est.y_m, est.yaw_deg) == pytest.approx((1.0, 2.5, 90.0), abs=1e-9)
    assert est.v_mps == pytest.approx(0.5)


def test_a_late_pose_is_applied_at_its_stamp_and_the_motion_since_replayed() -> None:
    ekf = PoseEkf()
    odom = [0.0]
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    _drive(ekf, 0.0, 50, dx=0.01, odom=odom)  # odometry says x = 0.5 at t = 1.0
    # The POSE measured at t = 0.9 (0.1 s old) says the rover was 0.1 m short then.
    ekf.correct(0.9, 0.35, 0.0, 0.0, R)
    est = ekf.estimate()
    assert est is not None
    # where the filter put it at 0.9, plus the 0.1 m driven since
    assert 0.4 < est.x_m < 0.49
    assert est.pose_stamp_s == 0.9 and est.pose_age_s == pytest.approx(0.1)


def test_a_slip_the_odometry_cannot_see_is_followed_at_once() -> None:
    ekf = PoseEkf()
    odom = [0.0]
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    t = _drive(ekf, 0.0, 25, dx=0.01, odom=odom)
    # The wheels turn on; the ground-seeing sensor says the rover slid 0.3 m sideways.
    ekf.correct(t, 0.25, 0.3, 0.0, R)
    held = ekf.estimate()
    assert held is not None and held.y_m == pytest.approx(0.0, abs=1e-6)  # one fix: held
    t = _drive(ekf, t, 5, dx=0.01, odom=odom)
    ekf.correct(t, 0.3, 0.31, 0.0, R)  # the next fix agrees: a slip
    est = ekf.estimate()
    assert est is not None
    assert est.y_m == pytest.approx(0.31, abs=0.02)
    assert ekf.inflations == 1 and ekf.outliers == 0


def test_one_bad_fix_does_not_move_the_estimate() -> None:
    """Review A8 (E3): one fix 0.4 m off was taken (the covariance inflated by it), the
    jump lasted until the next POSE, more estimates than the guard's persistence: the
    guard stopped a rover on its path at 0.54 s."""
    ekf = PoseEkf()
    odom = [0.0]
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    t = 0.0
    worst = 0.0
    for k in range(1, 11):  # 10 Hz POSE along the true path, 0.3 m/s; one fix 0.4 m off
        t = _drive(ekf, t, 5, dx=0.006, odom=odom)
        ekf.correct(t, 0.3 * t, 0.4 if k == 4 else 0.0, 0.0, R)
        est = ekf.estimate()
        assert est is not None
        worst = max(worst, math.hypot(est.x_m - 0.3 * t, est.y_m))
    assert worst < 0.01
    assert ekf.outliers == 1 and ekf.inflations == 0 and ekf.corrections == 10


def test_without_pose_the_covariance_grows_with_the_distance() -> None:
    ekf = PoseEkf()
    odom = [0.0]
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    sigmas = []
    t = 0.0
    for _ in range(3):
        t = _drive(ekf, t, 50, dx=0.01, odom=odom)
        est = ekf.estimate()
        assert est is not None
        sigmas.append(est.sigma_xy_m)
    assert sigmas[0] < sigmas[1] < sigmas[2]
    assert sigmas[2] > 3 * sigmas[0] / 2  # more than the POSE it started from
    cov = np.array(ekf.estimate().covariance).reshape(3, 3)  # type: ignore[union-attr]
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    # one POSE brings it back to the sensor's
    ekf.correct(t, 1.5, 0.0, 0.0, R)
    assert ekf.estimate().sigma_xy_m < 0.011  # type: ignore[union-attr]


def test_a_reset_starts_at_a_known_pose() -> None:
    ekf = PoseEkf()
    ekf.reset(1.0, 1.0, 0.0, np.eye(3) * 0.01, 0.0)
    assert ekf.ready
    ekf.predict(0.0, 0.0, 0.0, 0.0)
    ekf.predict(0.1, 0.1, 0.0, 0.0)
    est = ekf.estimate()
    assert est is not None and est.x_m == pytest.approx(1.1)


def test_a_pose_that_is_not_finite_is_refused_and_a_later_good_one_still_works() -> None:
    """Review A4 (E2): one NaN POSE made the estimate NaN for good; a good POSE 5 m away
    did not bring it back."""
    ekf = PoseEkf()
    odom = [0.0]
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    t = _drive(ekf, 0.0, 2, dx=0.01, odom=odom)
    ekf.correct(t, math.nan, 0.0, 0.0, R)
    ekf.correct(t, 0.0, math.inf, 0.0, R)
    ekf.predict(t + 0.02, math.nan, 0.0, 0.0)
    assert ekf.rejected == 3
    est = ekf.estimate()
    assert est is not None and est.finite and est.x_m == pytest.approx(0.01)  # 1 motion
    ekf.correct(t, 5.0, 0.0, 0.0, R)
    ekf.correct(t, 5.0, 0.0, 0.0, R)  # (two agreeing fixes: no outlier)
    est = ekf.estimate()
    assert est is not None and est.finite and est.x_m > 4.9


@pytest.mark.parametrize(
    "covariance",
    [
        np.zeros((3, 3)),  # singular: solving with it raised LinAlgError (E2b)
        np.diag([1e-4, -1e-4, 1e-4]),  # not positive definite
        np.array([[1e-4, 1e-3, 0.0], [0.0, 1e-4, 0.0], [0.0, 0.0, 1e-4]]),  # not symmetric
        np.diag([1e-4, math.nan, 1e-4]),
        [1.0, 2.0],  # not 3x3
    ],
)
def test_a_pose_covariance_that_is_no_covariance_is_refused_and_changes_nothing(
    covariance: object,
) -> None:
    ekf = PoseEkf()
    ekf.correct(0.0, 0.0, 0.0, 0.0, covariance)  # type: ignore[arg-type]
    assert not ekf.ready  # not even the first fix is taken
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    odom = [0.0]
    t = _drive(ekf, 0.0, 5, dx=0.01, odom=odom)
    ekf.correct(t, 0.05, 0.0, 0.0, covariance)  # type: ignore[arg-type]
    est = ekf.estimate()
    assert est is not None and est.finite
    # its stamp was not taken: the POSE's age says how old the last good one is
    assert est.pose_stamp_s == 0.0 and ekf.rejected == 2


def test_a_state_that_stops_being_finite_is_forgotten() -> None:
    ekf = PoseEkf()
    ekf.reset(0.0, 0.0, math.pi / 2, np.eye(3) * 1.7e308, 0.0)  # finite, near the top
    ekf.predict(0.0, 0.0, 0.0, 0.0)
    ekf.predict(0.02, 0.4, 0.0, 0.0)  # the covariance overflows
    assert ekf.poisoned == 1 and ekf.estimate() is None  # no estimate beats a wrong one
    ekf.correct(0.05, 1.0, 1.0, 0.0, R)
    est = ekf.estimate()
    assert est is not None and est.finite and est.x_m == 1.0


def test_an_odometry_jump_is_a_new_frame_not_motion() -> None:
    """Review A15: a bridge restart resets the odometry frame; the filter integrated the
    jump as motion. Beyond a plausible step it re-bases instead."""
    ekf = PoseEkf()
    ekf.correct(0.0, 1.0, 1.0, 0.0, R)
    odom = [3.0]
    t = _drive(ekf, 0.0, 10, dx=0.01, odom=odom)  # at 1.09 in the map
    ekf.predict(t + 0.02, 0.0, 0.0, 0.0)  # the bridge restarted: odom is 0 again
    ekf.predict(t + 0.04, 0.01, 0.0, 0.0)  # and it moves on from there
    est = ekf.estimate()
    assert est is not None and est.x_m == pytest.approx(1.10) and ekf.rebased == 1
    ekf.predict(t + 0.06, 0.01, 0.0, 3.0)  # a turn of 3 rad in 20 ms is no turn either
    assert ekf.rebased == 2 and ekf.estimate().yaw_deg == pytest.approx(0.0)  # type: ignore[union-attr]


@pytest.mark.parametrize("age_s", [1.2, 1.45])
def test_a_pose_as_old_as_the_wire_allows_is_applied_at_its_own_time(age_s: float) -> None:
    """The wire's POSE may be 1.02 s old before the bridge and ROS deliver it: the
    history keeps 1.5 s, and such a fix lands where the rover was then."""
    ekf = PoseEkf()
    odom = [0.0]
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    t = _drive(ekf, 0.0, 100, dx=0.006, odom=odom)  # 0.3 m/s for 2 s: x = 0.6
    stamp = t - age_s
    ekf.correct(stamp, 0.3 * stamp, 0.0, 0.0, R)  # the truth then: the odometry was right
    est = ekf.estimate()
    assert est is not None and est.x_m == pytest.approx(0.6, abs=0.005)
    assert ekf.too_old == 0 and ekf.corrections == 2


@pytest.mark.parametrize("age_s", [1.6, 2.0])
def test_a_pose_older_than_the_history_is_dropped_and_counted(age_s: float) -> None:
    """Review A9: a fix older than the history was applied at its oldest entry, as if
    1 s old: at 0.3 m/s, 2 s old pulled the estimate 0.3 m back."""
    ekf = PoseEkf()
    odom = [0.0]
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    t = _drive(ekf, 0.0, 150, dx=0.006, odom=odom)  # 0.3 m/s for 3 s: x = 0.9
    before = ekf.estimate()
    stamp = t - age_s
    ekf.correct(stamp, 0.3 * stamp, 0.0, 0.0, R)  # right for its time, but too old
    after = ekf.estimate()
    assert before is not None and after == before  # nothing changed, not even the age
    assert ekf.too_old == 1 and ekf.corrections == 1


def test_a_pose_between_sparse_odometry_lands_at_its_own_time() -> None:
    """A backlog thinned by the queue's depth leaves one ``odom`` sample for 0.4 s of
    motion: a POSE inside it splits that motion at its stamp, the estimate stays on the
    truth, and the motion after the POSE is what went unseen."""
    ekf = PoseEkf()
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    ekf.predict(0.0, 0.0, 0.0, 0.0)
    ekf.predict(0.4, 0.48, 0.0, 0.0, 1.2)  # 1.2 m/s
    ekf.correct(0.1, 0.12, 0.0, 0.0, R)  # the truth at 0.1
    est = ekf.estimate()
    assert est is not None and est.x_m == pytest.approx(0.48, abs=1e-6)
    assert est.pose_stamp_s == 0.1 and est.unseen_m == pytest.approx(0.36)
    ekf.correct(0.3, 0.36, 0.0, 0.0, R)
    assert ekf.estimate().unseen_m == pytest.approx(0.12)  # type: ignore[union-attr]
    assert ekf.corrections == 3


def test_a_backlog_read_pose_first_applies_no_motion_twice_and_sees_by_stamps() -> None:
    """CI (the walkthrough): after a stall of the onboard program its queues hand over
    a backlog, the POSE samples ahead of the ``odom`` samples they follow (and the
    ``odom`` queue, five deep, thinned). A POSE newer than the newest ``odom`` waits for
    the odometry to pass it: applied at once, the motion up to it was added again."""
    ekf = PoseEkf()
    odom = [0.0]
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    t = 0.0
    for _ in range(5):  # 1.2 m/s, POSE at 10 Hz, in step: x = 1.2 t
        t = _drive(ekf, t, 5, dx=0.024, odom=odom)
        ekf.correct(t, 1.2 * t, 0.0, 0.0, R)
    t0 = t
    # The stall: 0.4 s of samples, read after it as rclpy's executor takes them, one
    # per queue per turn, odom_ground first; only the last five odom were kept.
    poses = [t0 + 0.1 * k for k in range(1, 5)]
    odoms = [t0 + 0.02 * k for k in range(16, 21)]
    order: list[tuple[str, float]] = []
    for i in range(5):
        if i < len(poses):
            order.append(("pose", poses[i]))
        order.append(("odom", odoms[i]))
    worst_error = worst_unseen = 0.0
    for kind, stamp in order:
        if kind == "pose":
            ekf.correct(stamp, 1.2 * stamp, 0.0, 0.0, R)
        else:
            ekf.predict(stamp, 1.2 * stamp, 0.0, 0.0, 1.2)
        est = ekf.estimate()
        assert est is not None
        worst_error = max(worst_error, abs(est.x_m - 1.2 * est.stamp_s))
        worst_unseen = max(worst_unseen, est.unseen_m)
    assert worst_error < 0.01  # applied before the odometry up to it: 0.047 m off
    # by stamps: from the first POSE to the first odom kept, until the next POSE is read
    # (the core's unseen_grace_s); in the reading order it was all 0.48 m
    assert worst_unseen == pytest.approx(1.2 * 0.22)
    est = ekf.estimate()
    assert est is not None and est.pose_stamp_s == pytest.approx(t0 + 0.4)
    assert est.unseen_m == pytest.approx(0.0, abs=1e-9)


def test_a_pose_ahead_of_silent_odometry_is_applied_after_the_hold() -> None:
    ekf = PoseEkf()
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    ekf.predict(0.0, 0.0, 0.0, 0.0)  # then the odometry falls silent
    ekf.correct(0.5, 0.01, 0.0, 0.0, R)  # waits: the odometry may be behind
    assert ekf.estimate().pose_stamp_s == 0.0  # type: ignore[union-attr]
    ekf.correct(1.1, 0.02, 0.0, 0.0, R)  # 1.1 s ahead of it: silent, both applied
    est = ekf.estimate()
    assert est is not None and est.pose_stamp_s == 1.1
    assert est.x_m == pytest.approx(0.01, abs=1e-3)  # the mean of the three fixes
    assert ekf.corrections == 3


def test_an_estimate_is_taken_once_and_a_pose_that_changes_nothing_gives_none() -> None:
    """The guard counts estimates towards its persistence: a POSE that waits for the
    odometry, or is held outside the gate, must not hand it the same estimate again."""
    ekf = PoseEkf()
    assert ekf.take_estimate() is None  # no map pose yet
    ekf.correct(0.0, 0.0, 0.0, 0.0, R)
    ekf.predict(0.0, 0.0, 0.0, 0.0)
    first = ekf.take_estimate()
    assert first is not None and ekf.take_estimate() is None
    ekf.predict(0.02, 0.01, 0.0, 0.0, 0.5)
    assert ekf.take_estimate() is not None
    ekf.correct(0.05, 0.025, 0.0, 0.0, R)  # ahead of the odometry: waits
    assert ekf.take_estimate() is None
    ekf.correct(0.02, 0.5, 0.0, 0.0, R)  # 0.49 m off: held for the next to confirm
    assert ekf.take_estimate() is None
    ekf.predict(0.06, 0.03, 0.0, 0.0, 0.5)  # passes the waiting POSE: one change
    taken = ekf.take_estimate()
    assert taken is not None and taken.pose_stamp_s == 0.05
