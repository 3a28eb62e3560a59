"""Bridge parameters: defaults, validation, and one place that decides precedence.

:func:`load_params` merges, highest first: the command line, ROS parameters
(``--ros-args``, or the declared parameters of the rclpy node), environment variables
``ROVER_BRIDGE_<NAME>``, a parameters file (TOML or JSON, flat or under
``[rover_bridge.ros__parameters]``), then the defaults of :class:`BridgeParams`
(docs/bridge.md, "Parameters"). An unknown name or a bad value raises
:class:`~bridge.errors.ParameterError` naming the parameter, its source and what it must be.

The link goes to CAN when ``can_interface`` is set (``can://<interface>/<channel>`` with
``node_id``), else to ``device`` (a device path or any pyserial URL).
"""

from __future__ import annotations

import json
import math
import os
import sys
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from bridge.errors import ParameterError
from bridge.link.controllerlink import LinkConfig
from bridge.ros.rosport.contract import (
    CLEAR_EMERGENCY_STOP,
    COMMAND_STATUS,
    EMERGENCY_STOP,
    WHEEL_INSTRUCTIONS,
)
from bridge.ros.rosport.parameters import ParameterSpec
from firmware_proto.runtime.realtime import BRIDGE_PRIORITY
from firmware_proto.runtime.stall import DEFAULT_STALL_THRESHOLD_S
from firmware_proto.wire.messages import LINK_LOST_HEARTBEATS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "ENV_PREFIX",
    "BridgeParams",
    "check_params",
    "load_params",
    "parameter_specs",
]

ENV_PREFIX = "ROVER_BRIDGE_"


def _p(default: Any, description: str, *, runtime: bool = False) -> Any:
    """A parameter field: its default, what it is (with unit), and whether it can change
    while the bridge runs (``ros2 param set``); the others are read-only once started."""
    return field(default=default, metadata={"description": description, "runtime": runtime})


