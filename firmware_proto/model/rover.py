"""The rover description: geometry, mass, drive units, traction and safety thresholds.

One TOML file (``data/rover.toml`` by default) is read by every part, so that all agree
on what a distance or speed unit means. Load it with :func:`load_rover`; values are
immutable. A calibrated twin is a description with one more table, ``[calibration]``
(read by ``emulator.twinfile``), which :func:`load_rover` accepts and ignores.

Units are in the field names: ``_m`` metres, ``_mps`` m/s, ``_rad_s`` rad/s, ``_kg``.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from firmware_proto.errors import DescriptionError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = [
    "CALIBRATION_TABLE",
    "DEFAULT_ROVER_PATH",
    "Drive",
    "Environment",
    "Geometry",
    "Mass",
    "RoverDescription",
    "Safety",
    "Traction",
    "load_rover",
]

DEFAULT_ROVER_PATH = Path(__file__).resolve().parent / "data" / "rover.toml"

CALIBRATION_TABLE = "calibration"
"""The table a calibrated twin adds to a description; not part of the description."""


@dataclass(frozen=True)
class Geometry:
    """Chassis footprint and wheel placement, metres."""

    chassis_length_m: float
    chassis_width_m: float
    wheel_radius_m: float
    track_width_m: float
    wheelbase_m: float


@dataclass(frozen=True)
class Mass:
    """Rigid-body mass, kg."""

    mass_kg: float


@dataclass(frozen=True)
class Drive:
    """Command units and motor conventions (docs/architecture.md, Contracts 4)."""

    distance_units_per_m: int
    wheel_velocity_scale_rad_s: float
    left_wheel_sign: int
    right_wheel_sign: int
    max_speed: int
    max_distance: int
    wheel_accel_limit_mps2: float


@dataclass(frozen=True)
class Traction:
    """Wheel-ground friction model parameters (see docs/twin.md).

    Attributes:
        mu_longitudinal, mu_lateral: friction coefficients along and across a wheel.
        slip_saturation_mps: floor of the saturation slip speed (near standstill), m/s.
        slip_saturation_ratio: saturation slip speed per m/s of wheel speed.
        rolling_resistance: rolling resistance force / wheel load.
        turn_efficiency: body yaw / ideal yaw from wheel arc travel of an in-place
            spin, calibrated on the twin; planners turn by ``yaw * (track/2) / this``.
    """

    mu_longitudinal: float
    mu_lateral: float
    slip_saturation_mps: float
    slip_saturation_ratio: float
    rolling_resistance: float
    turn_efficiency: float


@dataclass(frozen=True)
class Environment:
    """Where the rover drives."""

    gravity_mps2: float


@dataclass(frozen=True)
class Safety:
    """Drift-control thresholds and the repair budget (docs/architecture.md, Contracts 6)."""

    drift_linear_m: float
    drift_angular_deg: float
    max_repair_attempts: int


@dataclass(frozen=True)
class RoverDescription:
    """The whole rover description; build it with :func:`load_rover`."""

    name: str
    geometry: Geometry
    mass: Mass
    drive: Drive
    traction: Traction
    environment: Environment
    safety: Safety

    # -- unit conversions shared by every part ------------------------------------
    def units_to_m(self, distance_units: float) -> float:
        """Convert encoder distance units to metres of wheel surface travel."""
        return distance_units / self.drive.distance_units_per_m

    def m_to_units(self, distance_m: float) -> int:
        """Convert metres of wheel travel to the nearest whole distance unit."""
        return round(distance_m * self.drive.distance_units_per_m)

    def speed_to_mps(self, speed: float) -> float:
        """Wheel surface speed, m/s, for a command speed in speed units."""
        return speed * self.drive.wheel_velocity_scale_rad_s * self.geometry.wheel_radius_m

    def speed_to_omega(self, speed: float) -> float:
        """Unsigned wheel angular speed, rad/s, for a command speed (``speed * k``)."""
        return speed * self.drive.wheel_velocity_scale_rad_s

    def turn_units_for_yaw(self, yaw_rad: float) -> int:
        """Distance units of a LEFT/RIGHT step that turns the body by ``|yaw_rad|`` on the
        spot: each side's arc travel for that yaw, divided by the calibrated
        ``traction.turn_efficiency`` (skid-steer wheels slip in a spin), rounded."""
        arc_m = abs(yaw_rad) * self.geometry.track_width_m / 2.0 / self.traction.turn_efficiency
        return self.m_to_units(arc_m)

    def yaw_for_turn_units(self, distance_units: float) -> float:
        """Body yaw, rad (unsigned), that a LEFT/RIGHT step of ``distance_units`` turns:
        the inverse of :meth:`turn_units_for_yaw`."""
        arc_m = self.units_to_m(distance_units)
        return self.traction.turn_efficiency * 2.0 * arc_m / self.geometry.track_width_m

    def step_duration_s(self, speed: int, distance: int) -> float:
        """Time, s, of a step's trapezoidal (or triangular) speed profile without slip,
        from rest to rest, at the wheel accel limit; 0 for a step with nothing to do."""
        v = self.speed_to_mps(speed)
        d = self.units_to_m(distance)
        if v <= 0.0 or d <= 0.0:
            return 0.0
        a = self.drive.wheel_accel_limit_mps2
        if d < v * v / a:  # never reaches cruise speed
            return 2.0 * math.sqrt(d / a)
        return d / v + v / a

    @property
    def max_speed_mps(self) -> float:
        """Top wheel surface speed, m/s."""
        return self.speed_to_mps(self.drive.max_speed)

    @property
    def footprint_radius_m(self) -> float:
        """Radius of the circle that encloses the chassis footprint, m."""
        return math.hypot(self.geometry.chassis_length_m, self.geometry.chassis_width_m) / 2

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict of every value, in file order."""
        return asdict(self)

    def digest(self) -> str:
        """SHA-256 of the canonical JSON of the values (for replayable verdicts)."""
        blob = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()


