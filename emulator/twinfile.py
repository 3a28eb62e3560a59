"""The calibrated twin description: a rover description with its fit attached.

``rover calibrate`` writes one file that every part can read:

- the whole rover description (``[geometry]`` ... ``[safety]``) with ``[traction]``
  holding the fitted ground's parameters and, as ``turn_efficiency``, the fitted
  ground's calibration spin: the planner's turn model then matches the twin
  (``rover go --rover FILE``, ``load_rover`` ignores the rest);
- a ``[calibration]`` table: the recordings, the map, the twin's step, the residuals
  before and after, and for every fitted parameter its value and relative 1-sigma error,
  with the covariance matrix of the logarithms (:class:`~emulator.calibration.
  Calibration`), each parameter's target 1-sigma, the noise the fit estimated
  (``slip_sigma``, ``pose_sigma_m``, ``heading_sigma_deg``: the gate's slip spread and
  start-pose spread), the gate's model discrepancy (``step_error_scale``: its 1-sigma in
  units of a plan's step error, :func:`gate.ensemble.step_error`; a file without it
  has none), how many held-out checks fell inside their bands, and the posterior's
  draws (``posterior_log``, what the gate samples grounds from);
  ``[calibration.regions]`` holds the fitted friction scale of each map region driven
  on.

:func:`load_twin` reads it back as a :class:`TwinDescription`: the rover description,
the calibration, and the ground to build twins with (:meth:`TwinDescription.world`
applies the region scales to the calibration's map). ``rover gate --twin FILE`` plays
every plan on it.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from emulator.calibration import Calibration, Noise, Residuals
from emulator.errors import GroundError
from emulator.ground import Ground
from firmware_proto.errors import DescriptionError
from firmware_proto.model.rover import CALIBRATION_TABLE, RoverDescription, load_rover
from firmware_proto.model.worldmap import WorldMap

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = ["TwinDescription", "load_twin", "twin_toml", "write_twin"]


@dataclass(frozen=True)
class TwinDescription:
    """A calibrated twin: the rover description to build twins from, and its fit.

    Attributes:
        rover: the description, traction fitted (what :func:`load_rover` reads).
        calibration: the fit.
    """

    rover: RoverDescription
    calibration: Calibration

    @property
    def ground(self) -> Ground:
        """The fitted ground (traction and region scales)."""
        return self.calibration.ground

    def world(self, world: WorldMap | None) -> WorldMap | None:
        """``world`` with the fitted region scales if it is the calibration's map;
        other maps unchanged."""
        if world is None or world.name != self.calibration.map_name:
            return world
        return self.ground.world(world, strict=False)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        if not value:
            return "{}"
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def _table(name: str, values: dict[str, Any]) -> list[str]:
    return [f"[{name}]", *(f"{k} = {_toml_value(v)}" for k, v in values.items()), ""]


def twin_toml(base: RoverDescription, calibration: Calibration) -> str:
    """The twin description's text (module docstring)."""
    rover = calibration.ground.rover(base)
    sections = rover.to_dict()
    sections["traction"]["turn_efficiency"] = round(calibration.turn_efficiency, 4)
    cal = calibration
    lines = [
        "# A calibrated twin: the rover description with its traction fitted to recorded",
        "# missions by `rover calibrate`; [calibration] says how well (docs/twin.md).",
        "# Serve it with `rover gate --twin FILE`; plan with it with `rover go --rover FILE`.",
        "schema_version = 1",
        f"name = {json.dumps(rover.name)}",
        "",
    ]
    for key in ("geometry", "mass", "drive", "traction", "environment", "safety"):
        lines += _table(key, sections[key])
    lines += _table(
        CALIBRATION_TABLE,
        {
            "schema_version": 1,
            "ground": cal.ground.name,
            "sources": list(cal.sources),
            "map": cal.map_name or "",
            "dt_s": cal.dt_s,
            "steps": cal.after.steps,
            "driving_s": cal.driving_s,
            "reduced_chi2": cal.reduced_chi2,
            "parameters": list(cal.parameters),
            "values": [cal.value(p) for p in cal.parameters],
            "relative_sigma": [round(cal.relative_sigma(p), 6) for p in cal.parameters],
            "covariance_log": [list(row) for row in cal.covariance],
            "fixed": {k: v for k, v in cal.ground.values().items() if k not in cal.parameters},
            "fixed_regions": list(cal.fixed_regions),
            "residuals_before": _residuals(cal.before),
            "residuals_after": _residuals(cal.after),
            **_noise(cal),
        },
    )
    if cal.ground.regions:
        lines += _table(f"{CALIBRATION_TABLE}.regions", dict(cal.ground.regions))
    return "\n".join(lines)


