"""The ground a twin drives on: its traction parameters and per-region friction.

The rover description's ``[traction]`` is what the gate *assumes*; a :class:`Ground` is
what the ground *is*: the five wheel-ground parameters of :mod:`emulator.traction` plus
a friction scale per map traction region (replacing the map's ``mu_scale``), applied
through :meth:`Ground.rover` and :meth:`Ground.world` (the twin itself is unchanged).
``rover emulate --ground NAME|FILE`` drives on one; ``rover calibrate`` fits one.

A ground file is TOML: ``schema_version = 1``, ``name``, ``description``, a
``[traction]`` subset (the rest from the rover description) and ``[regions]`` scales in
(0, 2]; shipped ones in ``emulator/grounds/`` load by bare name. ``turn_efficiency``
may stand for ``mu_lateral`` (:func:`solve_mu_lateral`); a file stating both is refused
unless they agree within :data:`TURN_EFFICIENCY_AGREEMENT`. docs/twin.md, "A ground the
gate does not know".
"""

from __future__ import annotations

import json
import logging
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from emulator.errors import GroundError
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = [
    "GROUNDS_DIR",
    "GROUND_PARAMETERS",
    "TURN_EFFICIENCY_AGREEMENT",
    "Ground",
    "ground_from_dict",
    "list_grounds",
    "load_ground",
    "parse_ground_setting",
    "solve_mu_lateral",
]

logger = logging.getLogger(__name__)

GROUNDS_DIR = Path(__file__).resolve().parent / "grounds"
"""Where the shipped ground files live (``load_ground("loose")``)."""

GROUND_PARAMETERS = (
    "mu_longitudinal",
    "mu_lateral",
    "slip_saturation_mps",
    "slip_saturation_ratio",
    "rolling_resistance",
)
"""The traction parameters a ground sets: the rover description's ``[traction]`` keys less
``turn_efficiency`` (a property of the rover on a ground, not a force-model input)."""

REGION_SCALE_MAX = 2.0
"""Largest region friction scale (the map format's bound)."""

_TURN_EFFICIENCY_TOLERANCE = 1e-4

TURN_EFFICIENCY_AGREEMENT = 0.005
"""Largest gap between a ground file's stated ``turn_efficiency`` and what its ``mu_lateral``
turns at (the rover description's own tolerance: docs/twin.md, Recalibrating)."""


@dataclass(frozen=True)
class Ground:
    """Wheel-ground parameters (SI, see :mod:`emulator.traction`) and region scales.

    Attributes:
        name: a short name for messages and files.
        mu_longitudinal, mu_lateral: friction coefficients along and across a wheel.
        slip_saturation_mps: floor of the saturation slip speed, m/s.
        slip_saturation_ratio: saturation slip speed per m/s of wheel speed.
        rolling_resistance: rolling resistance force / wheel load.
        regions: ``(region_id, mu_scale)`` pairs, sorted by id, replacing the map's
            scale of each named region.
        description: free text.
    """

    name: str
    mu_longitudinal: float
    mu_lateral: float
    slip_saturation_mps: float
    slip_saturation_ratio: float
    rolling_resistance: float
    regions: tuple[tuple[str, float], ...] = ()
    description: str = ""

    def __post_init__(self) -> None:
        for key in GROUND_PARAMETERS:
            value = getattr(self, key)
            if not (isinstance(value, float) and math.isfinite(value) and value > 0.0):
                raise GroundError(f"ground {self.name!r}: {key} must be a finite float > 0")
        ids = [rid for rid, _ in self.regions]
        if ids != sorted(set(ids)):
            raise GroundError(f"ground {self.name!r}: region ids must be unique and sorted")
        for rid, scale in self.regions:
            if not (math.isfinite(scale) and 0.0 < scale <= REGION_SCALE_MAX):
                raise GroundError(
                    f"ground {self.name!r}: region {rid!r} mu_scale must be in "
                    f"(0, {REGION_SCALE_MAX:g}], got {scale}"
                )

    @classmethod
    def of_rover(cls, rover: RoverDescription, world: WorldMap | None = None) -> Ground:
        """The ground a rover description assumes (its ``[traction]``), with the map's
        own region scales: what the gate's twin drives on."""
        t = rover.traction
        regions = tuple(sorted((r.id, r.mu_scale) for r in world.traction_regions)) if world else ()
        return cls(
            name=rover.name,
            mu_longitudinal=float(t.mu_longitudinal),
            mu_lateral=float(t.mu_lateral),
            slip_saturation_mps=float(t.slip_saturation_mps),
            slip_saturation_ratio=float(t.slip_saturation_ratio),
            rolling_resistance=float(t.rolling_resistance),
            regions=regions,
        )

    def values(self) -> dict[str, float]:
        """The five traction parameters by name, in :data:`GROUND_PARAMETERS` order."""
        return {key: getattr(self, key) for key in GROUND_PARAMETERS}

    def region_scale(self, region_id: str) -> float | None:
        """The scale this ground gives region ``region_id``, or ``None``."""
        for rid, scale in self.regions:
            if rid == region_id:
                return scale
        return None

    def with_values(self, **changes: float) -> Ground:
        """A copy with some traction parameters or region scales changed; a key
        ``region.ID`` sets region ``ID``'s scale.

        Raises:
            GroundError: an unknown key or a value out of range.
        """
        params: dict[str, Any] = {}
        regions = dict(self.regions)
        for key, value in changes.items():
            if key.startswith("region."):
                regions[key[len("region.") :]] = float(value)
            elif key in GROUND_PARAMETERS:
                params[key] = float(value)
            else:
                raise GroundError(
                    f"unknown ground parameter {key!r}; known: "
                    f"{', '.join(GROUND_PARAMETERS)}, region.ID"
                )
        return replace(self, regions=tuple(sorted(regions.items())), **params)

    def rover(self, base: RoverDescription) -> RoverDescription:
        """``base`` with its traction replaced by this ground's (``turn_efficiency``
        kept: it is the planner's model, see :func:`solve_mu_lateral`)."""
        return replace(base, traction=replace(base.traction, **self.values()))

    def world(self, world: WorldMap | None, *, strict: bool = True) -> WorldMap | None:
        """``world`` with the region scales of this ground.

        Args:
            world: the map (``None``: an open plane, which has no regions).
            strict: a region of this ground that the map lacks is an error; otherwise
                it is skipped (a ground calibrated on one map, served with others).

        Raises:
            GroundError: ``strict`` and a region is not in the map.
        """
        if not self.regions:
            return world
        present = {r.id for r in world.traction_regions} if world is not None else set()
        missing = sorted(rid for rid, _ in self.regions if rid not in present)
        if missing and strict:
            where = f"map {world.name!r}" if world is not None else "an open plane"
            raise GroundError(
                f"ground {self.name!r} sets region(s) {', '.join(missing)} that {where} "
                f"lacks (its regions: {', '.join(sorted(present)) or 'none'})"
            )
        if world is None:
            return None
        scales = dict(self.regions)
        regions = tuple(
            replace(r, mu_scale=scales[r.id]) if r.id in scales else r
            for r in world.traction_regions
        )
        return replace(world, traction_regions=regions)

    def to_toml(self) -> str:
        """The ground as a ground file (what :func:`load_ground` reads back)."""
        lines = [
            "schema_version = 1",
            f"name = {_toml_str(self.name)}",
            f"description = {_toml_str(self.description)}",
            "",
            "[traction]",
        ]
        lines += [f"{key} = {value!r}" for key, value in self.values().items()]
        if self.regions:
            lines += ["", "[regions]"]
            lines += [f"{_toml_key(rid)} = {scale!r}" for rid, scale in self.regions]
        return "\n".join(lines) + "\n"