_SECTIONS: dict[str, type[Any]] = {
    "geometry": Geometry,
    "mass": Mass,
    "drive": Drive,
    "traction": Traction,
    "environment": Environment,
    "safety": Safety,
}


def _section(doc: dict[str, Any], name: str, cls: type[Any], source: str) -> Any:
    table = doc.get(name)
    if not isinstance(table, dict):
        raise DescriptionError(f"{source}: missing table [{name}]")
    wanted = {f.name: f.type for f in fields(cls)}
    unknown = sorted(set(table) - set(wanted))
    if unknown:
        raise DescriptionError(f"{source}: unknown key(s) in [{name}]: {', '.join(unknown)}")
    missing = sorted(set(wanted) - set(table))
    if missing:
        raise DescriptionError(f"{source}: missing key(s) in [{name}]: {', '.join(missing)}")
    values: dict[str, Any] = {}
    for key, type_name in wanted.items():
        value = table[key]
        if type_name == "int":
            ok = isinstance(value, int) and not isinstance(value, bool)
        else:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            value = float(value)
        if not ok or (isinstance(value, float) and not math.isfinite(value)):
            raise DescriptionError(f"{source}: [{name}] {key} must be a finite {type_name}")
        values[key] = value
    return cls(**values)


def _check(rover: RoverDescription, source: str) -> None:
    g, d, t = rover.geometry, rover.drive, rover.traction
    positive = {
        "geometry.chassis_length_m": g.chassis_length_m,
        "geometry.chassis_width_m": g.chassis_width_m,
        "geometry.wheel_radius_m": g.wheel_radius_m,
        "geometry.track_width_m": g.track_width_m,
        "geometry.wheelbase_m": g.wheelbase_m,
        "mass.mass_kg": rover.mass.mass_kg,
        "drive.distance_units_per_m": d.distance_units_per_m,
        "drive.wheel_velocity_scale_rad_s": d.wheel_velocity_scale_rad_s,
        "drive.max_speed": d.max_speed,
        "drive.max_distance": d.max_distance,
        "drive.wheel_accel_limit_mps2": d.wheel_accel_limit_mps2,
        "traction.mu_longitudinal": t.mu_longitudinal,
        "traction.mu_lateral": t.mu_lateral,
        "traction.slip_saturation_mps": t.slip_saturation_mps,
        "traction.slip_saturation_ratio": t.slip_saturation_ratio,
        "traction.rolling_resistance": t.rolling_resistance,
        "traction.turn_efficiency": t.turn_efficiency,
        "environment.gravity_mps2": rover.environment.gravity_mps2,
        "safety.drift_linear_m": rover.safety.drift_linear_m,
        "safety.drift_angular_deg": rover.safety.drift_angular_deg,
        "safety.max_repair_attempts": rover.safety.max_repair_attempts,
    }
    for key, value in positive.items():
        if value <= 0:
            raise DescriptionError(f"{source}: {key} must be > 0, got {value}")
    if t.turn_efficiency > 1:
        raise DescriptionError(
            f"{source}: traction.turn_efficiency must be <= 1, got {t.turn_efficiency}"
        )
    for key, sign in (
        ("left_wheel_sign", d.left_wheel_sign),
        ("right_wheel_sign", d.right_wheel_sign),
    ):
        if sign not in (-1, 1):
            raise DescriptionError(f"{source}: drive.{key} must be -1 or +1, got {sign}")


def load_rover(path: str | Path | None = None) -> RoverDescription:
    """Read and validate a rover description from ``path`` (``None``: the packaged
    :data:`DEFAULT_ROVER_PATH`).

    Raises:
        DescriptionError: the file is missing, not TOML, or a value is absent, unknown, of
            the wrong type or out of range (names the key). ``[calibration]`` is not checked.
    """
    source = Path(path) if path is not None else DEFAULT_ROVER_PATH
    try:
        doc = tomllib.loads(source.read_text(encoding="utf-8"))
    except OSError as exc:
        raise DescriptionError(f"cannot read rover description {source}: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise DescriptionError(f"{source}: not valid TOML: {exc}") from exc
    if doc.get("schema_version") != 1:
        raise DescriptionError(f"{source}: schema_version must be 1")
    name = doc.get("name")
    if not isinstance(name, str) or not name:
        raise DescriptionError(f"{source}: name must be a non-empty string")
    extra = sorted(set(doc) - set(_SECTIONS) - {"schema_version", "name", CALIBRATION_TABLE})
    if extra:
        raise DescriptionError(f"{source}: unknown table(s) or key(s): {', '.join(extra)}")
    parts = {key: _section(doc, key, cls, str(source)) for key, cls in _SECTIONS.items()}
    rover = RoverDescription(name=name, **parts)
    _check(rover, str(source))
    return rover