@dataclass(frozen=True)
class BridgeParams:
    """Everything the bridge node can be told. Topic names without a leading slash are
    relative to ``namespace`` (ROS 2 rules); ``/diagnostics`` stays global by convention.
    Each field is also a ROS parameter of the node (:func:`parameter_specs`).
    """

    device: str = _p("/dev/rover-motor", "serial device path or pyserial URL of the controller")
    baud: int = _p(115200, "serial line rate, bit/s (a pty ignores it)")
    can_interface: str = _p("", "python-can interface for a CAN link ('' = serial link)")
    can_channel: str = _p("can0", "CAN channel, e.g. rovercan0 or vcan0")
    node_id: int = _p(1, "the controller's CAN node id")
    heartbeat_hz: float = _p(10.0, "host heartbeat and HELLO repeat rate, Hz", runtime=True)
    ack_timeout_s: float = _p(
        0.05, "wait for a MOTION's ACK before sending it again, s", runtime=True
    )
    motion_retries: int = _p(3, "retransmissions of one MOTION before fault:no_ack", runtime=True)
    link_lost_beats: int = _p(
        LINK_LOST_HEARTBEATS,
        "controller heartbeats missed before fault:link_lost (more for a slow adapter or computer)",
    )
    reconnect_min_s: float = _p(0.1, "first reconnect delay after a failure, s", runtime=True)
    reconnect_max_s: float = _p(2.0, "longest reconnect delay (backoff doubles), s", runtime=True)
    auto_clear_watchdog: bool = _p(
        True,
        "clear a latch held by the controller's watchdog alone once the link is back",
        runtime=True,
    )
    namespace: str = _p("", "the node's namespace")
    ros_backend: str = _p(
        "rclpy-process",
        "ROS port backend: rclpy-process (ROS 2 in child processes: no middleware call can "
        "stall the controller link), rclpy (ROS 2 in this process) or inprocess (tests)",
    )
    topic_wheel_instructions: str = _p(WHEEL_INSTRUCTIONS, "steps in (Int16MultiArray)")
    topic_command_status: str = _p(COMMAND_STATUS, "step and link status out (String)")
    topic_emergency_stop: str = _p(EMERGENCY_STOP, "emergency stop in (Bool true)")
    topic_clear_stop: str = _p(CLEAR_EMERGENCY_STOP, "release the STOP latch (Empty)")
    topic_odom: str = _p("odom", "encoders + IMU odometry out (Odometry)")
    topic_ground_pose: str = _p("odom_ground", "the controller's ground-seeing POSE (Odometry)")
    topic_diagnostics: str = _p("/diagnostics", "diagnostics out (DiagnosticArray)")
    odom_frame: str = _p("odom", "frame of /odom", runtime=True)
    map_frame: str = _p("map", "frame of the ground-seeing pose", runtime=True)
    base_frame: str = _p("base_link", "the rover's body frame", runtime=True)
    publish_tf: bool = _p(
        True,
        "publish /tf: odom -> base_link from odometry, map -> odom from the ground-seeing "
        "POSE (where tf2_msgs is installed: a sourced ROS 2 has it, the PyPI wheels do not)",
    )
    diagnostics_hz: float = _p(
        1.0, "/diagnostics rate, Hz (also at once on a link change)", runtime=True
    )
    rover_description: str = _p("", "rover description file ('' = the packaged one)")
    record: str = _p(
        "",
        "traffic log file ('' records nothing): a serial frame log on a serial link, a "
        "python-can log chosen by suffix on CAN (docs/traffic-logs.md)",
    )
    rt_priority: int = _p(
        BRIDGE_PRIORITY,
        "real-time priority of the bridge's process, which holds the controller link "
        "(SCHED_RR, memory locked, where permitted; 0 = normal scheduling; "
        "docs/realtime.md)",
    )
    stall_ms: float = _p(
        DEFAULT_STALL_THRESHOLD_S * 1e3,
        "log a stall of the bridge's process or of a link thread longer than this, ms",
    )

    @property
    def url(self) -> str:
        """The transport URL (see :mod:`bridge.link.transport`)."""
        if self.can_interface:
            return f"can://{self.can_interface}/{self.can_channel}?node={self.node_id}"
        if "://" in self.device or self.baud == 115200:
            return self.device
        return f"{self.device}?baud={self.baud}"

    def link_config(self) -> LinkConfig:
        """The :class:`LinkConfig` these parameters describe."""
        return LinkConfig(
            url=self.url,
            ack_timeout_s=self.ack_timeout_s,
            motion_retries=self.motion_retries,
            link_lost_beats=self.link_lost_beats,
            heartbeat_s=1.0 / self.heartbeat_hz,
            reconnect_min_s=self.reconnect_min_s,
            reconnect_max_s=self.reconnect_max_s,
            auto_clear_watchdog=self.auto_clear_watchdog,
        )

    def to_dict(self) -> dict[str, Any]:
        """All values by name."""
        return asdict(self)


_TYPES = {f.name: f.type for f in fields(BridgeParams)}
_RANGES: dict[str, tuple[float, float]] = {
    "baud": (300, 12_000_000),
    "node_id": (1, 15),
    "heartbeat_hz": (1.0, 100.0),
    "ack_timeout_s": (0.001, 10.0),
    "motion_retries": (0, 20),
    "link_lost_beats": (1, 100),
    "reconnect_min_s": (0.01, 60.0),
    "reconnect_max_s": (0.01, 600.0),
    "diagnostics_hz": (0.1, 50.0),
    "rt_priority": (0, 99),
    "stall_ms": (1.0, 60_000.0),
}
_BACKENDS = ("rclpy-process", "rclpy", "inprocess")


def _coerce(name: str, value: Any, source: str) -> Any:
    kind = _TYPES[name]
    try:
        if kind == "bool":
            if isinstance(value, str):
                lowered = value.strip().lower()
                if lowered not in ("1", "0", "true", "false", "yes", "no", "on", "off"):
                    raise ValueError(value)
                return lowered in ("1", "true", "yes", "on")
            if not isinstance(value, bool):
                raise ValueError(value)
            return value
        if kind == "int":
            if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
                raise ValueError(value)
            return int(value, 0) if isinstance(value, str) else int(value)
        if kind == "float":
            if isinstance(value, bool):
                raise ValueError(value)
            number = float(value)
            if not math.isfinite(number):
                raise ValueError(value)
            return number
        if not isinstance(value, str):
            raise ValueError(value)
        return value
    except (TypeError, ValueError):
        raise ParameterError(
            f"parameter {name} ({source}): {value!r} is not a valid {kind}"
        ) from None


