"""Fault injection: what can go wrong, when, and applying it to the emulator.

A fault is written as text, on the command line (``--inject``), on the control
interface or in code::

    KIND[:ARGS][@TRIGGER]

    slip:left=0.3          scale the friction of one side (left|right|both) to 30 %
    stall:right            lock the right side's wheels
    encoder-noise:left=40  add 40 distance units of 1-sigma noise to the left count
    encoder-dropout:left   the left encoder stops counting and flags an error
    imu-bias=0.05          add 0.05 rad/s to the yaw rate
    imu-dropout            the IMU goes silent
    pose-dropout           the pose sensor loses its fix
    reboot                 the controller resets (new boot nonce)
    link-drop=0.05         drop 5 % of frames, both directions
    link-corrupt=0.01      flip a bit in 1 % of frames (serial only)
    link-delay=0.2         delay every frame by 0.2 s
    clear:slip             undo a fault kind (clear:stall:right for one side)

    @t=5                   at twin time 5 s
    @d=1.5                 after 1.5 m of ground travel
    @region=sand           when the rover's centre enters map region "sand"

:func:`parse_fault` checks the text; :class:`Injector` applies a fault to a controller,
its twin and its link, refusing (``InjectionError``) what cannot be applied, and logs
every injection with its time. :class:`FaultSchedule` fires triggered faults from the
control loop. Everything random (link faults) draws from a seeded generator.
"""

from __future__ import annotations

import logging
import math
import random
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

from emulator.errors import InjectionError
from firmware_proto.message import Message
from firmware_proto.messages import FaultCode

if TYPE_CHECKING:  # the CLI imports this module for its help text; keep it light
    from emulator.controller import ControllerModel

__all__ = [
    "FAULT_KINDS",
    "FaultSchedule",
    "FaultSpec",
    "InjectionRecord",
    "Injector",
    "LinkFaultTarget",
    "Trigger",
    "parse_fault",
]

logger = logging.getLogger(__name__)

FAULT_KINDS: dict[str, str] = {
    "slip": "side=scale: friction of a side scaled (0 < scale <= 1)",
    "stall": "side: that side's wheels locked",
    "encoder-noise": "side=units: 1-sigma noise on a side's count",
    "encoder-dropout": "side: a side's encoder stops counting and flags an error",
    "imu-bias": "=rad_s: constant yaw-rate bias",
    "imu-dropout": "the IMU goes silent",
    "pose-dropout": "the pose sensor loses its fix",
    "reboot": "the controller resets",
    "link-drop": "=ratio: frames dropped, 0..1",
    "link-corrupt": "=ratio: frames with a flipped bit, 0..1 (serial only)",
    "link-delay": "=seconds: every frame delayed",
    "clear": ":kind[:side]: undo a fault",
}
"""Every fault kind and its argument, for help texts."""

_SIDED = {"slip", "stall", "encoder-noise", "encoder-dropout"}
_VALUED = {"slip", "encoder-noise", "imu-bias", "link-drop", "link-corrupt", "link-delay"}


@dataclass(frozen=True)
class Trigger:
    """When a scheduled fault fires: at a twin time, after a ground distance, or on
    entering a map region. All ``None``: at once."""

    at_s: float | None = None
    after_m: float | None = None
    region: str | None = None

    def __str__(self) -> str:
        if self.at_s is not None:
            return f"@t={self.at_s:g}"
        if self.after_m is not None:
            return f"@d={self.after_m:g}"
        if self.region is not None:
            return f"@region={self.region}"
        return ""


@dataclass(frozen=True)
class FaultSpec:
    """One fault: its kind, side (``left``/``right``/``both`` or ``None``), value, and
    for ``clear`` the kind it undoes."""

    kind: str
    side: str | None = None
    value: float | None = None
    target: str | None = None
    trigger: Trigger = field(default_factory=Trigger)

    def __str__(self) -> str:
        text = self.kind
        if self.kind == "clear":
            text += f":{self.target}" + (f":{self.side}" if self.side else "")
        elif self.side is not None:
            text += f":{self.side}" + (f"={self.value:g}" if self.value is not None else "")
        elif self.value is not None:
            text += f"={self.value:g}"
        return text + str(self.trigger)


def _parse_trigger(text: str) -> Trigger:
    key, sep, value = text.partition("=")
    if not sep:
        raise InjectionError(f"trigger '@{text}' must be @t=SECONDS, @d=METRES or @region=ID")
    if key == "region":
        if not value:
            raise InjectionError("@region needs a region id")
        return Trigger(region=value)
    try:
        number = float(value)
    except ValueError:
        raise InjectionError(f"trigger '@{text}': {value!r} is not a number") from None
    if not math.isfinite(number) or number < 0:
        raise InjectionError(f"trigger '@{text}' must be a finite number >= 0")
    if key == "t":
        return Trigger(at_s=number)
    if key == "d":
        return Trigger(after_m=number)
    raise InjectionError(f"unknown trigger '@{key}': use @t=, @d= or @region=")


