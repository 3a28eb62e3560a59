"""Request options of ``POST /validate_plan``, carried in the query string.

The body is exactly a Listing 1 plan (``additionalProperties: false``), so everything
else rides in the query: ``/validate_plan?map=scn02&start=1.0,2.0,90&render=1``.

The parameters (``map``, ``start`` as ``x,y,yaw_deg``, ``render``, ``margin_m``,
``pos_tol_m``, ``yaw_tol_deg``, ``sample_hz``, ``samples``, ``seed``, ``slip_sigma``,
``start_sigma_m``, ``start_sigma_deg``),
with their units, defaults and ranges: docs/gate.md's table under "POST /validate_plan",
and this server's ``/openapi.json``.

Parsing is strict, like the body: an unknown or repeated parameter, an empty value, or
a number that is not a plain finite decimal is an :class:`~gate.errors.OptionError`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from urllib.parse import parse_qsl, quote

from firmware_proto.model.pose import Pose
from gate.config import DEFAULT_SLIP_SIGMA, PlaybackSettings
from gate.errors import OptionError

__all__ = [
    "DEFAULT_SAMPLES",
    "DEFAULT_SEED",
    "DEFAULT_SLIP_SIGMA",
    "OPTION_LIMITS",
    "QUERY_PARAMETERS",
    "ResolvedOptions",
    "ValidateOptions",
]

QUERY_PARAMETERS = (
    "map",
    "start",
    "render",
    "margin_m",
    "pos_tol_m",
    "yaw_tol_deg",
    "sample_hz",
    "samples",
    "seed",
    "slip_sigma",
    "start_sigma_m",
    "start_sigma_deg",
)
"""Every query parameter ``/validate_plan`` accepts, in canonical order."""

OPTION_LIMITS: dict[str, tuple[float, float]] = {
    "margin_m": (0.0, 1.0),
    "pos_tol_m": (0.001, 10.0),
    "yaw_tol_deg": (0.01, 180.0),
    "sample_hz": (0.1, 1000.0),
    "samples": (1, 2000),
    "seed": (0, 2**32 - 1),
    "slip_sigma": (0.0, 1.0),
    "start_sigma_m": (0.0, 1.0),
    "start_sigma_deg": (0.0, 45.0),
}
"""Inclusive ranges of the numeric options (``sample_hz`` is further capped at 1/dt)."""

DEFAULT_SAMPLES = 1
"""One playback on the nominal twin unless a request asks for more."""
DEFAULT_SEED = 0

# ASCII digits only: Python's \d and float() also take other scripts' digits (an
# Arabic-Indic three, a fullwidth five), which the documented plain decimal excludes.
_INTEGER = re.compile(r"[0-9]+")
_NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_TRUE = ("1", "true")
_FALSE = ("0", "false")


def _number(name: str, text: str) -> float:
    if not _NUMBER.fullmatch(text):
        raise OptionError(name, f"not a decimal number: {text!r}")
    value = float(text)
    if not math.isfinite(value):
        raise OptionError(name, f"not a finite number: {text!r}")
    return value + 0.0  # no negative zero


def _ranged(name: str, text: str) -> float:
    value = _number(name, text)
    low, high = OPTION_LIMITS[name]
    if not low <= value <= high:
        raise OptionError(name, f"must be in [{low:g}, {high:g}], got {value:g}")
    return value


def _integer(name: str, text: str) -> int:
    if not _INTEGER.fullmatch(text) or len(text) > 12:
        raise OptionError(name, f"not a plain non-negative integer: {text!r}")
    value = int(text)
    low, high = OPTION_LIMITS[name]
    if not low <= value <= high:
        raise OptionError(name, f"must be in [{low:g}, {high:g}], got {value}")
    return value


def _pose(name: str, text: str) -> Pose:
    parts = text.split(",")
    if len(parts) != 3:
        raise OptionError(name, f"expected x,y,yaw_deg (three numbers), got {text!r}")
    x, y, yaw = (_number(name, p.strip()) for p in parts)
    return Pose(x, y, yaw)


def _fmt(value: float) -> str:
    return repr(float(value))


@dataclass(frozen=True)
class ValidateOptions:
    """Options of one validation as the client gave them (``None``: server default).

    Attributes:
        map: map name.
        start: start pose; ``None`` for the map's.
        render: add a PNG of the top-down view to the verdict.
        safety_margin_m, position_tolerance_m, yaw_tolerance_deg, sample_hz: overrides
            of the server's playback defaults.
        samples: twins to play (``None``: one); ``seed``: the seed of their draws;
            ``slip_sigma``: the spread of each side's friction factor.
        start_sigma_m, start_sigma_deg: 1-sigma error of the start pose as measured
            (per position axis, m; heading, deg), e.g. the rest's own noise; each
            ``None``: the calibrated twin's (its rests').
    """

    map: str | None = None
    start: Pose | None = None
    render: bool = False
    safety_margin_m: float | None = None
    position_tolerance_m: float | None = None
    yaw_tolerance_deg: float | None = None
    sample_hz: float | None = None
    samples: int | None = None
    seed: int | None = None
    slip_sigma: float | None = None
    start_sigma_m: float | None = None
    start_sigma_deg: float | None = None

    @classmethod
    def from_query(cls, query: str) -> ValidateOptions:
        """Parse a query string (without the ``?``).

        Raises:
            OptionError: unknown, repeated or empty parameter, or a bad value.
        """
        if not query:
            return cls()
        try:
            pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=True)
        except ValueError as exc:
            raise OptionError("", f"malformed query string: {exc}") from exc
        seen: dict[str, str] = {}
        for name, value in pairs:
            if name not in QUERY_PARAMETERS:
                raise OptionError(name, f"unknown parameter; known: {', '.join(QUERY_PARAMETERS)}")
            if name in seen:
                raise OptionError(name, "given more than once")
            if value == "":
                raise OptionError(name, "empty value")
            seen[name] = value
        render_text = seen.get("render", "0").lower()
        if render_text not in _TRUE + _FALSE:
            raise OptionError("render", f"expected 0, 1, true or false, got {render_text!r}")

        def ranged(name: str) -> float | None:
            return _ranged(name, seen[name]) if name in seen else None

        def integer(name: str) -> int | None:
            return _integer(name, seen[name]) if name in seen else None

        return cls(
            map=seen.get("map"),
            start=_pose("start", seen["start"]) if "start" in seen else None,
            render=render_text in _TRUE,
            safety_margin_m=ranged("margin_m"),
            position_tolerance_m=ranged("pos_tol_m"),
            yaw_tolerance_deg=ranged("yaw_tol_deg"),
            sample_hz=ranged("sample_hz"),
            samples=integer("samples"),
            seed=integer("seed"),
            slip_sigma=ranged("slip_sigma"),
            start_sigma_m=ranged("start_sigma_m"),
            start_sigma_deg=ranged("start_sigma_deg"),
        )

    def to_query(self) -> str:
        """The query string that :meth:`from_query` parses back to these options (only
        the options that are set, in canonical order)."""
        parts: list[str] = []
        if self.map is not None:
            parts.append("map=" + quote(self.map, safe=""))
        if self.start is not None:
            s = self.start
            parts.append(f"start={_fmt(s.x)},{_fmt(s.y)},{_fmt(s.yaw_deg)}")
        if self.render:
            parts.append("render=1")
        for name, value in (
            ("margin_m", self.safety_margin_m),
            ("pos_tol_m", self.position_tolerance_m),
            ("yaw_tol_deg", self.yaw_tolerance_deg),
            ("sample_hz", self.sample_hz),
        ):
            if value is not None:
                parts.append(f"{name}={_fmt(value)}")
        for name, count in (("samples", self.samples), ("seed", self.seed)):
            if count is not None:
                parts.append(f"{name}={count}")
        for name, value in (
            ("slip_sigma", self.slip_sigma),
            ("start_sigma_m", self.start_sigma_m),
            ("start_sigma_deg", self.start_sigma_deg),
        ):
            if value is not None:
                parts.append(f"{name}={_fmt(value)}")
        return "&".join(parts)

    def resolve(self, defaults: PlaybackSettings, default_map: str) -> ResolvedOptions:
        """Fill what is not set from the server's defaults.

        Raises:
            OptionError: ``sample_hz`` above the twin's step rate (``1 / dt_s``).
        """
        sample_hz = defaults.sample_hz if self.sample_hz is None else self.sample_hz
        if sample_hz * defaults.dt_s > 1.0 + 1e-9:
            raise OptionError(
                "sample_hz", f"must be at most {1.0 / defaults.dt_s:g} (one sample per step)"
            )
        return ResolvedOptions(
            map=default_map if self.map is None else self.map,
            start=self.start,
            render=self.render,
            safety_margin_m=(
                defaults.safety_margin_m if self.safety_margin_m is None else self.safety_margin_m
            ),
            position_tolerance_m=(
                defaults.position_tolerance_m
                if self.position_tolerance_m is None
                else self.position_tolerance_m
            ),
            yaw_tolerance_deg=(
                defaults.yaw_tolerance_deg
                if self.yaw_tolerance_deg is None
                else self.yaw_tolerance_deg
            ),
            sample_hz=sample_hz,
            samples=DEFAULT_SAMPLES if self.samples is None else self.samples,
            seed=DEFAULT_SEED if self.seed is None else self.seed,
            slip_sigma=defaults.slip_sigma if self.slip_sigma is None else self.slip_sigma,
            start_sigma_m=self.start_sigma_m,
            start_sigma_deg=self.start_sigma_deg,
        )


@dataclass(frozen=True)
class ResolvedOptions:
    """Options with every default filled in (``start`` may still be ``None``: the map's
    start pose, resolved by the validator once the map is known; ``start_sigma_m`` and
    ``start_sigma_deg`` may be ``None``: the calibrated twin's). ``samples`` > 1 asks
    for a verdict with its uncertainty (:mod:`gate.ensemble`)."""

    map: str
    start: Pose | None
    render: bool
    safety_margin_m: float
    position_tolerance_m: float
    yaw_tolerance_deg: float
    sample_hz: float
    samples: int = DEFAULT_SAMPLES
    seed: int = DEFAULT_SEED
    slip_sigma: float = DEFAULT_SLIP_SIGMA
    start_sigma_m: float | None = None
    start_sigma_deg: float | None = None

    def to_query(self, start: Pose) -> str:
        """A query string that pins every option (with ``start`` made explicit), so that
        the same request on a server with other defaults gives the same verdict. The
        draws' options appear only when ``samples`` > 1."""
        many = self.samples > 1
        return ValidateOptions(
            map=self.map,
            start=start,
            render=self.render,
            safety_margin_m=self.safety_margin_m,
            position_tolerance_m=self.position_tolerance_m,
            yaw_tolerance_deg=self.yaw_tolerance_deg,
            sample_hz=self.sample_hz,
            samples=self.samples if many else None,
            seed=self.seed if many else None,
            slip_sigma=self.slip_sigma if many else None,
            start_sigma_m=self.start_sigma_m if many else None,
            start_sigma_deg=self.start_sigma_deg if many else None,
        ).to_query()
