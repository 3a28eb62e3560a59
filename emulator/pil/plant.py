"""The pymunk twin as the plant of an emulated MCU: motor outputs in, sensors out.

The twin and sensor models of ``rover emulate``; the wheels turn at the surface speed
the PWM duty and direction pins command. Slip and stall go into the twin; an encoder
dropout holds that side's count and raises the decoder's error line. Pure: no I/O,
threads or clock (the caller steps it).
"""

from __future__ import annotations

import math
import random
import struct
from dataclasses import dataclass

from emulator.drive import motor_omegas
from emulator.sensors import EncoderModel, ImuModel, PoseSensor, SensorConfig, wrap_count
from emulator.twin import Pose2D, Twin
from firmware_proto.model.rover import RoverDescription

__all__ = ["SENSORS", "MotorOutputs", "TwinPlant"]

SENSORS = struct.Struct("<BBBB2i2i3hBB2ihI")
"""``pil_sensors_t`` (``port_pil/pil_port.h``)."""


@dataclass(frozen=True)
class MotorOutputs:
    """What the firmware drives: PWM duty (0..top) and direction (True: reverse) per
    motor, the PWM's top, and the wheel surface speed of 100 % duty (um/s)."""

    duty: tuple[int, int]
    reverse: tuple[bool, bool]
    top: int
    full_scale_um_s: int

    def motor_um_s(self) -> tuple[float, float]:
        """Commanded wheel surface speeds, motor frame, um/s."""
        scale = self.full_scale_um_s / (self.top + 1) if self.top > 0 else 0.0
        return (
            (-1.0 if self.reverse[0] else 1.0) * self.duty[0] * scale,
            (-1.0 if self.reverse[1] else 1.0) * self.duty[1] * scale,
        )


def _clamp16(value: float) -> int:
    return max(-32768, min(32767, round(value)))


class TwinPlant:
    """One twin (its ``dt_s`` is the step) with its sensors (``sensors``, noise seeded
    by ``seed``, POSE fixes at ``pose_hz``), stepped by the caller; ``rover`` is the
    twin's and the firmware's.
    """

    def __init__(
        self,
        rover: RoverDescription,
        twin: Twin,
        seed: int = 1,
        sensors: SensorConfig | None = None,
        pose_hz: float = 10.0,
    ) -> None:
        self.rover = rover
        self.twin = twin
        cfg = sensors or SensorConfig()
        rng = random.Random(seed)
        self.encoders = EncoderModel(rover, twin, rng, cfg.encoder_noise_units)
        self.imu = ImuModel(twin, rng, cfg)
        self.pose_sensor = PoseSensor(twin, rng, cfg)
        self._pose_every = max(1, round(1.0 / (pose_hz * twin.dt_s)))
        self._seq = 0
        self._pose_seq = 0
        self._pose: tuple[int, int, int, int, float] = (0, 0, 0, 0, 0.0)
        self._slip = [1.0, 1.0]
        self.commanded_mps = (0.0, 0.0)
        self.travel_m = 0.0
        """Ground travel of the rover's centre since the start, m (``@d=`` triggers)."""
        self._last_xy = (twin.pose.x_m, twin.pose.y_m)

    # -- faults ------------------------------------------------------------------------------
    def set_slip(self, side: int, scale: float) -> None:
        """That side's traction scaled (1: none lost)."""
        self._slip[side] = scale
        self.twin.set_traction_scale(self._slip[0], self._slip[1])

    def set_stall(self, side: int, locked: bool) -> None:
        """That side's wheels locked or free."""
        self.twin.set_wheel_locked(("left", "right")[side], locked)

    def set_dropout(self, side: int, dropped: bool) -> None:
        """That side's encoder holds its count and raises the error line."""
        self.encoders.dropout[side] = dropped

    def reboot(self) -> None:
        """The MCU was reset: the decoder's counters restart from zero, pending pose fixes
        are lost (the world goes on)."""
        self.encoders.reset()
        self.pose_sensor.clear()

    # -- one step ----------------------------------------------------------------------------
    def step(self, outputs: MotorOutputs) -> None:
        """Apply the motor outputs and advance the twin one step."""
        d = self.rover.drive
        ml, mr = outputs.motor_um_s()
        left, right = d.left_wheel_sign * ml / 1e6, d.right_wheel_sign * mr / 1e6
        self.commanded_mps = (left, right)
        self.twin.set_motor_omegas(*motor_omegas(self.rover, left, right))
        self.twin.step()
        pose = self.twin.pose
        self.travel_m += math.hypot(pose.x_m - self._last_xy[0], pose.y_m - self._last_xy[1])
        self._last_xy = (pose.x_m, pose.y_m)
        if self.twin.steps % self._pose_every == 0:
            self.pose_sensor.sample()
        for m in self.pose_sensor.due():
            yaw = round(math.degrees(m.pose.yaw_rad) * 10.0)
            yaw = (yaw + 1800) % 3600 - 1800
            sigma = 0 if m.sigma_m <= 0.0 else max(1, min(15, round(m.sigma_m * 100.0)))
            self._pose = (
                round(m.pose.x_m * 1000.0),
                round(m.pose.y_m * 1000.0),
                yaw,
                sigma,
                m.taken_s,
            )
            self._pose_seq = (self._pose_seq + 1) & 0xFF

    def sensors(self) -> bytes:
        """``pil_sensors`` as the harness posts it now (its ``seq`` advanced)."""
        d = self.rover.drive
        left, right = self.encoders.counts()
        enc = (
            int(wrap_count(d.left_wheel_sign * left)),
            int(wrap_count(d.right_wheel_sign * right)),
        )
        vl, vr = self.twin.wheel_surface_speeds_mps
        speed = (int(d.left_wheel_sign * vl * 1e6), int(d.right_wheel_sign * vr * 1e6))
        imu = self.imu.read()
        imu_raw = (
            (0, 0, 0)
            if imu is None
            else (
                _clamp16(imu.yaw_rate_rad_s * 1000.0),
                _clamp16(imu.accel_x_mps2 * 1000.0),
                _clamp16(imu.accel_y_mps2 * 1000.0),
            )
        )
        x, y, yaw, sigma, taken_s = self._pose
        age_us = max(0, round((self.twin.time_s - taken_s) * 1e6)) if self._pose_seq else 0
        error = (1 if self.encoders.dropout[0] else 0) | (2 if self.encoders.dropout[1] else 0)
        self._seq = (self._seq + 1) & 0xFF
        return SENSORS.pack(
            self._seq,
            error,
            0 if imu is None else 1,
            self._pose_seq,
            *enc,
            *speed,
            *imu_raw,
            sigma,
            0,
            max(-(2**31), min(2**31 - 1, x)),
            max(-(2**31), min(2**31 - 1, y)),
            yaw,
            min(age_us, 2**32 - 1),
        )

    @property
    def pose(self) -> Pose2D:
        """Ground truth."""
        return self.twin.pose
