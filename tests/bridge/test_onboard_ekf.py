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
    est = ekf.estimate()
    assert est is not None
    assert est.y_m == pytest.approx(0.3, abs=0.02)
    assert ekf.inflations == 1


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
