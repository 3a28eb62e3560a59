"""Gate settings: defaults, ranges, and where each value comes from.

:func:`load_config` is the one place that decides precedence: command-line arguments,
then the environment (``ROVER_GATE_<KEY>``, e.g. ``ROVER_GATE_PORT``), then a TOML file
(``[gate]`` table, same keys; its path from the ``config`` argument or
``ROVER_GATE_CONFIG``), then the defaults below. The keys are those of :data:`KEYS`.

Playback defaults (:class:`PlaybackSettings`) are what a request gets when it does not
override them in its query string; docs/gate.md explains each choice.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from firmware_proto.errors import BindPolicyError
from firmware_proto.http.bindpolicy import check_bind
from firmware_proto.http.limits import (
    DEFAULT_BODY_TIMEOUT_S,
    DEFAULT_HEAD_TIMEOUT_S,
    DEFAULT_IDLE_TIMEOUT_S,
    DEFAULT_MAX_CONNECTIONS,
    DEFAULT_MAX_CONNECTIONS_PER_ADDRESS,
)
from gate.errors import GateConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = [
    "DEFAULT_BODY_TIMEOUT_S",
    "DEFAULT_DRAIN_TIMEOUT_S",
    "DEFAULT_DT_S",
    "DEFAULT_HEAD_TIMEOUT_S",
    "DEFAULT_HOST",
    "DEFAULT_IDLE_TIMEOUT_S",
    "DEFAULT_MAP",
    "DEFAULT_MAX_BODY_BYTES",
    "DEFAULT_MAX_CONNECTIONS",
    "DEFAULT_MAX_CONNECTIONS_PER_ADDRESS",
    "DEFAULT_POOL",
    "DEFAULT_PORT",
    "DEFAULT_POSITION_TOLERANCE_M",
    "DEFAULT_QUEUE_DEPTH",
    "DEFAULT_REQUEST_TIMEOUT_S",
    "DEFAULT_SAFETY_MARGIN_M",
    "DEFAULT_SAMPLE_HZ",
    "DEFAULT_SLIP_SIGMA",
    "DEFAULT_YAW_TOLERANCE_DEG",
    "ENV_PREFIX",
    "KEYS",
    "MAX_TRAJECTORY_SAMPLES",
    "POOL_KINDS",
    "GateConfig",
    "PlaybackSettings",
    "default_workers",
    "load_config",
]

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
DEFAULT_MAP = "lab"
DEFAULT_POOL = "process"
POOL_KINDS = ("process", "thread")
DEFAULT_QUEUE_DEPTH = 16
"""Validations admitted beyond the running ones; more get 503 with Retry-After."""
DEFAULT_MAX_BODY_BYTES = 64 * 1024
"""A maximal Listing 1 plan is under 1 KiB; 64 KiB leaves room for any formatting."""
DEFAULT_REQUEST_TIMEOUT_S = 60.0
"""Longest wait for a worker's answer, s (well beyond the slowest valid plan's validation)."""
DEFAULT_DRAIN_TIMEOUT_S = 30.0
"""On shutdown, how long in-flight requests may take to finish."""

DEFAULT_DT_S = 0.01
"""The twin's fixed step for validation, s (``emulator.twin.GATE_DT_S``): plans end within a tenth
of the tolerances of the 1 ms reference, far faster (docs/gate.md has the measurements)."""
DEFAULT_SAMPLE_HZ = 10.0
"""Predicted trajectory rate: at top speed 3 cm and about 4 degrees between samples."""
DEFAULT_SAFETY_MARGIN_M = 0.10
"""Footprint inflation for collisions, m: covers the twin's error and keeps the 0.9 m passages
(SCN-03) open to the 0.5 m wide rover."""
DEFAULT_POSITION_TOLERANCE_M = 0.10
"""Largest accepted distance between the predicted final position and the goal."""
DEFAULT_YAW_TOLERANCE_DEG = 3.0
"""Largest accepted final yaw error, deg."""
DEFAULT_SLIP_SIGMA = 0.1
"""1-sigma of each side's log-normal friction factor in a verdict with uncertainty, unless the
request or a calibrated twin says otherwise: a side grips about 10 % more or less (docs/gate.md)."""
MAX_TRAJECTORY_SAMPLES = 10_000
"""Most samples in a verdict's trajectory, a constant so verdicts match everywhere: a slower rate
keeps a response under about 1 MB when the requested one would give more (docs/gate.md)."""

ENV_PREFIX = "ROVER_GATE_"

_MAX_DT_S = 0.02  # emulator.twin.MAX_DT_S (not imported: this module stays light)


def default_workers() -> int:
    """One worker per CPU core (the playback is CPU-bound)."""
    return max(1, os.cpu_count() or 1)


def _check_range(name: str, value: float, low: float, high: float, *, open_low: bool) -> None:
    ok = math.isfinite(value) and (value > low if open_low else value >= low) and value <= high
    if not ok:
        bracket = "(" if open_low else "["
        raise GateConfigError(f"{name} must be in {bracket}{low}, {high}], got {value}")


@dataclass(frozen=True)
class PlaybackSettings:
    """How plans are played and judged, unless a request overrides it.

    Attributes:
        dt_s: the twin's fixed physics step, s (server-wide, not per request).
        sample_hz: predicted trajectory rate, Hz.
        safety_margin_m: footprint inflation for collision checks, m.
        position_tolerance_m: accepted final distance from the goal, m.
        yaw_tolerance_deg: accepted final yaw error, degrees.
        slip_sigma: the slip spread of a verdict with uncertainty (a calibrated twin's
            own estimate, ``rover gate --twin``; else :data:`DEFAULT_SLIP_SIGMA`).
    """

    dt_s: float = DEFAULT_DT_S
    sample_hz: float = DEFAULT_SAMPLE_HZ
    safety_margin_m: float = DEFAULT_SAFETY_MARGIN_M
    position_tolerance_m: float = DEFAULT_POSITION_TOLERANCE_M
    yaw_tolerance_deg: float = DEFAULT_YAW_TOLERANCE_DEG
    slip_sigma: float = DEFAULT_SLIP_SIGMA

    def __post_init__(self) -> None:
        _check_range("dt_s", self.dt_s, 0.0, _MAX_DT_S, open_low=True)
        _check_range("sample_hz", self.sample_hz, 0.0, 1.0 / self.dt_s, open_low=True)
        _check_range("safety_margin_m", self.safety_margin_m, 0.0, 1.0, open_low=False)
        _check_range("position_tolerance_m", self.position_tolerance_m, 0.0, 10.0, open_low=True)
        _check_range("yaw_tolerance_deg", self.yaw_tolerance_deg, 0.0, 180.0, open_low=True)
        _check_range("slip_sigma", self.slip_sigma, 0.0, 1.0, open_low=False)


@dataclass(frozen=True)
class GateConfig:
    """Everything a gate server needs; build it with :func:`load_config` or directly.

    Attributes:
        host, port: where to listen (port 0 picks a free one).
        token: bearer token every request must carry; ``None`` for none. Required when
            ``host`` is not a loopback address.
        default_map: map for requests that do not name one: a shipped map's name or a
            JSON file (which is then served too, under its own name).
        rover_path: rover description TOML; ``None`` for the packaged one.
        workers: validations run in parallel.
        pool: ``"process"`` or ``"thread"`` (:mod:`gate.pool`).
        queue_depth: validations admitted to wait beyond the running ones.
        max_body_bytes: largest accepted request body.
        max_connections: open connections at once (beyond it, docs/gate.md
            "Capacity, keep-alive and shutdown"; :attr:`reserved_connections` are kept
            for the token).
        max_connections_per_address: of those, from one address.
        idle_timeout_s: a connection waiting this long for a request to start is closed.
        head_timeout_s: from a request's first byte to the end of its headers (408).
        body_timeout_s: from the end of the headers to the end of the body (408).
        request_timeout_s: longest wait for a worker's answer.
        drain_timeout_s: on shutdown, longest wait for in-flight requests.
        playback: defaults of the playback and verdict.
        cluster: address of a Dask scheduler (``tcp://host:port``) that plays the
            chunks of verdicts with uncertainty; ``None``: the local pool does.
        allowed_hosts: further names the gate answers to in ``Host`` (beside its
            address, ``localhost`` on loopback, the machine's name on a wildcard bind);
            any other is 421.

    Raises:
        GateConfigError: a value is out of range, or a non-loopback host has no token.
    """

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    token: str | None = field(default=None, repr=False)
    default_map: str = DEFAULT_MAP
    rover_path: str | None = None
    workers: int = field(default_factory=default_workers)
    pool: str = DEFAULT_POOL
    queue_depth: int = DEFAULT_QUEUE_DEPTH
    max_body_bytes: int = DEFAULT_MAX_BODY_BYTES
    max_connections: int = DEFAULT_MAX_CONNECTIONS
    max_connections_per_address: int = DEFAULT_MAX_CONNECTIONS_PER_ADDRESS
    idle_timeout_s: float = DEFAULT_IDLE_TIMEOUT_S
    head_timeout_s: float = DEFAULT_HEAD_TIMEOUT_S
    body_timeout_s: float = DEFAULT_BODY_TIMEOUT_S
    request_timeout_s: float = DEFAULT_REQUEST_TIMEOUT_S
    drain_timeout_s: float = DEFAULT_DRAIN_TIMEOUT_S
    playback: PlaybackSettings = field(default_factory=PlaybackSettings)
    cluster: str | None = None
    allowed_hosts: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise GateConfigError(f"port must be in 0..65535, got {self.port}")
        try:
            check_bind(self.host, self.token, hint="--token-file (or ROVER_GATE_TOKEN)")
        except BindPolicyError as exc:
            raise GateConfigError(str(exc)) from exc
        if self.pool not in POOL_KINDS:
            raise GateConfigError(f"pool must be one of {', '.join(POOL_KINDS)}, got {self.pool!r}")
        for name, value, low in (
            ("workers", self.workers, 1),
            ("queue_depth", self.queue_depth, 0),
            ("max_body_bytes", self.max_body_bytes, 1024),
            ("max_connections", self.max_connections, 1),
            ("max_connections_per_address", self.max_connections_per_address, 1),
        ):
            if value < low:
                raise GateConfigError(f"{name} must be >= {low}, got {value}")
        for name, seconds in (
            ("idle_timeout_s", self.idle_timeout_s),
            ("head_timeout_s", self.head_timeout_s),
            ("body_timeout_s", self.body_timeout_s),
            ("request_timeout_s", self.request_timeout_s),
            ("drain_timeout_s", self.drain_timeout_s),
        ):
            _check_range(name, seconds, 0.0, 3600.0, open_low=True)

    @property
    def reserved_connections(self) -> int:
        """Connections kept for those that have shown the token: a quarter of
        ``max_connections``, at most 64; none without a token."""
        return 0 if self.token is None else min(64, self.max_connections // 4)

    @property
    def capacity(self) -> int:
        """Validations admitted at once: ``workers + queue_depth``."""
        return self.workers + self.queue_depth


def _names(text: str) -> tuple[str, ...]:
    """A comma-separated list of names."""
    return tuple(n.strip() for n in text.split(",") if n.strip())


_PLAYBACK_KEYS = (
    "dt_s",
    "sample_hz",
    "safety_margin_m",
    "position_tolerance_m",
    "yaw_tolerance_deg",
)

KEYS: dict[str, Callable[[str], Any]] = {
    "host": str,
    "port": int,
    "token": str,
    "default_map": str,
    "rover_path": str,
    "workers": int,
    "pool": str,
    "queue_depth": int,
    "max_body_bytes": int,
    "max_connections": int,
    "max_connections_per_address": int,
    "idle_timeout_s": float,
    "head_timeout_s": float,
    "body_timeout_s": float,
    "request_timeout_s": float,
    "drain_timeout_s": float,
    "dt_s": float,
    "sample_hz": float,
    "safety_margin_m": float,
    "position_tolerance_m": float,
    "yaw_tolerance_deg": float,
    "cluster": str,
    "allowed_hosts": _names,
}
"""Every settable key and how its text form (environment) is parsed."""


def _from_file(path: Path) -> dict[str, Any]:
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise GateConfigError(f"cannot read gate config {path}: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise GateConfigError(f"{path}: not valid TOML: {exc}") from exc
    table = doc.get("gate", {})
    if not isinstance(table, dict) or set(doc) - {"gate"}:
        raise GateConfigError(f"{path}: expected only a [gate] table")
    unknown = sorted(set(table) - set(KEYS))
    if unknown:
        raise GateConfigError(f"{path}: unknown key(s) in [gate]: {', '.join(unknown)}")
    out: dict[str, Any] = {}
    for key, value in table.items():
        parse = KEYS[key]
        if parse is _names:
            ok = isinstance(value, list) and all(isinstance(v, str) for v in value)
        elif parse is float:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        elif parse is int:
            ok = isinstance(value, int) and not isinstance(value, bool)
        else:
            ok = isinstance(value, str)
        if not ok:
            raise GateConfigError(
                f"{path}: [gate] {key} has the wrong type ({type(value).__name__})"
            )
        if parse is _names:
            out[key] = tuple(value)
        else:
            out[key] = float(value) if parse is float else value
    return out


def load_config(
    args: Mapping[str, Any] | None = None,
    environ: Mapping[str, str] | None = None,
    config_path: str | Path | None = None,
) -> GateConfig:
    """Build the configuration: arguments, then environment, then file, then defaults.

    Args:
        args: command-line values by :data:`KEYS`; ``None`` counts as not given.
        environ: default ``os.environ`` (names: the module docstring).
        config_path: a TOML file with a ``[gate]`` table; beats ``ROVER_GATE_CONFIG``.

    Raises:
        GateConfigError: an unknown key, a value that does not parse, a value out of range,
            an unreadable file, or the bind policy (see :class:`GateConfig`).
    """
    env = os.environ if environ is None else environ
    given = {k: v for k, v in (args or {}).items() if v is not None}
    unknown = sorted(set(given) - set(KEYS))
    if unknown:
        raise GateConfigError(f"unknown setting(s): {', '.join(unknown)}")
    path = config_path if config_path is not None else env.get(ENV_PREFIX + "CONFIG")
    merged: dict[str, Any] = _from_file(Path(path)) if path else {}
    for key, parse in KEYS.items():
        text = env.get(ENV_PREFIX + key.upper())
        if text is not None and text != "":
            try:
                merged[key] = parse(text)
            except ValueError as exc:
                raise GateConfigError(f"{ENV_PREFIX}{key.upper()}: {exc}") from exc
    merged.update(given)
    playback = PlaybackSettings(**{k: merged.pop(k) for k in _PLAYBACK_KEYS if k in merged})
    try:
        return GateConfig(playback=playback, **merged)
    except TypeError as exc:  # pragma: no cover - KEYS and GateConfig agree (tested)
        raise GateConfigError(str(exc)) from exc