def parse_fault(text: str) -> FaultSpec:
    """Parse ``KIND[:SIDE][=VALUE][@TRIGGER]`` (see the module doc).

    Raises:
        InjectionError: unknown kind, missing or bad side or value; names the problem
            and lists the kinds.
    """
    body, _, trig = text.strip().partition("@")
    trigger = _parse_trigger(trig) if trig else Trigger()
    head, _, value_text = body.partition("=")
    kind, _, side = head.partition(":")
    if kind not in FAULT_KINDS:
        raise InjectionError(f"unknown fault {kind!r}; known: {', '.join(FAULT_KINDS)}")
    if kind == "clear":
        target, _, side = side.partition(":")
        if target not in FAULT_KINDS or target in ("clear", "reboot"):
            raise InjectionError(f"clear needs a fault kind to undo, got {target!r}")
        return FaultSpec("clear", side or None, None, target, trigger)
    if kind in _SIDED:
        if side not in ("left", "right", "both"):
            raise InjectionError(f"{kind} needs a side: {kind}:left, {kind}:right or {kind}:both")
    elif side:
        raise InjectionError(f"{kind} takes no side")
    value: float | None = None
    if kind in _VALUED:
        try:
            value = float(value_text)
        except ValueError:
            raise InjectionError(
                f"{kind} needs a number: {kind}{':' + side if side else ''}=VALUE"
            ) from None
        if not math.isfinite(value):
            raise InjectionError(f"{kind}: value must be finite")
    elif value_text:
        raise InjectionError(f"{kind} takes no value")
    return FaultSpec(kind, side or None, value, None, trigger)


class LinkFaultTarget(Protocol):
    """What a front end exposes for link faults."""

    def set_link_faults(
        self,
        *,
        drop: float | None = None,
        corrupt: float | None = None,
        delay_s: float | None = None,
    ) -> None:
        """Set any of the link fault levels; raise InjectionError if one cannot apply."""


@dataclass(frozen=True)
class InjectionRecord:
    """An applied injection: twin time, the fault, and who asked (cli, control, api,
    schedule)."""

    time_s: float
    fault: str
    source: str


class Injector:
    """Applies faults to a controller model, its twin and (optionally) its link.

    Call from the thread that owns the model. :attr:`log` lists every injection.
    """

    def __init__(self, model: ControllerModel, link: LinkFaultTarget | None = None) -> None:
        self.model = model
        self.link = link
        self.log: list[InjectionRecord] = []
        self._slip = [1.0, 1.0]

    def apply(self, spec: FaultSpec, source: str = "api") -> list[Message]:
        """Apply ``spec`` now (its trigger is the caller's business); returns messages the
        controller sends because of it (FAULT, IDENT).

        Raises:
            InjectionError: the fault cannot be applied here (e.g. a corrupting link
                fault on CAN, a scale out of range). Nothing is changed then.
        """
        out = self._apply(spec)
        record = InjectionRecord(self.model.now_s, str(spec), source)
        self.log.append(record)
        logger.info("injected %s at t=%.3f s (%s)", record.fault, record.time_s, source)
        return out

    def _sides(self, side: str | None) -> tuple[int, ...]:
        return {"left": (0,), "right": (1,), "both": (0, 1), None: (0, 1)}[side]

    def _apply(self, spec: FaultSpec) -> list[Message]:
        m = self.model
        kind, value = spec.kind, spec.value
        if kind == "slip":
            assert value is not None
            if not 0.0 < value <= 1.0:
                raise InjectionError(f"slip scale must be in (0, 1], got {value:g}")
            for s in self._sides(spec.side):
                self._slip[s] = value
            m.twin.set_traction_scale(self._slip[0], self._slip[1])
            return []
        if kind == "stall":
            for s in self._sides(spec.side):
                m.twin.set_wheel_locked(("left", "right")[s], True)
            return []
        if kind == "encoder-noise":
            assert value is not None
            if value < 0:
                raise InjectionError("encoder-noise must be >= 0")
            for s in self._sides(spec.side):
                m.encoders.noise_units[s] = value
            return []
        if kind == "encoder-dropout":
            for s in self._sides(spec.side):
                m.encoders.dropout[s] = True
            return m.raise_fault(FaultCode.ENCODER, condition=True)
        if kind == "imu-bias":
            assert value is not None
            m.imu.bias_rad_s = value
            return []
        if kind == "imu-dropout":
            m.imu.dropout = True
            return m.raise_fault(FaultCode.IMU, condition=True)
        if kind == "pose-dropout":
            m.pose_sensor.dropout = True
            return m.raise_fault(FaultCode.POSE, condition=True)
        if kind == "reboot":
            return m.reboot()
        if kind in ("link-drop", "link-corrupt", "link-delay"):
            return self._link(kind, value)
        if kind == "clear":
            return self._clear(spec)
        raise InjectionError(f"unknown fault {kind!r}")  # pragma: no cover - parse_fault guards

    def _link(self, kind: str, value: float | None) -> list[Message]:
        assert value is not None
        if self.link is None:
            raise InjectionError(f"{kind} needs a link: this emulator has no front end")
        if kind == "link-delay":
            if not 0.0 <= value <= 10.0:
                raise InjectionError(f"link-delay must be in 0..10 s, got {value:g}")
            self.link.set_link_faults(delay_s=value)
        else:
            if not 0.0 <= value <= 1.0:
                raise InjectionError(f"{kind} ratio must be in 0..1, got {value:g}")
            if kind == "link-drop":
                self.link.set_link_faults(drop=value)
            else:
                self.link.set_link_faults(corrupt=value)
        return []

    def _clear(self, spec: FaultSpec) -> list[Message]:
        m = self.model
        target = spec.target
        sides = self._sides(spec.side)
        if target == "slip":
            for s in sides:
                self._slip[s] = 1.0
            m.twin.set_traction_scale(self._slip[0], self._slip[1])
        elif target == "stall":
            for s in sides:
                m.twin.set_wheel_locked(("left", "right")[s], False)
        elif target == "encoder-noise":
            for s in sides:
                m.encoders.noise_units[s] = m.config.sensors.encoder_noise_units
        elif target == "encoder-dropout":
            for s in sides:
                m.encoders.dropout[s] = False
            if not any(m.encoders.dropout):
                return m.clear_fault_condition(FaultCode.ENCODER)
        elif target == "imu-bias":
            m.imu.bias_rad_s = m.config.sensors.imu_bias_rad_s
        elif target == "imu-dropout":
            m.imu.dropout = False
            return m.clear_fault_condition(FaultCode.IMU)
        elif target == "pose-dropout":
            m.pose_sensor.dropout = False
            return m.clear_fault_condition(FaultCode.POSE)
        elif target in ("link-drop", "link-corrupt", "link-delay"):
            if self.link is None:
                raise InjectionError(f"clear:{target} needs a link")
            key = {"link-drop": "drop", "link-corrupt": "corrupt", "link-delay": "delay_s"}[target]
            self.link.set_link_faults(**{key: 0.0})
        return []


