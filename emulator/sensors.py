"""Sensor models of the controller: wheel encoders, IMU, and a ground-seeing pose sensor.

Encoders cannot see slip; the IMU's yaw rate and the POSE sensor see the ground
(docs/architecture.md, Contracts 7). All three read the twin's ground truth and add
injectable noise, bias, latency and dropout. Pure: no I/O, threads or wall clock; every
draw comes from a ``random.Random`` the caller seeds.
"""

from __future__ import annotations

import math
import random
from collections import deque
from dataclasses import dataclass

from emulator.drive import travel_units
from emulator.twin import Pose2D, Twin
from firmware_proto.model.geometry import wrap_rad
from firmware_proto.model.rover import RoverDescription

__all__ = [
    "COUNTER_MODULUS",
    "EncoderModel",
    "ImuModel",
    "ImuReading",
    "PoseMeasurement",
    "PoseSensor",
    "SensorConfig",
    "count_delta",
    "wrap_count",
]

COUNTER_MODULUS = 1 << 32
"""An encoder counter is an int32, wrapping modulo this (firmware_proto/wire/c/fw/fw_hal.h)."""
_HALF = COUNTER_MODULUS // 2


def wrap_count(units: float) -> float:
    """``units`` as the 32-bit counter reads it: in ``[-2**31, 2**31)``, congruent modulo
    ``2**32``. A value already in range is returned unchanged (no float rounding)."""
    if -_HALF <= units < _HALF:
        return units
    return (units + _HALF) % COUNTER_MODULUS - _HALF


def count_delta(after: float, before: float) -> float:
    """Travel between two readings of a wrapping counter, distance units: the difference
    modulo ``2**32`` in ``[-2**31, 2**31)``, right across a wrap below ``2**31`` of travel."""
    return wrap_count(after - before)


@dataclass(frozen=True)
class SensorConfig:
    """Noise and timing of the sensors (defaults: a MEMS gyro and lab tracking).

    Attributes:
        encoder_noise_units: 1-sigma noise added to each reported count, distance units.
        imu_noise_rad_s: 1-sigma white noise on the yaw rate, rad/s.
        imu_bias_rad_s: constant yaw-rate bias, rad/s.
        accel_noise_mps2: 1-sigma noise on each acceleration axis, m/s^2.
        pose_noise_m: 1-sigma noise on each pose coordinate, m.
        pose_yaw_noise_rad: 1-sigma noise on the pose yaw, rad.
        pose_latency_s: age of a pose measurement when it is reported, s.
    """

    encoder_noise_units: float = 0.0
    imu_noise_rad_s: float = 0.003
    imu_bias_rad_s: float = 0.0
    accel_noise_mps2: float = 0.02
    pose_noise_m: float = 0.01
    pose_yaw_noise_rad: float = math.radians(0.5)
    pose_latency_s: float = 0.1


class EncoderModel:
    """Wheel counts since boot, forward positive, distance units, as a wrapping signed
    32-bit counter (differences via :func:`count_delta`). Per side: injectable noise and
    dropout (the count holds)."""

    def __init__(
        self, rover: RoverDescription, twin: Twin, rng: random.Random, noise_units: float
    ) -> None:
        self._rover = rover
        self._twin = twin
        self._rng = rng
        self.noise_units = [noise_units, noise_units]
        self.dropout = [False, False]
        self._offset = travel_units(rover, *twin.motor_angles_rad)
        self._held = [0.0, 0.0]
        d = rover.drive
        # travel_units's factors, for travel() on the hot path (the rover is immutable).
        self._scale = rover.geometry.wheel_radius_m * d.distance_units_per_m
        self._signs = (d.left_wheel_sign, d.right_wheel_sign)

    def reset(self) -> None:
        """Counts restart from zero (a reboot)."""
        self._offset = travel_units(self._rover, *self._twin.motor_angles_rad)
        self._held = [0.0, 0.0]

    def set_counts(self, left_units: float, right_units: float) -> None:
        """The counters read these values now and count on from them (rover frame)."""
        left, right = travel_units(self._rover, *self._twin.motor_angles_rad)
        self._offset = (left - left_units, right - right_units)
        self._held = [wrap_count(left_units), wrap_count(right_units)]

    def travel(self) -> tuple[float, float]:
        """Noise-free counts since boot in the counter's range (what the step logic
        integrates); a side in dropout holds its last value."""
        # travel_units and wrap_count inlined (the same arithmetic): this runs a few times
        # every control tick.
        angle_l, angle_r = self._twin.motor_angles_rad
        sign_l, sign_r = self._signs
        scale = self._scale
        offset = self._offset
        left = sign_l * angle_l * scale - offset[0]
        right = sign_r * angle_r * scale - offset[1]
        if not -_HALF <= left < _HALF:
            left = (left + _HALF) % COUNTER_MODULUS - _HALF
        if not -_HALF <= right < _HALF:
            right = (right + _HALF) % COUNTER_MODULUS - _HALF
        dropout, held = self.dropout, self._held
        if dropout[0]:
            left = held[0]
        else:
            held[0] = left
        if dropout[1]:
            right = held[1]
        else:
            held[1] = right
        return left, right

    def counts(self) -> tuple[int, int]:
        """Reported counts: travel plus noise, rounded, in the 32-bit counter's range (not
        yet wrapped to the 24 bits of ENCODERS)."""
        left, right = self.travel()
        sigma_l, sigma_r = self.noise_units
        dropout = self.dropout
        # Left's draw first, then right's.
        noise_l = self._rng.gauss(0.0, sigma_l) if sigma_l > 0.0 and not dropout[0] else 0.0
        noise_r = self._rng.gauss(0.0, sigma_r) if sigma_r > 0.0 and not dropout[1] else 0.0
        return int(wrap_count(round(left + noise_l))), int(wrap_count(round(right + noise_r)))


