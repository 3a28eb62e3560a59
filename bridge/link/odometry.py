"""Odometry from the controller's telemetry, for ``/odom`` and the ground-pose topic.

:class:`OdometryEstimator` takes distance from the encoders and heading from the
integrated gyro (a skid-steer rover's turns make encoder differencing over-read yaw),
falling back to the encoders without IMU samples for ``imu_timeout_s``; covariances grow
with distance and time (docs/bridge.md, "Odometry"). Across a controller reboot the pose
is continuous (:meth:`OdometryEstimator.observe_boot`); a jump larger than
:data:`MAX_PLAUSIBLE_STEP_M` between two readings is taken for a counter reset too.

Encoders cannot see slip; the controller's POSE does: :func:`ground_pose` turns it into
a pose in the map frame with its own covariance, what drift control must use
(docs/architecture.md, Contracts 7).

Pure: no I/O, no threads, no ROS. Times are the controller's clock (``t_ms``) for
integration and the host's for stamps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from firmware_proto.model.geometry import wrap_rad
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import Encoders, Imu, PoseMsg, WheelSpeeds

__all__ = ["GroundPose", "OdometryEstimate", "OdometryEstimator", "ground_pose", "unwrap24"]

_WRAP24 = 1 << 24
_HALF24 = 1 << 23

#: Relative 1-sigma error of encoder distance (slip-free): 2 % of the distance.
DISTANCE_SIGMA_PER_M = 0.02
#: 1-sigma heading error growth of the integrated gyro, rad per sqrt(s).
GYRO_RANDOM_WALK = 0.003
#: A jump larger than this between two encoder readings is a counter reset, not motion.
MAX_PLAUSIBLE_STEP_M = 0.5


def unwrap24(previous: int, current: int) -> int:
    """Signed change from one 24-bit wrapping count to the next."""
    return ((current - previous + _HALF24) % _WRAP24) - _HALF24


@dataclass(frozen=True)
class OdometryEstimate:
    """Pose of ``base_link`` in the odometry frame, its velocities and uncertainty.

    Attributes:
        x_m, y_m, yaw_rad: pose (yaw counter-clockwise, wrapped to [-pi, pi)).
        v_mps: forward speed (mean wheel speed).
        yaw_rate_rad_s: angular speed (gyro when available).
        distance_m: path length travelled by the wheels.
        var_xy_m2, var_yaw_rad2: position (per axis) and heading variance.
        heading_source: ``"imu"`` or ``"encoders"``.
    """

    x_m: float
    y_m: float
    yaw_rad: float
    v_mps: float
    yaw_rate_rad_s: float
    distance_m: float
    var_xy_m2: float
    var_yaw_rad2: float
    heading_source: str


class OdometryEstimator:
    """Dead reckoning from ENCODERS, IMU and WHEEL_SPEEDS messages."""

    def __init__(self, rover: RoverDescription, *, imu_timeout_s: float = 0.2) -> None:
        self.rover = rover
        self.imu_timeout_s = imu_timeout_s
        self._units_per_m = float(rover.drive.distance_units_per_m)
        self.reset()

    def reset(self, x_m: float = 0.0, y_m: float = 0.0, yaw_rad: float = 0.0) -> None:
        """Start over at a pose (counts are re-referenced at the next reading)."""
        self._x, self._y, self._yaw = x_m, y_m, yaw_rad
        self._distance = 0.0
        self._counts: tuple[int, int] | None = None
        self._imu_t_ms: int | None = None
        self._imu_age_s = math.inf
        self._imu_yaw_delta = 0.0
        self._yaw_rate = 0.0
        self._v = 0.0
        self._elapsed_s = 0.0
        self._enc_t_ms: int | None = None
        self._source = "imu"
        self._boot: int | None = None
        """Which boot the counts are of, as :meth:`observe_boot` was last told."""
        self.resets = 0
        """Jumps taken for a counter reset by the plausibility check."""
        self.reboots = 0
        """Re-basings on a new boot nonce."""

    def rereference(self) -> None:
        """Counts restart (controller reboot): keep the pose, forget the last counts."""
        self._counts = None
        self._imu_t_ms = None
        self._enc_t_ms = None
        self._imu_yaw_delta = 0.0

    def observe_boot(self, boot: int) -> bool:
        """Which boot of the controller the telemetry is from (the link's count of
        reboots, or its boot nonce), after every IDENT and HEARTBEAT. A change (not the
        first seen): re-base on the next reading, keeping the pose. Returns whether it
        re-based."""
        previous, self._boot = self._boot, boot
        if previous is None or previous == boot:
            return False
        self.reboots += 1
        self.rereference()
        return True

    def update_imu(self, msg: Imu) -> None:
        """Integrate one gyro sample (trapezoid-free: rate held since the last one)."""
        rate = msg.yaw_rate_mrad_s / 1000.0
        if self._imu_t_ms is not None:
            dt = ((msg.t_ms - self._imu_t_ms) & 0xFFFF) / 1000.0
            if 0.0 < dt < 1.0:
                self._imu_yaw_delta += rate * dt
        self._imu_t_ms = msg.t_ms
        self._imu_age_s = 0.0
        self._yaw_rate = rate

    def update_speeds(self, msg: WheelSpeeds) -> None:
        """Forward speed from the measured wheel speeds."""
        self._v = (msg.left_mm_s + msg.right_mm_s) / 2000.0

    def update_encoders(self, msg: Encoders) -> OdometryEstimate:
        """Advance the pose by the travel since the last reading; returns the estimate."""
        if self._counts is None or self._enc_t_ms is None:
            self._counts = (msg.left, msg.right)
            self._enc_t_ms = msg.t_ms
            self._imu_yaw_delta = 0.0
            return self.estimate()
        dl = unwrap24(self._counts[0], msg.left) / self._units_per_m
        dr = unwrap24(self._counts[1], msg.right) / self._units_per_m
        dt = ((msg.t_ms - self._enc_t_ms) & 0xFFFF) / 1000.0
        self._counts = (msg.left, msg.right)
        self._enc_t_ms = msg.t_ms
        if abs(dl) > MAX_PLAUSIBLE_STEP_M or abs(dr) > MAX_PLAUSIBLE_STEP_M:
            self.resets += 1  # a counter reset: re-referenced above, no motion
            self._imu_yaw_delta = 0.0
            return self.estimate()
        self._imu_age_s += dt
        if self._imu_age_s <= self.imu_timeout_s:
            dyaw = self._imu_yaw_delta
            source = "imu"
        else:
            track = self.rover.geometry.track_width_m
            dyaw = (dr - dl) / track * self.rover.traction.turn_efficiency
            self._yaw_rate = dyaw / dt if dt > 0 else 0.0
            source = "encoders"
        self._imu_yaw_delta = 0.0
        ds = (dl + dr) / 2.0
        mid = self._yaw + dyaw / 2.0
        self._x += ds * math.cos(mid)
        self._y += ds * math.sin(mid)
        self._yaw = wrap_rad(self._yaw + dyaw)
        self._distance += abs(ds)
        self._elapsed_s += max(0.0, dt)
        self._source = source
        return self.estimate()

    def estimate(self) -> OdometryEstimate:
        """The current estimate."""
        sigma_d = DISTANCE_SIGMA_PER_M * self._distance
        var_yaw = GYRO_RANDOM_WALK**2 * self._elapsed_s
        # Heading error turns into cross-track error along the path.
        var_xy = sigma_d**2 + var_yaw * self._distance**2 + 1e-6
        return OdometryEstimate(
            self._x,
            self._y,
            self._yaw,
            self._v,
            self._yaw_rate,
            self._distance,
            var_xy,
            var_yaw + 1e-6,
            self._source,
        )


@dataclass(frozen=True)
class GroundPose:
    """The controller's ground-seeing pose in the map frame.

    Attributes:
        sigma_m: its 1-sigma position error (from POSE ``sigma_cm``).
        age_s: how old the measurement was when the controller sent it.
    """

    x_m: float
    y_m: float
    yaw_rad: float
    sigma_m: float
    age_s: float


def ground_pose(msg: PoseMsg) -> GroundPose | None:
    """The pose in a POSE message, or ``None`` when it carries no fix (``sigma_cm`` 0)."""
    if msg.sigma_cm == 0:
        return None
    return GroundPose(
        msg.x_mm / 1000.0,
        msg.y_mm / 1000.0,
        math.radians(msg.yaw_ddeg / 10.0),
        msg.sigma_cm / 100.0,
        msg.age_4ms * 4 / 1000.0,
    )