def _toml_str(text: str) -> str:
    """A TOML basic string (JSON's escapes are TOML's)."""
    return json.dumps(text)


def _toml_key(key: str) -> str:
    bare = key and all(c.isalnum() or c in "-_" for c in key)
    return key if bare else _toml_str(key)


def list_grounds() -> tuple[str, ...]:
    """Names of the shipped grounds, sorted (``load_ground`` accepts each)."""
    return tuple(sorted(p.stem for p in GROUNDS_DIR.glob("*.toml")))


def ground_from_dict(doc: dict[str, Any], rover: RoverDescription, source: str) -> Ground:
    """Build a ground from a parsed ground file (see the module docstring).

    Raises:
        GroundError: a missing or unknown key, a wrong type, a value out of range, or
            both ``mu_lateral`` and ``turn_efficiency`` given. The message names the key.
    """
    if doc.get("schema_version") != 1:
        raise GroundError(f"{source}: schema_version must be 1")
    name = doc.get("name")
    if not isinstance(name, str) or not name:
        raise GroundError(f"{source}: name must be a non-empty string")
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise GroundError(f"{source}: description must be a string")
    extra = sorted(set(doc) - {"schema_version", "name", "description", "traction", "regions"})
    if extra:
        raise GroundError(f"{source}: unknown key(s) or table(s): {', '.join(extra)}")
    traction = doc.get("traction", {})
    regions = doc.get("regions", {})
    if not isinstance(traction, dict) or not isinstance(regions, dict):
        raise GroundError(f"{source}: [traction] and [regions] must be tables")
    unknown = sorted(set(traction) - set(GROUND_PARAMETERS) - {"turn_efficiency"})
    if unknown:
        raise GroundError(
            f"{source}: unknown key(s) in [traction]: {', '.join(unknown)} (known: "
            f"{', '.join(GROUND_PARAMETERS)}, turn_efficiency)"
        )
    values: dict[str, float] = {}
    for key, value in [*traction.items(), *((f"region.{k}", v) for k, v in regions.items())]:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise GroundError(f"{source}: {key} must be a number, got {value!r}")
        values[key] = float(value)
    target = values.pop("turn_efficiency", None)
    base = Ground.of_rover(rover)
    ground = replace(base, name=name, description=description)
    try:
        ground = ground.with_values(**values)
    except GroundError as exc:
        raise GroundError(f"{source}: {exc}") from None
    if target is not None and "mu_lateral" in traction:
        _check_turn_efficiency(rover, ground, target, source)
    elif target is not None:
        ground = replace(ground, mu_lateral=solve_mu_lateral(rover, ground, target))
    return ground