def check_params(params: BridgeParams) -> None:
    """Check every value and the rules between them.

    Raises:
        ParameterError: names the parameter and what it must be.
    """
    for name, (lo, hi) in _RANGES.items():
        value = getattr(params, name)
        if not lo <= value <= hi:
            raise ParameterError(f"parameter {name}: {value} is outside {lo:g}..{hi:g}")
    if params.reconnect_max_s < params.reconnect_min_s:
        raise ParameterError("parameter reconnect_max_s must be >= reconnect_min_s")
    if params.ros_backend not in _BACKENDS:
        raise ParameterError(
            f"parameter ros_backend: {params.ros_backend!r}; known: {', '.join(_BACKENDS)}"
        )
    if not params.can_interface and not params.device:
        raise ParameterError("parameter device: empty (or set can_interface for CAN)")
    if params.can_interface and not params.can_channel:
        raise ParameterError("parameter can_channel: required with can_interface")
    for name in _TYPES:
        if name.startswith("topic_") and not getattr(params, name):
            raise ParameterError(f"parameter {name}: empty topic name")


def _read_file(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ParameterError(f"cannot read parameters file {path}: {exc}") from exc
    try:
        doc: dict[str, Any] = json.loads(text) if path.suffix == ".json" else tomllib.loads(text)
    except (ValueError, tomllib.TOMLDecodeError) as exc:
        raise ParameterError(f"parameters file {path}: {exc}") from exc
    for key in ("rover_bridge", "/**"):
        section = doc.get(key)
        if isinstance(section, dict) and isinstance(section.get("ros__parameters"), dict):
            return dict(section["ros__parameters"])
    return doc


def load_params(
    overrides: Mapping[str, Any] | None = None,
    *,
    ros: Mapping[str, Any] | None = None,
    env: Mapping[str, str] | None = None,
    file: str | Path | None = None,
) -> BridgeParams:
    """Merge overrides > ROS parameters > environment > file > defaults, then validate.

    Args:
        overrides: values from the command line (``None`` values are ignored, so unset
            options do not override). Strings are converted to the parameter's type.
        ros: ROS parameters (``None`` values ignored), typed or as text.
        env: the environment (default ``os.environ``); only ``ROVER_BRIDGE_*`` is read.
        file: a TOML or JSON parameters file.

    Raises:
        ParameterError: unknown parameter, bad type or out of range; names it.
    """
    env = os.environ if env is None else env
    merged: dict[str, Any] = {}
    layers: list[tuple[str, Mapping[str, Any]]] = []
    if file is not None:
        layers.append((f"file {file}", _read_file(Path(file))))
    layers.append(
        (
            "environment",
            {
                key[len(ENV_PREFIX) :].lower(): value
                for key, value in env.items()
                if key.startswith(ENV_PREFIX)
            },
        )
    )
    layers.append(("ROS parameter", {k: v for k, v in (ros or {}).items() if v is not None}))
    layers.append(("command line", {k: v for k, v in (overrides or {}).items() if v is not None}))
    for source, layer in layers:
        for name, value in layer.items():
            if name not in _TYPES:
                known = ", ".join(sorted(_TYPES))
                raise ParameterError(f"unknown parameter {name!r} ({source}); known: {known}")
            merged[name] = _coerce(name, value, source)
    params = replace(BridgeParams(), **merged)
    check_params(params)
    return params


def parameter_specs(current: BridgeParams) -> list[ParameterSpec]:
    """Every bridge parameter as the node declares it: ``current`` values as defaults,
    descriptions and ranges from :class:`BridgeParams`, read-only unless it can change
    while the bridge runs."""
    specs = []
    for f in fields(BridgeParams):
        specs.append(
            ParameterSpec(
                name=f.name,
                default=getattr(current, f.name),
                description=f.metadata["description"],
                read_only=not f.metadata["runtime"],
                range=_RANGES.get(f.name),
            )
        )
    return specs