class FaultSchedule:
    """Faults waiting for their trigger; :meth:`poll` fires the due ones, in order.

    Ground distance is integrated from the twin's pose at every poll.
    """

    def __init__(self, injector: Injector, faults: list[FaultSpec] | None = None) -> None:
        self.injector = injector
        self.pending: list[FaultSpec] = list(faults or [])
        twin = injector.model.twin
        self._last_xy = (twin.pose.x_m, twin.pose.y_m)
        self.ground_m = 0.0
        world = twin.world
        self._regions = {r.id: r.polygon for r in world.traction_regions} if world else {}
        for spec in self.pending:
            self._check_region(spec)

    def _check_region(self, spec: FaultSpec) -> None:
        region = spec.trigger.region
        if region is not None and region not in self._regions:
            known = ", ".join(sorted(self._regions)) or "none in this map"
            raise InjectionError(f"{spec}: unknown region {region!r} (regions: {known})")

    def add(self, spec: FaultSpec) -> None:
        """Schedule ``spec``; a spec without trigger fires at the next poll.

        Raises:
            InjectionError: its region does not exist in the map.
        """
        self._check_region(spec)
        self.pending.append(spec)

    def poll(self) -> list[Message]:
        """Fire every fault whose trigger is met; returns the controller's messages."""
        twin = self.injector.model.twin
        pose = twin.pose
        self.ground_m += math.hypot(pose.x_m - self._last_xy[0], pose.y_m - self._last_xy[1])
        self._last_xy = (pose.x_m, pose.y_m)
        if not self.pending:
            return []
        out: list[Message] = []
        keep = []
        for spec in self.pending:
            if self._due(spec, twin.time_s, pose.x_m, pose.y_m):
                try:
                    out += self.injector.apply(spec, source="schedule")
                except InjectionError as exc:
                    logger.error("scheduled fault %s refused: %s", spec, exc)
            else:
                keep.append(spec)
        self.pending = keep
        return out

    def _due(self, spec: FaultSpec, now_s: float, x: float, y: float) -> bool:
        t = spec.trigger
        if t.at_s is not None:
            return now_s + 1e-9 >= t.at_s
        if t.after_m is not None:
            return self.ground_m >= t.after_m
        if t.region is not None:
            return _inside(x, y, self._regions[t.region])
        return True


def _inside(x: float, y: float, polygon: tuple[tuple[float, float], ...]) -> bool:
    """Point in polygon (even-odd rule)."""
    inside = False
    n = len(polygon)
    for i in range(n):
        (x1, y1), (x2, y2) = polygon[i], polygon[(i + 1) % n]
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def seeded_rng(seed: int) -> random.Random:
    """The generator link faults draw from, derived from the emulator's seed."""
    return random.Random(f"link-faults-{seed}")