def _noise(cal: Calibration) -> dict[str, Any]:
    """The noise terms, the targets and the checks' outcome (when the fit made them)."""
    out: dict[str, Any] = {}
    if cal.noise is not None:
        out["slip_sigma"] = round(cal.noise.slip_sigma, 6)
        out["pose_sigma_m"] = round(cal.noise.pose_sigma_m, 6)
        out["heading_sigma_deg"] = round(math.degrees(cal.noise.heading_sigma_rad), 6)
    if cal.step_error_scale > 0.0:
        out["step_error_scale"] = round(cal.step_error_scale, 6)
    if cal.targets:
        out["target_sigma"] = [round(t, 6) for t in cal.targets]
    if cal.checks:
        inside = [sum(c.inside[a] for c in cal.checks) for a in range(3)]
        out["checks"] = {"steps": len(cal.checks), "inside_forward_lateral_yaw": inside}
    if cal.draws:
        out["posterior_log"] = [[round(v, 7) for v in row] for row in cal.draws]
    return out


def _residuals(r: Residuals) -> dict[str, Any]:
    return {
        "forward_m": r.forward_m,
        "lateral_m": r.lateral_m,
        "yaw_deg": r.yaw_deg,
        "steps": r.steps,
    }


def write_twin(path: str | Path, base: RoverDescription, calibration: Calibration) -> None:
    """Write the twin description of ``calibration`` over ``base`` to ``path``.

    Raises:
        OSError: it cannot be written.
    """
    Path(path).write_text(twin_toml(base, calibration), encoding="utf-8")


def load_twin(path: str | Path) -> TwinDescription:
    """Read a twin description written by :func:`write_twin`.

    Raises:
        GroundError: the file cannot be read, is not a valid description, or has no
            valid ``[calibration]`` table (the message names what is wrong).
    """
    source = str(path)
    try:
        rover = load_rover(path)
        doc = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except DescriptionError as exc:
        raise GroundError(f"twin {source}: {exc}") from exc
    except (OSError, tomllib.TOMLDecodeError) as exc:  # pragma: no cover - load_rover read it
        raise GroundError(f"twin {source}: {exc}") from exc
    table = doc.get(CALIBRATION_TABLE)
    if not isinstance(table, dict):
        raise GroundError(
            f"twin {source}: no [{CALIBRATION_TABLE}] table: a plain rover description "
            "(serve it with --rover), not a calibrated twin"
        )
    try:
        calibration = _calibration(table, rover)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise GroundError(f"twin {source}: invalid [{CALIBRATION_TABLE}]: {exc!r}") from exc
    return TwinDescription(rover, calibration)


def _calibration(table: dict[str, Any], rover: RoverDescription) -> Calibration:
    if table.get("schema_version") != 1:
        raise ValueError("schema_version must be 1")
    names = tuple(str(n) for n in table["parameters"])
    values = [float(v) for v in table["values"]]
    cov = tuple(tuple(float(v) for v in row) for row in table["covariance_log"])
    if (
        len(values) != len(names)
        or len(cov) != len(names)
        or any(len(r) != len(names) for r in cov)
    ):
        raise ValueError("parameters, values and covariance_log disagree in size")
    if any(not math.isfinite(v) for row in cov for v in row):
        raise ValueError("covariance_log is not finite")
    regions = {str(k): float(v) for k, v in table.get("regions", {}).items()}
    ground = replace(
        Ground.of_rover(rover),
        name=str(table.get("ground", rover.name)),
        regions=tuple(sorted(regions.items())),
    ).with_values(**dict(zip(names, values, strict=True)))

    def residuals(key: str) -> Residuals:
        r = table[key]
        return Residuals(
            float(r["forward_m"]), float(r["lateral_m"]), float(r["yaw_deg"]), int(r["steps"])
        )

    noise = None
    if "slip_sigma" in table:
        noise = Noise(
            slip_sigma=float(table["slip_sigma"]),
            pose_sigma_m=float(table.get("pose_sigma_m", 0.0)),
            heading_sigma_rad=math.radians(float(table.get("heading_sigma_deg", 0.0))),
        )
        if (
            not (0.0 <= noise.slip_sigma <= 1.0)
            or noise.pose_sigma_m < 0
            or noise.heading_sigma_rad < 0
        ):
            raise ValueError("slip_sigma must be in [0, 1] and the pose sigmas >= 0")
    targets = tuple(float(t) for t in table.get("target_sigma", []))
    if targets and len(targets) != len(names):
        raise ValueError("target_sigma and parameters disagree in size")
    step_error_scale = float(table.get("step_error_scale", 0.0))
    if not (0.0 <= step_error_scale <= 10.0):
        raise ValueError("step_error_scale must be in [0, 10]")
    draws = tuple(tuple(float(v) for v in row) for row in table.get("posterior_log", []))
    if any(len(row) != len(names) or not all(map(math.isfinite, row)) for row in draws):
        raise ValueError("posterior_log rows must be finite and one value per parameter")
    return Calibration(
        ground=ground,
        parameters=names,
        covariance=cov,
        before=residuals("residuals_before"),
        after=residuals("residuals_after"),
        reduced_chi2=float(table["reduced_chi2"]),
        driving_s=float(table["driving_s"]),
        sources=tuple(str(s) for s in table.get("sources", [])),
        map_name=str(table["map"]) or None,
        dt_s=float(table["dt_s"]),
        turn_efficiency=float(rover.traction.turn_efficiency),
        fixed_regions=tuple(str(r) for r in table.get("fixed_regions", [])),
        noise=noise,
        targets=targets,
        draws=draws,
        step_error_scale=step_error_scale,
    )