def _check_turn_efficiency(
    rover: RoverDescription, ground: Ground, stated: float, source: str
) -> None:
    """Check a stated ``turn_efficiency`` against ``ground``'s ``mu_lateral`` (within
    :data:`TURN_EFFICIENCY_AGREEMENT`).

    Raises:
        GroundError: they do not (the message gives what ``mu_lateral`` turns at).
    """
    from emulator.playback import measure_turn_efficiency  # noqa: PLC0415 - a cycle

    if not (math.isfinite(stated) and 0.0 < stated < 1.0):
        raise GroundError(f"{source}: turn_efficiency must be in (0, 1), got {stated}")
    got = measure_turn_efficiency(
        ground.rover(rover), distance=rover.turn_units_for_yaw(math.pi / 2)
    )
    if abs(got - stated) > TURN_EFFICIENCY_AGREEMENT:
        raise GroundError(
            f"{source}: mu_lateral {ground.mu_lateral:g} and turn_efficiency {stated:g} "
            f"disagree: with that mu_lateral this ground turns at {got:.3f} (give "
            f"one, or both within {TURN_EFFICIENCY_AGREEMENT:g})"
        )


def load_ground(name_or_path: str | Path, rover: RoverDescription) -> Ground:
    """Read a ground file.

    Args:
        name_or_path: a shipped ground's bare name (``"loose"``) or a TOML path (one
            containing ``/`` or ending in ``.toml``).
        rover: the rover description that supplies the parameters the file leaves out.

    Raises:
        GroundError: unknown name (listing the shipped ones), unreadable file, not TOML,
            or invalid (see :func:`ground_from_dict`).
    """
    text_arg = str(name_or_path)
    if isinstance(name_or_path, Path) or "/" in text_arg or text_arg.endswith(".toml"):
        path = Path(name_or_path)
    else:
        known = list_grounds()
        if text_arg not in known:
            raise GroundError(f"no shipped ground {text_arg!r}; known: {', '.join(known)}")
        path = GROUNDS_DIR / f"{text_arg}.toml"
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise GroundError(f"cannot read ground file {path}: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise GroundError(f"{path}: not valid TOML: {exc}") from exc
    ground = ground_from_dict(doc, rover, str(path))
    logger.debug("loaded ground %s from %s", ground.name, path)
    return ground


def parse_ground_setting(text: str) -> tuple[str, float]:
    """``KEY=VALUE`` of ``--ground-set`` (``mu_lateral=0.7``, ``region.sandbox=0.3``,
    ``turn_efficiency=0.42``).

    Raises:
        GroundError: not ``KEY=VALUE`` with a number.
    """
    key, sep, value = text.partition("=")
    key = key.strip()
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not sep or not key or not math.isfinite(number):
        raise GroundError(f"--ground-set {text!r}: expected KEY=NUMBER, e.g. mu_lateral=0.7")
    return key, number


def solve_mu_lateral(rover: RoverDescription, ground: Ground, turn_efficiency: float) -> float:
    """The ``mu_lateral`` that gives ``ground`` ``turn_efficiency`` in the calibration
    spin (docs/twin.md), to 1e-4: a bisection on ``log(mu_lateral)`` in
    ``[0.02, 5] * mu_longitudinal`` (efficiency falls as it rises).

    Raises:
        GroundError: ``turn_efficiency`` is outside what that range reaches.
    """
    from emulator.playback import measure_turn_efficiency  # noqa: PLC0415 - a cycle

    if not (math.isfinite(turn_efficiency) and 0.0 < turn_efficiency < 1.0):
        raise GroundError(f"turn_efficiency must be in (0, 1), got {turn_efficiency}")
    distance = rover.turn_units_for_yaw(math.pi / 2.0)

    def efficiency(log_mu: float) -> float:
        trial = replace(ground, mu_lateral=math.exp(log_mu)).rover(rover)
        return measure_turn_efficiency(trial, distance=distance)

    lo = math.log(0.02 * ground.mu_longitudinal)
    hi = math.log(5.0 * ground.mu_longitudinal)
    e_lo, e_hi = efficiency(lo), efficiency(hi)
    if not e_hi <= turn_efficiency <= e_lo:
        raise GroundError(
            f"turn_efficiency {turn_efficiency:g} is outside what this ground reaches "
            f"({e_hi:.3f}..{e_lo:.3f} for mu_lateral "
            f"{math.exp(lo):.3g}..{math.exp(hi):.3g})"
        )
    for _ in range(60):
        mid = (lo + hi) / 2.0
        e_mid = efficiency(mid)
        if abs(e_mid - turn_efficiency) <= _TURN_EFFICIENCY_TOLERANCE:
            return math.exp(mid)
        if e_mid > turn_efficiency:
            lo = mid
        else:
            hi = mid
    return math.exp((lo + hi) / 2.0)