@dataclass(frozen=True)
class ImuReading:
    """One IMU sample: yaw rate (rad/s, counter-clockwise) and body-frame acceleration."""

    yaw_rate_rad_s: float
    accel_x_mps2: float
    accel_y_mps2: float


class ImuModel:
    """Yaw rate and planar acceleration from the twin, with white noise and a bias."""

    def __init__(self, twin: Twin, rng: random.Random, config: SensorConfig) -> None:
        self._twin = twin
        self._rng = rng
        self.noise_rad_s = config.imu_noise_rad_s
        self.bias_rad_s = config.imu_bias_rad_s
        self.accel_noise_mps2 = config.accel_noise_mps2
        self.dropout = False

    def read(self) -> ImuReading | None:
        """A sample, or ``None`` while the IMU is dropped out."""
        if self.dropout:
            return None
        yaw_rate, ax, ay = self._twin.imu_truth()
        gauss = self._rng.gauss
        return ImuReading(
            yaw_rate + self.bias_rad_s + gauss(0.0, self.noise_rad_s),
            ax + gauss(0.0, self.accel_noise_mps2),
            ay + gauss(0.0, self.accel_noise_mps2),
        )


@dataclass(frozen=True)
class PoseMeasurement:
    """A pose from the ground-seeing sensor: the noisy pose, its 1-sigma position error
    (m; 0 means no fix) and when it was taken (twin time, s)."""

    pose: Pose2D
    sigma_m: float
    taken_s: float


class PoseSensor:
    """Ground-truth pose with noise, reported ``latency_s`` after :meth:`sample` took
    it (:meth:`due`, oldest first). During a dropout samples carry ``sigma_m = 0`` (no
    fix) and the last fix's pose.
    """

    def __init__(self, twin: Twin, rng: random.Random, config: SensorConfig) -> None:
        self._twin = twin
        self._rng = rng
        self.noise_m = config.pose_noise_m
        self.yaw_noise_rad = config.pose_yaw_noise_rad
        self.latency_s = config.pose_latency_s
        self.dropout = False
        self._pending: deque[PoseMeasurement] = deque()
        self._last = twin.pose

    def sample(self) -> None:
        """Take a measurement at the twin's current time."""
        now = self._twin.time_s
        if self.dropout:
            self._pending.append(PoseMeasurement(self._last, 0.0, now))
            return
        truth = self._twin.pose
        gauss = self._rng.gauss
        pose = Pose2D(
            truth.x_m + gauss(0.0, self.noise_m),
            truth.y_m + gauss(0.0, self.noise_m),
            wrap_rad(truth.yaw_rad + gauss(0.0, self.yaw_noise_rad)),
        )
        self._last = pose
        # A perfect sensor still reports 1 cm: zero is reserved for "no fix".
        self._pending.append(PoseMeasurement(pose, max(self.noise_m, 0.01), now))

    def due(self) -> list[PoseMeasurement]:
        """Measurements whose latency has elapsed, oldest first (removed from the queue)."""
        now = self._twin.time_s
        out = []
        while self._pending and self._pending[0].taken_s + self.latency_s <= now + 1e-9:
            out.append(self._pending.popleft())
        return out

    def clear(self) -> None:
        """Drop measurements not yet reported (a reboot)."""
        self._pending.clear()
